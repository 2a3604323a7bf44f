// Several set-ups in one calibration: the same robot measured with the tracker (or the target) placed differently,
// e.g. two campaigns. One kinematic model, one base and one tool frame per set-up.
//
// The state is the robot's parameter vector (its base and tool frames those of set-up 0) followed by 12 frame
// parameters (base x, y, z, roll, pitch, yaw, then tool) per further set-up; set-up s's observations are predicted
// with the common kinematics and set-up s's frames, so their Jacobian is the kinematic one with the frame columns
// moved to set-up s's block. Which columns are estimated is the identifiable-set rule of identifiability.hpp on the
// stacked Jacobian of every set-up's rows (a joint zero and a base yaw trade off in every set-up alike: one of them
// is held for all). Gauss-Newton with Levenberg-Marquardt damping, columns scaled.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct SetupsProblem {
  const RobotModel* model = nullptr;
  std::vector<Eigen::VectorXd> starts;             // per set-up: kinematics with its registered frames (full vector)
  std::vector<std::vector<Observation>> observations;  // per set-up
  IdentifiabilityOptions identifiability;
  bool IsValid(std::string* error) const;          // >= 1 set-up, same kinematics in every start, rows in each
};

struct SetupsFit {
  bool converged = false;
  int iterations = 0;
  std::string message;
  std::vector<Eigen::VectorXd> params;  // per set-up: the common kinematics with that set-up's frames (SI)
  std::vector<int> estimated;           // state columns: kinematic index, or numParams() + 12 (s - 1) + k
  std::vector<int> estimated_kinematic; // the kinematic (non-frame) parameters among them, ascending
  double cost_per_row = 0;              // final sum of squared whitened residuals over the rows
};

// Throws std::invalid_argument when !problem.IsValid.
SetupsFit fitSetups(const SetupsProblem& problem, const SolverOptions& options = {});

}  // namespace cellcal
