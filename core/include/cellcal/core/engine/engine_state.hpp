// What a calibration engine must keep to resume where it stopped: the estimator's state and the engine's memory of
// recent poses. CalibrationEngine::exportState() gives it, importState() takes it back; files/state_file.hpp writes
// and reads it. A value: no files, no clocks.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/engine/pairing.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/model_extension.hpp"

namespace cellcal {

struct EngineState {
  // Whose state: checked against the cell file's robot on import.
  std::string robot_id, robot_name;
  int num_params = 0;
  Eigen::VectorXd nominal;
  EngineMode mode = EngineMode::kContinuous;

  std::uint64_t version = 0;
  std::uint32_t poses_used = 0;
  std::int64_t last_measurement_stamp_ns = 0;
  std::uint64_t last_tracker_sequence = 0;
  std::int64_t last_update_stamp_ns = 0;

  // The estimator (not what is published while a good version is held): full kinematic vector, the estimated
  // indices, the covariance over the estimated kinematic then extension parameters.
  Eigen::VectorXd params;
  std::vector<int> estimated;
  Eigen::MatrixXd covariance;
  std::vector<std::string> extensions;  // extensionSpec of each, in order
  Eigen::VectorXd extension_params;
  std::vector<int> estimated_extension;

  // The outlier gate's memory.
  int consecutive_outliers = 0;
  std::vector<double> gate_window;

  // The last version published with health ok, while another health is published: its model (calibrated_model.hpp;
  // the files keep params, extension_params, estimated and covariance: its extensions and estimated_extension are
  // the state's own, filled in on import) and its version.
  struct Good : CalibratedModel {
    std::uint64_t version = 0;
  };
  std::optional<Good> last_good;

  // Joint paths (backlash play), when an extension needs them.
  struct Play {
    std::vector<PlayTracker::Joint> joints;
    std::int64_t last_stamp_ns = 0;
  };
  std::optional<Play> play;

  // The recent poses' errors (the running statistics) and, in periodic mode, the poses of the unfinished batch.
  struct Recent {
    double prior_error_m = 0, post_error_m = 0, post_error_rad = 0, nis_per_row = 0;
  };
  std::vector<Recent> recent;
  struct PendingPose {
    PairedReading reading;
    std::optional<Drivers> drivers;  // with extensions: the drivers when it was paired
  };
  std::vector<PendingPose> pending_batch;

  // How the estimate started. Absent in states written before it was kept: as the cell file says (a calibration_file
  // or not), with the drift since the file's date already in the covariance.
  // kNominalFileWorse: the file fitted, but its first poses held the nominal kinematics better (file_trial.hpp).
  enum class Start { kNominal, kCalibrationFile, kNominalFileRefused, kNominalFileWorse };
  std::optional<Start> started_from;
  // Started from a calibration file whose date is this and no reading yet: the first reading widens the covariance by
  // the drift from this date to its stamp (0: nothing pending).
  std::int64_t file_drift_pending_since_ns = 0;
  // Why the calibration file was refused or withdrawn (kNominalFileRefused, kNominalFileWorse), as the engine said it.
  std::string start_warning;
  // A calibration file on trial against the kinematics it started from (file_trial.hpp): the file's model as the
  // engine started from it (the extensions are the state's), its nominal kinematics and the poses kept. Absent: no
  // trial running (states written before trials were kept have none).
  struct FileTrialState {
    Eigen::VectorXd file_params, file_extension_params, nominal;
    std::vector<PendingPose> poses;
  };
  std::optional<FileTrialState> file_trial;
  // Where the cell works (work_configurations.hpp), in the set's order. Absent in states written before it was kept:
  // the set starts empty (health judged over the workspace until the next pose).
  std::vector<Eigen::VectorXd> work_configurations;
};

}  // namespace cellcal
