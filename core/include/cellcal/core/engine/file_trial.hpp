// The trial of a calibration file against the kinematics it started from (calibration_engine.hpp). A calibration can
// do worse in this cell than the nominal kinematics it started from: made on a robot since repaired or re-mastered, or
// carried from a sibling robot. `calibrate --frames-only` judges that on a campaign's rows (compareWithNominal,
// diagnosis.hpp); the engine judges it the same way on its first poses.
//
// The trial keeps the poses the engine applies from the start. Once they visit kPositions distinct positions, both the
// file's model (at the start: kinematics, extensions) and its nominal kinematics (RobotCalibration::nominal_params)
// get their frames registered on every other position, in the order first visited (refineFrames with the kinematics
// held), and are judged on the readings of the others. No reading judges a model at a position its frames were
// registered on. The lower held-out mean is deployed, as `--frames-only` does: the file's model is kept, or withdrawn
// and the engine starts from the nominal model, taking the kept poses again. A cell whose first kMaxPoses poses visit
// fewer positions is not judged, and the engine says so.
//
//   trial.start(file_model, nominal_params);
//   if (trial.keep(pose)) {                              // after the pose was applied
//     const FileVerdict v = trial.judge(model);
//     const std::vector<DrivenReading> poses = trial.take();   // the trial ends
//     if (v.nominal_better) { /* start from nominal and apply `poses` again */ }
//   }
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <vector>

#include "cellcal/core/engine/file_probation.hpp"
#include "cellcal/core/engine/work_configurations.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

struct FileVerdict {
  bool judged = false;          // false: fewer than FileTrial::kPositions positions in FileTrial::kMaxPoses poses
  bool nominal_better = false;  // the nominal kinematics' held-out mean is the lower
  double mean_file_mm = 0, mean_nominal_mm = 0;
  // The file's mean distance minus the nominal kinematics' over the same readings, in standard errors of that paired
  // difference (> 0: the nominal kinematics are the better).
  double z = 0;
  std::size_t poses = 0, positions = 0, judged_readings = 0;
  // What was decided and on what, naming `file`: both figures, the positions, the standard errors.
  std::string text(const std::string& file) const;
};

class FileTrial {
 public:
  static constexpr std::size_t kPositions = 20;
  static constexpr std::size_t kMaxPoses = 200;
  // A pose is at a position when every joint lies within this of that position's first pose.
  static constexpr double kSameRad = WorkConfigurations::kSameRad;

  // Starts a trial of `file_model` against `nominal_params` (every kinematic parameter and frame, SI).
  void start(CalibratedModel file_model, Eigen::VectorXd nominal_params);
  bool active() const { return active_; }
  // Keeps one applied pose; true when judge() is due (kPositions positions, or kMaxPoses poses).
  bool keep(const DrivenReading& pose);
  // The file's model and the nominal kinematics judged on the poses kept (see above). Throws std::logic_error when
  // not active.
  FileVerdict judge(const RobotModel& model) const;
  // The poses kept, in order; the trial ends.
  std::vector<DrivenReading> take();

  // For the engine's state: what a restart needs to resume the trial.
  const CalibratedModel& fileModel() const { return file_model_; }
  const Eigen::VectorXd& nominalParams() const { return nominal_; }
  const std::vector<DrivenReading>& poses() const { return poses_; }
  void restore(CalibratedModel file_model, Eigen::VectorXd nominal_params, std::vector<DrivenReading> poses);

 private:
  void add(DrivenReading pose);  // appends it, with its position

  bool active_ = false;
  CalibratedModel file_model_;
  Eigen::VectorXd nominal_;
  std::vector<DrivenReading> poses_;
  std::vector<std::size_t> position_;    // each pose's position: its index among them, in the order first visited
  std::vector<std::size_t> first_pose_;  // each position's first pose
};

}  // namespace cellcal
