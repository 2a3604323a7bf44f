// Compensation: what to send an unmodified controller (which believes the nominal model) so that the real robot,
// described by the identified parameters, lands on the desired pose.
//
//   q*        = IK(identified model, desired)           joints that put the real robot on the target
//   corrected = FK(nominal model, q*)                   the pose the controller must be commanded to reach q*
//   correction = corrected (-) desired                  translation norm (m) and rotation angle (rad)
//
// Poses are in the tracker (cell) frame, like TargetPose; a controller wanting its base frame applies the nominal
// base_in_tracker inverse. A correction beyond the bound is refused (the desired pose is returned unchanged,
// applied = false) or, with ExceedAction::kClamp, scaled down to the bound along the same direction.
//
// With model extensions (model_extension.hpp) the identified model's parameters depend on the joints:
// params(q) = params + B(q) e. q* is then the fixed point q = IK(params(q), desired), found by iterating from the seed
// (B e changes little with q: a joint error of 1e-4 rad changes by far less when q moves by it, so two or three
// passes settle to the solver tolerance). Backlash's play state is that of the path the robot took: `path_rad`, the
// joints it visited before, oldest first (e.g. the previous compensated targets; the last kPlayHistory matter), then a
// straight move to q*. Without a path: a straight move from the seed.
//
// Outside the region the model was calibrated in its correction is a guess: with the estimate's covariance
// (IdentifiedModel::covariance), the predicted 1-sigma position error at q* is sqrt(trace(J P J^T)) over the position
// rows (the kinematic part, as the engine's hold bound); above CompensationSettings::max_predicted_sigma_m the target
// is passed through uncorrected (applied = false) with the reason.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <string>

#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

// What became of a target, as a code (counted per code by the compensation publisher; the text is in `reason`,
// built only when the target is not applied in full).
enum class CompensationOutcome {
  kApplied,
  kClamped,              // applied, scaled down to the bound
  kUnusableModel,        // the identified parameters are the wrong size or not finite
  kUnreachable,          // the identified model's joints for the target were not found from the seed
  kNotSettled,           // with model extensions: the fixed point q = IK(params(q)) did not settle
  kOutsideCalibration,   // predicted 1-sigma error above max_predicted_sigma_m
  kOverBound,            // correction above the bound, refused
  kClampUnreachable,     // correction above the bound, and the clamped pose unreachable
  kJointJump,            // a servo setpoint's joints corrected by more than max_joint_correction_rad (servo.hpp)
};
constexpr int kNumCompensationOutcomes = 9;
// "applied", "clamped", "unusable_model", "unreachable", "not_settled", "outside_calibration", "over_bound",
// "clamp_unreachable", "joint_jump".
const char* outcomeName(CompensationOutcome o);

struct CompensationResult {
  bool applied = false;
  bool clamped = false;
  CompensationOutcome outcome = CompensationOutcome::kUnusableModel;
  std::string reason;                      // why not applied / clamped; empty when applied in full
  Pose corrected_in_tracker = Pose::Identity();
  Eigen::VectorXd q_rad;                   // joint solution the robot will move to (empty when refused)
  double correction_position_m = 0;        // of the correction as computed (before any clamping)
  double correction_orientation_rad = 0;
  // The identified model's predicted 1-sigma position error at q_rad (NaN without a covariance).
  double predicted_sigma_position_m = std::numeric_limits<double>::quiet_NaN();
};

struct IdentifiedModel {
  Eigen::VectorXd params;                  // full kinematic vector (RobotModel layout)
  std::vector<Extension> extensions;       // empty: the geometric model
  Eigen::VectorXd extension_params;
  // Covariance of the estimated kinematic parameters (indices into params): with it, a target where the model's
  // predicted position error exceeds CompensationSettings::max_predicted_sigma_m is passed through uncorrected.
  // Empty: no such guard.
  std::vector<int> estimated = {};
  Eigen::MatrixXd covariance = Eigen::MatrixXd();
};

CompensationResult compensate(const RobotModel& nominal, const IdentifiedModel& identified,
                              const Pose& desired_in_tracker, const Eigen::VectorXd& q_seed_rad,
                              const CompensationSettings& settings, const std::vector<Eigen::VectorXd>& path_rad = {});
// The geometric model.
CompensationResult compensate(const RobotModel& nominal, const Eigen::VectorXd& identified_params,
                              const Pose& desired_in_tracker, const Eigen::VectorXd& q_seed_rad,
                              const CompensationSettings& settings);

}  // namespace cellcal
