#include "cellcal/core/engine/calibration_engine.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <iomanip>
#include <cmath>
#include <limits>
#include <random>
#include <sstream>
#include <stdexcept>

#include "cellcal/core/engine/calibration_start.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/model/kinematics.hpp"

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

constexpr size_t kRecentWindow = CalibrationEngine::kRecentPoses;

std::int64_t steadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace

CalibrationEngine::CalibrationEngine(const CellRobot& robot, const EngineSettings& settings, double time_compression)
    : robot_(&robot),
      settings_(&settings),
      time_compression_(time_compression),
      pairing_(robot.model, pairingOptions(robot, settings)),
      play_(robot.model.numJoints(), settings.settle_tolerance_rad),
      inputs_(settings),
      gate_(settings.outlier_gate_nis_per_row, kRecentWindow) {
  for (const auto& e : robot.extensions) tracks_play_ = tracks_play_ || followsPath(e.cause);
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
  snap_.verification_p997_position_m = snap_.verification_max_position_m = std::nan("");
  snap_.last_prior_error_position_m = std::nan("");
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
  {  // their position rows at the nominal parameters, every parameter's column (workspacePredictionSigma selects)
    KinematicsData data(m);
    Eigen::MatrixXd J(6, m.numParams());
    reference_rows_.resize(3 * static_cast<Eigen::Index>(reference_q_.size()), m.numParams());
    for (size_t r = 0; r < reference_q_.size(); ++r) {
      forwardKinematics(m, data, m.nominal, reference_q_[r]);
      computePoseJacobian(m, data, J);
      reference_rows_.middleRows<3>(3 * static_cast<Eigen::Index>(r)) = J.topRows<3>();
    }
  }
  if (robot.start) {
    startFromCalibration(*robot.start, robot.calibration_file);
    return;
  }
  const GaussianPrior prior =
      diagonalPrior(m, m.nominal, m.canonicalParams(), settings.prior_length_m, settings.prior_angle_rad);
  rls_ = std::make_unique<RlsCalibrator>(m, m.nominal, prior, robot.measurement);
  if (!robot.extensions.empty()) startExtensions(rls_->params(), rls_->estimated(), rls_->covariance());
  publishEstimate();
}

void CalibrationEngine::startFromCalibration(const RobotFile& file, const std::string& path) {
  const RobotModel& m = robot_->model;
  const RobotCalibration& cal = *file.calibration;
  const auto& exts = robot_->extensions;
  // The file's kinematics, frames and extension values, the file's covariance conditioned on what the engine does not
  // estimate (calibration_start.hpp). The drift since the file's date is added at the first reading, over the hours
  // from the date to that reading's stamp (the engine takes time from its inputs: a replay of the same readings gives
  // the same result whenever it runs).
  const CalibrationStart start = calibrationStart(m, file, exts, settings_->prior_length_m, settings_->prior_angle_rad,
                                                  robot_->measurement);
  const CalibratedModel& c = start.model;
  const auto date_ns = cal.dateUtcNs();
  file_date_ns_ = date_ns.value_or(0);
  start_prior_sd_ = start.prior_sd;
  const int covered = start.covered, capped = start.capped;
  const Eigen::Index n = c.numEstimated();
  rls_ = std::make_unique<RlsCalibrator>(m, c.params, c.estimated, exts, c.extension_params, c.estimated_extension,
                                         c.covariance);
  started_calibrated_ = true;
  std::ostringstream note;
  note << "started from " << path << ": calibrated " << (date_ns ? cal.provenanceValue("date_utc") : "(no date)");
  if (date_ns) note << " (the first reading widens its covariance by the drift from then to its stamp)";
  else note << " (no date_utc: no drift added)";
  note << "; " << covered << " of the " << n << " estimated parameters from it";
  if (capped) note << ", " << capped << " at most as wide as the uncalibrated prior";
  if (robot_->base_in_tracker || robot_->tool_in_flange)
    note << "; base and tool frames from the file (the cell file's base_in_tracker / tool_in_flange are the "
            "controller's nominal)";
  note << "; on probation until a pose fits it: " << kProbationPoses
       << " first poses in a row beyond the outlier gate (another set-up, a moved tracker) and the engine starts "
          "from the nominal model instead";
  if (cal.nominal_params.size() == m.numParams()) {
    trial_.start(c, cal.nominal_params);
    note << "; judged against the nominal kinematics it started from at its first " << FileTrial::kPositions
         << " positions (the better of the two is kept)";
  } else {
    note << "; not judged against nominal kinematics: the file does not give them (nominal_parameters: saved "
            "before they were kept)";
  }
  for (const auto& e : cal.extensions) {
    bool kept = false;
    for (const auto& x : exts) kept = kept || extensionSpec(x) == extensionSpec(e);
    if (!kept)
      note << "; WARNING: its kinematics were identified with " << extensionSpec(e)
           << ", which the cell's extensions do not name (add it to robots[].extensions)";
  }
  for (const auto& x : exts) {
    bool from_file = false;
    for (const auto& e : cal.extensions) from_file = from_file || extensionSpec(x) == extensionSpec(e);
    if (!from_file) note << "; " << extensionSpec(x) << " starts from its prior (not in the file)";
  }
  start_note_ = note.str();
  publishEstimate();
  snap_.version = 1;
  refreshStatistics();
  decideHealth();
  ++state_revision_;
}

