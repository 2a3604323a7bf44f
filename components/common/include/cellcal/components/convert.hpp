// Conversions between the wire types (idl/cellcal_msgs.idl, SI) and core's structs. No DDS entities here.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>

#include "cellcal/core/calibration_engine.hpp"
#include "cellcal/core/observation.hpp"
#include "cellcal/core/pairing.hpp"
#include "cellcal/core/se3.hpp"
#include "cellcal_msgs.h"

namespace cellcal::components {

JointSample toJointSample(const msg::JointState& m);
msg::JointState toJointState(const std::string& robot_id, std::int64_t stamp_ns, std::uint64_t sequence,
                             const Eigen::VectorXd& q_rad, bool settled);

TrackerSample toTrackerSample(const msg::TrackerPose& m);
// The reading of an observation (position, orientation unless position-only, covariance from its sigmas).
msg::TrackerPose toTrackerPose(const std::string& target_id, std::int64_t stamp_ns, std::uint64_t sequence,
                               const Observation& o);

msg::CalibrationState toCalibrationState(const CellRobot& robot, const CalibrationSnapshot& s, std::int64_t stamp_ns,
                                         std::uint64_t sequence);

// What a consumer needs of a CalibrationState: the full parameter vector of the robot's model (nominal values for
// parameters the message does not name). nullopt + error when the message does not fit the model.
struct ReceivedCalibration {
  std::uint64_t version = 0;
  msg::CalibrationHealth health = msg::HEALTH_UNCALIBRATED;
  Eigen::VectorXd params;
  std::vector<Extension> extensions;  // model extensions and their parameters (empty: geometric model)
  Eigen::VectorXd extension_params;
  std::uint32_t poses_used = 0;
  double verification_mean_position_m = 0;
  double residual_rms_position_m = 0;          // a-posteriori, over the recent poses
  std::uint64_t last_measurement_stamp_ns = 0;  // with version: tells a new calibration from a republished one
};
std::optional<ReceivedCalibration> fromCalibrationState(const RobotModel& model, const msg::CalibrationState& m,
                                                         std::string* error);

Pose toPose(const std::array<double, 3>& p_m, const std::array<double, 4>& q_xyzw);
void fromPose(const Pose& T, std::array<double, 3>& p_m, std::array<double, 4>& q_xyzw);

}  // namespace cellcal::components
