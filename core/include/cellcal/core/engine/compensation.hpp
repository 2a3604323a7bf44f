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
//
// With model extensions and the ranges they were judged over (IdentifiedModel::beyond_data, the robot file's, see
// prediction.hpp's BeyondRange), the predicted sigma adds what the extensions may do beyond their data's joint ranges;
// a target whose joints lie farther beyond a range than the extensions were judged is one where their correction was
// never tested: its predicted sigma is infinite and, with max_predicted_sigma_m set, it is passed through uncorrected
// (never_judged) with the joint named. The same over the drivers of extensions no joint bounds
// (IdentifiedModel::beyond_drivers, prediction.hpp's DriverRange: a link's gravity across it, evaluated at q*; a
// thermal driver, which the publisher does not know at a target, is taken at 0, its campaign's reference).
//
// With a residual map (IdentifiedModel::residual_map: what the calibrated model still leaves where the robot was
// measured, residual_map.hpp), near those poses the real robot lands at the model's position plus the map's correction
// c(q): q* is the fixed point of q = IK(model, desired - c(q)) (c changes little with q, as B e does), and the
// predicted sigma adds the map's own (sqrt(sigma_model^2 + 3 sigma_map^2), sigma_map per axis, ResidualMap::
// sigmaBound_m). Farther from every measured pose than the map's distance nothing is added: it never extrapolates.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <optional>
#include <string>
#include <utility>

#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/residual_map.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

// What became of a target, as a code (counted per code by the compensation publisher); the values behind it are
// CompensationResult's fields, put in words only by describe().
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
  kNeverJudged,          // beyond what the extensions were judged on (CompensationResult::unjudged), passed through
  kBadInput,             // a servo setpoint of the wrong size or not finite (servo.hpp)
};
constexpr int kNumCompensationOutcomes = 11;
// "applied", "clamped", "unusable_model", "unreachable", "not_settled", "outside_calibration", "over_bound",
// "clamp_unreachable", "joint_jump", "never_judged", "bad_input". The wire's CompensationOutcome (idl/cellcal_msgs.idl) has these
// in this order, then the compensation publisher's own.
const char* outcomeName(CompensationOutcome o);

// A range of the data the model's extensions were fitted on, a joint's (BeyondRange) or a driver's (DriverRange), and
// where a joint solution lies against it: the joint's angle (rad) or the driver's value, in its unit.
struct RangeAt {
  std::optional<BeyondRange> joint;
  std::optional<DriverRange> driver;
  double at = 0;
  bool empty() const { return !joint && !driver; }
};
// "joint 2 at 131.0 deg lies 41.0 deg beyond [-90.0, 90.0] deg, the range its model extensions were fitted on; they
// were judged up to 10.0 deg beyond it" (prediction.hpp's unjudgedText); "" when empty.
std::string describe(const RangeAt& range);

struct CompensationResult {
  bool applied = false;
  bool clamped = false;
  CompensationOutcome outcome = CompensationOutcome::kUnusableModel;
  Pose corrected_in_tracker = Pose::Identity();
  Eigen::VectorXd q_rad;                   // joint solution the robot will move to (empty when refused)
  double correction_position_m = 0;        // of the correction as computed (before any clamping)
  double correction_orientation_rad = 0;
  // The identified model's predicted 1-sigma position error at q_rad (NaN without a covariance).
  double predicted_sigma_position_m = std::numeric_limits<double>::quiet_NaN();
  // The residual map's correction at q_rad (in the tracker frame), where it applies.
  bool residual_map_applied = false;
  Eigen::Vector3d residual_map_correction_m = Eigen::Vector3d::Zero();
  // Where the target's joint solution lies beyond what the model's extensions were judged on (beyond_data,
  // beyond_drivers), the range and where: passed through (never_judged), or with the guard off applied with an
  // infinite predicted sigma. Empty where judged.
  RangeAt unjudged;
  // It lies beyond the data the extensions were fitted on (a joint's range or a gap in it, a driver's range) but within
  // the distance they were judged there. The predicted sigma carries the error the region folds measured there; a
  // periodic term standing for an error that grows can still err more (docs/planning.md). False where unjudged. A flag,
  // not a sentence: compensate runs on the servo path, and only a program's review reads where (compensateProgram).
  bool beyond_data = false;
  // What the outcome was decided on, as values: the inverse kinematics' residual (unreachable, clamp_unreachable), the
  // joints' last move of the extended model's fixed point (not_settled; `settled_extensions`: false when only a
  // residual map was iterated), and the bounds taken from the settings (outside_calibration, over_bound, clamped).
  double ik_position_error_m = 0;
  double ik_orientation_error_rad = 0;
  double settle_move_rad = 0;
  bool settled_extensions = true;
  double bound_sigma_m = 0;
  double bound_correction_m = 0;
  double bound_correction_rad = 0;
};
// The words for a result: why it was refused or clamped; "" when applied in full (said or not beyond the data: the
// flag is the caller's to word, as kBeyondDataNote). The edge's only translation of the values above.
std::string describe(const CompensationResult& result);
// What the compensation publisher says with a target applied where beyond_data is set (its CompensatedTarget's reason
// starts with it; the decision travels as CompensatedTarget::beyond_data, which the publisher's stats, `cellcal cell`
// and `cellcal status` count).
inline constexpr const char* kBeyondDataNote = "corrected beyond the extensions' data, within the distance they were judged";