// The drift of the parameters from the calibration file's date to the first reading's stamp (wall-clock hours, as
// the file's date is), each estimated parameter also taking the drift of those it stands for (structuralAbsorption),
// each variance at most the uncalibrated prior's.
void CalibrationEngine::addDriftSinceFile(std::int64_t stamp_ns) {
  const std::int64_t date_ns = file_date_ns_;
  file_date_ns_ = 0;
  const double age_h = std::max(0.0, static_cast<double>(stamp_ns - date_ns) * 1e-9 / 3600.0);
  const RobotModel& m = robot_->model;
  const std::vector<int> est = rls_->estimated();
  const auto ne = static_cast<Eigen::Index>(est.size());
  Eigen::MatrixXd P = rls_->covariance();
  const Eigen::MatrixXd T = structuralAbsorption(m, m.nominal, robot_->measurement, est);
  P.topLeftCorner(ne, ne) += T * drift_sigma_.cwiseAbs2().asDiagonal() * T.transpose() * (age_h / settings_->drift_per_h);
  const int capped = capVariances(P, start_prior_sd_);
  rls_ = std::make_unique<RlsCalibrator>(m, rls_->params(), est, rls_->extensions(), rls_->extensionParams(),
                                         rls_->estimatedExtension(), P);
  std::ostringstream note;
  if (stamp_ns <= date_ns)
    note << "first reading at or before the calibration file's date (by its stamp): no drift added";
  else
    note << "first reading " << std::fixed << std::setprecision(1) << age_h
         << " h after the calibration file's date (by its stamp): the drift model widened the file's covariance over "
            "that time";
  if (capped) note << ", " << capped << " parameters at most as wide as the uncalibrated prior";
  notes_.push_back(note.str());
  ++state_revision_;
}

// The readings held while the calibration file was on probation contradicted it: the engine starts over from the
// nominal model and the cell file's registration, then takes those readings.
bool CalibrationEngine::refuseCalibrationFile(double gate) {
  std::vector<Pending> held;
  for (auto& h : probation_.take()) held.push_back(std::move(h.pending));
  refused_file_ = true;
  startOverFromNominal(probation_.refusal(robot_->calibration_file, gate), held);
  return true;
}

// The trial's poses judged the file against its nominal kinematics: kept (said), or withdrawn and started over.
bool CalibrationEngine::judgeCalibrationFile() {
  const FileVerdict v = trial_.judge(robot_->model);
  file_verdict_ = v;
  const std::vector<Pending> poses = trial_.take();
  const std::string text = v.text(robot_->calibration_file);
  ++state_revision_;
  if (!v.judged || !v.nominal_better) {
    notes_.push_back(text);
    return false;
  }
  file_worse_ = true;
  // Those poses are applied again: they were counted when paired, and were all the engine applied since it started.
  counters_.paired -= std::min<std::uint64_t>(counters_.paired, poses.size());
  applied_readings_.clear();
  startOverFromNominal(text, poses);
  return true;
}

