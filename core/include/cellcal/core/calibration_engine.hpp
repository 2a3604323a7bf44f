// The calibration engine of one robot, without DDS: samples in, calibrations out. The engine process wraps one per
// robot of the cell file; `cellcal validate` runs the same code over a recording.
//
// Flow: joint states and tracker readings -> PairingBuffer -> Observation -> (process noise for the cell time since
// the previous update) -> RLS update, per pose (continuous mode) or per batch of N poses (periodic mode) -> a new
// version. A pose is one stand-still of the robot: the first reading paired in it is used, later readings of the
// same stand-still are counted (same_pose) and not applied (their robot error is the same; a tracker streaming at
// 1 kHz must not weigh a pose a thousand times). Before a pose updates the estimate, the current calibration predicts it: those a-priori errors are the
// engine's honest running verification (the pose was not used to make the prediction).
// Persistence: after every accepted pose the whole state (estimate, covariance, counters, the unapplied poses of a
// periodic batch) is written atomically (temporary file, rename) before process() returns; syncToDisk() then
// fsyncs it (the engine process calls it right after publishing, so the disk is off the latency path). A restarted engine
// resumes from it and rejects readings at or before the last applied one, so no update is lost or applied twice.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/cell_config.hpp"
#include "cellcal/core/pairing.hpp"
#include "cellcal/core/rls.hpp"

namespace cellcal {

enum class Health { kUncalibrated = 0, kOk = 1, kDegraded = 2, kHoldLastGood = 3 };
const char* healthName(Health h);

struct CalibrationSnapshot {
  std::uint64_t version = 0;          // 0 = nothing identified yet; +1 per accepted update
  EngineMode mode = EngineMode::kContinuous;
  Health health = Health::kUncalibrated;
  std::uint32_t poses_used = 0;
  Eigen::VectorXd params;             // full SI vector (RobotModel layout)
  std::vector<int> estimated;         // indices of params the RLS estimates
  // Model extensions of the cell file (CellRobot::extensions) and their parameters (extensionParamNames order).
  std::vector<Extension> extensions;
  Eigen::VectorXd extension_params;
  std::vector<int> estimated_extension;  // indices of extension_params the RLS estimates
  Eigen::MatrixXd covariance;         // over `estimated`, then `estimated_extension`
  double residual_rms_position_m = 0;     // a-posteriori, over the recent window of used poses
  double residual_rms_orientation_rad = 0;
  double verification_mean_position_m = 0;  // a-priori prediction error over the recent window (NaN until known)
  std::int64_t last_measurement_stamp_ns = 0;
  std::uint64_t last_tracker_sequence = 0;
  std::int64_t last_update_stamp_ns = 0;    // stamp of the reading that made this version
  // Consistency: mean normalized innovation squared per measurement row over the recent poses (about 1 when the
  // noise and drift models hold). Above EngineSettings::drift_alarm_nis_per_row (with >= 10 recent poses): the
  // robot moves faster than the drift model allows, or the model misses an effect -> drift_alarm.
  double recent_nis_per_row = 0;
  bool drift_alarm = false;
  // Condition number of the estimate's correlation matrix (scale-free): large = parameters hard to separate.
  double condition_number = 0;
};

struct EngineCounters {
  std::array<std::uint64_t, static_cast<size_t>(Rejection::kCount)> rejected{};
  std::uint64_t joint_states = 0, tracker_readings = 0, paired = 0;
  std::uint64_t same_pose = 0;               // paired readings of a pose already used (not applied again)
  std::string last_rejection;                // detail of the most recent rejection
};

class CalibrationEngine {
 public:
  // `robot` and `settings` must outlive the engine. Throws std::runtime_error when the state file exists but cannot
  // be used (another robot/model, corrupt): the message names the file and says what to do.
  CalibrationEngine(const CellRobot& robot, const EngineSettings& settings, double time_compression,
                    bool persist = true);

  std::string stateFile() const;
  bool restored() const { return restored_; }
  // What the restore did beyond resuming (e.g. the cell file added an extension: kinematic estimate kept, the
  // extension started from its prior); empty otherwise.
  const std::string& restoreNote() const { return restore_note_; }

  // Returns false (and counts the rejection) for a sample that will never be used.
  bool onJointState(const JointSample& s, std::int64_t receive_ns);
  bool onTrackerSample(const TrackerSample& s, std::int64_t receive_ns);
  // Pairs what can be paired and updates. Returns true when a new version was made. Every accepted pose is in the
  // state file (atomically replaced) when this returns: a SIGKILL after it loses nothing.
  bool process(std::int64_t now_ns);
  // fsync of the state file and its folder (power-loss durability); call after publishing a new version.
  void syncToDisk();
  // For a process that fsyncs off its latency path: true (once) when the file changed since the last call; then
  // call syncStateFile(stateFile()) from any thread.
  bool takeUnsynced() {
    const bool u = unsynced_;
    unsynced_ = false;
    return u;
  }

  const CalibrationSnapshot& snapshot() const { return snap_; }
  const EngineCounters& counters() const { return counters_; }
  const CellRobot& robot() const { return *robot_; }
  std::int64_t lastInputReceiveNs() const { return last_input_ns_; }
  // Wall time of the last update (linearization + RLS + persistence), ns.
  std::int64_t lastUpdateDurationNs() const { return last_update_duration_ns_; }

 private:
  struct Pending {
    PairedReading reading;
    Drivers drivers;  // play state when it was paired (the joint history moves on while a batch fills)
  };
  void applyPose(const Pending& p);
  void startExtensions(const Eigen::VectorXd& params, const std::vector<int>& estimated, const Eigen::MatrixXd& P);
  void finishUpdate(std::int64_t stamp_ns, std::uint64_t sequence);
  void refreshStatistics();
  bool samePoseAsLastUsed(const PairedReading& p) const;
  void persist();
  bool restore();
  void reject(Rejection r, const std::string& detail);

  const CellRobot* robot_;
  const EngineSettings* settings_;
  double time_compression_;
  bool persist_;
  bool restored_ = false;
  std::string restore_note_;
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
  std::int64_t last_input_ns_ = 0;
  std::int64_t last_update_duration_ns_ = 0;
  bool unsynced_ = false;
  Eigen::VectorXd last_joint_q_, used_q_;
  std::int64_t used_joint_stamp_ns_ = 0;
  std::deque<std::int64_t> motion_stamps_ns_;  // joint states that show the robot moving
};

// The pairing the engine does for `robot` (cellcal export pairs a recording the same way).
PairingOptions pairingOptions(const CellRobot& robot, const EngineSettings& settings);

// fsync of a file and its folder.
void syncStateFile(const std::string& path);

}  // namespace cellcal
