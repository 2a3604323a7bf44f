#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <algorithm>
#include <chrono>
#include <cmath>

#include "calibration_internal.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/se3.hpp"

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

Eigen::MatrixXd priorOverEstimated(const GaussianPrior& prior, const std::vector<int>& estimated,
                                   const Eigen::MatrixXd& absorption) {
  const auto ne = static_cast<Eigen::Index>(estimated.size());
  if (absorption.rows() != ne || (ne > 0 && absorption.cols() <= *std::max_element(estimated.begin(), estimated.end())))
    throw std::invalid_argument("priorOverEstimated: the absorption map does not match the estimated parameters");
  // The prior's parameters that enter: the estimated ones and those they stand for; the rest are held.
  std::vector<Eigen::Index> used;
  for (size_t b = 0; b < prior.indices.size(); ++b) {
    const int c = prior.indices[b];
    const bool estimated_c = std::find(estimated.begin(), estimated.end(), c) != estimated.end();
    if (estimated_c || (c < absorption.cols() && absorption.col(c).cwiseAbs().maxCoeff() > 0))
      used.push_back(static_cast<Eigen::Index>(b));
  }
  for (int c : estimated)
    if (std::find(prior.indices.begin(), prior.indices.end(), c) == prior.indices.end())
      throw std::invalid_argument("priorOverEstimated: the prior has no variance for an estimated parameter");
  // Conditioned on the held ones: the information restricted to `used`, inverted.
  const Eigen::MatrixXd info = prior.covariance.inverse();
  const auto nu = static_cast<Eigen::Index>(used.size());
  Eigen::MatrixXd info_used(nu, nu);
  Eigen::MatrixXd T(ne, nu);
  for (Eigen::Index a = 0; a < nu; ++a) {
    for (Eigen::Index b = 0; b < nu; ++b) info_used(a, b) = info(used[a], used[b]);
    T.col(a) = absorption.col(prior.indices[static_cast<size_t>(used[a])]);
  }
  const Eigen::MatrixXd P_used = info_used.ldlt().solve(Eigen::MatrixXd::Identity(nu, nu));
  Eigen::MatrixXd P = T * P_used * T.transpose();
  return 0.5 * (P + P.transpose());
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
  if (!outliers.IsValid(error)) return false;
  return identifiability.IsValid(error);
}