void CalibrationEngine::startOverFromNominal(const std::string& why, const std::vector<Pending>& readings) {
  const RobotModel& m = robot_->model;
  const GaussianPrior prior =
      diagonalPrior(m, m.nominal, m.canonicalParams(), settings_->prior_length_m, settings_->prior_angle_rad);
  rls_ = std::make_unique<RlsCalibrator>(m, m.nominal, prior, robot_->measurement);
  if (!robot_->extensions.empty()) startExtensions(rls_->params(), rls_->estimated(), rls_->covariance());
  started_calibrated_ = false;
  file_date_ns_ = 0;
  trial_.take();
  last_good_.reset();
  recent_.clear();
  gate_.clear();
  batch_.clear();
  used_q_.resize(0);
  snap_.last_update_stamp_ns = 0;
  snap_.poses_used = 0;
  snap_.last_prior_error_position_m = std::nan("");  // the withdrawing version: no pose made it
  work_.restore({});
  ++work_revision_;
  work_replaced_.clear();
  snap_.start_warning = why;
  notes_.push_back("WARNING: " + why);
  ++snap_.version;  // the file's model is withdrawn at once: compensation must stop applying it
  publishEstimate();
  refreshStatistics();
  decideHealth();
  ++state_revision_;
  // Each was a stand-still of its own when it came (the joint history of a resumed engine may not reach back to it).
  replaying_ = true;
  for (const auto& r : readings) handlePaired(r);
  replaying_ = false;
}

std::vector<std::string> CalibrationEngine::takeNotes() {
  std::vector<std::string> out(notes_.begin(), notes_.end());
  notes_.clear();
  return out;
}

