// Compensation of a servo loop's setpoint stream (one setpoint per controller cycle: Universal Robots' servoj at
// 500 Hz, KUKA RSI and ABB EGM at 250 Hz), with the switch to a new calibration version blended over time.
//
// Each setpoint is answered as compensate() answers a target (compensation.hpp): a joint setpoint q_s stands for the
// pose the controller believes it commands, FK(nominal, q_s), and is answered with the joints q* that put the real
// robot there (seeded at q_s); a Cartesian setpoint is answered with q* and the nominal model's pose of q*, seeded at
// its joints (or the last answer's).
//
// A new calibration version does not step the stream: from the first setpoint after it arrived, the answer moves from
// the old version's solution to the new one's over blend_s of the setpoints' own stamps (the controller's cycle
// clock, not the wall clock: a replay gives the same answers),
//   q = q_old* + w (q_new* - q_old*),  w = (t - t_start) / blend_s clipped to [0, 1],
// so between consecutive setpoints dt apart the correction moves by at most |q_new* - q_old*| dt / blend_s on top of
// what the setpoints' own motion changes. A version arriving during a blend waits for it to finish (only the newest
// waits); the first version applies at once; blend_s = 0 switches at once. During a blend both versions are solved
// (twice the cost). A setpoint either version cannot answer (unreachable, predicted error or correction over the
// bounds, or joints moved by more than compensation.max_joint_correction_deg from the seed: near a singularity the
// identified model reaches the pose on another branch) is passed through unchanged with the reason: the caller sees
// applied = false.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>

#include "cellcal/core/engine/compensation.hpp"

namespace cellcal {

struct ServoAnswer {
  bool applied = false;
  CompensationOutcome outcome = CompensationOutcome::kUnusableModel;  // the failing version's when not applied
  Eigen::VectorXd q_rad;                      // joints to command (the setpoint's own when not applied)
  Pose commanded = Pose::Identity();          // the nominal model's pose of q_rad (what the controller believes)
  std::uint64_t version = 0;                  // blended to (0: no calibration yet)
  std::uint64_t from_version = 0;             // blended from (= version when not blending)
  double weight = 1.0;                        // of `version`
  // Applied where a version blended lies beyond its extensions' data, within the distance they were judged there
  // (CompensationResult::beyond_data of either).
  bool beyond_data = false;
  // What decided it, as values (describe() words them): the version whose answer refused or clamped the setpoint and
  // that answer; for a joint jump the largest joint move and the bound; for a bad setpoint its size and the robot's.
  std::uint64_t decided_by = 0;
  CompensationResult result;
  double joint_move_rad = 0, joint_move_bound_rad = 0;
  long setpoint_joints = 0, robot_joints = 0;
};
// Why a setpoint was passed through or clamped ("v3: predicted error ... : setpoint passed through"); "" when applied
// in full.
std::string describe(const ServoAnswer& answer);

class ServoCompensator {
 public:
  ServoCompensator(const RobotModel& nominal, const CompensationSettings& settings, double blend_s);

  // A calibration to apply (a newer version than any before): at once for the first, else blended to from the next
  // setpoint on (after any blend in progress).
  void setCalibration(std::uint64_t version, IdentifiedModel model);

  // A joint setpoint: the controller's joints for this cycle.
  ServoAnswer answerJoints(std::int64_t cycle_stamp_ns, const Eigen::VectorXd& q_setpoint_rad);
  // A Cartesian setpoint (tracker/cell frame) with a seed (empty: the last answer's joints, else mid-range).
  ServoAnswer answerPose(std::int64_t cycle_stamp_ns, const Pose& desired_in_tracker, const Eigen::VectorXd& seed_rad);

  std::uint64_t version() const { return current_ ? current_->version : 0; }
  bool blending() const { return previous_.has_value(); }

 private:
  struct Version {
    std::uint64_t version = 0;
    IdentifiedModel model;
  };
  ServoAnswer answer(std::int64_t t_ns, const Pose& desired, const Eigen::VectorXd& seed,
                     const Eigen::VectorXd& pass_q);

  const RobotModel* nominal_;
  CompensationSettings settings_;
  double blend_s_;
  std::optional<Version> current_, previous_, waiting_;
  std::optional<std::int64_t> blend_start_ns_;  // the first setpoint's stamp after the switch
  Eigen::VectorXd last_q_;
  KinematicsData data_;
};

}  // namespace cellcal
