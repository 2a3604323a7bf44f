#include "cellcal/core/servo/realtime_compensator.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace cellcal {

bool RealtimeSettings::IsValid(std::string* error) const {
  const CompensationSettings& c = compensation;
  const char* bad = !(blend_s >= 0)                        ? "blend_s must be >= 0"
                    : max_ik_evaluations < 2               ? "max_ik_evaluations must be >= 2"
                    : !(c.max_correction_m > 0)            ? "compensation.max_correction_m must be > 0"
                    : !(c.max_correction_rad > 0)          ? "compensation.max_correction_rad must be > 0"
                    : !(c.max_ik_error_m > 0)              ? "compensation.max_ik_error_m must be > 0"
                    : !(c.max_predicted_sigma_m >= 0)      ? "compensation.max_predicted_sigma_m must be >= 0"
                    : !(c.max_joint_correction_rad > 0)    ? "compensation.max_joint_correction_rad must be > 0"
                    : !(recovery_rate_rad_s > 0)           ? "recovery_rate_rad_s must be > 0"
                                                           : nullptr;
  if (bad && error) *error = std::string("RealtimeSettings: ") + bad;
  return !bad;
}

std::unique_ptr<const ServoVersion> ServoVersion::prepare(const RobotModel& nominal, std::uint64_t version,
                                                          const IdentifiedModel& model, std::string* error) {
  auto fail = [&](const std::string& why) {
    if (error) *error = "calibration version " + std::to_string(version) + ": " + why;
    return std::unique_ptr<const ServoVersion>();
  };
  if (nominal.numJoints() > kMaxServoJoints)
    return fail("the robot has " + std::to_string(nominal.numJoints()) + " joints; the real-time compensator answers " +
                "up to " + std::to_string(kMaxServoJoints));
  std::string why;
  if (!model.IsValid(nominal, &why)) return fail(why);
  if (!model.extensions.empty())
    return fail("the model has extensions (" + extensionSpec(model.extensions.front()) +
                (model.extensions.size() > 1 ? ", ..." : "") +
                "); the controller's loop answers the geometric model, the compensation publisher's stream the "
                "extended one");
  if (model.residual_map && !model.residual_map->empty())
    return fail("the model has a residual map; the controller's loop answers the geometric model");
  std::unique_ptr<ServoVersion> v(new ServoVersion);
  v->version_ = version;
  v->params_ = model.params;
  const int ne = static_cast<int>(model.estimated.size());
  if (ne > 0 && model.covariance.rows() == model.numEstimated()) {
    const Eigen::MatrixXd P = model.covariance.topLeftCorner(ne, ne);
    if (!P.allFinite() || !P.isApprox(P.transpose(), 1e-9 * std::max(1e-300, P.cwiseAbs().maxCoeff())))
      return fail("its covariance is not finite and symmetric");
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(P);
    const double largest = eig.eigenvalues().cwiseAbs().maxCoeff();
    if (eig.eigenvalues().minCoeff() < -1e-9 * largest) return fail("its covariance is not positive semi-definite");
    v->sigma_factor_.setZero(nominal.numParams(), ne);
    for (int k = 0; k < ne; ++k) {
      const Eigen::VectorXd col = eig.eigenvectors().col(k) * std::sqrt(std::max(0.0, eig.eigenvalues()[k]));
      for (int i = 0; i < ne; ++i) v->sigma_factor_(model.estimated[static_cast<size_t>(i)], k) = col[i];
    }
  }
  return v;
}

const char* statusName(ServoStatus s) {
  switch (s) {
    case ServoStatus::kApplied: return "applied";
    case ServoStatus::kHeld: return "held";
    case ServoStatus::kNoCalibration: return "no_calibration";
    case ServoStatus::kBadSetpoint: return "bad_setpoint";
  }
  return "?";
}

