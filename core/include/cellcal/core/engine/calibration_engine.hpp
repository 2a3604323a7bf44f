// The calibration engine of one robot, without DDS: samples in, calibrations out. The engine process wraps one per
// robot of the cell file; `cellcal validate` runs the same code over a recording.
//
// Flow: joint states and tracker readings -> PairingBuffer -> Observation -> (process noise for the cell time since
// the previous update) -> RLS update, per pose (continuous mode) or per batch of N poses (periodic mode) -> a new
// version. A pose is one stand-still of the robot: the first reading paired in it is used, later readings of the
// same stand-still are counted (same_pose) and not applied (their robot error is the same; a tracker streaming at
// 1 kHz must not weigh a pose a thousand times). Before a pose updates the estimate, the current calibration predicts it: those a-priori errors are the
// engine's honest running verification (the pose was not used to make the prediction).
// State: exportState() gives everything a restart needs (estimate, covariance, counters, the unapplied poses of a
// periodic batch; engine_state.hpp), importState() resumes from it; stateRevision() changes whenever a restart would
// need a new copy (every accepted pose). The engine touches no file: its host (components' EngineHost) writes the
// state file (engine/state_file.hpp) after every change, before it publishes, so nothing published is lost on a
// SIGKILL; a resumed engine rejects readings at or before the last applied one, so no update is lost or applied twice.
//
// Safety (docs/RELIABILITY.md):
//  - gate: a pose whose normalized innovation is beyond the chi-square gate (EngineSettings::outlier_gate_probability)
//    is rejected as an outlier; outlier_hold_after stand-stills gated in a row mean the robot or the tracker changed
//    (a bumped station): drift alarm and health hold_last_good until a pose passes the gate again;
//  - an update that would make the estimate non-finite is rolled back (unsafe_update);
//  - the published calibration is the estimate while it is healthy. When the model's predicted position error
//    (1 sigma, worst over where the cell works: the configurations it measured, work_configurations.hpp) exceeds
//    hold_prediction_sigma_m (covariance blow-up, or directions the recent poses no longer excite), the engine keeps
//    learning but publishes the last good
//    calibration with health hold_last_good; a drift alarm (recent NIS per row too high: a slowly biased tracker,
//    a missing model effect) publishes the estimate with health degraded, and compensation keeps its last ok one.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/engine/engine_state.hpp"
#include "cellcal/core/engine/file_probation.hpp"
#include "cellcal/core/engine/file_trial.hpp"
#include "cellcal/core/engine/health.hpp"
#include "cellcal/core/engine/input_watch.hpp"
#include "cellcal/core/engine/outlier_gate.hpp"
#include "cellcal/core/engine/pairing.hpp"
#include "cellcal/core/engine/work_configurations.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/identification/rls.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {


// What the engine publishes: the calibrated model (calibrated_model.hpp: the RLS estimate, or the held version's;
// extensions are the cell file's, CellRobot::extensions; the covariance is over every estimated kinematic, then
// extension parameter) and the engine's version, health and statistics.
struct CalibrationSnapshot : CalibratedModel {
  std::uint64_t version = 0;          // 0 = nothing identified yet; +1 per accepted update
  EngineMode mode = EngineMode::kContinuous;
  Health health = Health::kUncalibrated;
  std::uint32_t poses_used = 0;
  double residual_rms_position_m = 0;     // a-posteriori, over the recent window of used poses
  double residual_rms_orientation_rad = 0;
  double verification_mean_position_m = 0;  // a-priori prediction error over the recent window (NaN until known)
  // The same errors' 99.7th percentile (statistics.hpp's percentile: the max below 334 poses) and max, and how many
  // poses the window holds (at most kRecentPoses): one held-out figure, named as every summary names it.
  double verification_p997_position_m = 0, verification_max_position_m = 0;
  std::uint32_t verification_poses = 0;
  // The a-priori position error of the pose that made this version (predicted before it was used; NaN for a version
  // no pose made): a run's held-out errors are these, one per update.
  double last_prior_error_position_m = 0;
  std::int64_t last_measurement_stamp_ns = 0;
  std::uint64_t last_tracker_sequence = 0;
  std::int64_t last_update_stamp_ns = 0;    // stamp of the reading that made this version
  // Consistency: mean normalized innovation squared per measurement row over the recent poses (about 1 when the
  // noise and drift models hold). Above EngineSettings::drift_alarm_nis_per_row (with >= 10 recent poses): the
  // robot moves faster than the drift model allows, or the model misses an effect -> drift_alarm.
  double recent_nis_per_row = 0;
  bool drift_alarm = false;
  // Predicted 1-sigma position error of the estimate where the cell works (worst over the configurations the engine
  // measured, work_configurations.hpp; over the reference configurations of the workspace until it has measured one),
  // m: the figure health is judged on. The same over the whole workspace: CalibrationEngine::workspacePredictionSigma.
  double prediction_sigma_position_m = 0;
  // The health rule's verdict on this version: its cause and what it was decided on (health.hpp; describe() words it,
  // e.g. "holding v52: 5 poses in a row beyond the outlier gate").
  HealthVerdict health_verdict;
  // When health is hold_last_good: the version whose parameters are published (params, covariance, ... are its).
  std::uint64_t held_version = 0;
  // Set when the engine refused its calibration file (its first poses contradicted it) or withdrew it (its first
  // positions held its nominal kinematics better, file_trial.hpp) and started from nominal.
  std::string start_warning;
};

