// Shared by the batch solvers (not installed).
#pragma once

#include <Eigen/Cholesky>

#include "cellcal/core/calibration.hpp"

namespace cellcal::internal {

// Throws std::invalid_argument naming what is wrong with the problem or the options.
void requireValid(const CalibrationProblem& problem, const SolverOptions& options);

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

}  // namespace cellcal::internal
