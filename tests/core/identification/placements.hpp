// Test draws of where a robot stands in the tracker frame: a random placement (tracker 0-3 m away in x and y, any
// yaw, a slightly tilted base; a target 50-150 mm off the flange), and the same robot after the tracker moved
// (0.3-2 m, turned up to 90 deg). The config's seed is the robot's hidden errors: a moved copy keeps them.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <random>

#include "cellcal/core/sim/simulation.hpp"

namespace cellcal::test {

inline SimulationConfig randomPlacement(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  SimulationConfig sc;
  sc.seed = rng();
  sc.base_in_tracker << 3 * u(rng), 3 * u(rng), u(rng), 0.02 * u(rng), 0.02 * u(rng), kPi * u(rng);
  sc.tool_in_flange << 0.1 * u(rng), 0.1 * u(rng), 0.05 + 0.1 * std::abs(u(rng)), 0, 0, 0;
  return sc;
}

inline SimulationConfig trackerMoved(SimulationConfig sc, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  const Eigen::Vector3d dir = Eigen::Vector3d(u(rng), u(rng), 0.3 * u(rng)).normalized();
  sc.base_in_tracker.head<3>() += (0.3 + 1.7 * std::abs(u(rng))) * dir;
  sc.base_in_tracker[5] += 0.5 * kPi * u(rng);
  return sc;
}

}  // namespace cellcal::test