std::string describe(const RealtimeAnswer& a) {
  std::ostringstream m;
  m.precision(4);
  switch (a.status) {
    case ServoStatus::kBadSetpoint:
      m << "setpoint rejected: " << a.value << " joint values (the robot has " << a.bound << ") or not finite";
      return m.str();
    case ServoStatus::kNoCalibration: return "no calibration received yet";
    case ServoStatus::kApplied:
      if (a.outcome != CompensationOutcome::kClamped) return "";
      break;
    case ServoStatus::kHeld: break;
  }
  m << "v" << a.decided_by << ": ";
  switch (a.outcome) {
    case CompensationOutcome::kUnreachable:
      m << "the identified model does not reach the setpoint's pose (closest " << a.value * 1e3 << " mm, bound "
        << a.bound * 1e3 << " mm)";
      break;
    case CompensationOutcome::kOutsideCalibration:
      m << "predicted error " << a.value * 1e3 << " mm (1 sigma) above compensation.max_predicted_sigma_mm "
        << a.bound * 1e3;
      break;
    case CompensationOutcome::kOverBound:
    case CompensationOutcome::kClamped:
    case CompensationOutcome::kClampUnreachable:
      m << "correction " << a.value * 1e3 << " mm exceeds the bound " << a.bound * 1e3 << " mm (or its angle its bound)"
        << (a.outcome == CompensationOutcome::kClamped ? ": clamped to the bound"
            : a.outcome == CompensationOutcome::kClampUnreachable ? "; the clamped pose is out of reach" : "");
      break;
    case CompensationOutcome::kJointJump:
      m << "the correction moves a joint by " << radToDeg(a.value) << " deg, above compensation.max_joint_correction_deg "
        << radToDeg(a.bound) << ": another branch near a singularity";
      break;
    default: m << outcomeName(a.outcome); break;
  }
  if (a.status == ServoStatus::kHeld) m << ": holding " << std::lround(100 * a.hold_fraction) << " % of the last correction";
  return m.str();
}

struct RealtimeCompensator::Solve {
  CompensationOutcome outcome = CompensationOutcome::kUnreachable;
  ServoJoints dq;
  double sigma_m = std::numeric_limits<double>::quiet_NaN();
  double value = 0, bound = 0;
  int evaluations = 0;
};

RealtimeCompensator::RealtimeCompensator(const RobotModel& nominal, const RealtimeSettings& settings)
    : nominal_(&nominal), settings_(settings), n_(nominal.numJoints()), data_(nominal) {
  std::string error;
  if (!settings.IsValid(&error)) throw std::invalid_argument(error);
  if (n_ > kMaxServoJoints || n_ < 1)
    throw std::invalid_argument("RealtimeCompensator: the robot has " + std::to_string(n_) + " joints (1 to " +
                                std::to_string(kMaxServoJoints) + ")");
  for (auto& slot : retired_) slot.store(nullptr, std::memory_order_relaxed);
  frozen_dq_.setZero(n_);
  last_dq_.setZero(n_);
  hold_dq_.setZero(n_);
  q_eval_.setZero(n_);
  joint_jacobian_.setZero(6, n_);
  pose_jacobian_.setZero(6, nominal.numParams());
}

RealtimeCompensator::~RealtimeCompensator() {
  collectRetired();
  delete mailbox_.exchange(nullptr);
  delete current_;
  delete waiting_;
  if (from_ == From::kVersion) delete from_version_;
}

bool RealtimeCompensator::publish(std::unique_ptr<const ServoVersion> version) {
  collectRetired();
  if (!version || version->version() <= last_published_) return false;
  last_published_ = version->version();
  delete mailbox_.exchange(version.release(), std::memory_order_acq_rel);  // one the controller never took
  return true;
}

void RealtimeCompensator::collectRetired() {
  std::uint32_t tail = retired_tail_.load(std::memory_order_relaxed);
  const std::uint32_t head = retired_head_.load(std::memory_order_acquire);
  for (; tail != head; ++tail) delete retired_[tail % kRetireSlots].exchange(nullptr, std::memory_order_relaxed);
  retired_tail_.store(tail, std::memory_order_release);
}

void RealtimeCompensator::retire(const ServoVersion* v) noexcept {
  if (!v) return;
  const std::uint32_t head = retired_head_.load(std::memory_order_relaxed);
  // Never full: between two of the feed's calls the controller retires at most what it holds (current, previous,
  // waiting) and the one version it took.
  if (head - retired_tail_.load(std::memory_order_acquire) >= kRetireSlots) return;
  retired_[head % kRetireSlots].store(v, std::memory_order_relaxed);
  retired_head_.store(head + 1, std::memory_order_release);
}

