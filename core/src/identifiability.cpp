#include "cellcal/core/identifiability.hpp"

#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

namespace cellcal {

bool IdentifiabilityOptions::IsValid(std::string* error) const {
  if (!(rank_tolerance > 0 && rank_tolerance < 1) || !(weak_separation >= 0 && weak_separation < 1)) {
    if (error) *error = "rank_tolerance must be in (0, 1) and weak_separation in [0, 1)";
    return false;
  }
  return true;
}

std::vector<int> independentColumns(const Eigen::MatrixXd& J, const std::vector<int>& order,
                                    const IdentifiabilityOptions& options) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument("IdentifiabilityOptions: " + err);
  const Eigen::Index m = J.rows();
  Eigen::MatrixXd Q(m, std::min<Eigen::Index>(m, static_cast<Eigen::Index>(order.size())));
  int k = 0;
  std::vector<int> kept;
  // A column many orders below the strongest one is round-off, not excitation (e.g. a rotation about an axis the
  // target lies on): normalizing it would turn noise into a direction.
  double max_norm = 0;
  for (int c : order) max_norm = std::max(max_norm, J.col(c).norm());
  const double min_norm = 1e-10 * max_norm;
  // Two passes over the candidates in priority order. The first keeps only columns well clear of the kept span
  // (> weak_separation); the second revisits the rest against everything kept by then. A near-gauge that only a
  // small angle breaks (joint 6's alpha and a tool roll, separated by a tool pitch of a few hundredths of a degree)
  // is thus closed by the well-separated parameter instead of being estimated as two nearly equal columns.
  auto residual = [&](int c, Eigen::VectorXd& v) {
    v = J.col(c) / J.col(c).norm();
    for (int pass = 0; pass < 2; ++pass) v -= Q.leftCols(k) * (Q.leftCols(k).transpose() * v);
    return v.norm();
  };
  std::vector<int> deferred;
  Eigen::VectorXd v;
  for (int c : order) {
    if (J.col(c).norm() <= min_norm || k >= m) continue;
    const double res = residual(c, v);
    if (res > std::max(options.weak_separation, options.rank_tolerance)) {
      Q.col(k++) = v / res;
      kept.push_back(c);
    } else {
      deferred.push_back(c);
    }
  }
  for (int c : deferred) {
    const double res = k < m ? residual(c, v) : 0.0;
    if (res > options.rank_tolerance) {
      Q.col(k++) = v / res;
      kept.push_back(c);
    }
  }
  std::sort(kept.begin(), kept.end());
  return kept;
}

IdentifiabilityReport analyzeIdentifiability(const RobotModel& model, const Eigen::MatrixXd& J,
                                             const IdentifiabilityOptions& options) {
  if (J.cols() != model.numParams()) throw std::invalid_argument("analyzeIdentifiability: J has the wrong column count");
  std::vector<int> cand = options.candidates.empty() ? model.canonicalParams() : options.candidates;
  // Priority: joints (base to flange, natural parameter order), then base, then tool: ascending index order.
  std::sort(cand.begin(), cand.end());

  IdentifiabilityReport rep;
  rep.num_candidates = static_cast<int>(cand.size());
  const Eigen::Index m = J.rows();
  rep.identifiable = independentColumns(J, cand, options);
  const int k = static_cast<int>(rep.identifiable.size());
  std::vector<int> dropped;
  for (int c : cand)
    if (!std::binary_search(rep.identifiable.begin(), rep.identifiable.end(), c)) dropped.push_back(c);
  double max_norm = 0;
  for (int c : cand) max_norm = std::max(max_norm, J.col(c).norm());
  const double min_norm = 1e-10 * max_norm;
  rep.rank = k;

  // Scaled Jacobian of the kept columns: condition number, and what each dropped column merges into.
  Eigen::MatrixXd Js(m, k);
  for (int i = 0; i < k; ++i) Js.col(i) = J.col(rep.identifiable[i]) / J.col(rep.identifiable[i]).norm();
  if (k > 0) {
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(Js);
    const auto& s = svd.singularValues();
    rep.condition_number = s(s.size() - 1) > 0 ? s(0) / s(s.size() - 1) : INFINITY;
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(Js);
  for (int c : dropped) {
    DroppedParameter d;
    d.index = c;
    d.name = model.paramName(c);
    const double norm = J.col(c).norm();
    if (norm > min_norm && k > 0) {
      const Eigen::VectorXd coef = qr.solve(J.col(c) / norm);
      for (int i = 0; i < k; ++i)
        if (std::abs(coef[i]) >= 0.05) d.merged_into.emplace_back(rep.identifiable[i], coef[i]);
      std::sort(d.merged_into.begin(), d.merged_into.end(),
                [](const auto& a, const auto& b) { return std::abs(a.second) > std::abs(b.second); });
    }
    rep.dropped.push_back(std::move(d));
  }
  return rep;
}

IdentifiabilityReport analyzeIdentifiability(const RobotModel& model, const Eigen::VectorXd& params,
                                             const std::vector<Observation>& obs,
                                             const IdentifiabilityOptions& options) {
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackResiduals(model, params, obs, r, &J);
  return analyzeIdentifiability(model, J, options);
}

IdentifiabilityReport structuralIdentifiability(const RobotModel& model, const Eigen::VectorXd& params,
                                                MeasurementKind kind, const IdentifiabilityOptions& options) {
  std::mt19937_64 rng(20240607);
  std::vector<Observation> obs(200);
  KinematicsData data(model);
  for (auto& o : obs) {
    o.q_rad.resize(model.numJoints());
    for (int j = 0; j < model.numJoints(); ++j) {
      const double lo = std::max(model.limits[j].lower_rad, -kPi), hi = std::min(model.limits[j].upper_rad, kPi);
      o.q_rad[j] = std::uniform_real_distribution<double>(lo, hi)(rng);
    }
    o.kind = kind;
    o.measured_in_tracker = forwardKinematics(model, data, params, o.q_rad);
  }
  return analyzeIdentifiability(model, params, obs, options);
}

std::string IdentifiabilityReport::summary(const RobotModel& model) const {
  std::ostringstream s;
  s << rank << " of " << num_candidates << " parameters identifiable, condition number " << condition_number << "\n";
  for (const auto& d : dropped) {
    s << "  fixed " << model.paramName(d.index);
    if (d.merged_into.empty()) {
      s << " (not excited by these poses)";
    } else {
      s << " (merged into";
      for (size_t i = 0; i < std::min<size_t>(3, d.merged_into.size()); ++i)
        s << " " << model.paramName(d.merged_into[i].first);
      s << ")";
    }
    s << "\n";
  }
  return s.str();
}

}  // namespace cellcal
