#include <Eigen/QR>
#include <chrono>
#include <cmath>

#include "calibration_internal.hpp"
#include "cellcal/core/se3.hpp"

namespace cellcal {

GaussianPrior diagonalPrior(const RobotModel& model, const Eigen::VectorXd& mean, const std::vector<int>& indices,
                            double sigma_length_m, double sigma_angle_rad) {
  GaussianPrior p;
  p.mean = mean;
  p.indices = indices;
  p.covariance = Eigen::MatrixXd::Zero(indices.size(), indices.size());
  for (size_t i = 0; i < indices.size(); ++i) {
    const double s = model.isLength(indices[i]) ? sigma_length_m : sigma_angle_rad;
    p.covariance(i, i) = s * s;
  }
  return p;
}

bool CalibrationProblem::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (!model) return fail("model is null");
  std::string e;
  if (!model->IsValid(&e)) return fail(e);
  if (initial_params.size() != model->numParams())
    return fail("initial_params has " + std::to_string(initial_params.size()) + " entries, the model needs " +
                std::to_string(model->numParams()));
  if (!initial_params.allFinite()) return fail("initial_params is not finite");
  if (observations.empty()) return fail("no observations");
  for (size_t i = 0; i < observations.size(); ++i) {
    const auto& o = observations[i];
    const std::string w = "observation " + std::to_string(i) + ": ";
    if (o.q_rad.size() != model->numJoints()) return fail(w + "wrong number of joint angles");
    if (!o.q_rad.allFinite() || !o.measured_in_tracker.matrix().allFinite()) return fail(w + "not finite");
    if (!(o.sigma_position_m > 0) || (o.kind == MeasurementKind::kPose6D && !(o.sigma_orientation_rad > 0)))
      return fail(w + "sigmas must be > 0");
  }
  if (prior) {
    if (prior->mean.size() != model->numParams()) return fail("prior.mean must be a full parameter vector");
    const auto k = static_cast<Eigen::Index>(prior->indices.size());
    if (prior->covariance.rows() != k || prior->covariance.cols() != k) return fail("prior.covariance size mismatch");
    for (int i : prior->indices)
      if (i < 0 || i >= model->numParams()) return fail("prior index out of range");
    if (Eigen::LLT<Eigen::MatrixXd>(prior->covariance).info() != Eigen::Success)
      return fail("prior.covariance is not positive definite");
  }
  return identifiability.IsValid(error);
}

bool SolverOptions::IsValid(std::string* error) const {
  if (max_iterations < 1 || !(step_tolerance > 0)) {
    if (error) *error = "max_iterations must be >= 1 and step_tolerance > 0";
    return false;
  }
  return true;
}

std::vector<NamedParameter> CalibrationResult::parameters(const RobotModel& model,
                                                          const Eigen::VectorXd& initial) const {
  std::vector<NamedParameter> out;
  for (int i = 0; i < model.numParams(); ++i) {
    NamedParameter p;
    p.name = model.paramNameHuman(i);
    p.initial = model.toHuman(i, initial[i]);
    p.value = model.toHuman(i, params[i]);
    for (size_t k = 0; k < estimated.size(); ++k)
      if (estimated[k] == i) {
        p.estimated = true;
        p.stddev = std::abs(model.toHuman(i, std::sqrt(covariance(k, k))));
      }
    out.push_back(p);
  }
  return out;
}

namespace internal {

void requireValid(const CalibrationProblem& problem, const SolverOptions& options) {
  std::string err;
  if (!problem.IsValid(&err)) throw std::invalid_argument("CalibrationProblem: " + err);
  if (!options.IsValid(&err)) throw std::invalid_argument("SolverOptions: " + err);
}

ReducedProblem::ReducedProblem(const CalibrationProblem& p) : problem(&p) {
  const RobotModel& model = *p.model;
  identifiability = analyzeIdentifiability(model, p.initial_params, p.observations, p.identifiability);
  if (p.prior) {
    const auto structural =
        structuralIdentifiability(model, p.initial_params, p.observations.front().kind, p.identifiability);
    estimated = structural.identifiable;
  } else {
    estimated = identifiability.identifiable;
  }
  if (p.prior) {
    // Information over the prior's indices, restricted to the estimated ones (the others are held fixed).
    const Eigen::MatrixXd info = p.prior->covariance.inverse();
    const auto n = static_cast<Eigen::Index>(estimated.size());
    Eigen::MatrixXd sub = Eigen::MatrixXd::Zero(n, n);
    std::vector<int> pos(estimated.size(), -1);
    for (size_t a = 0; a < estimated.size(); ++a)
      for (size_t b = 0; b < p.prior->indices.size(); ++b)
        if (p.prior->indices[b] == estimated[a]) pos[a] = static_cast<int>(b);
    for (Eigen::Index a = 0; a < n; ++a)
      for (Eigen::Index b = 0; b < n; ++b)
        if (pos[a] >= 0 && pos[b] >= 0) sub(a, b) = info(pos[a], pos[b]);
    Eigen::LLT<Eigen::MatrixXd> llt(sub + 1e-30 * Eigen::MatrixXd::Identity(n, n));
    prior_sqrt_info = llt.matrixU();
    prior_mean.resize(n);
    for (Eigen::Index a = 0; a < n; ++a) prior_mean[a] = p.prior->mean[estimated[a]];
  }
}

void ReducedProblem::evaluate(const Eigen::VectorXd& params, Eigen::VectorXd& r, Eigen::MatrixXd* J) const {
  Eigen::MatrixXd Jfull;
  stackResiduals(*problem->model, params, problem->observations, r, J ? &Jfull : nullptr);
  if (J) {
    J->resize(Jfull.rows(), static_cast<Eigen::Index>(estimated.size()));
    for (size_t k = 0; k < estimated.size(); ++k) J->col(k) = Jfull.col(estimated[k]);
  }
}

double ReducedProblem::dataCost(const Eigen::VectorXd& params) const {
  Eigen::VectorXd r;
  evaluate(params, r, nullptr);
  return 0.5 * r.squaredNorm();
}

Eigen::MatrixXd ReducedProblem::covariance(const Eigen::VectorXd& params) const {
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  evaluate(params, r, &J);
  Eigen::MatrixXd H = J.transpose() * J;
  if (prior_sqrt_info.size()) H += prior_sqrt_info.transpose() * prior_sqrt_info;
  return H.ldlt().solve(Eigen::MatrixXd::Identity(H.rows(), H.cols()));
}

void ReducedProblem::finish(CalibrationResult& result) const {
  result.estimated = estimated;
  result.identifiability = identifiability;
  result.covariance = covariance(result.params);
  const double n = static_cast<double>(problem->observations.size());
  result.final_cost_per_observation = dataCost(result.params) / n;
}

}  // namespace internal

