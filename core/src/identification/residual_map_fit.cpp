// Choosing a residual map's kernel (residual_map.hpp): the marginal likelihood and its gradient, Ceres' L-BFGS. Apart
// from residual_map.cpp so that what a robot file's parser reaches (conditioning, prediction) needs no solver.
#include <ceres/gradient_problem.h>
#include <ceres/gradient_problem_solver.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>

#include "cellcal/core/identification/residual_map.hpp"
#include "residual_map_detail.hpp"

namespace cellcal {
namespace {

using residual_map_detail::kernel;

constexpr double kFloorM = 1e-9;  // the smallest signal and noise sigma a map is given: 1 nm

// -log p(Y | theta) per row, the three axes together, and its gradient (theta: log l_1..l_d, log s, log n):
//   f = (1/2 tr(Y^T K^-1 Y) + 3/2 log|K|) / m + 3/2 log(2 pi)
//   df/dtheta_k = 1/(2m) tr((3 K^-1 - A A^T) dK/dtheta_k),  A = K^-1 Y,
//   dK/dlog l_j = s^2 E o D_j (D_j: squared scaled differences of joint j), dK/dlog s = 2 s^2 E, dK/dlog n = 2 n^2 I.
class NegLogLikelihood : public ceres::FirstOrderFunction {
 public:
  NegLogLikelihood(const std::vector<Eigen::VectorXd>& q, const std::vector<int>& rows, const Eigen::MatrixXd& Y)
      : Y_(Y), d_(static_cast<int>(q.front().size())) {
    Q_.resize(static_cast<Eigen::Index>(rows.size()), d_);
    for (size_t i = 0; i < rows.size(); ++i) Q_.row(static_cast<Eigen::Index>(i)) = q[static_cast<size_t>(rows[i])].transpose();
  }
  int NumParameters() const override { return d_ + 2; }
  bool Evaluate(const double* theta, double* cost, double* gradient) const override {
    const Eigen::Index m = Q_.rows();
    Eigen::VectorXd l(d_);
    for (int j = 0; j < d_; ++j) l[j] = std::exp(theta[j]);
    // Below a nanometre the likelihood of residuals that are all (nearly) zero runs to -inf as s, n -> 0 and
    // exp() underflows to 0: the line search is kept above the floor (an evaluation below it is infeasible).
    if (theta[d_] < kLogFloorM || theta[d_ + 1] < kLogFloorM) return false;
    const double s2 = std::exp(2 * theta[d_]), n2 = std::exp(2 * theta[d_ + 1]);
    if (!std::isfinite(s2) || !std::isfinite(n2) || !l.allFinite()) return false;
    const Eigen::MatrixXd Qs = Q_ * l.cwiseInverse().asDiagonal();
    const Eigen::MatrixXd K = kernel(Qs, s2, n2);
    const Eigen::LLT<Eigen::MatrixXd> llt(K);
    if (llt.info() != Eigen::Success) return false;
    const Eigen::MatrixXd A = llt.solve(Y_);
    const double logdet = 2.0 * llt.matrixLLT().diagonal().array().log().sum();
    *cost = (0.5 * Y_.cwiseProduct(A).sum() + 1.5 * logdet) / static_cast<double>(m) + 1.5 * std::log(2 * kPiLocal);
    if (!std::isfinite(*cost)) return false;
    if (!gradient) return true;
    Eigen::MatrixXd W = 3.0 * llt.solve(Eigen::MatrixXd::Identity(m, m));
    W.noalias() -= A * A.transpose();
    const Eigen::MatrixXd SE = K - n2 * Eigen::MatrixXd::Identity(m, m);  // s^2 E
    const Eigen::MatrixXd WSE = W.cwiseProduct(SE);
    const double scale = 0.5 / static_cast<double>(m);
    for (int j = 0; j < d_; ++j) {
      double g = 0;
      for (Eigen::Index c = 0; c < m; ++c)
        for (Eigen::Index r = 0; r < m; ++r) {
          const double dq = Qs(r, j) - Qs(c, j);
          g += WSE(r, c) * dq * dq;
        }
      gradient[j] = scale * g;
    }
    gradient[d_] = scale * 2.0 * WSE.sum();
    gradient[d_ + 1] = scale * 2.0 * n2 * W.trace();
    return true;
  }

 private:
  static constexpr double kPiLocal = 3.14159265358979323846;
  static constexpr double kLogFloorM = -20.7232658370;  // just below log(1e-9): 1 nm
  Eigen::MatrixXd Q_;
  Eigen::MatrixXd Y_;
  int d_;
};

}  // namespace

bool ResidualMapOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* m) {
    if (error) *error = m;
    return false;
  };
  if (fit_rows < 10) return fail("fit_rows must be >= 10");
  if (max_rows < fit_rows) return fail("max_rows must be >= fit_rows");
  if (!(max_distance > 0)) return fail("max_distance must be > 0");
  return true;
}

