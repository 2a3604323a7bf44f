// Conversions between the wire types (idl/cellcal_msgs.idl, SI) and core's structs. No DDS entities here.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>

#include "cellcal/components/engine_host.hpp"
#include "cellcal/components/udp_lines.hpp"
#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/engine/pairing.hpp"
#include "cellcal/core/engine/pose_requests.hpp"
#include "cellcal/core/model/se3.hpp"
#include "cellcal_msgs.h"

namespace cellcal::components {

JointSample toJointSample(const msg::JointState& m);
msg::JointState toJointState(const std::string& robot_id, std::int64_t stamp_ns, std::uint64_t sequence,
                             const Eigen::VectorXd& q_rad, bool settled);

TrackerSample toTrackerSample(const msg::TrackerPose& m);
// The reading of an observation (position, orientation unless position-only, covariance from its sigmas).
msg::TrackerPose toTrackerPose(const std::string& target_id, std::int64_t stamp_ns, std::uint64_t sequence,
                               const Observation& o);
// A reading from a tracker bridge's line (udp_lines.hpp).
msg::TrackerPose toTrackerPose(const TrackerLine& line, std::int64_t stamp_ns, std::uint64_t sequence);
// The 6x6 covariance (row-major; position then orientation) of independent axes with these sigmas.
std::array<double, 36> readingCovariance(double sigma_position_m, double sigma_orientation_rad);

msg::CalibrationState toCalibrationState(const CellRobot& robot, const CalibrationSnapshot& s, std::int64_t stamp_ns,
                                         std::uint64_t sequence);
// The same into a sample kept per robot for every publish (the engine's path): its sequences keep their capacity and
// the parameter names are rebuilt only when the robot or the model extensions differ from the sample's. Equal on the
// wire to toCalibrationState's, whatever the sample held before.
void fillCalibrationState(const CellRobot& robot, const CalibrationSnapshot& s, std::int64_t stamp_ns,
                          std::uint64_t sequence, msg::CalibrationState& m);

// A robot's diagnostics as the engine publishes them: rejections by reason (and `inputs_refused` samples the engine's
// full input queue refused before any robot could be told), health, the stale inputs (`stale_inputs`, empty when
// fresh), persistence, identifiability and latencies.
msg::CalibrationDiagnostics toCalibrationDiagnostics(const EngineHost::Robot& robot, const std::string& stale_inputs,
                                                     std::uint64_t inputs_refused, std::int64_t stamp_ns,
                                                     std::uint64_t sequence);

// The engine's proposal on the wire (configurations row-major; at most 1024 values: 64 configurations of 16 joints).
msg::PoseRequest toPoseRequest(const std::string& robot_id, const PoseProposal& p, std::size_t candidates,
                               std::int64_t stamp_ns, std::uint64_t sequence);
// The configurations of a PoseRequest; nullopt + error when it does not fit a robot of `joints` joints.
std::optional<std::vector<Eigen::VectorXd>> fromPoseRequest(const msg::PoseRequest& m, int joints, std::string* error);

// What a consumer needs of a CalibrationState: the calibrated model (calibrated_model.hpp: the full parameter vector
// of the robot's model, nominal values for parameters the message does not name; the extensions and their values; the
// estimated kinematic parameters and their covariance from parameter_stddevs and parameter_correlations, empty when
// the sender sent no correlations; estimated_extension empty: the wire carries the kinematic block) and the version,
// health and statistics. nullopt + error when the message does not fit the model.
struct ReceivedCalibration : CalibratedModel {
  std::uint64_t version = 0;
  msg::CalibrationHealth health = msg::HEALTH_UNCALIBRATED;
  std::uint32_t poses_used = 0;
  double verification_mean_position_m = 0;
  double residual_rms_position_m = 0;          // a-posteriori, over the recent poses
  std::uint64_t last_measurement_stamp_ns = 0;  // with version: tells a new calibration from a republished one
};
std::optional<ReceivedCalibration> fromCalibrationState(const RobotModel& model, const msg::CalibrationState& m,
                                                         std::string* error);

// The wire's health as the engine names it ("uncalibrated", "ok", "degraded", "hold_last_good"; the IDL enum follows
// core's Health).
const char* healthText(msg::CalibrationHealth h);
// Why the health is not ok, as core names it ("none", "too_few_poses", ...; the IDL enum follows core's HealthCause).
const char* healthCauseText(msg::HealthCause c);

// A compensation outcome's name: core's (outcomeName: "applied", "unreachable", "never_judged", ...), then the
// publisher's own ("pass_through", "no_calibration", "no_good_calibration").
const char* outcomeText(msg::CompensationOutcome o);

Pose toPose(const std::array<double, 3>& p_m, const std::array<double, 4>& q_xyzw);
void fromPose(const Pose& T, std::array<double, 3>& p_m, std::array<double, 4>& q_xyzw);

}  // namespace cellcal::components
