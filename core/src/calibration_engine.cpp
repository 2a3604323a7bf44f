#include "cellcal/core/calibration_engine.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>

#include <Eigen/Eigenvalues>
#include <nlohmann/json.hpp>
#include <iomanip>
#include <sstream>
#include <stdexcept>

#include "cellcal/core/calibration.hpp"
#include "cellcal/core/kinematics.hpp"
#include "cellcal/core/statistics.hpp"

namespace cellcal {

PairingOptions pairingOptions(const CellRobot& robot, const EngineSettings& s) {
  PairingOptions o;
  o.max_skew_s = s.max_pairing_skew_s;
  o.settle_tolerance_rad = s.settle_tolerance_rad;
  o.max_sample_age_s = s.max_sample_age_s;
  o.kind = robot.measurement;
  return o;
}

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr const char* kStateFormat = "cellcal-engine-state/1";
constexpr size_t kRecentWindow = 30;

std::int64_t steadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}


void writeAll(int fd, const std::string& data, const std::string& path) {
  size_t off = 0;
  while (off < data.size()) {
    const ssize_t n = ::write(fd, data.data() + off, data.size() - off);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw std::runtime_error(path + ": write failed: " + std::strerror(errno));
    }
    off += static_cast<size_t>(n);
  }
}

// Atomic replace: a reader (or a restart after SIGKILL) sees the old file or the new one, never a mix. The data
// reach the disk with syncFile() (CalibrationEngine::syncToDisk), which the engine process calls right after
// publishing, so the latency path does not wait for the disk.
void atomicWrite(const std::string& path, const std::string& data) {
  const fs::path p(path);
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error(tmp + ": cannot create: " + std::strerror(errno));
  try {
    writeAll(fd, data, tmp);
  } catch (...) {
    ::close(fd);
    ::unlink(tmp.c_str());
    throw;
  }
  if (::close(fd) != 0) {  // NFS and some filesystems report a full disk only here
    const std::string err = std::strerror(errno);
    ::unlink(tmp.c_str());
    throw std::runtime_error(tmp + ": close failed: " + err);
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string err = std::strerror(errno);
    ::unlink(tmp.c_str());
    throw std::runtime_error(path + ": rename failed: " + err);
  }
}

}  // namespace

void syncStateFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error(path + ": cannot open to fsync: " + std::strerror(errno));
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) throw std::runtime_error(path + ": fsync failed: " + std::strerror(err));
  const fs::path p(path);
  const int dfd = ::open(p.parent_path().empty() ? "." : p.parent_path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

namespace {

json driversToJson(const Drivers& d) {
  return {{"motion_direction", std::vector<double>(d.motion_direction.data(), d.motion_direction.data() + d.motion_direction.size())},
          {"recent_steps_rad", std::vector<double>(d.recent_steps_rad.data(), d.recent_steps_rad.data() + d.recent_steps_rad.size())}};
}

Drivers driversFromJson(const json& j) {
  Drivers d;
  const auto m = j.at("motion_direction").get<std::vector<double>>();
  const auto r = j.at("recent_steps_rad").get<std::vector<double>>();
  d.motion_direction = Eigen::Map<const Eigen::VectorXd>(m.data(), static_cast<Eigen::Index>(m.size()));
  if (r.size() != m.size() * kPlayHistory) throw std::runtime_error("recent_steps_rad size");
  d.recent_steps_rad = Eigen::Map<const Eigen::MatrixXd>(r.data(), static_cast<Eigen::Index>(m.size()), kPlayHistory);
  return d;
}

json observationToJson(const PairedReading& p) {
  const Observation& o = p.observation;
  const Eigen::Quaterniond qn(o.measured_in_tracker.linear());
  return {{"q_rad", std::vector<double>(o.q_rad.data(), o.q_rad.data() + o.q_rad.size())},
          {"position_m", {o.measured_in_tracker.translation().x(), o.measured_in_tracker.translation().y(),
                          o.measured_in_tracker.translation().z()}},
          {"orientation_xyzw", {qn.x(), qn.y(), qn.z(), qn.w()}},
          {"pose6d", o.kind == MeasurementKind::kPose6D},
          {"sigma_position_m", o.sigma_position_m},
          {"sigma_orientation_rad", o.sigma_orientation_rad},
          {"tracker_stamp_ns", p.tracker_stamp_ns},
          {"tracker_sequence", p.tracker_sequence},
          {"joint_stamp_ns", p.joint_stamp_ns}};
}

PairedReading observationFromJson(const json& j) {
  PairedReading p;
  const auto q = j.at("q_rad").get<std::vector<double>>();
  p.observation.q_rad = Eigen::Map<const Eigen::VectorXd>(q.data(), static_cast<Eigen::Index>(q.size()));
  const auto pos = j.at("position_m").get<std::vector<double>>();
  const auto ori = j.at("orientation_xyzw").get<std::vector<double>>();
  p.observation.measured_in_tracker = Pose::Identity();
  p.observation.measured_in_tracker.translation() = Eigen::Vector3d(pos.at(0), pos.at(1), pos.at(2));
  p.observation.measured_in_tracker.linear() =
      Eigen::Quaterniond(ori.at(3), ori.at(0), ori.at(1), ori.at(2)).normalized().toRotationMatrix();
  p.observation.kind = j.at("pose6d").get<bool>() ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
  p.observation.sigma_position_m = j.at("sigma_position_m").get<double>();
  p.observation.sigma_orientation_rad = j.at("sigma_orientation_rad").get<double>();
  p.tracker_stamp_ns = j.at("tracker_stamp_ns").get<std::int64_t>();
  p.tracker_sequence = j.at("tracker_sequence").get<std::uint64_t>();
  p.joint_stamp_ns = j.at("joint_stamp_ns").get<std::int64_t>();
  return p;
}

}  // namespace

const char* healthName(Health h) {
  switch (h) {
    case Health::kUncalibrated: return "uncalibrated";
    case Health::kOk: return "ok";
    case Health::kDegraded: return "degraded";
    case Health::kHoldLastGood: return "hold_last_good";
  }
  return "?";
}

CalibrationEngine::CalibrationEngine(const CellRobot& robot, const EngineSettings& settings, double time_compression,
                                     bool persist)
    : robot_(&robot),
      settings_(&settings),
      time_compression_(time_compression),
      persist_(persist),
      pairing_(robot.model, pairingOptions(robot, settings)),
      play_(robot.model.numJoints(), settings.settle_tolerance_rad) {
  for (const auto& e : robot.extensions) tracks_play_ = tracks_play_ || e.cause == Cause::kBacklash;
  const RobotModel& m = robot.model;
  DriftModel drift;
  drift.joint_offset_rad = settings.drift_joint_offset_rad;
  drift.joint_length_m = settings.drift_joint_length_m;
  drift.axis_angle_rad = settings.drift_axis_angle_rad;
  drift.frame_length_m = settings.drift_frame_length_m;
  drift.frame_angle_rad = settings.drift_frame_angle_rad;
  drift_sigma_ = drift.sigmas(m);
  snap_.mode = settings.mode;
  snap_.verification_mean_position_m = std::nan("");
  // Reference configurations for the predicted error: fixed (the same in every process and after a restart), spread
  // over 80 % of each joint's range (at most +-180 deg).
  std::mt19937_64 ref_rng(0x63656c6c63616cULL);
  for (int k = 0; k < 16; ++k) {
    Eigen::VectorXd q(m.numJoints());
    for (int j = 0; j < m.numJoints(); ++j)
      q[j] = std::uniform_real_distribution<double>(0.8 * std::max(m.limits[j].lower_rad, -kPi),
                                                    0.8 * std::min(m.limits[j].upper_rad, kPi))(ref_rng);
    reference_q_.push_back(q);
  }
  if (!(persist_ && restore())) {
    const GaussianPrior prior =
        diagonalPrior(m, m.nominal, m.canonicalParams(), settings.prior_length_m, settings.prior_angle_rad);
    rls_ = std::make_unique<RlsCalibrator>(m, m.nominal, prior, robot.measurement);
    if (!robot.extensions.empty()) startExtensions(rls_->params(), rls_->estimated(), rls_->covariance());
    snap_.params = rls_->params();
    snap_.estimated = rls_->estimated();
    snap_.covariance = rls_->covariance();
  }
  snap_.extensions = rls_->extensions();
  snap_.extension_params = rls_->extensionParams();
  snap_.estimated_extension = rls_->estimatedExtension();
}

// The extension parameters start at zero (no effect) with a prior whose 1 sigma makes a joint error of
// prior_angle_rad, uncorrelated with the kinematic estimate.
void CalibrationEngine::startExtensions(const Eigen::VectorXd& params, const std::vector<int>& estimated,
                                        const Eigen::MatrixXd& P) {
  const RobotModel& m = robot_->model;
  const auto& exts = robot_->extensions;
  const Eigen::VectorXd sigma = extensionPriorSigma(m, params, exts, settings_->prior_angle_rad);
  std::vector<int> acting;  // parameters whose basis column acts (extensionPriorSigma > 0)
  for (Eigen::Index k = 0; k < sigma.size(); ++k)
    if (sigma[k] > 0) acting.push_back(static_cast<int>(k));
  const auto ne = static_cast<Eigen::Index>(estimated.size()), nx = static_cast<Eigen::Index>(acting.size());
  Eigen::MatrixXd full = Eigen::MatrixXd::Zero(ne + nx, ne + nx);
  full.topLeftCorner(ne, ne) = P.topLeftCorner(ne, ne);
  for (Eigen::Index k = 0; k < nx; ++k) full(ne + k, ne + k) = sigma[acting[static_cast<size_t>(k)]] * sigma[acting[static_cast<size_t>(k)]];
  rls_ = std::make_unique<RlsCalibrator>(m, params, estimated, exts, Eigen::VectorXd::Zero(sigma.size()), acting, full);
}

std::string CalibrationEngine::stateFile() const {
  return (fs::path(settings_->state_dir) / (robot_->robot_id + ".state.json")).string();
}

void CalibrationEngine::reject(Rejection r, const std::string& detail) {
  ++counters_.rejected[static_cast<size_t>(r)];
  counters_.last_rejection = std::string(rejectionName(r)) + ": " + detail;
}

bool CalibrationEngine::onJointState(const JointSample& s, std::int64_t receive_ns) {
  ++counters_.joint_states;
  last_joint_ns_ = receive_ns;
  std::string detail;
  if (auto r = pairing_.addJointState(s, receive_ns, &detail)) {
    reject(*r, robot_->robot_id + " " + detail);
    return false;
  }
  if (tracks_play_) play_.add(s.stamp_ns, s.q_rad);
  // Remember when the robot moved (a new stand-still starts a new pose).
  const bool moved = !s.settled || (last_joint_q_.size() == s.q_rad.size() &&
                                    (s.q_rad - last_joint_q_).cwiseAbs().maxCoeff() > settings_->settle_tolerance_rad);
  if (moved) {
    motion_stamps_ns_.push_back(s.stamp_ns);
    while (motion_stamps_ns_.size() > 256) motion_stamps_ns_.pop_front();
  }
  last_joint_q_ = s.q_rad;
  return true;
}

// Same stand-still as the one whose joints were q at stamp_ns: same joints, and no motion seen in between.
bool CalibrationEngine::samePose(const PairedReading& p, const Eigen::VectorXd& q, std::int64_t stamp_ns) const {
  if (q.size() != p.observation.q_rad.size()) return false;
  if ((p.observation.q_rad - q).cwiseAbs().maxCoeff() > settings_->settle_tolerance_rad) return false;
  for (std::int64_t t : motion_stamps_ns_)
    if (t > stamp_ns && t <= p.joint_stamp_ns) return false;
  return true;
}

std::string CalibrationEngine::staleInputs(std::int64_t now_ns) const {
  const auto limit = static_cast<std::int64_t>(settings_->stale_input_s * 1e9);
  std::string out;
  auto check = [&](const char* topic, std::int64_t last) {
    if (last != 0 && now_ns - last <= limit) return;
    std::ostringstream m;
    m << (out.empty() ? "" : "; ") << topic << ": ";
    if (last == 0) m << "nothing received yet";
    else m << "nothing for " << std::fixed << std::setprecision(1) << (now_ns - last) * 1e-9 << " s";
    out += m.str();
  };
  check("joint_state", last_joint_ns_);
  check("tracker_pose", last_tracker_ns_);
  return out;
}

bool CalibrationEngine::onTrackerSample(const TrackerSample& s, std::int64_t receive_ns) {
  ++counters_.tracker_readings;
  last_tracker_ns_ = receive_ns;
  std::string detail;
  if (auto r = pairing_.addTrackerSample(s, receive_ns, &detail)) {
    reject(*r, robot_->target_id + " " + detail);
    return false;
  }
  return true;
}

bool CalibrationEngine::process(std::int64_t now_ns) {
  PairingOutcome out = pairing_.poll(now_ns);
  for (const auto& [r, d] : out.rejected) reject(r, robot_->target_id + " " + d);
  bool changed = false;
  const bool extended = !rls_->extensions().empty();
  for (const auto& p : out.paired) {
    const auto t0 = steadyNs();
    Pending pending{p, extended ? play_.driversAt(p.joint_stamp_ns, p.observation.q_rad) : Drivers{}};
    const bool same_as_used = samePose(p, used_q_, used_joint_stamp_ns_);
    if (settings_->outlier_gate_nis_per_row > 0) {
      const double nis = rls_->normalizedInnovation(p.observation, extended ? &pending.drivers : nullptr);
      const int rows = p.observation.rows();
      // A noise model that is too optimistic for this cell (every pose's NIS high) must not gate good poses: the gate
      // scales with the recent median NIS per row when that is above 1. A gross error (a bumped target, a beam
      // break caught mid-reading) is hundreds of sigmas and stays far outside.
      // The median is over every new stand-still, gated or not: when most poses look like outliers the model (or the
      // station) changed, the gate opens within half a window, and the drift alarm says so, instead of the engine
      // freezing on an estimate that no longer fits.
      double scale = 1;
      if (gate_window_.size() >= 5) {
        std::vector<double> v(gate_window_.begin(), gate_window_.end());
        std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
        scale = std::max(1.0, v[v.size() / 2]);
      }
      const double gate = settings_->outlier_gate_nis_per_row * rows * scale;
      const bool new_stand_still = !same_as_used && !samePose(p, gated_q_, gated_joint_stamp_ns_);
      if (new_stand_still && std::isfinite(nis)) {
        gate_window_.push_back(nis / rows);
        while (gate_window_.size() > kRecentWindow) gate_window_.pop_front();
      }
      if (!(nis <= gate)) {
        std::ostringstream m;
        m << robot_->target_id << " tracker reading #" << p.tracker_sequence << ": normalized innovation " << nis
          << " above the gate " << gate << " (" << rows << " rows)";
        reject(Rejection::kOutlier, m.str());
        if (new_stand_still) {
          ++consecutive_outliers_;
          gated_q_ = p.observation.q_rad;
          gated_joint_stamp_ns_ = p.joint_stamp_ns;
          const Health before = snap_.health;
          decideHealth();
          if (snap_.health != before) changed = true;  // publish the hold at once
        }
        continue;
      }
    }
    consecutive_outliers_ = 0;
    gated_q_.resize(0);
    ++counters_.paired;
    // One update per stand-still: further readings of the same pose repeat its robot error (repeatability), so
    // using them as independent observations would overweight the pose. The first reading is used at once.
    if (same_as_used) {
      ++counters_.same_pose;
      continue;
    }
    used_q_ = p.observation.q_rad;
    used_joint_stamp_ns_ = p.joint_stamp_ns;
    if (settings_->mode == EngineMode::kContinuous) {
      if (applyPose(pending)) {
        finishUpdate(p.tracker_stamp_ns, p.tracker_sequence);
        changed = true;
      }
    } else {
      batch_.push_back(std::move(pending));
      if (static_cast<int>(batch_.size()) >= settings_->batch_poses) {
        bool any = false;
        for (const auto& b : batch_) any = applyPose(b) || any;
        batch_.clear();
        if (any) {
          finishUpdate(p.tracker_stamp_ns, p.tracker_sequence);
          changed = true;
        }
      } else {
        snap_.last_measurement_stamp_ns = p.tracker_stamp_ns;
        snap_.last_tracker_sequence = p.tracker_sequence;
        pairing_.setAppliedUntil(p.tracker_stamp_ns);
        if (persist_) persist();
      }
    }
    last_update_duration_ns_ = steadyNs() - t0;
  }
  return changed;
}

bool CalibrationEngine::applyPose(const Pending& pending) {
  const PairedReading& p = pending.reading;
  const Drivers* drivers = rls_->extensions().empty() ? nullptr : &pending.drivers;
  const RlsCalibrator before_update = *rls_;  // for a roll-back (a 30x30 covariance: cheap beside the update)
  // Random walk of the parameters over the cell time since the previous update.
  if (snap_.last_update_stamp_ns > 0 && p.tracker_stamp_ns > snap_.last_update_stamp_ns) {
    const double dt_h = (p.tracker_stamp_ns - snap_.last_update_stamp_ns) * 1e-9 * time_compression_ / 3600.0;
    rls_->addProcessNoise(drift_sigma_ * std::sqrt(dt_h / settings_->drift_per_h));
  }
  const Observation& o = p.observation;
  const Pose before = rls_->predict(o.q_rad, drivers);
  const double nis = rls_->addObservation(o, drivers);
  const Pose after = rls_->predict(o.q_rad, drivers);
  if (!std::isfinite(nis) || !rls_->params().allFinite() || !rls_->extensionParams().allFinite() ||
      !rls_->covariance().allFinite() || !after.matrix().allFinite()) {
    *rls_ = before_update;
    std::ostringstream m;
    m << robot_->target_id << " tracker reading #" << p.tracker_sequence
      << ": the update made the estimate non-finite; rolled back to version " << snap_.version;
    reject(Rejection::kUnsafeUpdate, m.str());
    return false;
  }
  snap_.last_update_stamp_ns = p.tracker_stamp_ns;
  Recent r;
  r.prior_error_m = (o.measured_in_tracker.translation() - before.translation()).norm();
  r.post_error_m = (o.measured_in_tracker.translation() - after.translation()).norm();
  r.nis_per_row = nis / o.rows();
  r.post_error_rad = o.kind == MeasurementKind::kPose6D
                         ? logSO3(o.measured_in_tracker.linear() * after.linear().transpose()).norm()
                         : 0.0;
  recent_.push_back(r);
  while (recent_.size() > kRecentWindow) recent_.pop_front();
  ++snap_.poses_used;
  return true;
}

// decideHealth() sets the published parameters: the estimate, or the last good version while holding.
void CalibrationEngine::finishUpdate(std::int64_t stamp_ns, std::uint64_t sequence) {
  ++snap_.version;
  snap_.last_measurement_stamp_ns = stamp_ns;
  snap_.last_tracker_sequence = sequence;
  pairing_.setAppliedUntil(stamp_ns);
  refreshStatistics();
  decideHealth();
  if (persist_) persist();
}

// Worst over the reference configurations of sqrt(trace(J P J^T)) for the position rows, kinematic part of the state.
double CalibrationEngine::predictionSigma() const {
  const RobotModel& m = robot_->model;
  KinematicsData data(m);
  Eigen::MatrixXd J(6, m.numParams());
  const auto& est = rls_->estimated();
  const auto n = static_cast<Eigen::Index>(est.size());
  const Eigen::MatrixXd P = rls_->covariance().topLeftCorner(n, n);
  Eigen::MatrixXd Js(3, n);
  double worst = 0;
  for (const auto& q : reference_q_) {
    forwardKinematics(m, data, rls_->params(), q);
    computePoseJacobian(m, data, J);
    for (Eigen::Index k = 0; k < n; ++k) Js.col(k) = J.col(est[static_cast<size_t>(k)]).head<3>();
    const double var = (Js * P * Js.transpose()).trace();
    worst = std::max(worst, std::isfinite(var) ? std::sqrt(std::max(0.0, var)) : std::numeric_limits<double>::infinity());
  }
  return worst;
}

// Healthy once there are enough poses for every estimated parameter twice over (rows per pose: 6 or 3); then ok,
// degraded (drift alarm) or hold_last_good (outliers in a row, predicted error above the bound).
void CalibrationEngine::decideHealth() {
  const size_t rows = robot_->measurement == MeasurementKind::kPose6D ? 6 : 3;
  const size_t state = rls_->estimated().size() + rls_->estimatedExtension().size();
  const size_t needed = 2 * ((state + rows - 1) / rows);
  snap_.prediction_sigma_position_m = predictionSigma();
  snap_.health_reason.clear();
  snap_.held_version = 0;
  auto publishEstimate = [&] {
    snap_.params = rls_->params();
    snap_.estimated = rls_->estimated();
    snap_.covariance = rls_->covariance();
    snap_.extension_params = rls_->extensionParams();
  };
  std::ostringstream why;
  if (consecutive_outliers_ >= settings_->outlier_hold_after) {
    why << consecutive_outliers_ << " poses in a row beyond the outlier gate: the robot, the target or the tracker "
        << "moved (check the station and the target, then re-register if it was bumped)";
    snap_.drift_alarm = true;
  } else if (snap_.prediction_sigma_position_m > settings_->hold_prediction_sigma_m) {
    why << "predicted position error " << snap_.prediction_sigma_position_m * 1e3 << " mm (1 sigma) above the bound "
        << settings_->hold_prediction_sigma_m * 1e3 << " mm: the recent poses do not pin the model down";
  }
  if (snap_.poses_used < needed) {
    publishEstimate();
    snap_.health = Health::kUncalibrated;
    snap_.health_reason = std::to_string(snap_.poses_used) + " of the " + std::to_string(needed) + " poses needed";
    return;
  }
  if (!why.str().empty()) {
    if (last_good_) {
      snap_.health = Health::kHoldLastGood;
      snap_.held_version = last_good_->version;
      snap_.params = last_good_->params;
      snap_.estimated = last_good_->estimated;
      snap_.covariance = last_good_->covariance;
      snap_.extension_params = last_good_->extension_params;
      snap_.health_reason = "holding v" + std::to_string(last_good_->version) + ": " + why.str();
    } else {
      publishEstimate();
      snap_.health = Health::kUncalibrated;
      snap_.health_reason = "nothing good to hold yet: " + why.str();
    }
    return;
  }
  publishEstimate();
  if (snap_.drift_alarm) {
    snap_.health = Health::kDegraded;
    std::ostringstream d;
    d << "drift alarm: recent normalized innovation " << snap_.recent_nis_per_row << " per row (alarm above "
      << settings_->drift_alarm_nis_per_row << "): the estimate follows something the noise and drift models do not "
      << "allow (a biased tracker, a missing model effect)";
    snap_.health_reason = d.str();
    return;
  }
  snap_.health = Health::kOk;
  last_good_ = Good{snap_.version, snap_.params, snap_.extension_params, snap_.estimated, snap_.covariance};
}

void CalibrationEngine::refreshStatistics() {
  double sp = 0, so = 0, pe = 0, nis = 0;
  for (const auto& r : recent_) {
    sp += r.post_error_m * r.post_error_m;
    so += r.post_error_rad * r.post_error_rad;
    pe += r.prior_error_m;
    nis += r.nis_per_row;
  }
  const double n = static_cast<double>(recent_.size());
  snap_.residual_rms_position_m = recent_.empty() ? 0.0 : std::sqrt(sp / n);
  snap_.residual_rms_orientation_rad = recent_.empty() ? 0.0 : std::sqrt(so / n);
  snap_.verification_mean_position_m = recent_.empty() ? std::nan("") : pe / n;
  snap_.recent_nis_per_row = recent_.empty() ? 0.0 : nis / n;
  snap_.drift_alarm = recent_.size() >= 10 && snap_.recent_nis_per_row > settings_->drift_alarm_nis_per_row;
  const Eigen::MatrixXd& P = rls_->covariance();
  if (P.rows() > 0) {
    const Eigen::VectorXd d = P.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
    const Eigen::MatrixXd corr = d.asDiagonal() * P * d.asDiagonal();
    const Eigen::VectorXd ev = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(corr, Eigen::EigenvaluesOnly).eigenvalues();
    snap_.condition_number = ev.minCoeff() > 0 ? ev.maxCoeff() / ev.minCoeff() : std::numeric_limits<double>::infinity();
  }
}

void CalibrationEngine::persist() {
  const RobotModel& m = robot_->model;
  json j;
  j["format"] = kStateFormat;
  j["robot_id"] = robot_->robot_id;
  j["robot_name"] = m.name;
  j["num_params"] = m.numParams();
  j["version"] = snap_.version;
  j["poses_used"] = snap_.poses_used;
  j["mode"] = settings_->mode == EngineMode::kContinuous ? "continuous" : "periodic";
  j["last_measurement_stamp_ns"] = snap_.last_measurement_stamp_ns;
  j["last_tracker_sequence"] = snap_.last_tracker_sequence;
  j["last_update_stamp_ns"] = snap_.last_update_stamp_ns;
  j["nominal"] = std::vector<double>(m.nominal.data(), m.nominal.data() + m.nominal.size());
  // The estimator's state (what a restart resumes), which is not what is published while holding a good version.
  const Eigen::VectorXd& params = rls_->params();
  const Eigen::MatrixXd& P = rls_->covariance();
  j["params"] = std::vector<double>(params.data(), params.data() + params.size());
  j["estimated"] = rls_->estimated();
  j["covariance"] = std::vector<double>(P.data(), P.data() + P.size());
  j["consecutive_outliers"] = consecutive_outliers_;
  j["gate_window"] = std::vector<double>(gate_window_.begin(), gate_window_.end());
  if (last_good_ && snap_.health != Health::kOk) {
    const Good& g = *last_good_;
    j["last_good"] = {{"version", g.version},
                      {"params", std::vector<double>(g.params.data(), g.params.data() + g.params.size())},
                      {"extension_params", std::vector<double>(g.extension_params.data(), g.extension_params.data() + g.extension_params.size())},
                      {"estimated", g.estimated},
                      {"covariance", std::vector<double>(g.covariance.data(), g.covariance.data() + g.covariance.size())}};
  }
  json exts = json::array();
  for (const auto& e : rls_->extensions()) exts.push_back(extensionSpec(e));
  j["extensions"] = exts;
  const Eigen::VectorXd& xp = rls_->extensionParams();
  j["extension_params"] = std::vector<double>(xp.data(), xp.data() + xp.size());
  j["estimated_extension"] = rls_->estimatedExtension();
  if (tracks_play_) {
    json play = json::array();
    for (const auto& J : play_.joints()) {
      json turns = json::array();
      for (const auto& t : J.turns) turns.push_back({t.stamp_ns, t.q_rad});
      play.push_back({{"turns", turns}, {"direction", J.direction}, {"extreme", {J.extreme.stamp_ns, J.extreme.q_rad}}});
    }
    j["play"] = {{"joints", play}, {"last_stamp_ns", play_.lastStampNs()}};
  }
  json recent = json::array();
  for (const auto& r : recent_) recent.push_back({r.prior_error_m, r.post_error_m, r.post_error_rad, r.nis_per_row});
  j["recent"] = recent;
  json batch = json::array();
  for (const auto& b : batch_) {
    json o = observationToJson(b.reading);
    if (!rls_->extensions().empty()) o["drivers"] = driversToJson(b.drivers);
    batch.push_back(o);
  }
  j["pending_batch"] = batch;
  // A failed write (disk full, read-only, permissions) leaves the previous file whole (atomicWrite): the update stays
  // in memory, the error is reported, and the next update writes the whole state again.
  try {
    std::error_code ec;
    fs::create_directories(settings_->state_dir, ec);
    atomicWrite(stateFile(), j.dump());
    persist_error_.clear();
    unsynced_ = true;
  } catch (const std::exception& e) {
    ++persist_failures_;
    persist_error_ = std::string("state not saved (the previous file is intact; retried with the next update): ") + e.what();
  }
}

void CalibrationEngine::syncToDisk() {
  if (!unsynced_) return;
  syncStateFile(stateFile());
  unsynced_ = false;
}

bool CalibrationEngine::restore() {
  const std::string path = stateFile();
  std::ifstream in(path);
  if (!in) return false;
  const RobotModel& m = robot_->model;
  auto fail = [&](const std::string& why) -> bool {
    throw std::runtime_error(path + ": " + why + " (move the file away to start this robot's calibration over)");
  };
  json j;
  try {
    j = json::parse(in);
  } catch (const json::exception& e) {
    fail(std::string("not a readable engine state: ") + e.what());
  }
  try {
    if (j.at("format") != kStateFormat) fail("unknown format '" + j.at("format").dump() + "'");
    if (j.at("robot_id") != robot_->robot_id) fail("state of robot '" + j.at("robot_id").get<std::string>() + "'");
    if (j.at("num_params").get<int>() != m.numParams() || j.at("robot_name") != m.name)
      fail("made for model '" + j.at("robot_name").get<std::string>() + "', the cell now says '" + m.name + "'");
    const auto nominal = j.at("nominal").get<std::vector<double>>();
    for (int i = 0; i < m.numParams(); ++i)
      if (nominal.at(i) != m.nominal[i])
        fail("the nominal model changed since (" + m.paramName(i) + "): the state no longer applies");
    const auto params = j.at("params").get<std::vector<double>>();
    const auto estimated = j.at("estimated").get<std::vector<int>>();
    const auto cov = j.at("covariance").get<std::vector<double>>();
    // The covariance is over the state: the estimated kinematic parameters, then any estimated extension ones.
    const auto ne = static_cast<Eigen::Index>(estimated.size());
    const auto nt = static_cast<Eigen::Index>(std::llround(std::sqrt(static_cast<double>(cov.size()))));
    if (static_cast<int>(params.size()) != m.numParams() || nt * nt != static_cast<Eigen::Index>(cov.size()) || nt < ne)
      fail("parameter or covariance size mismatch");
    for (int e : estimated)
      if (e < 0 || e >= m.numParams()) fail("estimated index out of range");
    const Eigen::VectorXd p = Eigen::Map<const Eigen::VectorXd>(params.data(), m.numParams());
    const Eigen::MatrixXd P = Eigen::Map<const Eigen::MatrixXd>(cov.data(), nt, nt);
    if (!p.allFinite() || !P.allFinite()) fail("non-finite values");
    // Extensions: resumed when the cell file still names the same ones; else the kinematic estimate is kept and
    // the cell file's extensions start from their prior (an extension added after `cellcal diagnose` does not
    // throw away hours of calibration).
    std::vector<std::string> saved, wanted;
    if (j.contains("extensions")) saved = j.at("extensions").get<std::vector<std::string>>();
    for (const auto& e : robot_->extensions) wanted.push_back(extensionSpec(e));
    if (saved == wanted && !saved.empty()) {
      const auto xp = j.at("extension_params").get<std::vector<double>>();
      const auto xe = j.at("estimated_extension").get<std::vector<int>>();
      if (static_cast<int>(xp.size()) != numExtensionParams(m, robot_->extensions) ||
          nt != ne + static_cast<Eigen::Index>(xe.size()))
        fail("extension parameter or covariance size mismatch");
      for (int e : xe)
        if (e < 0 || e >= static_cast<int>(xp.size())) fail("estimated extension index out of range");
      rls_ = std::make_unique<RlsCalibrator>(m, p, estimated, robot_->extensions,
                                             Eigen::Map<const Eigen::VectorXd>(xp.data(), static_cast<Eigen::Index>(xp.size())),
                                             xe, P);
    } else {
      const Eigen::MatrixXd Pk = P.topLeftCorner(ne, ne);
      if (robot_->extensions.empty())
        rls_ = std::make_unique<RlsCalibrator>(m, p, estimated, Pk);
      else
        startExtensions(p, estimated, Pk);
      if (saved != wanted) {
        auto list = [](const std::vector<std::string>& v) {
          std::string s;
          for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
          return s.empty() ? std::string("none") : s;
        };
        restore_note_ = "extensions changed since the state was saved (" + list(saved) + " -> " + list(wanted) +
                        "): kinematic estimate kept, extensions start from their prior";
      }
    }
    if (tracks_play_ && j.contains("play")) {
      const json& pl = j.at("play");
      std::vector<PlayTracker::Joint> joints;
      for (const auto& J : pl.at("joints")) {
        PlayTracker::Joint x;
        for (const auto& t : J.at("turns")) x.turns.push_back({t.at(0).get<std::int64_t>(), t.at(1).get<double>()});
        x.direction = J.at("direction").get<int>();
        x.extreme = {J.at("extreme").at(0).get<std::int64_t>(), J.at("extreme").at(1).get<double>()};
        joints.push_back(std::move(x));
      }
      if (static_cast<int>(joints.size()) == m.numJoints()) play_.restore(std::move(joints), pl.at("last_stamp_ns").get<std::int64_t>());
    }
    snap_.version = j.at("version").get<std::uint64_t>();
    snap_.poses_used = j.at("poses_used").get<std::uint32_t>();
    snap_.last_measurement_stamp_ns = j.at("last_measurement_stamp_ns").get<std::int64_t>();
    snap_.last_tracker_sequence = j.at("last_tracker_sequence").get<std::uint64_t>();
    snap_.last_update_stamp_ns = j.at("last_update_stamp_ns").get<std::int64_t>();
    for (const auto& r : j.at("recent"))
      recent_.push_back({r.at(0).get<double>(), r.at(1).get<double>(), r.at(2).get<double>(), r.at(3).get<double>()});
    for (const auto& b : j.at("pending_batch"))
      batch_.push_back({observationFromJson(b), b.contains("drivers") ? driversFromJson(b.at("drivers")) : Drivers{}});
    if (j.contains("consecutive_outliers")) consecutive_outliers_ = j.at("consecutive_outliers").get<int>();
    if (j.contains("gate_window"))
      for (double v : j.at("gate_window").get<std::vector<double>>()) gate_window_.push_back(v);
    if (j.contains("last_good")) {
      const json& g = j.at("last_good");
      Good good;
      good.version = g.at("version").get<std::uint64_t>();
      const auto gp = g.at("params").get<std::vector<double>>();
      const auto gx = g.at("extension_params").get<std::vector<double>>();
      const auto gc = g.at("covariance").get<std::vector<double>>();
      good.estimated = g.at("estimated").get<std::vector<int>>();
      const auto gn = static_cast<Eigen::Index>(std::llround(std::sqrt(static_cast<double>(gc.size()))));
      if (static_cast<int>(gp.size()) != m.numParams() || gn * gn != static_cast<Eigen::Index>(gc.size()))
        fail("last_good: parameter or covariance size mismatch");
      good.params = Eigen::Map<const Eigen::VectorXd>(gp.data(), m.numParams());
      good.extension_params = Eigen::Map<const Eigen::VectorXd>(gx.data(), static_cast<Eigen::Index>(gx.size()));
      good.covariance = Eigen::Map<const Eigen::MatrixXd>(gc.data(), gn, gn);
      if (!good.params.allFinite() || !good.covariance.allFinite()) fail("last_good: non-finite values");
      last_good_ = std::move(good);
    }
  } catch (const json::exception& e) {
    fail(std::string("missing or malformed field: ") + e.what());
  }
  snap_.params = rls_->params();
  snap_.estimated = rls_->estimated();
  snap_.covariance = rls_->covariance();
  snap_.extension_params = rls_->extensionParams();
  pairing_.setAppliedUntil(snap_.last_measurement_stamp_ns);
  if (snap_.version > 0) {
    refreshStatistics();
    decideHealth();
  }
  restored_ = true;
  return true;
}

}  // namespace cellcal
