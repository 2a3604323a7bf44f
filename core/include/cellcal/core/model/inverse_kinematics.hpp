// Numerical inverse kinematics on any model (any parameter vector): damped least squares with joint limits and
// restarts. Used by compensation: solve the identified model for the joints that reach a target.
//
// Starts, in order, until one reaches the tolerances: the seed; a path from the pose the seed reaches to the target
// in 8 steps (keeps the seed's branch); the best pose so far moved along the Jacobian's weakest direction, both ways
// (out of a saddle on an elbow or wrist singularity, where Gauss-Newton sees no descent); the seed with growing
// noise; random configurations. An attempt stopped by the iteration budget while still descending (linear convergence
// near a singularity) then goes on with ten times the budget. `cellcal_ik_sweep` (make bench) measures the failure
// rate over thousands of random seeds.
#pragma once

#include <Eigen/Core>
#include <string>

#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/measurement_kind.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct IkOptions {
  MeasurementKind kind = MeasurementKind::kPose6D;  // kPosition3D: reach the position, any orientation
  int max_iterations = 500;           // near a singularity convergence is only linear
  int restarts = 8;                  // starts tried after the given seed (deterministic; see above)
  double position_tolerance_m = 1e-9;
  double orientation_tolerance_rad = 1e-9;
  double damping = 1e-12;            // smallest Levenberg damping (m^2); it adapts upward on failed steps
  double orientation_weight_m = 0.5; // a radian of orientation error counts as this many metres
  // An attempt the budget stopped while still descending goes on with ten times the budget (near a singularity the
  // descent is linear). False bounds the cost: a caller answering a stream (compensation) refuses such a target.
  bool extend_when_descending = true;
  bool IsValid(std::string* error) const;
};

enum class IkStatus { kSolved, kOutOfReach };

struct IkResult {
  IkStatus status = IkStatus::kOutOfReach;
  Eigen::VectorXd q_rad;          // best solution found (within limits)
  double position_error_m = 0;    // residual of q_rad
  double orientation_error_rad = 0;
  int iterations = 0;
  std::string message;            // why it failed, with the residual
  bool ok() const { return status == IkStatus::kSolved; }
};

IkResult solveInverseKinematics(const RobotModel& model, const Eigen::VectorXd& params, const Pose& target_in_tracker,
                                const Eigen::VectorXd& q_seed_rad, const IkOptions& options = {});

}  // namespace cellcal