void RealtimeCompensator::startBlendFromLast(std::int64_t t) noexcept {
  if (from_ == From::kVersion) retire(from_version_);
  from_version_ = nullptr;
  from_ = settings_.blend_s > 0 ? From::kFrozen : From::kNone;
  frozen_dq_ = last_dq_;
  blend_start_ns_ = t;
  blend_duration_s_ = settings_.blend_s;
  blend_duration_pending_ = true;
  // The blend restarts at weight 0 (this cycle commands the frozen correction): the newest version can be its target
  // without a step. Without this, blends restarted by refusals near a singularity kept a waiting version out for as
  // long as they went on (a stream saw one version in 9 s while the feed handed over 15).
  if (waiting_) {
    retire(current_);
    current_ = waiting_;
    waiting_ = nullptr;
  }
}

void RealtimeCompensator::takeNewest(std::int64_t t) noexcept {
  const ServoVersion* v = mailbox_.exchange(nullptr, std::memory_order_acq_rel);
  if (!v) return;
  if (!current_) {
    current_ = v;
    if (cycled_) startBlendFromLast(t);  // a running stream: from what it was commanded
  } else if (settings_.blend_s <= 0) {
    retire(current_);
    current_ = v;
  } else if (from_ != From::kNone) {
    retire(waiting_);  // only the newest waits
    waiting_ = v;
  } else {
    from_ = From::kVersion;
    from_version_ = current_;
    current_ = v;
    blend_start_ns_ = t;
    blend_duration_s_ = settings_.blend_s;
    blend_duration_pending_ = false;
  }
}

// The damped least-squares descent of inverse_kinematics.cpp (descend) on fixed-size storage, bounded by evaluations.
bool RealtimeCompensator::descend(const Eigen::VectorXd& params, const Pose& target, ServoJoints& q,
                                  int& evaluations, double& position_error_m) noexcept {
  constexpr double kTolerance = 1e-9, kOrientationWeight = 0.5, kDamping = 1e-12;
  using Vector6 = Eigen::Matrix<double, 6, 1>;
  const int budget = evaluations + settings_.max_ik_evaluations;
  auto error = [&](const ServoJoints& qq, Vector6& e) {
    q_eval_ = qq;
    e = poseError(target, forwardKinematics(*nominal_, data_, params, q_eval_));
    e.tail<3>() *= kOrientationWeight;
    ++evaluations;
  };
  auto clampToLimits = [&](ServoJoints& qq) {
    for (int j = 0; j < n_; ++j) qq[j] = std::clamp(qq[j], nominal_->limits[j].lower_rad, nominal_->limits[j].upper_rad);
  };
  Vector6 e, e_trial;
  ServoJoints q_trial, step;
  Eigen::Matrix<double, 6, 6> JJt;
  Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt;
  clampToLimits(q);
  error(q, e);
  double lambda = std::max(kDamping, 1e-6);
  while (evaluations < budget) {
    if (e.head<3>().norm() < kTolerance && e.tail<3>().norm() / kOrientationWeight < kTolerance) break;
    // data_ holds the forward kinematics of q: the last evaluation was error(q) or the accepted trial.
    computeJointJacobian(*nominal_, data_, joint_jacobian_);
    joint_jacobian_.bottomRows<3>() *= kOrientationWeight;
    bool improved = false;
    for (int tries = 0; tries < 30 && !improved && evaluations < budget; ++tries) {
      JJt.noalias() = joint_jacobian_ * joint_jacobian_.transpose();
      JJt.diagonal().array() += std::max(lambda, 0.1 * e.squaredNorm());
      ldlt.compute(JJt);
      step.noalias() = joint_jacobian_.transpose() * ldlt.solve(e);
      q_trial = q + step;
      clampToLimits(q_trial);
      error(q_trial, e_trial);
      if (e_trial.squaredNorm() < e.squaredNorm()) {
        q = q_trial;
        e = e_trial;
        lambda = std::max(kDamping, lambda * 1e-3);
        improved = true;
      } else {
        lambda *= 10.0;
      }
    }
    if (!improved) break;
  }
  position_error_m = e.head<3>().norm();
  return e.head<3>().norm() < kTolerance && e.tail<3>().norm() / kOrientationWeight < kTolerance;
}

