// Batch kinematic calibration: problem struct -> solve -> result struct.
//
//   CalibrationProblem p{&model, initial_params, observations};
//   std::string why;
//   if (!p.IsValid(&why)) ...;
//   CalibrationResult r = solveGaussNewton(p);          // or solveLevenbergMarquardt(p) (Ceres)
//
// Which parameters are estimated: without a prior, the set the observations identify (identifiability.hpp); with
// a prior, the structurally identifiable set (the prior fills directions the data leave open). All others are held
// at their initial value and listed in result.identifiability.dropped. With plausible ranges
// (identifiability.prior_sigma), the set is decided again at the noise the fit leaves (noise_scale: the root of its
// variance factor, when above the options'); the fit is made again from the start if that holds more parameters, and
// result.identifiability.noise_scale says which noise decided.
// Costs are 1/2 sum |whitened residual|^2 over the data (prior excluded), divided by the number of observations.
// Gross errors: with `outliers.enabled` (the default) both solvers fit, screen every observation against the fit
// (outliers.hpp) and refit on the rows kept from the same start, until the flagged set repeats; result.outliers names
// the rows left out and the costs are over the rows kept. On clean data nothing is flagged: the plain fit.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/identification/outliers.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

// Gaussian prior on some parameters: mean (full parameter vector) and covariance over `indices`.
struct GaussianPrior {
  Eigen::VectorXd mean;
  std::vector<int> indices;
  Eigen::MatrixXd covariance;
};

// Diagonal prior: length parameters sigma_length_m, angles sigma_angle_rad, over `indices`.
GaussianPrior diagonalPrior(const RobotModel& model, const Eigen::VectorXd& mean, const std::vector<int>& indices,
                            double sigma_length_m, double sigma_angle_rad);

// The covariance over `estimated` that `prior` implies when the estimated parameters also carry the ones they stand
// for (absorption: absorptionMap over `estimated`, identifiability.hpp) and every other parameter is held at its
// mean: the prior conditioned on the held ones, then mapped, T P T^T. With no absorbed parameter in the prior this is
// the prior's information restricted to `estimated`, inverted. Throws if an estimated parameter has no variance.
Eigen::MatrixXd priorOverEstimated(const GaussianPrior& prior, const std::vector<int>& estimated,
                                   const Eigen::MatrixXd& absorption);

struct CalibrationProblem {
  const RobotModel* model = nullptr;
  Eigen::VectorXd initial_params;          // full vector (model.numParams())
  std::vector<Observation> observations;
  std::optional<GaussianPrior> prior;
  IdentifiabilityOptions identifiability;
  OutlierOptions outliers;
  bool IsValid(std::string* error) const;
};

struct SolverOptions {
  int max_iterations = 50;
  double step_tolerance = 1e-9;  // stop when the column-scaled step norm falls below this
  // Or when a step moves the model's predictions at the rows by less than this, RMS over the whitened rows (in the
  // readings' sigmas): the fit is at its solution for everything the data see, while parameters the data barely pin
  // may still drift along directions that move no prediction.
  double prediction_tolerance = 1e-3;
  bool IsValid(std::string* error) const;
};

struct NamedParameter {
  std::string name;        // human units, e.g. "joint2.a_mm"
  double initial = 0;      // human units
  double value = 0;        // human units
  double stddev = 0;       // human units; 0 when not estimated
  bool estimated = false;
};

struct CalibrationResult {
  bool converged = false;
  int iterations = 0;
  double initial_cost_per_observation = 0;
  double final_cost_per_observation = 0;
  double solve_time_s = 0;
  std::string message;
  Eigen::VectorXd params;                  // full vector, SI
  std::vector<int> estimated;              // indices into params
  Eigen::MatrixXd covariance;              // over `estimated`, SI (from the whitened Jacobian and the prior)
  IdentifiabilityReport identifiability;
  OutlierScreen outliers;                  // rows of problem.observations left out, and the robust scales
  std::vector<NamedParameter> parameters(const RobotModel& model, const Eigen::VectorXd& initial) const;
};

CalibrationResult solveGaussNewton(const CalibrationProblem& problem, const SolverOptions& options = {});
CalibrationResult solveLevenbergMarquardt(const CalibrationProblem& problem, const SolverOptions& options = {});

}  // namespace cellcal