ResidualMap fitResidualMap(const std::vector<Eigen::VectorXd>& q, const std::vector<Eigen::Vector3d>& y,
                           const ResidualMapOptions& o) {
  std::string error;
  if (!o.IsValid(&error)) throw std::invalid_argument("ResidualMapOptions: " + error);
  if (q.size() != y.size()) throw std::invalid_argument("fitResidualMap: configurations and residuals differ in number");
  if (q.size() < 10) throw std::invalid_argument("fitResidualMap: " + std::to_string(q.size()) + " rows (at least 10)");
  const Eigen::Index d = q.front().size();
  for (const auto& x : q)
    if (x.size() != d || !x.allFinite()) throw std::invalid_argument("fitResidualMap: configurations of unequal size or not finite");
  std::vector<int> order(q.size());
  std::iota(order.begin(), order.end(), 0);
  std::mt19937_64 rng(o.seed);
  std::shuffle(order.begin(), order.end(), rng);
  const std::vector<int> fit_rows(order.begin(), order.begin() + std::min<std::size_t>(order.size(), static_cast<std::size_t>(o.fit_rows)));
  const std::vector<int> map_rows(order.begin(), order.begin() + std::min<std::size_t>(order.size(), static_cast<std::size_t>(o.max_rows)));
  auto stack = [&](const std::vector<int>& rows) {
    Eigen::MatrixXd Y(static_cast<Eigen::Index>(rows.size()), 3);
    for (size_t i = 0; i < rows.size(); ++i) Y.row(static_cast<Eigen::Index>(i)) = y[static_cast<size_t>(rows[i])].transpose();
    return Y;
  };
  const Eigen::MatrixXd Yfit = stack(fit_rows);
  // Start: each length scale the joint's spread over the rows, s the residuals' RMS, n a third of it.
  Eigen::VectorXd theta(d + 2);
  {
    Eigen::VectorXd mean = Eigen::VectorXd::Zero(d), sq = Eigen::VectorXd::Zero(d);
    for (int r : fit_rows) mean += q[static_cast<size_t>(r)];
    mean /= static_cast<double>(fit_rows.size());
    for (int r : fit_rows) sq += (q[static_cast<size_t>(r)] - mean).cwiseAbs2();
    for (Eigen::Index j = 0; j < d; ++j) theta[j] = std::log(std::max(1e-3, std::sqrt(sq[j] / static_cast<double>(fit_rows.size()))));
    const double rms = std::max(kFloorM, std::sqrt(Yfit.squaredNorm() / static_cast<double>(Yfit.size())));
    theta[d] = std::log(rms);
    theta[d + 1] = std::log(std::max(kFloorM, rms / 3));
  }
  // Maximum marginal likelihood: L-BFGS on the analytic gradient (Ceres' gradient solver) from three starts (each
  // joint's spread x 0.3, 1 and 3), the best kept: the likelihood has local optima (on Series A after the extended
  // model, the start at the spread alone settled at twice the noise and a third longer length scales on joint 3).
  NegLogLikelihood* nll = new NegLogLikelihood(q, fit_rows, Yfit);
  const ceres::GradientProblem problem(nll);  // owns nll
  ceres::GradientProblemSolver::Options so;
  so.max_num_iterations = 200;
  so.logging_type = ceres::SILENT;
  double best = std::numeric_limits<double>::infinity();
  Eigen::VectorXd chosen = theta;
  for (const double widen : {0.3, 1.0, 3.0}) {
    Eigen::VectorXd t = theta;
    t.head(d).array() += std::log(widen);
    ceres::GradientProblemSolver::Summary summary;
    ceres::Solve(so, problem, t.data(), &summary);
    if (summary.final_cost < best && t.allFinite()) {
      best = summary.final_cost;
      chosen = t;
    }
  }
  theta = chosen;
  ResidualMapKernel k;
  k.length_rad = theta.head(d).array().exp();
  k.signal_m = std::max(kFloorM, std::exp(theta[d]));
  k.noise_m = std::max(kFloorM, std::exp(theta[d + 1]));
  k.max_distance = o.max_distance;
  std::vector<Eigen::VectorXd> mq;
  std::vector<Eigen::Vector3d> my;
  for (int r : map_rows) {
    mq.push_back(q[static_cast<size_t>(r)]);
    my.push_back(y[static_cast<size_t>(r)]);
  }
  ResidualMap map = conditionResidualMap(std::move(mq), std::move(my), k);
  map.nll_per_row_ = best;
  return map;
}

}  // namespace cellcal
