// Levenberg-Marquardt with Ceres. Analytic Jacobians (kinematics.hpp): no autodiff in this TU, so it compiles fast.
#include <ceres/ceres.h>

#include <chrono>

#include "calibration_internal.hpp"

namespace cellcal {
namespace {

// Residual f = W (model(x) - measured) of one observation (Ceres' sign: minimise 1/2 |f|^2),
// over the single parameter block x = params[estimated].
class ObservationCost final : public ceres::CostFunction {
 public:
  ObservationCost(const RobotModel& model, const Observation& obs, const Eigen::VectorXd& base_params,
                  const std::vector<int>& estimated)
      : model_(model), obs_(obs), base_(base_params), estimated_(estimated), data_(model) {
    set_num_residuals(obs.rows());
    mutable_parameter_block_sizes()->push_back(static_cast<int32_t>(estimated.size()));
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    for (size_t k = 0; k < estimated_.size(); ++k) params_[estimated_[k]] = parameters[0][k];
    Eigen::Matrix<double, 6, 1> r;
    const int rows = whitenedResidual(model_, data_, params_, obs_, r, jacobians && jacobians[0] ? &J_ : nullptr);
    for (int i = 0; i < rows; ++i) residuals[i] = -r[i];
    if (jacobians && jacobians[0]) {
      const auto m = estimated_.size();
      for (int i = 0; i < rows; ++i)
        for (size_t k = 0; k < m; ++k) jacobians[0][i * m + k] = J_(i, estimated_[k]);
    }
    return true;
  }

 private:
  const RobotModel& model_;
  const Observation& obs_;
  const Eigen::VectorXd base_;
  const std::vector<int>& estimated_;
  mutable KinematicsData data_;
  mutable Eigen::VectorXd params_ = base_;
  mutable Eigen::MatrixXd J_;
};

// f = U (x - mean): the Gaussian prior as whitened rows.
class PriorCost final : public ceres::CostFunction {
 public:
  PriorCost(const Eigen::MatrixXd& U, const Eigen::VectorXd& mean) : U_(U), mean_(mean) {
    set_num_residuals(static_cast<int>(U.rows()));
    mutable_parameter_block_sizes()->push_back(static_cast<int32_t>(U.cols()));
  }
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const Eigen::Map<const Eigen::VectorXd> x(parameters[0], U_.cols());
    Eigen::Map<Eigen::VectorXd>(residuals, U_.rows()) = U_ * (x - mean_);
    if (jacobians && jacobians[0])
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(jacobians[0], U_.rows(),
                                                                                         U_.cols()) = U_;
    return true;
  }

 private:
  Eigen::MatrixXd U_;
  Eigen::VectorXd mean_;
};

// Stops the solver once a successful step moved the whitened predictions by less than `tolerance` RMS over the rows
// (SolverOptions::prediction_tolerance): Ceres' own tests look at the parameters and the cost, which a direction the
// data barely pin keeps from settling.
class PredictionsSettled final : public ceres::IterationCallback {
 public:
  PredictionsSettled(const internal::ReducedProblem& rp, const std::vector<double>& x, const Eigen::VectorXd& base,
                     double tolerance)
      : rp_(rp), x_(x), params_(base), tolerance_(tolerance) {
    rp_.evaluate(current(), last_, nullptr);
  }
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    if (s.iteration == 0 || !s.step_is_successful) return ceres::SOLVER_CONTINUE;
    Eigen::VectorXd r;
    rp_.evaluate(current(), r, nullptr);
    const bool settled = (r - last_).norm() < tolerance_ * std::sqrt(static_cast<double>(r.size()));
    last_ = std::move(r);
    return settled ? ceres::SOLVER_TERMINATE_SUCCESSFULLY : ceres::SOLVER_CONTINUE;
  }

 private:
  const Eigen::VectorXd& current() {
    for (size_t k = 0; k < x_.size(); ++k) params_[rp_.estimated[k]] = x_[k];
    return params_;
  }
  const internal::ReducedProblem& rp_;
  const std::vector<double>& x_;
  Eigen::VectorXd params_, last_;
  double tolerance_;
};

}  // namespace

CalibrationResult solveLevenbergMarquardt(const CalibrationProblem& problem, const SolverOptions& options) {
  internal::requireValid(problem, options);
  return internal::solveScreened(problem, options, internal::solveLevenbergMarquardtPlain);
}

CalibrationResult internal::solveLevenbergMarquardtPlain(const CalibrationProblem& problem,
                                                          const SolverOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  internal::ReducedProblem rp(problem);
  CalibrationResult res;
  res.params = problem.initial_params;
  const double n_obs = static_cast<double>(problem.observations.size());
  res.initial_cost_per_observation = rp.dataCost(res.params) / n_obs;

  std::vector<double> x(rp.estimated.size());
  for (size_t k = 0; k < x.size(); ++k) x[k] = res.params[rp.estimated[k]];
  ceres::Problem::Options popts;
  popts.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  ceres::Problem cp(popts);
  for (const auto& o : problem.observations)
    cp.AddResidualBlock(new ObservationCost(*problem.model, o, problem.initial_params, rp.estimated), nullptr,
                        x.data());
  if (rp.prior_sqrt_info.size()) cp.AddResidualBlock(new PriorCost(rp.prior_sqrt_info, rp.prior_mean), nullptr, x.data());

  ceres::Solver::Options so;
  so.minimizer_type = ceres::TRUST_REGION;
  so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = 1e-10;  // relative cost change: far below what the noise can resolve
  so.gradient_tolerance = 1e-14;
  so.parameter_tolerance = options.step_tolerance;
  so.num_threads = 1;
  so.logging_type = ceres::SILENT;
  PredictionsSettled settled(rp, x, res.params, options.prediction_tolerance);
  so.callbacks.push_back(&settled);
  so.update_state_every_iteration = true;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &cp, &summary);

  for (size_t k = 0; k < x.size(); ++k) res.params[rp.estimated[k]] = x[k];
  res.iterations = static_cast<int>(summary.iterations.size()) - 1;
  res.converged = summary.termination_type == ceres::CONVERGENCE || summary.termination_type == ceres::USER_SUCCESS;
  res.message = summary.termination_type == ceres::USER_SUCCESS
                    ? "converged (the last step moved the predictions by less than " + internal::settledText(options) + ")"
                    : summary.message;
  rp.finish(res);
  res.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace cellcal