void CalibrationEngine::publishEstimate() {
  static_cast<CalibratedModel&>(snap_) = rls_->model();
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

void CalibrationEngine::reject(Rejection r, const std::string& detail) {
  ++counters_.rejected[static_cast<size_t>(r)];
  counters_.last_rejection = std::string(rejectionName(r)) + ": " + detail;
}

bool CalibrationEngine::admitted(std::optional<Rejection> r, const std::string& id, const std::string& detail) {
  if (!r) return true;
  reject(*r, id + " " + detail);
  return false;
}

bool CalibrationEngine::onJointState(const JointSample& s, std::int64_t receive_ns) {
  ++counters_.joint_states;
  inputs_.jointReceived(receive_ns);
  std::string detail;
  if (!admitted(pairing_.addJointState(s, receive_ns, &detail), robot_->robot_id, detail)) return false;
  if (tracks_play_) play_.add(s.stamp_ns, s.q_rad);
  inputs_.jointAdmitted(s);  // a new stand-still starts a new pose
  return true;
}

// Same stand-still as the one whose joints were q at stamp_ns: same joints, and no motion seen in between.
bool CalibrationEngine::samePose(const PairedReading& p, const Eigen::VectorXd& q, std::int64_t stamp_ns) const {
  if (q.size() != p.observation.q_rad.size()) return false;
  if ((p.observation.q_rad - q).cwiseAbs().maxCoeff() > settings_->settle_tolerance_rad) return false;
  return !inputs_.movedBetween(stamp_ns, p.joint_stamp_ns);
}

std::string CalibrationEngine::clockWarning() const {
  const auto hint = pairing_.clockOffsetHint();
  return hint ? clockOffsetText(*hint) : "";
}

std::string CalibrationEngine::staleInputs(std::int64_t now_ns) const { return inputs_.staleInputs(now_ns); }

bool CalibrationEngine::onTrackerSample(const TrackerSample& s, std::int64_t receive_ns) {
  ++counters_.tracker_readings;
  inputs_.trackerReceived(receive_ns);
  std::string detail;
  return admitted(pairing_.addTrackerSample(s, receive_ns, &detail), robot_->target_id, detail);
}

bool CalibrationEngine::process(std::int64_t now_ns) {
  PairingOutcome out = pairing_.poll(now_ns);
  for (const auto& [r, d] : out.rejected) reject(r, robot_->target_id + " " + d);
  bool changed = false;
  for (const auto& p : out.paired) {
    const bool extended = !rls_->extensions().empty();
    Pending pending{p, extended ? play_.driversAt(p.joint_stamp_ns, p.observation.q_rad) : Drivers{}};
    changed = handlePaired(pending) || changed;
  }
  return changed;
}

// One paired reading: the outlier gate (with the calibration file on probation at the start), one update per
// stand-still, continuous or periodic. True when a version was made or the health changed.
bool CalibrationEngine::handlePaired(const Pending& pending) {
  const PairedReading& p = pending.reading;
  const auto t0 = steadyNs();
  if (file_date_ns_ != 0) addDriftSinceFile(p.tracker_stamp_ns);
  const bool same_as_used = !replaying_ && samePose(p, used_q_, used_joint_stamp_ns_);
  if (gate_.enabled())
    if (const std::optional<bool> stopped = gateReading(pending, same_as_used)) return *stopped;
  // A pose passed the gate: readings held on probation were outliers after all.
  for (const auto& h : probation_.take()) reject(Rejection::kOutlier, h.rejection);
  gate_.passed();
  ++counters_.paired;
  // One update per stand-still: further readings of the same pose repeat its robot error (repeatability), so
  // using them as independent observations would overweight the pose. The first reading is used at once.
  if (same_as_used) {
    ++counters_.same_pose;
    return false;
  }
  used_q_ = p.observation.q_rad;
  used_joint_stamp_ns_ = p.joint_stamp_ns;
  bool changed = usePose(pending);
  // A calibration file on trial: its first positions judge it against its nominal kinematics.
  if (trial_.active() && trial_.keep(pending)) changed = judgeCalibrationFile() || changed;
  last_update_duration_ns_ = steadyNs() - t0;
  return changed;
}

// The outlier gate on a paired reading: nullopt when it passed. Else the reading is rejected as an outlier, held while
// the calibration file is on probation, or refuses the file, and the value is handlePaired's: true when the health
// changed (outliers in a row hold the last good version at once) or the file was refused.
std::optional<bool> CalibrationEngine::gateReading(const Pending& pending, bool same_as_used) {
  const PairedReading& p = pending.reading;
  const bool extended = !rls_->extensions().empty();
  // After a silence longer than the drift model's period (a tracker link down for hours of cell time), the gate's
  // window describes the robot as it was: its innovations are judged afresh (once per silence), so a robot that
  // drifted further than the model allows is followed after a few poses (and the drift alarm says so) instead of
  // every pose after the silence being gated against the old window.
  if (snap_.last_update_stamp_ns > 0 &&
      (p.tracker_stamp_ns - snap_.last_update_stamp_ns) * 1e-9 * time_compression_ / 3600.0 > settings_->drift_per_h)
    gate_.clearOnceAfter(snap_.last_update_stamp_ns);
  const double nis = rls_->normalizedInnovation(p.observation, extended ? &pending.drivers : nullptr);
  const int rows = p.observation.rows();
  const double gate = gate_.gate(rows);  // scaled by the recent median NIS per row (outlier_gate.hpp)
  const bool new_stand_still =
      !same_as_used && (replaying_ || !samePose(p, gate_.gatedQ(), gate_.gatedJointStampNs()));
  if (new_stand_still && std::isfinite(nis)) gate_.record(nis / rows);
  if (nis <= gate) return std::nullopt;
  std::ostringstream m;
  m << robot_->target_id << " tracker reading #" << p.tracker_sequence << ": normalized innovation " << nis
    << " above the gate " << gate << " (" << rows << " rows)";
  // A calibration file on probation (no pose has passed the gate since the engine started from it): its first
  // stand-stills are held; kProbationPoses in a row beyond the gate mean it does not fit this cell.
  if (new_stand_still && onProbation()) {
    const Pose predicted = rls_->predict(p.observation.q_rad, extended ? &pending.drivers : nullptr);
    const bool refused = probation_.hold(
        {pending, m.str(), (p.observation.measured_in_tracker.translation() - predicted.translation()).norm(),
         nis / rows});
    gate_.gatedStandStill(p.observation.q_rad, p.joint_stamp_ns, /*count=*/false);
    return refused && refuseCalibrationFile(gate);
  }
  reject(Rejection::kOutlier, m.str());
  if (!new_stand_still) return false;
  gate_.gatedStandStill(p.observation.q_rad, p.joint_stamp_ns, /*count=*/true);
  const Health before = snap_.health;
  decideHealth();
  return snap_.health != before;  // publish the hold at once
}

// A pose that passed the gate into the estimate: at once (continuous), or with its batch (periodic). True when a
// version was made.
bool CalibrationEngine::usePose(const Pending& pending) {
  const PairedReading& p = pending.reading;
  if (settings_->mode == EngineMode::kContinuous) {
    if (!applyPose(pending)) return false;
    finishUpdate(p.tracker_stamp_ns, p.tracker_sequence);
    return true;
  }
  batch_.push_back(pending);
  if (static_cast<int>(batch_.size()) < settings_->batch_poses) {
    snap_.last_measurement_stamp_ns = p.tracker_stamp_ns;
    snap_.last_tracker_sequence = p.tracker_sequence;
    pairing_.setAppliedUntil(p.tracker_stamp_ns);
    ++state_revision_;
    return false;
  }
  bool any = false;
  for (const auto& b : batch_) any = applyPose(b) || any;
  batch_.clear();
  if (any) finishUpdate(p.tracker_stamp_ns, p.tracker_sequence);
  return any;
}

bool CalibrationEngine::applyPose(const Pending& pending) {
  const PairedReading& p = pending.reading;
  const Drivers* drivers = rls_->extensions().empty() ? nullptr : &pending.drivers;
  rls_->save(rollback_);  // for a roll-back
  // Random walk of the parameters over the cell time since the previous update.
  if (snap_.last_update_stamp_ns > 0 && p.tracker_stamp_ns > snap_.last_update_stamp_ns) {
    const double dt_h = (p.tracker_stamp_ns - snap_.last_update_stamp_ns) * 1e-9 * time_compression_ / 3600.0;
    rls_->addProcessNoise(drift_sigma_, robot_->measurement, dt_h / settings_->drift_per_h);
  }
  const Observation& o = p.observation;
  const Pose before = rls_->predict(o.q_rad, drivers);
  const double nis = rls_->addObservation(o, drivers);
  const Pose after = rls_->predict(o.q_rad, drivers);
  if (!std::isfinite(nis) || !rls_->params().allFinite() || !rls_->extensionParams().allFinite() ||
      !rls_->covariance().allFinite() || !after.matrix().allFinite()) {
    rls_->restore(rollback_);
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
  snap_.last_prior_error_position_m = r.prior_error_m;
  while (recent_.size() > kRecentWindow) recent_.pop_front();
  const std::size_t work_before = work_.configurations().size();
  if (const std::optional<std::size_t> changed = work_.offer(o.q_rad)) {
    if (work_.configurations().size() != work_before) ++work_revision_;
    else work_replaced_.push_back(*changed);
  }
  ++snap_.poses_used;
  applied_readings_.push_back({p.tracker_sequence, p.tracker_stamp_ns});
  if (applied_readings_.size() > kAppliedKept) applied_readings_.pop_front();
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
  ++state_revision_;
}

// Worst of sqrt(trace(J P J^T)) for the position rows, kinematic part of the state, over the work configurations
// (where the cell works), with J at the nominal parameters (the linearization the predicted error needs: the
// estimate's corrections change it by their relative size, 1e-3). The rows are the RLS estimator's tracked
// variances: each update brings them up to date at a cost of the update's rank (6) instead of the state's size, and
// each configuration's variance is the sum of its three. A replaced configuration's rows alone are computed again.
// The engine test checks every configuration's figure against kinematicPositionSigma.
double CalibrationEngine::predictionSigma() {
  const RobotModel& m = robot_->model;
  const std::vector<int>& estimated = rls_->estimated();
  const std::vector<Eigen::VectorXd>& work = work_.configurations();
  const auto configs = static_cast<Eigen::Index>(work.size());
  const Eigen::Index state = rls_->covariance().rows();
  std::optional<KinematicsData> data;  // made only when rows are (most poses change none)
  Eigen::MatrixXd J;
  auto rowsAt = [&](Eigen::Index r) {
    if (!data) {
      data.emplace(m);
      J.resize(6, m.numParams());
    }
    forwardKinematics(m, *data, m.nominal, work[static_cast<size_t>(r)]);
    computePoseJacobian(m, *data, J);
    for (size_t c = 0; c < estimated.size(); ++c)
      sigma_rows_.block<3, 1>(3 * r, static_cast<Eigen::Index>(c)) = J.col(estimated[c]).head<3>();
  };
  // Rebuilt when the state changes shape or the work configurations change in number (or are restored); tracked
  // again by each new estimator (a new rls_ tracks nothing).
  const bool rebuild = sigma_rows_.rows() != 3 * configs || sigma_rows_.cols() != state ||
                       sigma_rows_estimated_ != estimated || sigma_rows_work_revision_ != work_revision_;
  if (rebuild) {
    sigma_rows_ = Eigen::MatrixXd::Zero(3 * configs, state);
    for (Eigen::Index r = 0; r < configs; ++r) rowsAt(r);
    sigma_rows_estimated_ = estimated;
    sigma_rows_work_revision_ = work_revision_;
  } else {
    for (const std::size_t w : work_replaced_) {
      const auto r = static_cast<Eigen::Index>(w);
      rowsAt(r);
      if (rls_->estimator().trackedRows().rows() == sigma_rows_.rows())
        rls_->retrackRows(3 * r, sigma_rows_.middleRows<3>(3 * r));
    }
  }
  work_replaced_.clear();
  if (rebuild || rls_->estimator().trackedRows().rows() != sigma_rows_.rows()) rls_->trackVariances(sigma_rows_);
  const Eigen::VectorXd& v = rls_->estimator().trackedVariances();
  work_sigma_m_.assign(work.size(), 0.0);
  double worst = 0;
  for (Eigen::Index r = 0; r < configs; ++r) {
    const double var = v.segment<3>(3 * r).sum();
    const double sigma = std::isfinite(var) ? std::sqrt(std::max(0.0, var)) : std::numeric_limits<double>::infinity();
    work_sigma_m_[static_cast<size_t>(r)] = sigma;
    worst = std::max(worst, sigma);
  }
  return worst;
}

// The same over the reference configurations, from the estimator's covariance directly (for the diagnostics' period
// and the health rule before the first pose, not for every pose).
double CalibrationEngine::workspacePredictionSigma() const {
  const std::vector<int>& estimated = rls_->estimated();
  const auto ne = static_cast<Eigen::Index>(estimated.size());
  Eigen::MatrixXd G(reference_rows_.rows(), ne);
  for (Eigen::Index c = 0; c < ne; ++c) G.col(c) = reference_rows_.col(estimated[static_cast<size_t>(c)]);
  const Eigen::VectorXd v = (G * rls_->covariance().topLeftCorner(ne, ne)).cwiseProduct(G).rowwise().sum();
  double worst = 0;
  for (Eigen::Index r = 0; 3 * r < v.size(); ++r) {
    const double var = v.segment<3>(3 * r).sum();
    if (!std::isfinite(var)) return std::numeric_limits<double>::infinity();
    worst = std::max(worst, std::sqrt(std::max(0.0, var)));
  }
  return worst;
}

// The health rule (health.hpp) on this estimate; a hold publishes the last good version's model.
void CalibrationEngine::decideHealth() {
  // Where the cell works; before its first pose, over the workspace.
  snap_.prediction_sigma_position_m = work_.empty() ? workspacePredictionSigma() : predictionSigma();
  HealthFacts f;
  f.poses_used = snap_.poses_used;
  f.poses_needed = posesNeeded(rls_->estimated().size() + rls_->estimatedExtension().size(), robot_->measurement,
                               started_calibrated_);
  f.consecutive_outliers = gate_.inARow();
  f.prediction_sigma_m = snap_.prediction_sigma_position_m;
  f.work_configurations = work_.configurations().size();
  f.drift_alarm = snap_.drift_alarm;
  f.recent_nis_per_row = snap_.recent_nis_per_row;
  if (last_good_) f.good_version = last_good_->version;
  f.refused_file = refused_file_;
  f.file_worse = file_worse_;
  const HealthVerdict v = judgeHealth(f, *settings_);
  snap_.drift_alarm = v.drift_alarm;
  snap_.health = v.health;
  snap_.health_verdict = v;
  snap_.held_version = v.hold ? last_good_->version : 0;
  if (v.hold) static_cast<CalibratedModel&>(snap_) = *last_good_;
  else publishEstimate();
  if (v.health == Health::kOk) last_good_ = EngineState::Good{snap_, snap_.version};
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
  std::vector<double> prior;
  for (const auto& r : recent_) prior.push_back(r.prior_error_m);
  snap_.verification_p997_position_m = recent_.empty() ? std::nan("") : percentile(prior, 0.997);
  snap_.verification_max_position_m = recent_.empty() ? std::nan("") : *std::max_element(prior.begin(), prior.end());
  snap_.verification_poses = static_cast<std::uint32_t>(recent_.size());
  snap_.recent_nis_per_row = recent_.empty() ? 0.0 : nis / n;
  snap_.drift_alarm = recent_.size() >= 10 && snap_.recent_nis_per_row > settings_->drift_alarm_nis_per_row;
}

double CalibrationEngine::conditionNumber() const {
  const Eigen::MatrixXd& P = rls_->covariance();
  if (P.rows() == 0) return 0.0;
  const Eigen::VectorXd d = P.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
  const Eigen::MatrixXd corr = d.asDiagonal() * P * d.asDiagonal();
  const Eigen::VectorXd ev = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(corr, Eigen::EigenvaluesOnly).eigenvalues();
  return ev.minCoeff() > 0 ? ev.maxCoeff() / ev.minCoeff() : std::numeric_limits<double>::infinity();
}

EngineState CalibrationEngine::exportState() const {
  const RobotModel& m = robot_->model;
  EngineState s;
  s.robot_id = robot_->robot_id;
  s.robot_name = m.name;
  s.num_params = m.numParams();
  s.nominal = m.nominal;
  s.mode = settings_->mode;
  s.version = snap_.version;
  s.poses_used = snap_.poses_used;
  s.last_measurement_stamp_ns = snap_.last_measurement_stamp_ns;
  s.last_tracker_sequence = snap_.last_tracker_sequence;
  s.last_update_stamp_ns = snap_.last_update_stamp_ns;
  // The estimator's state (what a restart resumes), which is not what is published while holding a good version.
  s.params = rls_->params();
  s.estimated = rls_->estimated();
  s.covariance = rls_->covariance();
  for (const auto& e : rls_->extensions()) s.extensions.push_back(extensionSpec(e));
  s.extension_params = rls_->extensionParams();
  s.estimated_extension = rls_->estimatedExtension();
  s.consecutive_outliers = gate_.inARow();
  s.gate_window.assign(gate_.window().begin(), gate_.window().end());
  if (last_good_ && snap_.health != Health::kOk)
    s.last_good = last_good_;
  if (tracks_play_) s.play = EngineState::Play{play_.joints(), play_.lastStampNs()};
  for (const auto& r : recent_) s.recent.push_back({r.prior_error_m, r.post_error_m, r.post_error_rad, r.nis_per_row});
  const bool extended = !rls_->extensions().empty();
  for (const auto& b : batch_)
    s.pending_batch.push_back({b.reading, extended ? std::optional<Drivers>(b.drivers) : std::nullopt});
  s.started_from = refused_file_         ? EngineState::Start::kNominalFileRefused
                   : file_worse_         ? EngineState::Start::kNominalFileWorse
                   : started_calibrated_ ? EngineState::Start::kCalibrationFile
                                         : EngineState::Start::kNominal;
  if (trial_.active()) {
    EngineState::FileTrialState t{trial_.fileModel().params, trial_.fileModel().extension_params,
                                  trial_.nominalParams(), {}};
    for (const auto& p : trial_.poses())
      t.poses.push_back({p.reading, extended ? std::optional<Drivers>(p.drivers) : std::nullopt});
    s.file_trial = std::move(t);
  }
  s.file_drift_pending_since_ns = file_date_ns_;
  s.start_warning = snap_.start_warning;
  s.work_configurations = work_.configurations();
  return s;
}

void CalibrationEngine::importState(const EngineState& s) {
  const RobotModel& m = robot_->model;
  auto fail = [](const std::string& why) { throw std::runtime_error(why); };
  if (s.robot_id != robot_->robot_id) fail("state of robot '" + s.robot_id + "'");
  if (s.num_params != m.numParams() || s.robot_name != m.name)
    fail("made for model '" + s.robot_name + "', the cell now says '" + m.name + "'");
  if (s.nominal.size() != m.numParams()) fail("the nominal model changed since: the state no longer applies");
  for (int i = 0; i < m.numParams(); ++i)
    if (s.nominal[i] != m.nominal[i])
      fail("the nominal model changed since (" + m.paramName(i) + "): the state no longer applies");
  // The covariance is over the state: the estimated kinematic parameters, then any estimated extension ones.
  const auto ne = static_cast<Eigen::Index>(s.estimated.size());
  const Eigen::Index nt = s.covariance.rows();
  if (s.params.size() != m.numParams() || s.covariance.cols() != nt || nt < ne) fail("parameter or covariance size mismatch");
  for (int e : s.estimated)
    if (e < 0 || e >= m.numParams()) fail("estimated index out of range");
  if (!s.params.allFinite() || !s.covariance.allFinite()) fail("non-finite values");
  std::optional<EngineState::Good> good = s.last_good;
  if (good) {
    if (good->params.size() != m.numParams() || good->covariance.rows() != good->covariance.cols())
      fail("last_good: parameter or covariance size mismatch");
    if (!good->params.allFinite() || !good->covariance.allFinite()) fail("last_good: non-finite values");
  }
  // Extensions: resumed when the cell file still names the same ones; else the kinematic estimate is kept and the
  // cell file's extensions start from their prior (an extension added after `cellcal diagnose` does not throw away
  // hours of calibration).
  std::vector<std::string> wanted;
  for (const auto& e : robot_->extensions) wanted.push_back(extensionSpec(e));
  std::string note;
  if (s.extensions == wanted && !wanted.empty()) {
    if (s.extension_params.size() != numExtensionParams(m, robot_->extensions) ||
        nt != ne + static_cast<Eigen::Index>(s.estimated_extension.size()))
      fail("extension parameter or covariance size mismatch");
    for (int e : s.estimated_extension)
      if (e < 0 || e >= s.extension_params.size()) fail("estimated extension index out of range");
    rls_ = std::make_unique<RlsCalibrator>(m, s.params, s.estimated, robot_->extensions, s.extension_params,
                                           s.estimated_extension, s.covariance);
  } else {
    const Eigen::MatrixXd Pk = s.covariance.topLeftCorner(ne, ne);
    if (robot_->extensions.empty())
      rls_ = std::make_unique<RlsCalibrator>(m, s.params, s.estimated, Pk);
    else
      startExtensions(s.params, s.estimated, Pk);
    if (s.extensions != wanted) {
      auto list = [](const std::vector<std::string>& v) {
        std::string out;
        for (const auto& x : v) out += (out.empty() ? "" : ", ") + x;
        return out.empty() ? std::string("none") : out;
      };
      note = "extensions changed since the state was saved (" + list(s.extensions) + " -> " + list(wanted) +
             "): kinematic estimate kept, extensions start from their prior";
    }
  }
  start_note_.clear();
  // How it started: kept since states say it; before, the cell file's calibration_file decided, and the drift since
  // the file's date was in the saved covariance.
  file_date_ns_ = 0;
  if (s.started_from) {
    started_calibrated_ = *s.started_from == EngineState::Start::kCalibrationFile;
    refused_file_ = *s.started_from == EngineState::Start::kNominalFileRefused;
    file_worse_ = *s.started_from == EngineState::Start::kNominalFileWorse;
    if (started_calibrated_) file_date_ns_ = s.file_drift_pending_since_ns;
    snap_.start_warning = s.start_warning;
  }
  probation_.take();  // readings held before the import are not the resumed state's
  trial_.take();
  if (s.file_trial) {  // a trial running when the state was saved: resumed with the model it judges
    const auto& t = s.file_trial.value();
    if (t.file_params.size() != m.numParams() || t.nominal.size() != m.numParams() ||
        t.file_extension_params.size() != rls_->extensionParams().size())
      fail("file_trial: parameter size mismatch");
    CalibratedModel file = CalibratedModel::geometric(t.file_params);
    file.extensions = rls_->extensions();
    file.extension_params = t.file_extension_params;
    std::vector<Pending> poses;
    for (const auto& p : t.poses) poses.push_back({p.reading, p.drivers ? *p.drivers : Drivers{}});
    trial_.restore(std::move(file), t.nominal, std::move(poses));
  }
  if (robot_->start)
    note += std::string(note.empty() ? "" : "; ") + "resumed from its state file: calibration_file " +
            robot_->calibration_file + " (the start of a new cell) is not used";
  restore_note_ = note;
  if (tracks_play_ && s.play && static_cast<int>(s.play->joints.size()) == m.numJoints())
    play_.restore(s.play->joints, s.play->last_stamp_ns);
  snap_.version = s.version;
  snap_.poses_used = s.poses_used;
  snap_.last_measurement_stamp_ns = s.last_measurement_stamp_ns;
  snap_.last_tracker_sequence = s.last_tracker_sequence;
  snap_.last_update_stamp_ns = s.last_update_stamp_ns;
  recent_.clear();
  for (const auto& r : s.recent) recent_.push_back({r.prior_error_m, r.post_error_m, r.post_error_rad, r.nis_per_row});
  batch_.clear();
  for (const auto& b : s.pending_batch) batch_.push_back({b.reading, b.drivers ? *b.drivers : Drivers{}});
  gate_.restore(s.gate_window.begin(), s.gate_window.end(), s.consecutive_outliers);
  std::vector<Eigen::VectorXd> work;
  for (const auto& q : s.work_configurations)
    if (q.size() == m.numJoints() && q.allFinite()) work.push_back(q);
  work_.restore(work);
  ++work_revision_;
  work_replaced_.clear();
  if (good) {  // the files keep its extensions and their estimated set once, as the state's
    good->extensions = rls_->extensions();
    good->estimated_extension = rls_->estimatedExtension();
    if (good->extension_params.size() != numExtensionParams(m, good->extensions)) {
      good.reset();  // made with other extensions: it cannot be published as this cell file's model
      restore_note_ += std::string(restore_note_.empty() ? "" : "; ") + "the held good version was made with other "
                       "extensions and is not kept";
    }
  }
  last_good_ = std::move(good);
  publishEstimate();
  pairing_.setAppliedUntil(snap_.last_measurement_stamp_ns);
  if (snap_.version > 0) {
    refreshStatistics();
    decideHealth();
  }
}

std::map<std::string, std::uint64_t> rejectionCounts(const EngineCounters& counters) {
  std::map<std::string, std::uint64_t> out;
  for (size_t k = 0; k < counters.rejected.size(); ++k)
    if (counters.rejected[k]) out[rejectionName(static_cast<Rejection>(k))] = counters.rejected[k];
  return out;
}

}  // namespace cellcal
