// Where an engine's estimate starts when the cell file gives the robot a calibrated robot file (CellRobot::start):
// the estimation math of that start, apart from the engine that uses it (calibration_engine.hpp).
//
// The state is what the engine estimates when it starts from nominal (the structurally identifiable kinematic
// parameters, then the extension parameters that act), at the file's kinematics and frames. Its prior is the file's
// covariance of those entries conditioned on every other parameter the file covers (Gaussian conditioning: the engine
// holds them at the file's values; parameters in the span of others, as joint 1's offset and the base yaw, are
// individually wide and strongly correlated there), the uncalibrated prior for entries the file does not cover, and
// each variance at most the uncalibrated prior's. Extension values the file fitted (matched by name) are taken, the
// others start at zero (no effect).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/measurement_kind.hpp"

namespace cellcal {

struct CalibrationStart {
  // The starting estimate: params, extensions and their values, the state (estimated, estimated_extension: the
  // acting extension parameters) and its prior covariance.
  CalibratedModel model;
  Eigen::VectorXd prior_sd;  // the uncalibrated prior's 1-sigma over the state (what caps a variance)
  int covered = 0;           // state entries the file covers
  int capped = 0;            // variances brought down to the uncalibrated prior's
};

// `file` must hold a calibration section (file.calibration); `extensions`: the cell file's for the robot.
CalibrationStart calibrationStart(const RobotModel& model, const RobotFile& file, const std::vector<Extension>& extensions,
                                  double prior_length_m, double prior_angle_rad, MeasurementKind measurement);

// Scales row and column k of P so that its variance is at most sd[k]^2 (k < sd.size()); returns how many were scaled.
int capVariances(Eigen::MatrixXd& P, const Eigen::VectorXd& sd);

}  // namespace cellcal
