#include "cellcal/core/identification/identifiability.hpp"

#include <Eigen/QR>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>

namespace cellcal {

bool IdentifiabilityOptions::IsValid(std::string* error) const {
  if (!(rank_tolerance > 0 && rank_tolerance < 1) || !(conditioning_guard >= 0 && conditioning_guard <= 1)) {
    if (error) *error = "rank_tolerance must be in (0, 1) and conditioning_guard in [0, 1]";
    return false;
  }
  if (!(noise_scale > 0) || !std::isfinite(noise_scale) || !prior_sigma.allFinite() || (prior_sigma.array() < 0).any()) {
    if (error) *error = "noise_scale must be > 0 and finite, prior_sigma finite and >= 0";
    return false;
  }
  return true;
}

Eigen::VectorXd plausibleDeviation(const RobotModel& model, double length_m, double angle_rad) {
  Eigen::VectorXd s = Eigen::VectorXd::Zero(model.numParams());
  for (int i = 0; i < 5 * model.numJoints(); ++i) s[i] = model.isLength(i) ? length_m : angle_rad;
  return s;
}

double noiseScaleOf(const Eigen::VectorXd& r, int estimated) {
  const double dof = static_cast<double>(r.size()) - estimated;
  return dof > 0 ? std::max(1.0, std::sqrt(r.squaredNorm() / dof)) : 1.0;
}

std::vector<int> identificationPriority(const RobotModel& model) {
  std::vector<int> out;
  for (int k = 0; k < 6; ++k) out.push_back(model.toolParam(static_cast<FrameParam>(k)));
  for (int k = 0; k < 6; ++k) out.push_back(model.baseParam(static_cast<FrameParam>(k)));
  for (int i = 0; i < 5 * model.numJoints(); ++i) out.push_back(i);
  std::vector<int> canonical;
  for (int i : out)
    if (model.isCanonical(i)) canonical.push_back(i);
  return canonical;
}

namespace {
// The plausible-range test (identifiability.hpp) on columns of J fitted together, from J^T J (formed once).
struct RangeTest {
  RangeTest(const Eigen::MatrixXd& J, const IdentifiabilityOptions& o) : options(o) {
    if (o.prior_sigma.size() > 0) G = J.transpose() * J;
  }
  double range(int c) const { return c < options.prior_sigma.size() ? options.prior_sigma[c] : 0.0; }
  // Whether a least-squares fit of `cols` together pins each of them that has a range better than that range.
  bool pinned(const std::vector<int>& cols) const {
    if (G.size() == 0) return true;
    const auto n = static_cast<Eigen::Index>(cols.size());
    Eigen::VectorXd d(n);
    for (Eigen::Index i = 0; i < n; ++i) d[i] = 1.0 / std::sqrt(G(cols[i], cols[i]));
    Eigen::MatrixXd N(n, n);
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j < n; ++j) N(i, j) = G(cols[i], cols[j]) * d[i] * d[j];
    const Eigen::MatrixXd inv = N.ldlt().solve(Eigen::MatrixXd::Identity(n, n));
    bool ok = true;
    for (Eigen::Index i = 0; i < n; ++i) {
      const double sigma = options.noise_scale * std::sqrt(inv(i, i)) * d[i];
      if (range(cols[i]) > 0 && !(sigma < range(cols[i]))) ok = false;
    }
    return ok;
  }
  const IdentifiabilityOptions& options;
  Eigen::MatrixXd G;
};
}  // namespace