bool SolverOptions::IsValid(std::string* error) const {
  if (max_iterations < 1 || !(step_tolerance > 0) || !(prediction_tolerance >= 0)) {
    if (error) *error = "max_iterations must be >= 1, step_tolerance > 0 and prediction_tolerance >= 0";
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
  IdentifiabilityReport structural;
  if (p.prior) {
    structural = structuralIdentifiability(model, p.initial_params, p.observations.front().kind, p.identifiability);
    estimated = structural.identifiable;
  } else {
    estimated = identifiability.identifiable;
  }
  const bool prior_covers = p.prior && std::all_of(estimated.begin(), estimated.end(), [&](int c) {
                              return std::find(p.prior->indices.begin(), p.prior->indices.end(), c) !=
                                     p.prior->indices.end();
                            });
  if (prior_covers) {
    // The prior over the estimated parameters, with the uncertainty of those they stand for (priorOverEstimated).
    const Eigen::MatrixXd P = priorOverEstimated(*p.prior, estimated, structural.absorption);
    const auto n = P.rows();
    Eigen::LLT<Eigen::MatrixXd> llt(P.ldlt().solve(Eigen::MatrixXd::Identity(n, n)) +
                                    1e-30 * Eigen::MatrixXd::Identity(n, n));
    prior_sqrt_info = llt.matrixU();
    prior_mean.resize(n);
    for (Eigen::Index a = 0; a < n; ++a) prior_mean[a] = p.prior->mean[estimated[a]];
  } else if (p.prior) {
    // Some estimated parameter has no prior: the information over the ones it has (the others held fixed).
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

namespace internal {

OutlierScreen screenFit(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                        const OutlierOptions& options) {
  KinematicsData data(model);
  std::vector<Eigen::Vector3d> pos;
  std::vector<double> ori;
  for (const auto& o : obs) {
    const Pose& T = forwardKinematics(model, data, params, o.q_rad);
    pos.push_back(o.measured_in_tracker.translation() - T.translation());
    ori.push_back(o.kind == MeasurementKind::kPose6D
                      ? logSO3(o.measured_in_tracker.linear() * T.linear().transpose()).norm()
                      : std::nan(""));
  }
  return screenOutliers(pos, ori, options);
}

namespace {
CalibrationResult fitAndScreen(const CalibrationProblem& problem, const SolverOptions& options,
                               CalibrationResult (*solve)(const CalibrationProblem&, const SolverOptions&));
}  // namespace

CalibrationResult solveScreened(const CalibrationProblem& problem, const SolverOptions& options,
                                CalibrationResult (*solve)(const CalibrationProblem&, const SolverOptions&)) {
  const auto t0 = std::chrono::steady_clock::now();
  CalibrationResult res = fitAndScreen(problem, options, solve);
  const IdentifiabilityOptions& io = problem.identifiability;
  if (io.prior_sigma.size() == 0) return res;
  // With plausible ranges the decision depends on the noise: decided again with the residual the fit leaves (model
  // error included), which only ever holds more; refit when the estimated set changes.
  std::vector<Observation> kept;
  for (int i : keptRows(static_cast<int>(problem.observations.size()), res.outliers.rows))
    kept.push_back(problem.observations[static_cast<size_t>(i)]);
  Eigen::VectorXd r;
  stackResiduals(*problem.model, res.params, kept, r, nullptr);
  const double scale = noiseScaleOf(r, static_cast<int>(res.estimated.size()));
  if (!(scale > io.noise_scale)) return res;
  CalibrationProblem again = problem;
  again.identifiability.noise_scale = scale;
  const IdentifiabilityReport rep = analyzeIdentifiability(*problem.model, problem.initial_params, kept, again.identifiability);
  if (rep.identifiable == res.estimated) {
    res.identifiability = rep;
  } else {
    res = fitAndScreen(again, options, solve);
  }
  res.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

namespace {
CalibrationResult fitAndScreen(const CalibrationProblem& problem, const SolverOptions& options,
                               CalibrationResult (*solve)(const CalibrationProblem&, const SolverOptions&)) {
  const auto t0 = std::chrono::steady_clock::now();
  CalibrationResult res = solve(problem, options);
  res.outliers = screenFit(*problem.model, res.params, problem.observations, problem.outliers);
  if (!problem.outliers.enabled) return res;
  const int n = static_cast<int>(problem.observations.size());
  std::vector<int> used;  // the flagged set the current fit left out
  for (int round = 0; round < problem.outliers.max_rounds && res.outliers.rows != used; ++round) {
    // Refit without the flagged rows (never fewer than half of them kept), from the same start.
    if (2 * static_cast<int>(res.outliers.rows.size()) > n) break;
    used = res.outliers.rows;
    CalibrationProblem sub = problem;
    sub.observations.clear();
    for (int i : keptRows(n, used)) sub.observations.push_back(problem.observations[static_cast<size_t>(i)]);
    res = solve(sub, options);
    res.outliers = screenFit(*problem.model, res.params, problem.observations, problem.outliers);
  }
  res.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}
}  // namespace

}  // namespace internal

CalibrationResult solveGaussNewton(const CalibrationProblem& problem, const SolverOptions& options) {
  internal::requireValid(problem, options);
  return internal::solveScreened(problem, options, internal::solveGaussNewtonPlain);
}

CalibrationResult internal::solveGaussNewtonPlain(const CalibrationProblem& problem, const SolverOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  internal::ReducedProblem rp(problem);
  const auto m = static_cast<Eigen::Index>(rp.estimated.size());
  const bool has_prior = rp.prior_sqrt_info.size() > 0;
  auto full = [&](const Eigen::VectorXd& x) {
    Eigen::VectorXd params = problem.initial_params;
    for (Eigen::Index k = 0; k < m; ++k) params[rp.estimated[k]] = x[k];
    return params;
  };
  // Data rows, then the prior's whitened rows U (mean - x).
  auto eval = [&](const Eigen::VectorXd& x, Eigen::VectorXd& b, Eigen::MatrixXd* A) {
    Eigen::VectorXd r;
    Eigen::MatrixXd J;
    rp.evaluate(full(x), r, A ? &J : nullptr);
    b.resize(r.size() + (has_prior ? m : 0));
    b.head(r.size()) = r;
    if (has_prior) b.tail(m) = rp.prior_sqrt_info * (rp.prior_mean - x);
    if (A) {
      A->resize(b.size(), m);
      A->topRows(J.rows()) = J;
      if (has_prior) A->bottomRows(m) = rp.prior_sqrt_info;
    }
  };
  Eigen::VectorXd x0(m);
  for (Eigen::Index k = 0; k < m; ++k) x0[k] = problem.initial_params[rp.estimated[k]];
  CalibrationResult res;
  res.initial_cost_per_observation = rp.dataCost(problem.initial_params) / static_cast<double>(problem.observations.size());
  const internal::GaussNewtonOutcome gn = internal::gaussNewton(eval, x0, options);
  res.params = full(gn.x);
  res.iterations = gn.iterations;
  res.converged = gn.converged;
  res.message = gn.message;
  rp.finish(res);
  res.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

}  // namespace cellcal
