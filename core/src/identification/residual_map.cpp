#include "cellcal/core/identification/residual_map.hpp"
#include "residual_map_detail.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

namespace cellcal {
namespace residual_map_detail {

Eigen::MatrixXd kernel(const Eigen::MatrixXd& Qs, double s2, double n2) {
  const Eigen::VectorXd sq = Qs.rowwise().squaredNorm();
  Eigen::MatrixXd K = -2.0 * Qs * Qs.transpose();
  K.colwise() += sq;
  K.rowwise() += sq.transpose();
  K = (-0.5 * K.array().max(0.0)).exp() * s2;
  K.diagonal().array() += n2;
  return K;
}

Eigen::MatrixXd scaled(const std::vector<Eigen::VectorXd>& q, const std::vector<int>& rows, const Eigen::VectorXd& l) {
  Eigen::MatrixXd Q(static_cast<Eigen::Index>(rows.size()), l.size());
  for (size_t i = 0; i < rows.size(); ++i) Q.row(static_cast<Eigen::Index>(i)) = q[static_cast<size_t>(rows[i])].cwiseQuotient(l).transpose();
  return Q;
}

}  // namespace residual_map_detail

using residual_map_detail::kernel;
using residual_map_detail::scaled;

bool ResidualMapKernel::IsValid(int joints, std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (length_rad.size() != joints)
    return fail(std::to_string(length_rad.size()) + " length scales for " + std::to_string(joints) + " joints");
  if (!length_rad.allFinite() || (length_rad.array() <= 0).any()) return fail("length scales must be finite and > 0");
  if (!(signal_m > 0 && std::isfinite(signal_m))) return fail("the signal sigma must be finite and > 0");
  if (!(noise_m > 0 && std::isfinite(noise_m))) return fail("the noise sigma must be finite and > 0");
  if (!(max_distance > 0)) return fail("max_distance must be > 0");
  return true;
}

ResidualMap conditionResidualMap(std::vector<Eigen::VectorXd> q, std::vector<Eigen::Vector3d> y, const ResidualMapKernel& k) {
  if (q.empty() || q.size() != y.size()) throw std::invalid_argument("residual map: no rows, or configurations and residuals differ in number");
  std::string error;
  if (!k.IsValid(static_cast<int>(q.front().size()), &error)) throw std::invalid_argument("residual map: " + error);
  for (size_t i = 0; i < q.size(); ++i)
    if (q[i].size() != k.length_rad.size() || !q[i].allFinite() || !y[i].allFinite())
      throw std::invalid_argument("residual map: row " + std::to_string(i + 1) + " is not finite or has another number of joints");
  ResidualMap map;
  map.length_rad_ = k.length_rad;
  map.signal_m_ = k.signal_m;
  map.noise_m_ = k.noise_m;
  map.max_distance_ = k.max_distance;
  std::vector<int> all(q.size());
  std::iota(all.begin(), all.end(), 0);
  Eigen::MatrixXd Y(static_cast<Eigen::Index>(y.size()), 3);
  for (size_t i = 0; i < y.size(); ++i) Y.row(static_cast<Eigen::Index>(i)) = y[i].transpose();
  const Eigen::LLT<Eigen::MatrixXd> llt(kernel(scaled(q, all, map.length_rad_), k.signal_m * k.signal_m, k.noise_m * k.noise_m));
  if (llt.info() != Eigen::Success) throw std::invalid_argument("residual map: the kernel matrix is not positive definite");
  map.L_ = llt.matrixL();
  map.alpha_ = llt.solve(Y);
  map.q_ = std::move(q);
  map.y_ = std::move(y);
  return map;
}

ResidualMap::Prediction ResidualMap::predict(const Eigen::VectorXd& q, bool with_sigma) const {
  Prediction p;
  if (q_.empty() || q.size() != length_rad_.size()) return p;
  const auto n = static_cast<Eigen::Index>(q_.size());
  Eigen::VectorXd k(n);
  double nearest2 = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0; i < n; ++i) {
    const double d2 = (q - q_[static_cast<size_t>(i)]).cwiseQuotient(length_rad_).squaredNorm();
    nearest2 = std::min(nearest2, d2);
    k[i] = signal_m_ * signal_m_ * std::exp(-0.5 * d2);
  }
  p.distance = std::sqrt(nearest2);
  p.applies = p.distance <= max_distance_;
  if (!p.applies) return p;
  p.correction_m = alpha_.transpose() * k;
  if (with_sigma) {
    const Eigen::VectorXd v = L_.triangularView<Eigen::Lower>().solve(k);
    p.sigma_m = std::sqrt(std::max(0.0, signal_m_ * signal_m_ - v.squaredNorm()));
  }
  return p;
}

double ResidualMap::sigmaBound_m(const Eigen::VectorXd& q, int nearest) const {
  if (q_.empty() || q.size() != length_rad_.size() || nearest < 1) return signal_m_;
  std::vector<std::pair<double, int>> d2(q_.size());
  for (size_t i = 0; i < q_.size(); ++i) d2[i] = {(q - q_[i]).cwiseQuotient(length_rad_).squaredNorm(), static_cast<int>(i)};
  const size_t m = std::min(q_.size(), static_cast<size_t>(nearest));
  std::partial_sort(d2.begin(), d2.begin() + static_cast<std::ptrdiff_t>(m), d2.end());
  std::vector<int> rows(m);
  for (size_t i = 0; i < m; ++i) rows[i] = d2[i].second;
  const Eigen::MatrixXd Q = scaled(q_, rows, length_rad_);
  const Eigen::LLT<Eigen::MatrixXd> llt(residual_map_detail::kernel(Q, signal_m_ * signal_m_, noise_m_ * noise_m_));
  Eigen::VectorXd k(static_cast<Eigen::Index>(m));
  for (size_t i = 0; i < m; ++i) k[static_cast<Eigen::Index>(i)] = signal_m_ * signal_m_ * std::exp(-0.5 * d2[i].first);
  const Eigen::VectorXd v = llt.matrixL().solve(k);
  return std::sqrt(std::max(0.0, signal_m_ * signal_m_ - v.squaredNorm()));
}

}  // namespace cellcal