std::vector<int> independentColumns(const Eigen::MatrixXd& J, const std::vector<int>& order,
                                    const IdentifiabilityOptions& options, std::vector<int>* taken_order) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument("IdentifiabilityOptions: " + err);
  const Eigen::Index m = J.rows();
  // A column many orders below the strongest one is round-off, not excitation (e.g. a rotation about an axis the
  // target lies on): normalizing it would turn noise into a direction.
  double max_norm = 0;
  for (int c : order) max_norm = std::max(max_norm, J.col(c).norm());
  const double min_norm = 1e-10 * max_norm;
  // Unit-norm candidates, deflated by every kept direction as it is taken (modified Gram-Schmidt, twice for
  // stability): R.col(i) is candidate i's part outside the kept span, its norm the sine of its angle to that span.
  std::vector<int> cand;
  for (int c : order)
    if (J.col(c).norm() > min_norm && std::find(options.held.begin(), options.held.end(), c) == options.held.end())
      cand.push_back(c);
  const auto nc = static_cast<Eigen::Index>(cand.size());
  Eigen::MatrixXd R(m, nc);
  for (Eigen::Index i = 0; i < nc; ++i) R.col(i) = J.col(cand[i]) / J.col(cand[i]).norm();
  std::vector<bool> taken(cand.size(), false);
  std::vector<int> kept;
  Eigen::MatrixXd Q(m, std::min(m, nc));
  // Candidate i may be taken: it leaves the kept span by more than the rank tolerance and, with plausible ranges, the
  // rows pin it and every kept column fitted together with it better than their ranges.
  const RangeTest ranges(J, options);
  auto eligible = [&](Eigen::Index i) {
    if (taken[static_cast<size_t>(i)] || !(R.col(i).norm() > options.rank_tolerance)) return false;
    std::vector<int> with = kept;
    with.push_back(cand[static_cast<size_t>(i)]);
    return ranges.pinned(with);
  };
  Eigen::Index k = 0;
  std::vector<bool> can(cand.size());
  while (k < std::min(m, nc)) {
    double best = 0;
    for (Eigen::Index i = 0; i < nc; ++i) {
      can[static_cast<size_t>(i)] = eligible(i);  // once per step: with ranges each test factors a normal matrix
      if (can[static_cast<size_t>(i)]) best = std::max(best, R.col(i).norm());
    }
    if (!(best > 0)) break;
    // The highest-priority column that is not much closer to the kept span than the best-separated one.
    Eigen::Index pick = -1;
    for (Eigen::Index i = 0; i < nc && pick < 0; ++i)
      if (can[static_cast<size_t>(i)] && R.col(i).norm() >= options.conditioning_guard * best) pick = i;
    taken[pick] = true;
    kept.push_back(cand[pick]);
    Eigen::VectorXd q = R.col(pick);
    for (Eigen::Index j = 0; j < k; ++j) q -= Q.col(j) * Q.col(j).dot(q);  // re-orthogonalize
    q.normalize();
    Q.col(k++) = q;
    for (Eigen::Index i = 0; i < nc; ++i)
      if (!taken[i]) R.col(i) -= q * q.dot(R.col(i));
  }
  if (taken_order) *taken_order = kept;
  std::sort(kept.begin(), kept.end());
  return kept;
}

namespace {
std::vector<Observation> structuralObservations(const RobotModel& model, const Eigen::VectorXd& params,
                                               MeasurementKind kind) {
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
  return obs;
}

// The kept columns of J scaled to unit norm and factored once: what another column is, to first order, in their terms
// (the dropped parameters' merge coefficients and the absorption map both solve against it).
struct KeptSpan {
  KeptSpan(const Eigen::MatrixXd& J, const std::vector<int>& kept) : kept(kept), scale(kept.size()), Js(J.rows(), kept.size()) {
    for (size_t i = 0; i < kept.size(); ++i) {
      const auto ii = static_cast<Eigen::Index>(i);
      scale[ii] = J.col(kept[i]).norm();
      Js.col(ii) = J.col(kept[i]) / scale[ii];
    }
    qr.compute(Js);
  }
  const std::vector<int>& kept;
  Eigen::VectorXd scale;
  Eigen::MatrixXd Js;
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr;
};

// absorptionMap over a factored span (its contract in identifiability.hpp).
Eigen::MatrixXd absorption(const RobotModel& model, const Eigen::MatrixXd& J, const KeptSpan& span, double absorb_sine) {
  const auto k = static_cast<Eigen::Index>(span.kept.size());
  Eigen::MatrixXd T = Eigen::MatrixXd::Zero(k, model.numParams());
  for (Eigen::Index i = 0; i < k; ++i) T(i, span.kept[static_cast<size_t>(i)]) = 1.0;
  if (k == 0) return T;
  for (Eigen::Index i = 0; i < k; ++i)
    if (!(span.scale[i] > 0)) throw std::invalid_argument("absorptionMap: a kept column is zero");
  double max_norm = 0;
  for (int c = 0; c < model.numParams(); ++c) max_norm = std::max(max_norm, J.col(c).norm());
  for (int c : model.canonicalParams()) {
    if (std::find(span.kept.begin(), span.kept.end(), c) != span.kept.end()) continue;
    const double norm = J.col(c).norm();
    if (!(norm > 1e-10 * max_norm)) continue;  // not excited: nothing to stand for
    const Eigen::VectorXd u = J.col(c) / norm;
    const Eigen::VectorXd coef = span.qr.solve(u);
    if ((span.Js * coef - u).norm() > absorb_sine) continue;  // the kept columns do not span it
    // J_c = norm * Js coef = J_kept diag(1/scale) coef * norm.
    T.col(c) = coef.cwiseQuotient(span.scale) * norm;
  }
  return T;
}
}  // namespace

