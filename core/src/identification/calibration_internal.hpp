// Shared by the batch solvers (not installed).
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/model/model_extension.hpp"

namespace cellcal::internal {

// Throws std::invalid_argument naming what is wrong with the problem or the options.
void requireValid(const CalibrationProblem& problem, const SolverOptions& options);

// One fit of every observation (no screening).
CalibrationResult solveGaussNewtonPlain(const CalibrationProblem& problem, const SolverOptions& options);
CalibrationResult solveLevenbergMarquardtPlain(const CalibrationProblem& problem, const SolverOptions& options);
// The fit-screen alternation of calibration.hpp around one of them.
CalibrationResult solveScreened(const CalibrationProblem& problem, const SolverOptions& options,
                                CalibrationResult (*solve)(const CalibrationProblem&, const SolverOptions&));
// Every observation's errors at `params`, screened.
OutlierScreen screenFit(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                        const OutlierOptions& options);

// Paired improvement of squared position errors from residual set a to residual set b (row by row), in standard
// errors of the mean difference: positive when b is better.
double pairedZ(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b);
// Whether residual set b improves on a (row by row) by more than `z_limit` standard errors (pairedZ, written to `z`)
// and more than `min_gain` of the mean squared position error.
bool improves(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b, double z_limit,
              double min_gain, double* z);
// Mean position error (mm) and mean squared position error (m^2) of residuals (not empty).
struct ResidualMeans {
  double mean_mm = 0, mse_m2 = 0;
};
ResidualMeans residualMeans(const std::vector<Eigen::Vector3d>& r);
// `options` with plausible ranges for the extension columns (identifiability.hpp): when its prior_sigma is given, the
// columns before `ext0` keep theirs (none beyond its size) and the extension columns from `ext0` on get
// extensionPriorSigma(model, params, exts, kPlausibleExtensionJointErrorRad). Without prior_sigma: unchanged.
IdentifiabilityOptions withExtensionRanges(const IdentifiabilityOptions& options, const RobotModel& model,
                                           const Eigen::VectorXd& params, const std::vector<Extension>& exts,
                                           Eigen::Index ext0);
// Rows fitted and rows judged: one fold of a split by region (RegionCheck).
using Fold = std::pair<std::vector<int>, std::vector<int>>;
// The two folds RegionCheck judges `cause` on: by the angle of its joint (the rows beyond the `joint_end` quantile
// at either end judged, the others fitted) or by the workspace (regionSplit: each half fitted, the other judged).
std::vector<Fold> regionFolds(const std::vector<Observation>& obs, const Extension& cause, double joint_end);
// The two folds by a value per row: the rows above its (1 - end) quantile judged and the others fitted, then the rows
// below its `end` quantile judged and the others fitted (regionFolds by a joint's angle).
std::vector<Fold> endFolds(const std::vector<double>& x, double end);
// Indices 0..n-1, every one when n <= max_rows (or max_rows <= 0), else every k-th evenly through them, at most
// max_rows.
std::vector<int> evenlyThinned(size_t n, int max_rows);

// The linear-algebra view of a CalibrationProblem restricted to the estimated parameters.
struct ReducedProblem {
  const CalibrationProblem* problem = nullptr;
  std::vector<int> estimated;
  IdentifiabilityReport identifiability;
  // Prior as whitened rows: r_prior = U (mean - x) over `estimated` (U upper, U^T U = information); empty if none.
  Eigen::MatrixXd prior_sqrt_info;
  Eigen::VectorXd prior_mean;  // over `estimated`

  explicit ReducedProblem(const CalibrationProblem& p);
  // Whitened data residual (measured - model) and its Jacobian over `estimated` (J may be null).
  void evaluate(const Eigen::VectorXd& params, Eigen::VectorXd& r, Eigen::MatrixXd* J) const;
  double dataCost(const Eigen::VectorXd& params) const;
  // Posterior covariance over `estimated` at params.
  Eigen::MatrixXd covariance(const Eigen::VectorXd& params) const;
  void finish(CalibrationResult& result) const;
};

// "0.001 of the readings' sigma": SolverOptions::prediction_tolerance in words.
inline std::string settledText(const SolverOptions& options) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%g of the readings' sigma", options.prediction_tolerance);
  return buf;
}

struct GaussNewtonOutcome {
  Eigen::VectorXd x;
  int iterations = 0;
  bool converged = false;
  std::string message;
  double cost = 0;  // 1/2 |b|^2 at x
};

// Gauss-Newton with column scaling and step halving on a least-squares problem given as
//   eval(x, b, A): the whitened residual b (measured - model, and any prior rows) at x and, when A is not null, its
//   Jacobian A = d model / dx, so that the step s minimizes |A s - b|.
// Stops when no step decreases the cost or the column-scaled step is below options.step_tolerance.
template <typename Eval>
GaussNewtonOutcome gaussNewton(Eval&& eval, Eigen::VectorXd x, const SolverOptions& options) {
  GaussNewtonOutcome out;
  Eigen::VectorXd b, b_trial;
  Eigen::MatrixXd A;
  eval(x, b, &A);
  double cost = 0.5 * b.squaredNorm();
  for (out.iterations = 1; out.iterations <= options.max_iterations; ++out.iterations) {
    const Eigen::VectorXd scale = A.colwise().norm().cwiseMax(1e-300).cwiseInverse();
    const Eigen::VectorXd y = (A * scale.asDiagonal()).colPivHouseholderQr().solve(b);
    const Eigen::VectorXd step = scale.asDiagonal() * y;
    double t = 1.0, trial_cost = 0;
    Eigen::VectorXd trial;
    for (int h = 0; h < 20; ++h, t *= 0.5) {  // step halving keeps the cost monotone far from the solution
      trial = x + t * step;
      eval(trial, b_trial, nullptr);
      trial_cost = 0.5 * b_trial.squaredNorm();
      if (trial_cost <= cost) break;
    }
    if (trial_cost > cost) {
      out.converged = true;
      out.message = "converged (no further decrease)";
      break;
    }
    x = trial;
    cost = trial_cost;
    if ((t * y).norm() < options.step_tolerance) {
      out.converged = true;
      out.message = "converged (step below tolerance)";
      break;
    }
    if ((A * (t * step)).norm() < options.prediction_tolerance * std::sqrt(static_cast<double>(b.size()))) {
      out.converged = true;
      out.message = "converged (the last step moved the predictions by less than " + settledText(options) + ")";
      break;
    }
    eval(x, b, &A);
  }
  if (!out.converged) {
    out.iterations = options.max_iterations;
    out.message = "maximum iterations reached";
  }
  out.x = std::move(x);
  out.cost = cost;
  return out;
}

}  // namespace cellcal::internal
