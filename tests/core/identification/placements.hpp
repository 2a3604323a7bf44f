// Test draws of where a robot stands in the tracker frame: a random placement (tracker 0-3 m away in x and y, any
// yaw, a slightly tilted base; a target 50-150 mm off the flange), and the same robot after the tracker moved
// (0.3-2 m, turned up to 90 deg). The config's seed is the robot's hidden errors: a moved copy keeps them.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <random>

#include "cellcal/core/model/inverse_kinematics.hpp"
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

// A target as an SMR in a nest on the flange: 0.1-0.2 mm off the flange axis in a random direction, 0-80 mm along it.
inline void nearAxisTarget(SimulationConfig& sc, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  const double off = (0.1 + 0.1 * u(rng)) * 1e-3, dir = 2 * kPi * u(rng);
  sc.tool_in_flange << off * std::cos(dir), off * std::sin(dir), 0.08 * u(rng), 0, 0, 0;
}

// A Cartesian grid at one tool orientation, as trackers are often run: n x n x n target positions in a cube of edge
// 0.3-0.5 m about the flange pose of a random configuration, at its orientation, as the nominal model's joints
// (inverse kinematics, each seeded from the last); positions it does not reach are left out. `edge_m` receives the edge.
inline std::vector<Eigen::VectorXd> gridAtOneOrientation(const SimulatedCell& cell, int n, std::mt19937_64& rng,
                                                         double* edge_m = nullptr) {
  std::uniform_real_distribution<double> u(0, 1);
  const RobotModel& m = cell.model();
  KinematicsData data(m);
  const Eigen::VectorXd centre_q = cell.randomConfigurations(1, rng).front();
  const Pose centre = forwardKinematics(m, data, m.nominal, centre_q);
  const double edge = 0.3 + 0.2 * u(rng);
  if (edge_m) *edge_m = edge;
  std::vector<Eigen::VectorXd> qs;
  Eigen::VectorXd seed_q = centre_q;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k) {
        Pose target = centre;
        target.translation() += edge * (Eigen::Vector3d(i, j, k) / (n - 1.0) - Eigen::Vector3d::Constant(0.5));
        const IkResult ik = solveInverseKinematics(m, m.nominal, target, seed_q);
        if (!ik.ok()) continue;
        qs.push_back(ik.q_rad);
        seed_q = ik.q_rad;
      }
  return qs;
}

}  // namespace cellcal::test