struct EngineCounters {
  std::array<std::uint64_t, static_cast<size_t>(Rejection::kCount)> rejected{};
  std::uint64_t joint_states = 0, tracker_readings = 0, paired = 0;
  std::uint64_t same_pose = 0;               // paired readings of a pose already used (not applied again)
  std::string last_rejection;                // detail of the most recent rejection
};

class CalibrationEngine {
 public:
  // The recent window of the snapshot's statistics (verification_mean_position_m, residuals, NIS): this many poses.
  static constexpr size_t kRecentPoses = 30;
  // `robot` and `settings` must outlive the engine. It starts uncalibrated, from the nominal model and the prior; or,
  // when the cell file gives the robot a calibration_file (CellRobot::start), calibrated: version 1, health ok (when
  // its predicted error is within hold_prediction_sigma_m), the file's kinematics, frames and extension values the
  // estimate, its covariance the prior. The first reading widens each parameter's variance by the drift model over the
  // hours from the file's date to that reading's stamp (at most to the uncalibrated prior's): the engine takes time
  // from its inputs, never from the clock. Parameters the file does not cover (an extension it did not fit) start from
  // the engine's prior. startNote() says what was taken.
  // The file is on probation until a pose passes the outlier gate (file_probation.hpp): when its first
  // kProbationPoses stand-stills are all beyond the gate (calibrated on another set-up, a moved tracker), the engine
  // says so (snapshot().start_warning, takeNotes()), starts from the nominal model and the cell file's registration,
  // and applies those readings.
  // A file that fits is on trial against the kinematics it started from (file_trial.hpp: RobotCalibration::
  // nominal_params; files saved before they were kept are not judged): at its first FileTrial::kPositions positions,
  // the file's model and its nominal kinematics, frames registered alike, are judged on held-out positions. Where the
  // nominal kinematics do better, the engine says so with both figures, withdraws the file's model (a new version)
  // and starts from the nominal model, applying those poses again; else it says that the file is kept, with both.
  static constexpr size_t kProbationPoses = FileProbation::kPoses;
  CalibrationEngine(const CellRobot& robot, const EngineSettings& settings, double time_compression);

  // Resumes from a saved state. Throws std::runtime_error saying why when the state does not fit this robot (another
  // robot or model, a changed nominal model, inconsistent sizes); the engine is unchanged then.
  void importState(const EngineState& state);
  EngineState exportState() const;
  // Changes whenever exportState() would give a state a restart needs and the last copy lacks (every accepted pose).
  std::uint64_t stateRevision() const { return state_revision_; }
  // What importState did beyond resuming (e.g. the cell file added an extension: kinematic estimate kept, the
  // extension started from its prior); empty otherwise.
  const std::string& restoreNote() const { return restore_note_; }
  // How the engine started from CellRobot::start ("started from <file>: calibrated ..."); empty without one.
  const std::string& startNote() const { return start_note_; }

