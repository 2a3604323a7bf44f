#include "cellcal/core/engine/servo.hpp"

#include <algorithm>
#include <stdexcept>
#include <utility>

#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

ServoCompensator::ServoCompensator(const RobotModel& nominal, const CompensationSettings& settings, double blend_s)
    : nominal_(&nominal), settings_(settings), blend_s_(blend_s), data_(nominal) {
  if (!(blend_s >= 0)) throw std::invalid_argument("ServoCompensator: blend_s must be >= 0");
}

void ServoCompensator::setCalibration(std::uint64_t version, IdentifiedModel model) {
  Version v{version, std::move(model)};
  if (!current_ || blend_s_ == 0) {
    current_ = std::move(v);
    previous_.reset();
    waiting_.reset();
    blend_start_ns_.reset();
  } else if (previous_ && !blend_start_ns_) {
    current_ = std::move(v);  // no setpoint saw the version it replaces
  } else if (previous_) {
    waiting_ = std::move(v);  // after the blend in progress
  } else {
    previous_ = std::move(current_);
    current_ = std::move(v);
    blend_start_ns_.reset();
  }
}

ServoAnswer ServoCompensator::answerJoints(std::int64_t cycle_stamp_ns, const Eigen::VectorXd& q_setpoint_rad) {
  if (q_setpoint_rad.size() != nominal_->numJoints() || !q_setpoint_rad.allFinite()) {
    ServoAnswer a;
    a.q_rad = q_setpoint_rad;
    a.outcome = CompensationOutcome::kBadInput;
    a.setpoint_joints = static_cast<long>(q_setpoint_rad.size());
    a.robot_joints = nominal_->numJoints();
    return a;
  }
  return answer(cycle_stamp_ns, forwardKinematics(*nominal_, data_, nominal_->nominal, q_setpoint_rad), q_setpoint_rad,
                q_setpoint_rad);
}

ServoAnswer ServoCompensator::answerPose(std::int64_t cycle_stamp_ns, const Pose& desired_in_tracker,
                                         const Eigen::VectorXd& seed_rad) {
  return answer(cycle_stamp_ns, desired_in_tracker, seed_rad.size() == 0 ? last_q_ : seed_rad, seed_rad);
}

ServoAnswer ServoCompensator::answer(std::int64_t t_ns, const Pose& desired, const Eigen::VectorXd& seed,
                                     const Eigen::VectorXd& pass_q) {
  ServoAnswer out;
  out.q_rad = pass_q;
  out.commanded = desired;
  if (!current_) return out;  // version 0: no calibration yet
  double w = 1.0;
  if (previous_) {
    if (!blend_start_ns_) blend_start_ns_ = t_ns;
    w = std::clamp(static_cast<double>(t_ns - *blend_start_ns_) * 1e-9 / blend_s_, 0.0, 1.0);
    if (w >= 1.0) {
      previous_.reset();
      blend_start_ns_.reset();
      if (waiting_) {  // the next blend starts here, at the old one's end: w = 0 is the answer the last one ended on
        previous_ = std::move(current_);
        current_ = std::move(waiting_);
        waiting_.reset();
        blend_start_ns_ = t_ns;
        w = 0.0;
      }
    }
  }
  out.version = current_->version;
  out.from_version = previous_ ? previous_->version : current_->version;
  out.weight = previous_ ? w : 1.0;
  const CompensationResult now = compensate(*nominal_, current_->model, desired, seed, settings_);
  std::optional<CompensationResult> before;
  if (previous_) before = compensate(*nominal_, previous_->model, desired, seed, settings_);
  const CompensationResult* const results[] = {&now, before ? &*before : nullptr};
  for (const CompensationResult* r : results) {
    if (!r || r->applied) continue;
    out.outcome = r->outcome;
    out.decided_by = r == &now ? out.version : out.from_version;
    out.result = *r;
    return out;
  }
  // The same branch as the setpoint: a correction of joints, not a turn of the wrist in a singularity's null space.
  if (seed.size() == nominal_->numJoints()) {
    for (const CompensationResult* r : results) {
      if (!r) continue;
      const double moved = (r->q_rad - seed).cwiseAbs().maxCoeff();
      if (moved <= settings_.max_joint_correction_rad) continue;
      out.outcome = CompensationOutcome::kJointJump;
      out.decided_by = r == &now ? out.version : out.from_version;
      out.joint_move_rad = moved;
      out.joint_move_bound_rad = settings_.max_joint_correction_rad;
      return out;
    }
  }
  out.applied = true;
  out.outcome = now.outcome;
  out.beyond_data = now.beyond_data || (before && before->beyond_data);
  out.q_rad = before ? Eigen::VectorXd(before->q_rad + out.weight * (now.q_rad - before->q_rad)) : now.q_rad;
  out.commanded = before ? forwardKinematics(*nominal_, data_, nominal_->nominal, out.q_rad) : now.corrected_in_tracker;
  if (now.clamped || (before && before->clamped)) {
    out.decided_by = now.clamped ? out.version : out.from_version;
    out.result = now.clamped ? now : *before;
  }
  last_q_ = out.q_rad;
  return out;
}

std::string describe(const ServoAnswer& a) {
  if (a.outcome == CompensationOutcome::kBadInput)
    return "setpoint rejected: " + std::to_string(a.setpoint_joints) + " joint values (the robot has " +
           std::to_string(a.robot_joints) + ") or not finite";
  if (a.version == 0) return "no calibration received yet";
  if (a.outcome == CompensationOutcome::kJointJump)
    return "v" + std::to_string(a.decided_by) + " moves a joint by " + std::to_string(a.joint_move_rad * 180 / kPi) +
           " deg (compensation.max_joint_correction_deg " + std::to_string(a.joint_move_bound_rad * 180 / kPi) +
           "): another branch near a singularity: setpoint passed through";
  if (!a.applied) return "v" + std::to_string(a.decided_by) + ": " + describe(a.result) + ": setpoint passed through";
  return a.result.clamped ? describe(a.result) : std::string();
}

}  // namespace cellcal
