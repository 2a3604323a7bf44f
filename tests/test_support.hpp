// Helpers shared by the tests: robot files and seeds.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdlib>
#include <random>
#include <string>

#include "cellcal/core/robot_yaml.hpp"

namespace cellcal::test {

inline RobotModel robot(const std::string& name) {
  return loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/" + name + ".yaml");
}

// A fresh random seed per run (so no test is tuned to one seed), reproducible with CELLCAL_TEST_SEED=<n>.
// The seed is printed and recorded in the test's XML properties.
inline std::uint64_t testSeed() {
  std::uint64_t seed;
  if (const char* env = std::getenv("CELLCAL_TEST_SEED")) {
    seed = std::strtoull(env, nullptr, 10);
  } else {
    seed = (static_cast<std::uint64_t>(std::random_device{}()) << 32) ^ std::random_device{}();
  }
  ::testing::Test::RecordProperty("seed", std::to_string(seed));
  std::printf("[   SEED   ] CELLCAL_TEST_SEED=%llu\n", static_cast<unsigned long long>(seed));
  return seed;
}

}  // namespace cellcal::test