  // Returns false (and counts the rejection) for a sample that will never be used.
  bool onJointState(const JointSample& s, std::int64_t receive_ns);
  bool onTrackerSample(const TrackerSample& s, std::int64_t receive_ns);
  // Pairs what can be paired and updates. Returns true when a new version was made.
  bool process(std::int64_t now_ns);

  const CalibrationSnapshot& snapshot() const { return snap_; }
  // Condition number of the estimate's correlation matrix (scale-free): large = parameters hard to separate; 0 before
  // there is an estimate. Computed on each call (an eigen-decomposition of the state's size: for the diagnostics'
  // period, not for every pose).
  double conditionNumber() const;
  // The estimate's predicted 1-sigma position error over the whole workspace (the worst of fixed reference
  // configurations spread over 80 % of each joint's range), m: information, not a gate. A cell whose program keeps to
  // one orientation or region leaves it wide; the poses cellcal/pose_request proposes lower it, and compensation gates
  // each target by its own predicted error. Computed on each call from the covariance (for the diagnostics' period).
  double workspacePredictionSigma() const;
  const std::vector<Eigen::VectorXd>& referenceConfigurations() const { return reference_q_; }
  // Where the cell works: the configurations over which snapshot().prediction_sigma_position_m is the worst, and the
  // predicted 1-sigma position error at each (as of the last health decision).
  const std::vector<Eigen::VectorXd>& workConfigurations() const { return work_.configurations(); }
  const std::vector<double>& workPredictionSigmas() const { return work_sigma_m_; }
  const EngineCounters& counters() const { return counters_; }
  // The calibration file's trial verdict (file_trial.hpp), once judged by this engine object (not kept in the state:
  // a restart after the judgement has the notes it logged and, when withdrawn, snapshot().start_warning).
  const std::optional<FileVerdict>& fileVerdict() const { return file_verdict_; }
  const CellRobot& robot() const { return *robot_; }
  // Inputs that stopped: "joint_state: nothing for 4.1 s; tracker_pose: ..." (empty when both streams are fresh;
  // InputWatch::staleInputs). A robot that works between campaigns, moving or standing, is not a stale tracker.
  std::string staleInputs(std::int64_t now_ns) const;
  // Said when the recent tracker readings fit the robot's stand-stills only once shifted in time
  // (PairingBuffer::clockOffsetHint): how far, how many, what to check. Empty: no sign of a clock offset.
  std::string clockWarning() const;
  // Wall time of the last update (linearization + RLS), ns.
  std::int64_t lastUpdateDurationNs() const { return last_update_duration_ns_; }
  // The readings applied to the estimate since this engine was made, in the order applied (the last kAppliedKept):
  // which readings a calibration used, by the tracker's sequence number and stamp.
  struct AppliedReading {
    std::uint64_t tracker_sequence = 0;
    std::int64_t stamp_ns = 0;
  };
  static constexpr std::size_t kAppliedKept = 4096;
  const std::deque<AppliedReading>& appliedReadings() const { return applied_readings_; }
  // What happened since the last call that an operator should read once (the drift added at the first reading, a
  // refused calibration file); the engine process logs them.
  std::vector<std::string> takeNotes();

 private:
  using Pending = DrivenReading;  // the play state when it was paired (the joint history moves on while a batch fills)
  bool handlePaired(const Pending& pending);
  std::optional<bool> gateReading(const Pending& pending, bool same_as_used);  // nullopt: passed
  bool usePose(const Pending& pending);
  bool onProbation() const { return started_calibrated_ && !refused_file_ && snap_.poses_used == 0; }
  bool refuseCalibrationFile(double gate);
  // The trial's verdict (file_trial.hpp); true when the file was withdrawn.
  bool judgeCalibrationFile();
  // Starts over from the nominal model and the cell file's registration (the file refused or withdrawn: `why`), then
  // applies `readings` again.
  void startOverFromNominal(const std::string& why, const std::vector<Pending>& readings);
  void addDriftSinceFile(std::int64_t stamp_ns);
  bool applyPose(const Pending& p);  // false: rolled back (unsafe_update)
  bool samePose(const PairedReading& p, const Eigen::VectorXd& q, std::int64_t stamp_ns) const;
  double predictionSigma();
  void decideHealth();
  void startExtensions(const Eigen::VectorXd& params, const std::vector<int>& estimated, const Eigen::MatrixXd& P);
  void startFromCalibration(const RobotFile& file, const std::string& path);
  void finishUpdate(std::int64_t stamp_ns, std::uint64_t sequence);
  void refreshStatistics();
  // The RLS estimate (parameters, covariance, extensions) into the snapshot.
  void publishEstimate();
  void reject(Rejection r, const std::string& detail);
  // True without r; else counts the rejection r of id's sample (detail: why) and returns false.
  bool admitted(std::optional<Rejection> r, const std::string& id, const std::string& detail);

