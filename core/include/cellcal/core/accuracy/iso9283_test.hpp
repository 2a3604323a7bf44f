// An ISO 9283 test from a measurement file (CSV v1 with the `pose` and `cycle` columns): its rows grouped by test
// pose, each row one visit, and the figures of iso9283.hpp per pose and between poses.
//
// The commanded pose of a visit is what a model says the row's joints reach: the nominal model (what the controller
// believes) or a calibrated one (what compensation would command: the robot lands where that model is wrong, so the
// figures against it are the accuracy compensation leaves). Both commanded and attained poses are taken into the
// model's base frame (the standard's base coordinate system), through the model's base_in_tracker: the cell's
// registration.
#pragma once

#include <Eigen/Core>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/accuracy/iso9283.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

// The model whose accuracy is tested (kinematics, frames and any extensions: calibrated_model.hpp) and the robot
// model it is relative to.
struct Iso9283Model : CalibratedModel {
  const RobotModel* model = nullptr;
};

// The visits of each test pose, the poses in the order of their names (numbers as numbers: P1, P2, ..., P10). Cycle: the row's `cycle`, else its count at its
// pose (1, 2, ...). Approach: the pose of the row before (unknown for the file's first row); a pose reached from
// several others has several approach directions (vAP). Orientation when `orientation` and the row has one.
// Throws ConfigError "<file>:<line>: pose: ..." for a row without a pose name.
std::vector<Iso9283PoseInput> iso9283Visits(const MeasurementFile& file, const Iso9283Model& model, bool orientation);

struct Iso9283Report {
  std::vector<Iso9283Pose> poses;
  std::vector<Iso9283Distance> distances;
};

// Every pose's figures, and the distance figures of each pair (empty `pairs`: P2-P4 when the test has both, the
// standard's pair, else its first two poses). Throws std::invalid_argument naming the pose (fewer than 2 cycles) or
// the pair (a pose not in the test).
Iso9283Report iso9283Report(const std::vector<Iso9283PoseInput>& visits,
                            const std::vector<std::pair<std::string, std::string>>& pairs = {});

}  // namespace cellcal