// One version's answer at q_s, as compensate() gives it for the pose FK(nominal, q_s) seeded at q_s, then servo.hpp's
// joint-jump guard.
bool RealtimeCompensator::solve(const ServoVersion& v, const ServoJoints& q_s, Solve& out) noexcept {
  const CompensationSettings& s = settings_.compensation;
  const RobotModel& m = *nominal_;
  q_eval_ = q_s;
  const Pose desired = forwardKinematics(m, data_, m.nominal, q_eval_);
  ++out.evaluations;
  ServoJoints q = q_s;
  bool within = true;
  for (int j = 0; j < n_; ++j) within = within && q[j] >= m.limits[j].lower_rad && q[j] <= m.limits[j].upper_rad;
  if (!within)
    for (int j = 0; j < n_; ++j) q[j] = 0.5 * (m.limits[j].lower_rad + m.limits[j].upper_rad);
  double ik_error_m = 0;
  const bool reached = descend(v.params(), desired, q, out.evaluations, ik_error_m);
  if (!reached || ik_error_m > s.max_ik_error_m) {
    out.outcome = CompensationOutcome::kUnreachable;
    out.value = ik_error_m;
    out.bound = s.max_ik_error_m;
    return false;
  }
  if (v.hasCovariance()) {  // the predicted 1-sigma position error at q*: |J_p G|
    q_eval_ = q;
    forwardKinematics(m, data_, v.params(), q_eval_);
    ++out.evaluations;
    computePoseJacobian(m, data_, pose_jacobian_);
    double var = 0;
    const auto& G = v.sigmaFactor();
    for (int k = 0; k < G.cols(); ++k) var += (pose_jacobian_.topRows<3>() * G.col(k)).squaredNorm();
    out.sigma_m = std::isfinite(var) ? std::sqrt(std::max(0.0, var)) : std::numeric_limits<double>::infinity();
    if (s.max_predicted_sigma_m > 0 && !(out.sigma_m <= s.max_predicted_sigma_m)) {
      out.outcome = CompensationOutcome::kOutsideCalibration;
      out.value = out.sigma_m;
      out.bound = s.max_predicted_sigma_m;
      return false;
    }
  }
  // The correction from the setpoint's pose to what the controller must be commanded, within the bounds.
  q_eval_ = q;
  const Pose corrected = forwardKinematics(m, data_, m.nominal, q_eval_);
  ++out.evaluations;
  const Eigen::Matrix<double, 6, 1> c = poseError(corrected, desired);
  const double over = std::max(c.head<3>().norm() / s.max_correction_m, c.tail<3>().norm() / s.max_correction_rad);
  out.outcome = CompensationOutcome::kApplied;
  if (over > 1.0) {
    out.value = c.head<3>().norm();
    out.bound = s.max_correction_m;
    if (s.on_exceed == ExceedAction::kRefuse) {
      out.outcome = CompensationOutcome::kOverBound;
      return false;
    }
    Pose clamped = Pose::Identity();
    clamped.translation() = desired.translation() + c.head<3>() / over;
    clamped.linear() = expSO3(c.tail<3>() / over) * desired.linear();
    double clamp_error_m = 0;
    if (!descend(m.nominal, clamped, q, out.evaluations, clamp_error_m)) {
      out.outcome = CompensationOutcome::kClampUnreachable;
      return false;
    }
    out.outcome = CompensationOutcome::kClamped;
  }
  out.dq = q - q_s;
  const double moved = out.dq.cwiseAbs().maxCoeff();
  if (moved > s.max_joint_correction_rad) {
    out.outcome = CompensationOutcome::kJointJump;
    out.value = moved;
    out.bound = s.max_joint_correction_rad;
    return false;
  }
  return true;
}