  const CellRobot* robot_;
  const EngineSettings* settings_;
  double time_compression_;
  std::uint64_t state_revision_ = 0;
  std::string restore_note_;
  std::string start_note_;
  bool started_calibrated_ = false;  // from a calibrated robot file: healthy without poses of its own
  bool refused_file_ = false;        // its first poses contradicted it: started from nominal
  bool file_worse_ = false;          // its first positions held its nominal kinematics better: started from nominal
  FileTrial trial_;
  std::optional<FileVerdict> file_verdict_;
  bool replaying_ = false;  // startOverFromNominal applies readings again: each a stand-still of its own
  std::int64_t file_date_ns_ = 0;    // the file's date while the drift since it is not yet added
  Eigen::VectorXd start_prior_sd_;   // the uncalibrated prior's widths over the state (caps the file's variances)
  FileProbation probation_;
  std::deque<std::string> notes_;
  PairingBuffer pairing_;
  std::unique_ptr<RlsCalibrator> rls_;
  Eigen::VectorXd drift_sigma_;       // accumulated over settings.drift_per_h
  CalibrationSnapshot snap_;
  EngineCounters counters_;
  std::vector<Pending> batch_;        // periodic mode: poses waiting for the batch to fill
  // Joint paths, for extensions whose driver is the play state (backlash): fed and persisted only when the cell file
  // names one (the joint-state path runs at the controller's rate).
  bool tracks_play_ = false;
  PlayTracker play_;
  struct Recent {
    double prior_error_m, post_error_m, post_error_rad, nis_per_row;
  };
  std::deque<Recent> recent_;
  InputWatch inputs_;  // stand-stills, when the robot moved, stale streams (input_watch.hpp)
  std::optional<EngineState::Good> last_good_;  // the last version published with health ok
  OutlierGate gate_;  // the recent new stand-stills' NIS, those gated in a row, the last gated (outlier_gate.hpp)
  std::vector<Eigen::VectorXd> reference_q_;
  Eigen::MatrixXd reference_rows_;  // their position rows of the Jacobian at the nominal parameters (3 per configuration)
  WorkConfigurations work_;
  std::uint64_t work_revision_ = 0;         // +1 whenever work_ changes its size or is restored
  std::vector<std::size_t> work_replaced_;  // members replaced since predictionSigma() last ran (their rows retracked)
  std::vector<double> work_sigma_m_;        // predictionSigma()'s figure at each work configuration
  // predictionSigma()'s rows: the position rows of every work configuration's Jacobian at the nominal parameters over
  // the state (the estimated kinematic columns; zero for extension columns), for the estimated set and the work
  // configurations they are of.
  Eigen::MatrixXd sigma_rows_;
  std::vector<int> sigma_rows_estimated_;
  std::uint64_t sigma_rows_work_revision_ = 0;
  RlsCalibrator::Checkpoint rollback_;  // applyPose's, reused
  std::int64_t last_update_duration_ns_ = 0;
  std::deque<AppliedReading> applied_readings_;
  Eigen::VectorXd used_q_;
  std::int64_t used_joint_stamp_ns_ = 0;
};

// The rejections counted, by name (rejectionName), those above zero.
std::map<std::string, std::uint64_t> rejectionCounts(const EngineCounters& counters);

// The pairing the engine does for `robot` (cellcal export pairs a recording the same way).
PairingOptions pairingOptions(const CellRobot& robot, const EngineSettings& settings);

}  // namespace cellcal
