// Helpers shared by the tests: robot files and seeds.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/observation.hpp"

namespace cellcal::test {

// A file's whole content ("" when it cannot be read).
inline std::string readTextFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// A figure a command rendered with gnuplot: a PNG (its signature) or an SVG gnuplot produced, with some content.
inline ::testing::AssertionResult isGnuplotFigure(const std::string& path) {
  if (!std::ifstream(path)) return ::testing::AssertionFailure() << path << " does not exist";
  const std::string bytes = readTextFile(path);
  const bool png = bytes.rfind("\x89PNG\r\n\x1a\n", 0) == 0;
  const bool svg = bytes.find("<svg") != std::string::npos && bytes.find("Produced by GNUPLOT") != std::string::npos;
  if (!png && !svg) return ::testing::AssertionFailure() << path << " is neither a PNG nor a gnuplot SVG";
  if (bytes.size() < 10000) return ::testing::AssertionFailure() << path << " has only " << bytes.size() << " bytes";
  return ::testing::AssertionSuccess();
}

inline RobotModel robot(const std::string& name) {
  return loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/" + name + ".yaml");
}

// The TX60 and UR10 robot files, and the UR5 from its URDF where ../shared has it (issue #35's real grid was a UR5's).
inline std::vector<RobotModel> robotsWithUr5() {
  std::vector<RobotModel> robots = {robot("staubli_tx60"), robot("ur10")};
  const std::filesystem::path ur5 =
      std::filesystem::path(CELLCAL_CONFIG_DIR) / "../../shared/robots/ros-industrial/universal_robots/ur5.urdf";
  if (std::filesystem::exists(ur5)) robots.push_back(loadRobotFile(ur5.string()).model);
  return robots;
}

// The median of v (the upper one of an even count), 0 when v is empty.
inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

// The running test's full name ("Suite.Name", "Prefix/Suite.Name/3" for a parameterized one; "" outside a test).
inline std::string currentTestName() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  return info ? std::string(info->test_suite_name()) + "." + info->name() : std::string();
}

// The seed of the running test's random draws. Contract:
//  - unset CELLCAL_TEST_SEED: a fixed seed of the test's own (FNV-1a of its full name), so `make test` repeats run for
//    run and no two tests share one;
//  - CELLCAL_TEST_SEED=<n>: n, for every test (repeats a failure, or a sweep's draw);
//  - CELLCAL_TEST_SEED=random: a fresh seed (tools/sweep.sh passes numbers instead, so each failure it counts has
//    a seed to repeat).
// Every call within one test returns the same seed, except with `random`. It is printed with the command that
// repeats the test (ctest shows it for a failing test) and recorded in the test's XML properties.
inline std::uint64_t testSeed() {
  const std::string name = currentTestName();
  std::uint64_t seed = 14695981039346656037ull;
  for (char c : name) seed = (seed ^ static_cast<unsigned char>(c)) * 1099511628211ull;
  const char* env = std::getenv("CELLCAL_TEST_SEED");
  if (env != nullptr && std::string(env) == "random") {
    seed = (static_cast<std::uint64_t>(std::random_device{}()) << 32) ^ std::random_device{}();
  } else if (env != nullptr && *env != '\0') {
    char* end = nullptr;
    seed = std::strtoull(env, &end, 10);
    if (end == env || *end != '\0') {
      ADD_FAILURE() << "CELLCAL_TEST_SEED='" << env << "' is neither a number nor 'random'";
    }
  }
  ::testing::Test::RecordProperty("seed", std::to_string(seed));
  std::string self = "<test binary>";
  if (std::FILE* f = std::fopen("/proc/self/cmdline", "rb")) {
    char buf[512] = {0};
    if (std::fgets(buf, sizeof buf, f) != nullptr) self = buf;  // argv[0] ends at its NUL
    std::fclose(f);
  }
  std::printf("[   SEED   ] CELLCAL_TEST_SEED=%llu %s --gtest_filter='%s'\n", static_cast<unsigned long long>(seed),
              self.c_str(), name.c_str());
  std::fflush(stdout);
  return seed;
}

// A measurement file's row of a simulated reading at joints q (its orientation when the reading is 6D).
inline MeasurementRow measuredRow(const Eigen::VectorXd& q, const Observation& o) {
  MeasurementRow r;
  r.q_rad = q;
  r.position_m = o.measured_in_tracker.translation();
  if (o.kind == MeasurementKind::kPose6D) r.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
  return r;
}

}  // namespace cellcal::test