RealtimeAnswer RealtimeCompensator::correct(std::int64_t t, const double* q_setpoint, int joints) noexcept {
  RealtimeAnswer a;
  bool finite = q_setpoint != nullptr && joints == n_;
  for (int j = 0; finite && j < joints; ++j) finite = std::isfinite(q_setpoint[j]);
  if (!finite) {
    a.status = ServoStatus::kBadSetpoint;
    a.outcome = CompensationOutcome::kBadInput;
    if (q_setpoint && joints >= 0 && joints <= kMaxServoJoints) a.q_rad = Eigen::Map<const Eigen::VectorXd>(q_setpoint, joints);
    a.correction_rad.setZero(a.q_rad.size());
    a.value = joints;
    a.bound = n_;
    return a;
  }
  const ServoJoints q_s = Eigen::Map<const Eigen::VectorXd>(q_setpoint, n_);
  takeNewest(t);
  const double blend_s = settings_.blend_s;
  double w = 1.0;
  if (from_ != From::kNone) {
    w = std::clamp(static_cast<double>(t - blend_start_ns_) * 1e-9 / blend_duration_s_, 0.0, 1.0);
    if (w >= 1.0) {
      if (from_ == From::kVersion) retire(from_version_);
      from_version_ = nullptr;
      from_ = From::kNone;
      if (waiting_) {  // the next blend starts here, at the last one's end
        from_ = From::kVersion;
        from_version_ = current_;
        current_ = waiting_;
        waiting_ = nullptr;
        blend_start_ns_ = t;
        blend_duration_s_ = blend_s;
        blend_duration_pending_ = false;
        w = 0.0;
      }
    }
  }
  cycled_ = true;
  ServoJoints dq = ServoJoints::Zero(n_);
  if (!current_) {
    a.status = ServoStatus::kNoCalibration;
  } else {
    a.version = a.from_version = a.decided_by = current_->version();
    Solve to;
    const bool answered = solve(*current_, q_s, to);
    a.ik_evaluations = to.evaluations;
    a.predicted_sigma_m = to.sigma_m;
    a.outcome = to.outcome;
    a.value = to.value;
    a.bound = to.bound;
    if (!answered) {  // hold the last correction, fading over blend_s of the refusals
      if (!refusing_) {
        refusing_ = true;
        refuse_start_ns_ = t;
        hold_dq_ = last_dq_;
      }
      a.status = ServoStatus::kHeld;
      a.hold_fraction =
          blend_s > 0 ? std::clamp(1.0 - static_cast<double>(t - refuse_start_ns_) * 1e-9 / blend_s, 0.0, 1.0) : 0.0;
      dq = a.hold_fraction * hold_dq_;
    } else {
      if (refusing_) {  // answered again: from what the stream was last commanded
        refusing_ = false;
        startBlendFromLast(t);
        w = from_ == From::kNone ? 1.0 : 0.0;
      }
      ServoJoints dq_from = frozen_dq_;
      if (from_ == From::kVersion) {
        Solve from;
        const bool from_answered = solve(*from_version_, q_s, from);
        a.ik_evaluations += from.evaluations;
        if (from_answered) {
          dq_from = from.dq;
        } else {  // the previous version cannot answer here: blend from what the stream was last commanded
          a.from_refused = true;
          startBlendFromLast(t);
          dq_from = frozen_dq_;
          w = 0.0;
        }
      }
      if (from_ == From::kFrozen && blend_duration_pending_) {  // its length from the jump it has to make
        blend_duration_pending_ = false;
        const double jump = n_ > 0 ? (to.dq - dq_from).cwiseAbs().maxCoeff() : 0.0;
        blend_duration_s_ = std::clamp(jump / settings_.recovery_rate_rad_s, 1e-9, blend_s);
        w = std::clamp(static_cast<double>(t - blend_start_ns_) * 1e-9 / blend_duration_s_, 0.0, 1.0);
      }
      a.status = ServoStatus::kApplied;
      if (from_ == From::kVersion) a.from_version = from_version_->version();
      a.weight = from_ == From::kNone ? 1.0 : w;
      dq = from_ == From::kNone ? to.dq : ServoJoints(dq_from + w * (to.dq - dq_from));
    }
  }
  last_dq_ = dq;
  a.correction_rad = dq;
  a.q_rad = q_s + dq;
  return a;
}

}  // namespace cellcal
