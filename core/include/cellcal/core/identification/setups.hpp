// Several set-ups in one calibration: the same robot measured with the tracker (or the target) placed differently,
// e.g. two campaigns. One kinematic model, one base and one tool frame per set-up.
//
// The state is the robot's parameter vector (its base and tool frames those of set-up 0) followed by 12 frame
// parameters (base x, y, z, roll, pitch, yaw, then tool) per further set-up; set-up s's observations are predicted
// with the common kinematics and set-up s's frames, so their Jacobian is the kinematic one with the frame columns
// moved to set-up s's block. Which columns are estimated is the identifiable-set rule of identifiability.hpp on the
// stacked Jacobian of every set-up's rows (a joint zero and a base yaw trade off in every set-up alike: one of them
// is held for all). Gauss-Newton with Levenberg-Marquardt damping, columns scaled.
//
// Model extensions (model_extension.hpp) are the robot's, so their parameters e are common to every set-up and come
// last in the state: a row of set-up s is predicted at p_s + B e and its e columns are J B, with B the basis at set-up
// s's start (fixed during the fit, as in fitExtended; a prediction afterwards takes it at the solution). The
// extension columns have the lowest priority (as in fitExtended). A backlash's basis depends on its width: as in
// fitExtended, it is re-evaluated at the fitted width until the width settles, and a set-up's rows whose play state
// is unknown (the joint has not moved since the set-up's data began) do not take part (`rows_left_out`). No thermal
// drift on a time driver without its warm-up time constant (fitExtended searches it); IsValid says so.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct SetupsProblem {
  const RobotModel* model = nullptr;
  std::vector<Eigen::VectorXd> starts;             // per set-up: kinematics with its registered frames (full vector)
  std::vector<std::vector<Observation>> observations;  // per set-up
  std::vector<Extension> extensions;               // the model's extensions; empty: geometric
  std::vector<std::vector<Drivers>> drivers;       // per set-up, one per observation (needed with extensions)
  IdentifiabilityOptions identifiability;
  // >= 1 set-up, same kinematics in every start, rows in each; with extensions: drivers for every row, and each
  // extension one this fit takes (see above).
  bool IsValid(std::string* error) const;
};

struct SetupsFit {
  bool converged = false;
  int iterations = 0;
  std::string message;
  std::vector<Eigen::VectorXd> params;  // per set-up: the common kinematics with that set-up's frames (SI)
  std::vector<int> estimated;           // state columns: kinematic index, numParams() + 12 (s - 1) + k, or (after
                                        // every set-up's frames) numParams() + 12 (S - 1) + extension parameter
  std::vector<int> estimated_kinematic; // the kinematic (non-frame) parameters among them, ascending
  Eigen::VectorXd extension_params;     // common to every set-up (numExtensionParams(model, extensions))
  std::vector<int> estimated_extension; // extension parameters estimated (others held at 0), ascending
  double cost_per_row = 0;              // final sum of squared whitened residuals over the rows
  std::vector<int> rows_left_out;       // per set-up (empty: none): rows of an unknown backlash play state
};

// Throws std::invalid_argument when !problem.IsValid.
SetupsFit fitSetups(const SetupsProblem& problem, const SolverOptions& options = {});

// Set-up s's model under a fit: the common kinematics and extension parameters with its frames (no covariance).
ExtendedFit setupFit(const SetupsProblem& problem, const SetupsFit& fit, size_t s);

// fitSetups, then screening for gross errors (outliers.hpp) in each set-up against its own robust scale (set-ups may
// differ in noise): refit on the rows kept until the flagged sets repeat, never leaving out half of a set-up's rows.
// `screens` (optional) receives the last screening per set-up, indices into problem.observations[s].
SetupsFit fitSetupsRobust(const SetupsProblem& problem, const SolverOptions& solver, const OutlierOptions& outliers,
                          std::vector<OutlierScreen>* screens);

}  // namespace cellcal