IdentifiabilityReport analyzeIdentifiability(const RobotModel& model, const Eigen::MatrixXd& J,
                                             const IdentifiabilityOptions& options) {
  if (J.cols() != model.numParams()) throw std::invalid_argument("analyzeIdentifiability: J has the wrong column count");
  std::vector<int> cand = identificationPriority(model);
  auto in = [](const std::vector<int>& v, int c) { return std::find(v.begin(), v.end(), c) != v.end(); };
  cand.erase(std::remove_if(cand.begin(), cand.end(),
                            [&](int c) {
                              return (!options.candidates.empty() && !in(options.candidates, c)) || in(options.held, c);
                            }),
             cand.end());

  IdentifiabilityReport rep;
  rep.num_candidates = static_cast<int>(cand.size());
  rep.identifiable = independentColumns(J, cand, options, &rep.taken);
  const int k = static_cast<int>(rep.identifiable.size());
  std::vector<int> dropped;
  for (int c : cand)
    if (!std::binary_search(rep.identifiable.begin(), rep.identifiable.end(), c)) dropped.push_back(c);
  double max_norm = 0;
  for (int c : cand) max_norm = std::max(max_norm, J.col(c).norm());
  const double min_norm = 1e-10 * max_norm;
  rep.rank = k;

  // Scaled Jacobian of the kept columns: condition number, and what each dropped column merges into.
  const KeptSpan span(J, rep.identifiable);
  if (k > 0) {
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(span.Js);
    const auto& s = svd.singularValues();
    rep.condition_number = s(s.size() - 1) > 0 ? s(0) / s(s.size() - 1) : INFINITY;
  }
  rep.noise_scale = options.noise_scale;
  const RangeTest ranges(J, options);
  for (int c : dropped) {
    DroppedParameter d;
    d.index = c;
    d.name = model.paramName(c);
    const double norm = J.col(c).norm();
    d.prior_sigma_si = ranges.range(c);
    d.data_sigma_si = INFINITY;
    if (norm > min_norm) {
      const double outside = k > 0 ? (span.Js * span.qr.solve(J.col(c) / norm) - J.col(c) / norm).norm() : 1.0;
      if (outside > 0) d.data_sigma_si = options.noise_scale / (norm * outside);
      std::vector<int> with = rep.identifiable;
      with.push_back(c);
      d.below_prior = options.prior_sigma.size() > 0 && outside > options.rank_tolerance && !ranges.pinned(with);
    }
    if (norm > min_norm && k > 0) {
      const Eigen::VectorXd coef = span.qr.solve(J.col(c) / norm);
      for (int i = 0; i < k; ++i)
        if (std::abs(coef[i]) >= 0.05) d.merged_into.emplace_back(rep.identifiable[i], coef[i]);
      std::sort(d.merged_into.begin(), d.merged_into.end(),
                [](const auto& a, const auto& b) { return std::abs(a.second) > std::abs(b.second); });
    }
    rep.dropped.push_back(std::move(d));
  }
  rep.absorption = absorption(model, J, span, kDefaultAbsorbSine);
  return rep;
}

Eigen::MatrixXd absorptionMap(const RobotModel& model, const Eigen::MatrixXd& J, const std::vector<int>& kept,
                              double absorb_sine) {
  if (J.cols() != model.numParams()) throw std::invalid_argument("absorptionMap: J has the wrong column count");
  return absorption(model, J, KeptSpan(J, kept), absorb_sine);
}

Eigen::MatrixXd structuralAbsorption(const RobotModel& model, const Eigen::VectorXd& params, MeasurementKind kind,
                                     const std::vector<int>& kept) {
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackResiduals(model, params, structuralObservations(model, params, kind), r, &J);
  return absorptionMap(model, J, kept);
}

IdentifiabilityReport analyzeIdentifiability(const RobotModel& model, const Eigen::VectorXd& params,
                                             const std::vector<Observation>& obs,
                                             const IdentifiabilityOptions& options) {
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackResiduals(model, params, obs, r, &J);
  return analyzeIdentifiability(model, J, options);
}


std::vector<int> frameGauge(const RobotModel& model, const Eigen::VectorXd& params, double rank_tolerance) {
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackResiduals(model, params, structuralObservations(model, params, MeasurementKind::kPose6D), r, &J);
  std::vector<int> frames;
  for (int k = 0; k < 6; ++k) {
    frames.push_back(model.baseParam(static_cast<FrameParam>(k)));
    frames.push_back(model.toolParam(static_cast<FrameParam>(k)));
  }
  const KeptSpan span(J, frames);
  std::vector<int> out;
  for (int c : model.canonicalParams()) {
    if (c >= 5 * model.numJoints()) continue;
    const double norm = J.col(c).norm();
    if (!(norm > 0)) continue;
    const Eigen::VectorXd u = J.col(c) / norm;
    if ((span.Js * span.qr.solve(u) - u).norm() < rank_tolerance) out.push_back(c);
  }
  return out;
}

IdentifiabilityReport structuralIdentifiability(const RobotModel& model, const Eigen::VectorXd& params,
                                                MeasurementKind kind, const IdentifiabilityOptions& options) {
  return analyzeIdentifiability(model, params, structuralObservations(model, params, kind), options);
}

std::string IdentifiabilityReport::summary(const RobotModel& model) const {
  std::ostringstream s;
  s << rank << " of " << num_candidates << " parameters identifiable, condition number " << condition_number << "\n";
  for (const auto& d : dropped) {
    s << "  fixed " << model.paramName(d.index);
    if (d.below_prior && d.prior_sigma_si > 0 && d.data_sigma_si >= d.prior_sigma_si) {
      s << " (the data pin it to +-" << d.data_sigma_si << ", no better than its plausible +-" << d.prior_sigma_si << ")";
    } else if (d.below_prior) {
      s << " (fitted with the others, they would pin some of them no better than their plausible range)";
    } else if (d.merged_into.empty()) {
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
