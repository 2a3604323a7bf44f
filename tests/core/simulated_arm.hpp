// Simulated arms of the robot files and URDFs a test draws from, measured by a tracker: joint errors, a placement of
// tracker and target, readings of noise sigma_m (and sigma_rad, 6D). For tests of carried calibrations (the
// campaign's --frames-only, the engine's start from a calibration file).
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "cellcal/core/campaign/campaign_input.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal::test {

// The robot files of config/robots and, when ../shared is there, arms of its URDFs.
inline std::vector<RobotModel> armsToDraw(const std::vector<std::string>& urdfs) {
  std::vector<RobotModel> robots = {loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/ur10.yaml"),
                                    loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml")};
  const std::filesystem::path arms = std::filesystem::path(CELLCAL_CONFIG_DIR) / "../../shared/robots/ros-industrial";
  for (const auto& f : urdfs)
    if (std::filesystem::exists(arms / f)) robots.push_back(loadRobotModel((arms / f).string()));
  return robots;
}

// A simulated arm of `file` measured by a tracker: joint errors, a placement of tracker and target, readings.
struct SimulatedArm {
  const RobotModel& file;
  std::mt19937_64& rng;
  bool six_d = false;
  double sigma_m = 0.01e-3, sigma_rad = degToRad(0.001);
  double span = 0.8;  // of each joint's range (within +-180 deg), about its middle
  double u01() { return std::uniform_real_distribution<double>(0.0, 1.0)(rng); }
  double g() { return std::normal_distribution<double>(0.0, 1.0)(rng); }
  double signedIn(double lo, double hi) { return (u01() < 0.5 ? -1 : 1) * (lo + (hi - lo) * u01()); }
  // Every canonical joint parameter moved 0.1-0.5 mm or 0.01-0.05 deg, times `scale`.
  Eigen::VectorXd jointErrors(double scale) {
    Eigen::VectorXd e = Eigen::VectorXd::Zero(file.numParams());
    for (int i : file.canonicalParams())
      if (i < 5 * file.numJoints())
        e[i] = scale * (file.isLength(i) ? signedIn(1e-4, 5e-4) : degToRad(signedIn(0.01, 0.05)));
    return e;
  }
  Eigen::VectorXd configuration() {
    Eigen::VectorXd q(file.numJoints());
    for (int j = 0; j < file.numJoints(); ++j) {
      const auto& l = file.limits[static_cast<size_t>(j)];
      const double lo = std::max(l.lower_rad, -kPi), hi = std::min(l.upper_rad, kPi);
      q[j] = lo + (0.5 - span / 2 + span * u01()) * (hi - lo);
    }
    return q;
  }
  // `p` with a tracker 1-3 m away at any yaw and a target up to 15 cm from the flange at any orientation.
  Eigen::VectorXd placed(Eigen::VectorXd p) {
    p.segment<6>(file.baseParam(FrameParam::kX)) << signedIn(1.0, 3.0), signedIn(1.0, 3.0), signedIn(0, 0.5),
        signedIn(0, 0.2), signedIn(0, 0.2), signedIn(0, kPi);
    p.segment<6>(file.toolParam(FrameParam::kX)) << signedIn(0, 0.05), signedIn(0, 0.05), signedIn(0.05, 0.15),
        signedIn(0, kPi), signedIn(0, kPi), signedIn(0, kPi);
    return p;
  }
  MeasurementFile measure(const Eigen::VectorXd& truth, int n) {
    MeasurementFile f;
    KinematicsData data(file);
    for (int k = 0; k < n; ++k) {
      MeasurementRow row;
      row.line = k + 2;
      row.q_rad = configuration();
      const Pose T = forwardKinematics(file, data, truth, row.q_rad);
      row.position_m = T.translation() + sigma_m * Eigen::Vector3d(g(), g(), g());
      if (six_d) row.orientation = Eigen::Quaterniond(expSO3(sigma_rad * Eigen::Vector3d(g(), g(), g())) * T.linear());
      f.rows.push_back(row);
    }
    return f;
  }
  InputOptions options() const {
    InputOptions o;
    o.sigma_position_m = sigma_m;
    o.sigma_orientation_rad = sigma_rad;
    return o;
  }
};

}  // namespace cellcal::test