CalibrationResult solveGaussNewton(const CalibrationProblem& problem, const SolverOptions& options) {
  internal::requireValid(problem, options);
  const auto t0 = std::chrono::steady_clock::now();
  internal::ReducedProblem rp(problem);
  CalibrationResult res;
  res.params = problem.initial_params;
  const double n_obs = static_cast<double>(problem.observations.size());
  const bool has_prior = rp.prior_sqrt_info.size() > 0;
  auto total_cost = [&](const Eigen::VectorXd& params, double data_cost) {
    if (!has_prior) return data_cost;
    Eigen::VectorXd x(rp.estimated.size());
    for (size_t k = 0; k < rp.estimated.size(); ++k) x[k] = params[rp.estimated[k]];
    return data_cost + 0.5 * (rp.prior_sqrt_info * (x - rp.prior_mean)).squaredNorm();
  };
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  rp.evaluate(res.params, r, &J);
  double data_cost = 0.5 * r.squaredNorm();
  res.initial_cost_per_observation = data_cost / n_obs;
  double cost = total_cost(res.params, data_cost);
  const auto m = static_cast<Eigen::Index>(rp.estimated.size());
  for (res.iterations = 1; res.iterations <= options.max_iterations; ++res.iterations) {
    // Stack data and prior rows; scale columns to unit norm so metres and radians are comparable.
    Eigen::MatrixXd A(J.rows() + (has_prior ? m : 0), m);
    Eigen::VectorXd b(A.rows());
    A.topRows(J.rows()) = J;
    b.head(J.rows()) = r;
    if (has_prior) {
      Eigen::VectorXd x(m);
      for (Eigen::Index k = 0; k < m; ++k) x[k] = res.params[rp.estimated[k]];
      A.bottomRows(m) = rp.prior_sqrt_info;
      b.tail(m) = rp.prior_sqrt_info * (rp.prior_mean - x);
    }
    const Eigen::VectorXd scale = A.colwise().norm().cwiseMax(1e-300).cwiseInverse();
    const Eigen::VectorXd y = (A * scale.asDiagonal()).colPivHouseholderQr().solve(b);
    const Eigen::VectorXd step = scale.asDiagonal() * y;
    // Step halving keeps the cost monotone far from the solution.
    double t = 1.0;
    Eigen::VectorXd trial;
    double trial_cost = 0, trial_data = 0;
    Eigen::VectorXd r_trial;
    for (int h = 0; h < 20; ++h, t *= 0.5) {
      trial = res.params;
      for (Eigen::Index k = 0; k < m; ++k) trial[rp.estimated[k]] += t * step[k];
      rp.evaluate(trial, r_trial, nullptr);
      trial_data = 0.5 * r_trial.squaredNorm();
      trial_cost = total_cost(trial, trial_data);
      if (trial_cost <= cost) break;
    }
    if (trial_cost > cost) {  // no descent possible: at the minimum within precision
      res.converged = true;
      res.message = "converged (no further decrease)";
      break;
    }
    res.params = trial;
    cost = trial_cost;
    data_cost = trial_data;
    if ((t * y).norm() < options.step_tolerance) {
      res.converged = true;
      res.message = "converged (step below tolerance)";
      break;
    }
    rp.evaluate(res.params, r, &J);
  }
  if (!res.converged) {
    res.iterations = options.max_iterations;
    res.message = "maximum iterations reached";
  }
  rp.finish(res);
  res.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace cellcal