// The model compensation applies: a calibrated model (calibrated_model.hpp) and, optionally, a residual map. With a
// covariance, a target where the model's predicted position error (of the estimated kinematic parameters) exceeds
// CompensationSettings::max_predicted_sigma_m is passed through uncorrected; without one, no such guard.
struct IdentifiedModel : CalibratedModel {
  IdentifiedModel() = default;
  explicit IdentifiedModel(CalibratedModel model) : CalibratedModel(std::move(model)) {}
  // What the calibration still leaves where the robot was measured (a calibrated robot file's residual map; not
  // owned: it must outlive this model), and the rotation from the tracker frame it was made in into this model's
  // (identity when the registration is the same).
  const ResidualMap* residual_map = nullptr;
  Eigen::Matrix3d residual_map_rotation = Eigen::Matrix3d::Identity();
  // The joint ranges the extensions' data covered and how far beyond them they were judged (a calibrated robot file's
  // beyond_data); empty: not known, no such guard.
  std::vector<BeyondRange> beyond_data;
  // The same over the drivers of extensions no joint bounds (the robot file's beyond_drivers).
  std::vector<DriverRange> beyond_drivers;
};

// The residual map of a calibrated robot file (`calibrate --residual-map --save-robot`; none: nothing changes) attached
// to `model`: `start` must outlive it. The map was made in the tracker frame of the file's registration; its
// corrections turn with the base from there into the frame of model.params' base (the cell's registration, or the
// engine's estimate of it).
void attachResidualMap(const RobotFile& start, IdentifiedModel& model);
// Both things a calibrated robot file gives compensation beside the model: its residual map (as above) and, where the
// model's extensions are the file's (the same list, in any order), the file's beyond_data. The engine's later poses
// do not widen those ranges: it does not judge its extensions beyond its data.
void attachRobotFile(const RobotFile& start, IdentifiedModel& model);

CompensationResult compensate(const RobotModel& nominal, const IdentifiedModel& identified,
                              const Pose& desired_in_tracker, const Eigen::VectorXd& q_seed_rad,
                              const CompensationSettings& settings, const std::vector<Eigen::VectorXd>& path_rad = {});
// The geometric model.
CompensationResult compensate(const RobotModel& nominal, const Eigen::VectorXd& identified_params,
                              const Pose& desired_in_tracker, const Eigen::VectorXd& q_seed_rad,
                              const CompensationSettings& settings);

// What compensation does with a robot program: compensate() at each configuration q, the target the pose `nominal`
// commands there (its forward kinematics at q, in the tracker frame of nominal's frames), seeded at q. Before
// production: which of a program's targets the model corrects and which it passes through. A target passed through
// because the extensions were never judged there (unjudged) lies where the calibration's data never were; measuring
// the robot at that configuration brings it into the data of the next calibration (`cellcal plan cover`).
struct ProgramCompensation {
  std::vector<CompensationResult> results;  // one per configuration, in order
  int applied = 0;   // applied or clamped
  int unjudged = 0;  // passed through where the extensions were never judged
  int refused = 0;   // every other outcome: a predicted error over the guard, unreachable, over the bound, ...
  int beyond_data = 0;  // of the applied ones, those beyond the extensions' data (CompensationResult::beyond_data)
  // Per configuration, for those: the first range it lies beyond (describe(): "joint 2 at 40.0 deg lies 12.0 deg
  // beyond ..."); empty for the others.
  std::vector<RangeAt> beyond_data_at;
};
ProgramCompensation compensateProgram(const RobotModel& nominal, const IdentifiedModel& identified,
                                      const std::vector<Eigen::VectorXd>& program, const CompensationSettings& settings);

}  // namespace cellcal
