#include "cellcal/core/identification/diagnosis.hpp"

#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/cause.hpp"

#include <Eigen/QR>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <stdexcept>

#include "calibration_internal.hpp"
#include "extended_fit_internal.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/identification/statistics.hpp"

namespace cellcal {

std::string DiagnosisData::thermalText() const {
  std::string out = has_thermal ? thermal_source : "none";
  if (constant_temperature_c) {
    char b[80];
    std::snprintf(b, sizeof b, " (temperature_c constant at %.2f C)", *constant_temperature_c);
    out += b;
  }
  return out;
}

namespace internal {
double pairedZ(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b) {
  std::vector<double> d(a.size());
  for (size_t i = 0; i < a.size(); ++i) d[i] = a[i].squaredNorm() - b[i].squaredNorm();
  return meanZ(d);
}

ResidualMeans residualMeans(const std::vector<Eigen::Vector3d>& r) {
  ResidualMeans m;
  for (const auto& e : r) m.mean_mm += e.norm(), m.mse_m2 += e.squaredNorm();
  m.mean_mm *= 1e3 / static_cast<double>(r.size());
  m.mse_m2 /= static_cast<double>(r.size());
  return m;
}

bool improves(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b, double z_limit,
              double min_gain, double* z) {
  *z = pairedZ(a, b);
  return *z > z_limit && 1.0 - residualMeans(b).mse_m2 / residualMeans(a).mse_m2 > min_gain;
}

std::vector<int> evenlyThinned(size_t n, int max_rows) {
  const size_t stride = max_rows > 0 ? std::max<size_t>(1, (n + static_cast<size_t>(max_rows) - 1) / static_cast<size_t>(max_rows)) : 1;
  std::vector<int> keep;
  for (size_t i = 0; i < n; i += stride) keep.push_back(static_cast<int>(i));
  return keep;
}
}  // namespace internal
using internal::pairedZ;

using internal::bases;
using internal::needsTimeConstant;
using internal::rowParams;
using internal::screenFitRows;
using internal::stackExtended;

bool DiagnosisOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (!(penalty_per_param >= 0)) return fail("penalty_per_param must be >= 0");
  if (!(min_gain >= 0 && min_gain < 1)) return fail("min_gain must be in [0, 1)");
  if (!(min_z >= 0)) return fail("min_z must be >= 0");
  if (!(parsimony_z >= 0)) return fail("parsimony_z must be >= 0");
  if (max_causes < 1) return fail("max_causes must be >= 1");
  if (!(structure_alpha > 0 && structure_alpha < 1)) return fail("structure_alpha must be in (0, 1)");
  if (!(excitation_ratio >= 0 && excitation_ratio < 1)) return fail("excitation_ratio must be in [0, 1)");
  if (!(max_extrapolation_ratio >= 0)) return fail("max_extrapolation_ratio must be >= 0 (0: off)");
  if (screen_keep < 0) return fail("screen_keep must be >= 0 (0: no screen, every candidate fitted in full)");
  if (screen_rows < 0) return fail("screen_rows must be >= 0 (0: every row)");
  if (!(screen_margin >= 0)) return fail("screen_margin must be >= 0");
  if (region_min_rows < 8) return fail("region_min_rows must be >= 8");
  if (region_fit_rows < 0) return fail("region_fit_rows must be >= 0 (0: every row)");
  if (!(region_z >= 0) || !std::isfinite(region_z)) return fail("region_z must be finite and >= 0");
  if (!(region_joint_end > 0 && region_joint_end < 0.5)) return fail("region_joint_end must be in (0, 0.5)");
  if (std::string e; !outliers.IsValid(&e)) return fail(e);
  for (Cause c : causes)
    if (c == Cause::kNone) return fail("causes: 'none' is not an extension (it is the default outcome)");
  std::string e;
  if (!solver.IsValid(&e)) return fail("solver: " + e);
  if (!identifiability.IsValid(&e)) return fail("identifiability: " + e);
  return true;
}

namespace {

// A driver the residual may follow, and its regressors (n x p, one row per observation).
struct DriverRegressors {
  std::string name;
  Eigen::MatrixXd X;
};

// The drivers residualStructure tests: each joint's angle (first and second harmonics), the gravity torque of each
// joint compliance applies to, the thermal driver and time, each joint's direction of motion, and the position in the
// workspace (to second order).
std::vector<DriverRegressors> structureDrivers(const RobotModel& model, const CalibratedModel& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                               bool has_thermal) {
  const auto n = static_cast<Eigen::Index>(obs.size());
  std::vector<DriverRegressors> drivers_x;
  const int nj = model.numJoints();
  for (int j = 0; j < nj; ++j) {
    Eigen::MatrixXd X(n, 4);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double q = obs[static_cast<size_t>(i)].q_rad[j];
      X.row(i) << std::sin(q), std::cos(q), std::sin(2 * q), std::cos(2 * q);
    }
    drivers_x.push_back({"q" + std::to_string(j + 1), X});
  }
  for (int j = 0; j < nj; ++j) {
    if (!applicable(model, Extension{Cause::kJointCompliance, j}, false)) continue;
    Eigen::MatrixXd X(n, 2);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double t = complianceDriver(model, fit.params, obs[static_cast<size_t>(i)].q_rad, j);
      X.row(i) << t, t * t;
    }
    drivers_x.push_back({"gravity_torque_" + std::to_string(j + 1), X});
  }
  if (has_thermal) {
    Eigen::MatrixXd X(n, 2);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double t = drivers[static_cast<size_t>(i)].thermal;
      X.row(i) << t, t * t;
    }
    drivers_x.push_back({drivers.front().thermal_is_time ? "time" : "thermal", X});
  }
  bool stamped = !drivers.front().thermal_is_time;
  for (const auto& d : drivers) stamped = stamped && std::isfinite(d.elapsed_h);
  if (stamped) {  // time besides the temperature: a drift the thermometer does not see
    Eigen::MatrixXd X(n, 2);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double t = drivers[static_cast<size_t>(i)].elapsed_h;
      X.row(i) << t, t * t;
    }
    drivers_x.push_back({"time", X});
  }
  for (int j = 0; j < nj; ++j) {
    Eigen::MatrixXd X(n, 1);
    for (Eigen::Index i = 0; i < n; ++i) {
      const auto& d = drivers[static_cast<size_t>(i)].motion_direction;
      X(i, 0) = d.size() > j ? d[j] : 0;
    }
    if (X.cwiseAbs().maxCoeff() > 0 && (X.array() != X(0, 0)).any()) drivers_x.push_back({"direction_" + std::to_string(j + 1), X});
  }
  {
    Eigen::MatrixXd X(n, 9);
    for (Eigen::Index i = 0; i < n; ++i) {
      const std::vector<Pose> F = chainFrames(model, fit.params, obs[static_cast<size_t>(i)].q_rad);
      const Eigen::Vector3d p = F[0].inverse() * F.back().translation();
      X.row(i) << p.x(), p.y(), p.z(), p.x() * p.x(), p.y() * p.y(), p.z() * p.z(), p.x() * p.y(), p.x() * p.z(),
          p.y() * p.z();
    }
    drivers_x.push_back({"workspace", X});
  }
  return drivers_x;
}

}  // namespace

std::vector<DriverStructure> residualStructure(const RobotModel& model, const CalibratedModel& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                               bool has_thermal, double alpha) {
  const auto n = static_cast<Eigen::Index>(obs.size());
  std::vector<DriverStructure> out;
  if (n < 10) return out;
  const std::vector<Eigen::Vector3d> res = positionResiduals(model, fit, obs, drivers);
  const Eigen::Index m = 3 * n;
  Eigen::VectorXd Y(m);
  for (Eigen::Index i = 0; i < n; ++i) Y.segment<3>(3 * i) = res[static_cast<size_t>(i)];
  // What the fit's own parameters could absorb: their (unwhitened) position Jacobian columns on these rows, and a
  // constant per axis.
  const std::vector<Eigen::MatrixXd> B = bases(model, fit, obs, drivers);
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackExtended(model, fit.params, fit.extension_params.size() ? fit.extension_params : Eigen::VectorXd(), obs, B, r, &J);
  const int np = model.numParams();
  std::vector<int> cols = fit.estimated;
  for (int k : fit.estimated_extension) cols.push_back(np + k);
  Eigen::MatrixXd X0 = Eigen::MatrixXd::Zero(m, static_cast<Eigen::Index>(cols.size()) + 3);
  for (Eigen::Index i = 0, row = 0; i < n; ++i) {
    const Observation& o = obs[static_cast<size_t>(i)];
    for (size_t c = 0; c < cols.size(); ++c)
      X0.block(3 * i, static_cast<Eigen::Index>(c), 3, 1) = J.block(row, cols[c], 3, 1) * o.sigma_position_m;
    X0.block<3, 3>(3 * i, static_cast<Eigen::Index>(cols.size())).setIdentity();
    row += o.rows();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr0(X0);
  qr0.setThreshold(1e-10);
  const Eigen::Index r0 = qr0.rank();
  const Eigen::MatrixXd Q0 = (qr0.householderQ() * Eigen::MatrixXd::Identity(m, r0));
  auto project_out = [&](const Eigen::MatrixXd& X) -> Eigen::MatrixXd { return X - Q0 * (Q0.transpose() * X); };
  const Eigen::VectorXd R0 = project_out(Y);
  const double sse0 = R0.squaredNorm();
  if (!(sse0 > 0)) return out;
  const std::vector<DriverRegressors> drivers_x = structureDrivers(model, fit, obs, drivers, has_thermal);
  const double tests = static_cast<double>(drivers_x.size());
  for (const DriverRegressors& c : drivers_x) {
    // Each regressor acts on each axis separately.
    const Eigen::Index pd = c.X.cols();
    Eigen::MatrixXd X1 = Eigen::MatrixXd::Zero(m, 3 * pd);
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index k = 0; k < pd; ++k)
        for (int a = 0; a < 3; ++a) X1(3 * i + a, 3 * k + a) = c.X(i, k);
    const Eigen::MatrixXd X1p = project_out(X1);
    Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr1(X1p);
    qr1.setThreshold(1e-8);
    const Eigen::Index r1 = qr1.rank();
    const double dof2 = static_cast<double>(m - r0 - r1);
    if (r1 == 0 || dof2 < 1) continue;
    const Eigen::MatrixXd Q1 = qr1.householderQ() * Eigen::MatrixXd::Identity(m, r1);
    const double sse1 = (R0 - Q1 * (Q1.transpose() * R0)).squaredNorm();
    DriverStructure d;
    d.driver = c.name;
    d.share = std::clamp((sse0 - sse1) / sse0, 0.0, 1.0);
    const double F = sse1 > 0 ? ((sse0 - sse1) / static_cast<double>(r1)) / (sse1 / dof2) : INFINITY;
    d.p_value = std::isfinite(F) ? fSurvival(F, static_cast<double>(r1), dof2) : 0.0;
    d.significant = d.p_value < alpha / tests;
    out.push_back(d);
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.share > b.share; });
  return out;
}

NoiseEstimate estimateNoise(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& fitted,
                            const std::vector<Drivers>& fitted_drivers, const std::vector<Observation>& predicted,
                            const std::vector<Drivers>& predicted_drivers) {
  NoiseEstimate e;
  // Every row's residual; rows at the same configuration grouped (sorted by joint 1, then compared joint by joint).
  std::vector<Eigen::Vector3d> res = positionResiduals(model, fit, fitted, fitted_drivers);
  const std::vector<Eigen::Vector3d> pres = positionResiduals(model, fit, predicted, predicted_drivers);
  res.insert(res.end(), pres.begin(), pres.end());
  std::vector<const Eigen::VectorXd*> q;
  for (const auto& o : fitted) q.push_back(&o.q_rad);
  for (const auto& o : predicted) q.push_back(&o.q_rad);
  // A row the model cannot predict (before a backlash joint first moves: its play state unknown) differs from its
  // repeat by the play, not by the readings' noise: it is no repeat.
  std::vector<bool> known;
  for (const auto& d : fitted_drivers) known.push_back(!playStateUnknown(fit.extensions, d));
  for (const auto& d : predicted_drivers) known.push_back(!playStateUnknown(fit.extensions, d));
  constexpr double kSameRad = 2e-3;
  std::vector<size_t> order(q.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return (*q[a])[0] < (*q[b])[0]; });
  std::vector<int> group(q.size(), -1);
  int groups = 0;
  for (size_t a = 0; a < order.size(); ++a) {
    const size_t i = order[a];
    if (group[i] >= 0) continue;
    group[i] = groups;
    for (size_t b = a + 1; known[i] && b < order.size() && (*q[order[b]])[0] - (*q[i])[0] < kSameRad; ++b) {
      const size_t k = order[b];
      if (group[k] < 0 && known[k] && ((*q[k]) - (*q[i])).cwiseAbs().maxCoeff() < kSameRad) group[k] = groups;
    }
    ++groups;
  }
  std::vector<Eigen::Vector3d> sum(static_cast<size_t>(groups), Eigen::Vector3d::Zero());
  std::vector<int> count(static_cast<size_t>(groups), 0);
  for (size_t i = 0; i < res.size(); ++i) {
    sum[static_cast<size_t>(group[i])] += res[i];
    ++count[static_cast<size_t>(group[i])];
  }
  double ss = 0;
  int dof = 0, repeated_groups = 0, repeated_rows = 0;
  for (size_t i = 0; i < res.size(); ++i) {
    const auto g = static_cast<size_t>(group[i]);
    if (count[g] < 2) continue;
    ss += (res[i] - sum[g] / count[g]).squaredNorm();
  }
  for (int c : count)
    if (c >= 2) dof += 3 * (c - 1), ++repeated_groups, repeated_rows += c;
  if (dof >= 30) {
    e.sigma_position_mm = std::sqrt(ss / dof) * 1e3;
    e.dof = dof;
    e.from_repeats = true;
    e.source = "repeated poses (" + std::to_string(repeated_groups) + " groups, " + std::to_string(repeated_rows) + " rows)";
    return e;
  }
  // The fit's own residual, with its degrees of freedom.
  const std::vector<Eigen::Vector3d> fr = positionResiduals(model, fit, fitted, fitted_drivers);
  double s2 = 0;
  for (const auto& v : fr) s2 += v.squaredNorm();
  const int rows = totalRows(fitted);
  const int params = static_cast<int>(fit.estimated.size() + fit.estimated_extension.size());
  e.dof = std::max(1, rows - params);
  e.sigma_position_mm = std::sqrt(s2 / (3.0 * static_cast<double>(fr.size())) * rows / e.dof) * 1e3;
  e.source = "residual of the " + modelLabel(fit.extensions) + " fit on " + std::to_string(fitted.size()) +
             " identification rows (" + std::to_string(e.dof) + " dof; holds whatever the model leaves)";
  return e;
}

std::vector<Extension> DiagnosisResult::causes() const {
  std::vector<Extension> out;
  for (const auto& s : selection) out.push_back(s.added);
  return out;
}

const DriverStructure* DiagnosisResult::structureLeft() const {
  for (const auto& d : structure_after)
    if (d.significant) return &d;
  return nullptr;
}

namespace {

// Significance and parsimony of one forward-selection round: `cands` in score order against `base` (their
// verification residuals parallel). Returns the index chosen, or -1.
int chooseCandidate(const CandidateResult& base, const std::vector<CandidateResult>& cands,
                    const std::vector<std::vector<Eigen::Vector3d>>& residuals, const DiagnosisOptions& options) {
  auto significant = [&](size_t i) {
    const CandidateResult& c = cands[i];
    return c.score < base.score && 1.0 - c.verify_mse_m2 / base.verify_mse_m2 > options.min_gain && c.z > options.min_z;
  };
  if (cands.empty() || !significant(0)) return -1;
  size_t pick = 0;
  for (bool changed = true; changed;) {
    changed = false;
    for (size_t i = 0; i < cands.size(); ++i) {
      if (i == pick || !significant(i)) continue;
      if (cands[i].fit.numEstimatedExtension() >= cands[pick].fit.numEstimatedExtension()) continue;
      if (pairedZ(residuals[i], residuals[pick]) > options.parsimony_z) continue;
      pick = i;
      changed = true;
      break;  // candidates are in score order: the best-scoring simpler one
    }
  }
  return static_cast<int>(pick);
}

bool conflicts(const Extension& e, const std::vector<Extension>& chosen) {
  for (const auto& c : chosen) {
    if (c.cause == e.cause && c.joint == e.joint) return true;
    if (e.cause != Cause::kNone && causeModel(e.cause).conflicts(e, c)) return true;
  }
  return false;
}

// A forward-selection round's candidates judged by one linearized step from the round's base fit, before any is
// fitted in full. The whitened residual and the kinematic Jacobian of every identification row, and the position
// residual and Jacobian of every verification row, are taken once at the base (as it predicts each row: its
// extensions included); the normal equations of the base's own columns once too. A candidate adds only its own
// columns J_i B_i: their products with the base's, the Schur complement that says which of them leave the base's span
// (the sine of the angle, as independentColumns decides on the stacked Jacobian), and the Gauss-Newton step over the
// base's columns and the kept new ones. The verification residual that step predicts gives the candidate's score and
// its paired z against the base. A candidate whose columns all lie in the base's span adds nothing (nullopt).
class RoundScreen {
 public:
  RoundScreen(const RobotModel& model, const Eigen::VectorXd& start, const ExtendedFit& base,
              const std::vector<Observation>& I, const std::vector<Drivers>& ID, const std::vector<Observation>& V,
              const std::vector<Drivers>& VD, double rank_tolerance)
      : model_(model), start_(start), base_(base), I_(I), ID_(ID), V_(V), VD_(VD), tol_(rank_tolerance) {
    const int np = model.numParams();
    const auto nbk = static_cast<Eigen::Index>(base.estimated.size());
    const auto nb = nbk + static_cast<Eigen::Index>(base.estimated_extension.size());
    const std::vector<Eigen::MatrixXd> BI = bases(model, start, base.extensions, I, ID, base.extension_params);
    const std::vector<Eigen::MatrixXd> BV = bases(model, start, base.extensions, V, VD, base.extension_params);
    KinematicsData data(model);
    const int m = totalRows(I);
    r_.resize(m);
    Jk_.resize(m, np);
    Ab_.resize(m, nb);
    Eigen::Matrix<double, 6, 1> ri;
    Eigen::MatrixXd Ji;
    int row = 0;
    for (size_t i = 0; i < I.size(); ++i) {
      const Eigen::VectorXd pi = rowParams(base, BI[i]);
      const int rows = whitenedResidual(model, data, pi, I[i], ri, &Ji);
      r_.segment(row, rows) = ri.head(rows);
      Jk_.middleRows(row, rows) = Ji.topRows(rows);
      for (Eigen::Index c = 0; c < nbk; ++c) Ab_.block(row, c, rows, 1) = Ji.block(0, base.estimated[c], rows, 1);
      if (nb > nbk) {
        const Eigen::MatrixXd JB = Ji.topRows(rows) * BI[i];
        for (Eigen::Index c = nbk; c < nb; ++c)
          Ab_.block(row, c, rows, 1) = JB.col(base.estimated_extension[static_cast<size_t>(c - nbk)]);
      }
      row += rows;
    }
    // The base's columns, scaled to unit norm, as Q R (Householder, thin Q): what a candidate's columns leave of the
    // base's span is found by projecting them out, as independentColumns does on the stacked Jacobian (the normal
    // equations would square the conditioning of nearly dependent columns).
    scale_b_ = Ab_.colwise().norm().transpose().cwiseMax(1e-300).cwiseInverse();
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(Ab_ * scale_b_.asDiagonal());
    Qb_ = qr.householderQ() * Eigen::MatrixXd::Identity(m, nb);
    Rb_ = qr.matrixQR().topRows(nb).triangularView<Eigen::Upper>();
    r_perp_ = r_ - Qb_ * (Qb_.transpose() * r_);
    // Verification rows: position residual (m) and position Jacobian (m per SI unit) at the base.
    ev_.resize(V.size());
    Jv_.resize(V.size());
    Avb_.resize(V.size());
    for (size_t i = 0; i < V.size(); ++i) {
      const Eigen::VectorXd pi = rowParams(base, BV[i]);
      whitenedResidual(model, data, pi, V[i], ri, &Ji);
      const double s = V[i].sigma_position_m;
      ev_[i] = ri.head<3>() * s;
      Jv_[i] = Ji.topRows(3) * s;
      Avb_[i].resize(3, nb);
      for (Eigen::Index c = 0; c < nbk; ++c) Avb_[i].col(c) = Jv_[i].col(base.estimated[c]);
      if (nb > nbk) {
        const Eigen::MatrixXd JB = Jv_[i] * BV[i];
        for (Eigen::Index c = nbk; c < nb; ++c) Avb_[i].col(c) = JB.col(base.estimated_extension[static_cast<size_t>(c - nbk)]);
      }
    }
  }

  struct Screened {
    double score = 0;            // verify_mse_m2 * (1 + penalty * k / rows), of the predicted residuals
    CandidateResult result;      // the step's parameters and predicted verification figures (no identification figures)
    std::vector<Eigen::Vector3d> residuals;  // predicted verification position residuals
  };

  std::optional<Screened> screen(const Extension& ext, double penalty_per_param) const {
    const int k = numExtensionParams(model_, ext);
    const Eigen::Index nb = Ab_.cols();
    // The candidate's columns on the identification rows, scaled to unit norm.
    Eigen::MatrixXd Ac(r_.size(), k);
    int row = 0;
    for (size_t i = 0; i < I_.size(); ++i) {
      const int rows = I_[i].rows();
      Ac.middleRows(row, rows) = Jk_.middleRows(row, rows) * extensionBasis(model_, start_, ext, I_[i].q_rad, ID_[i]);
      row += rows;
    }
    const Eigen::VectorXd norms = Ac.colwise().norm().transpose();
    const double base_max = Ab_.cols() ? Ab_.colwise().norm().maxCoeff() : norms.maxCoeff();
    // What of each new column (unit norm) leaves the base's span and the new columns kept before it: kept while that
    // sine exceeds the rank tolerance (modified Gram-Schmidt, twice).
    std::vector<Eigen::Index> kept;
    Eigen::MatrixXd U(r_.size(), k);  // orthonormal: the kept columns' parts outside the base's span
    for (Eigen::Index j = 0; j < k; ++j) {
      if (!(norms[j] > 1e-10 * base_max)) continue;
      Eigen::VectorXd c = Ac.col(j) / norms[j];
      for (int pass = 0; pass < 2; ++pass) {
        c -= Qb_ * (Qb_.transpose() * c);
        for (size_t a = 0; a < kept.size(); ++a) c -= U.col(static_cast<Eigen::Index>(a)) * U.col(static_cast<Eigen::Index>(a)).dot(c);
      }
      const double sine = c.norm();
      if (!(sine > tol_)) continue;
      U.col(static_cast<Eigen::Index>(kept.size())) = c / sine;
      kept.push_back(j);
    }
    if (kept.empty()) return std::nullopt;
    const auto nk = static_cast<Eigen::Index>(kept.size());
    // The least-squares step over the base's columns and the kept new ones: the new ones' coefficients from what the
    // base leaves (their parts outside its span), the base's from the rest.
    Eigen::MatrixXd Ck(r_.size(), nk), Ck_perp(r_.size(), nk);
    for (Eigen::Index a = 0; a < nk; ++a) {
      Ck.col(a) = Ac.col(kept[a]);
      Ck_perp.col(a) = Ck.col(a) - Qb_ * (Qb_.transpose() * Ck.col(a));
    }
    const Eigen::VectorXd yk = Ck_perp.colPivHouseholderQr().solve(r_perp_);
    const Eigen::VectorXd rest = r_ - Ck * yk;
    Eigen::VectorXd xb = Ab_.cols() ? Eigen::VectorXd(Rb_.triangularView<Eigen::Upper>().solve(Qb_.transpose() * rest))
                                    : Eigen::VectorXd();
    xb = xb.cwiseProduct(scale_b_);
    Eigen::VectorXd xc = Eigen::VectorXd::Zero(k);
    for (Eigen::Index a = 0; a < nk; ++a) xc[kept[a]] = yk[a];
    if (!xb.allFinite() || !xc.allFinite()) return std::nullopt;
    // The step's parameters, as a fit would report them.
    Screened out;
    ExtendedFit& f = out.result.fit;
    f.extensions = base_.extensions;
    f.extensions.push_back(ext);
    f.extension_names = extensionParamNames(model_, f.extensions);
    f.params = base_.params;
    const auto nbk = static_cast<Eigen::Index>(base_.estimated.size());
    for (Eigen::Index c = 0; c < nbk; ++c) f.params[base_.estimated[c]] += xb[c];
    const auto kb = base_.extension_params.size();
    f.extension_params = Eigen::VectorXd::Zero(kb + k);
    if (kb) f.extension_params.head(kb) = base_.extension_params;
    for (Eigen::Index c = nbk; c < nb; ++c) f.extension_params[base_.estimated_extension[static_cast<size_t>(c - nbk)]] += xb[c];
    f.extension_params.tail(k) = xc;
    f.estimated = base_.estimated;
    f.estimated_extension = base_.estimated_extension;
    for (Eigen::Index a = 0; a < nk; ++a) f.estimated_extension.push_back(static_cast<int>(kb + kept[a]));
    f.converged = false;
    f.message = "screened: one linearized step from the round's base fit";
    // The verification residual the step predicts.
    ErrorStats& v = out.result.verification;
    double sum = 0, sq = 0;
    out.residuals.resize(V_.size());
    for (size_t i = 0; i < V_.size(); ++i) {
      const Eigen::MatrixXd Bc = extensionBasis(model_, start_, ext, V_[i].q_rad, VD_[i]);
      const Eigen::Vector3d e = ev_[i] - Avb_[i] * xb - Jv_[i] * (Bc * xc);
      out.residuals[i] = e;
      const double d = e.norm() * 1e3;
      sum += d;
      sq += d * d;
      v.max_mm = std::max(v.max_mm, d);
    }
    v.rows = static_cast<int>(V_.size());
    v.mean_mm = V_.empty() ? 0 : sum / static_cast<double>(V_.size());
    v.rms_mm = V_.empty() ? 0 : std::sqrt(sq / static_cast<double>(V_.size()));
    out.result.verify_mse_m2 = std::pow(v.rms_mm * 1e-3, 2);
    out.score = out.result.verify_mse_m2 *
                (1.0 + penalty_per_param * f.numEstimatedExtension() / static_cast<double>(r_.size()));
    out.result.score = out.score;
    return out;
  }

 private:
  const RobotModel& model_;
  const Eigen::VectorXd& start_;
  const ExtendedFit& base_;
  const std::vector<Observation>& I_;
  const std::vector<Drivers>& ID_;
  const std::vector<Observation>& V_;
  const std::vector<Drivers>& VD_;
  double tol_;
  Eigen::VectorXd r_;
  Eigen::MatrixXd Jk_, Ab_;
  Eigen::VectorXd scale_b_, r_perp_;
  Eigen::MatrixXd Qb_, Rb_;
  std::vector<Eigen::Vector3d> ev_;
  std::vector<Eigen::MatrixXd> Jv_, Avb_;
};

struct Selection {
  CandidateResult geometric;
  std::vector<CandidateResult> candidates;
  int chosen = -1;
  std::vector<SelectionStep> steps;
};

}  // namespace

namespace {
DiagnosisResult diagnoseAtNoise(const RobotModel& model, const Eigen::VectorXd& start, const DiagnosisData& data,
                                const DiagnosisOptions& options, std::chrono::steady_clock::time_point t0);
}  // namespace

DiagnosisResult diagnose(const RobotModel& model, const Eigen::VectorXd& start, const DiagnosisData& data,
                         const DiagnosisOptions& options) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument("DiagnosisOptions: " + err);
  if (data.identification.size() < 8 || data.verification.empty())
    throw std::invalid_argument("diagnose: needs at least 8 identification and 1 verification observation");
  const auto t0 = std::chrono::steady_clock::now();
  if (options.identifiability.prior_sigma.size() == 0) return diagnoseAtNoise(model, start, data, options, t0);
  // With plausible ranges, which parameters every model estimates follows the noise: the residual of a robust
  // geometric fit on the identification rows (what the geometric model leaves counts as noise), decided once for all.
  OutlierScreen screen;
  const ExtendedFit g = fitExtendedRobust(model, start, data.identification, data.identification_drivers, {},
                                          options.solver, options.identifiability, nullptr, options.outliers, &screen);
  const std::vector<Observation> kept = subset(data.identification, keptRows(static_cast<int>(data.identification.size()), screen.rows));
  Eigen::VectorXd r;
  stackResiduals(model, g.params, kept, r, nullptr);
  DiagnosisOptions at = options;
  at.identifiability.noise_scale =
      std::max(options.identifiability.noise_scale, noiseScaleOf(r, static_cast<int>(g.estimated.size())));
  return diagnoseAtNoise(model, start, data, at, t0);
}

namespace {

// The rows a selection is judged on: identification (I, ID) and verification (V, VD), gross errors left out.
struct SelectionRows {
  std::vector<Observation> I;
  std::vector<Drivers> ID;
  std::vector<Observation> V;
  std::vector<Drivers> VD;
};

// One round's candidates, fitted in full and sorted by score (with their verification residuals and the extension
// each added), and those the screen judged but did not fit.
struct Round {
  std::vector<CandidateResult> sorted;
  std::vector<std::vector<Eigen::Vector3d>> residuals;
  std::vector<Extension> added;
  std::vector<CandidateResult> only_screened;
};

// The forward selection: the geometric model, then round by round the cause that lowers the held-out error most and
// significantly (chooseCandidate), up to max_causes.
class ForwardSelection {
 public:
  ForwardSelection(const RobotModel& model, const Eigen::VectorXd& start, const DiagnosisOptions& options,
                   std::vector<Extension> to_try, std::function<void()> progress)
      : model_(model), start_(start), options_(options), to_try_(std::move(to_try)), progress_(std::move(progress)) {}

  Selection run(std::vector<Observation> I, std::vector<Drivers> ID, std::vector<Observation> V,
                std::vector<Drivers> VD) const {
    const SelectionRows rows{std::move(I), std::move(ID), std::move(V), std::move(VD)};
    Selection sel;
    std::vector<ExcitationDeficit> geometric_held;
    const IdentifiabilityOptions geometric_io = heldFor(rows, {}, &geometric_held);
    sel.geometric = evaluate(rows, fitExtended(model_, start_, rows.I, rows.ID, Extension{}, options_.solver, geometric_io));
    sel.geometric.held = geometric_held;
    progress_();
    CandidateResult base = sel.geometric;
    std::vector<Eigen::Vector3d> base_res = positionResiduals(model_, base.fit, rows.V, rows.VD);
    // The screen's rows: every one up to screen_rows, else every k-th (evenly through the file) of each set.
    const std::vector<int> si = internal::evenlyThinned(rows.I.size(), options_.screen_rows),
                           sv = internal::evenlyThinned(rows.V.size(), options_.screen_rows);
    const SelectionRows screen_rows{subset(rows.I, si), subset(rows.ID, si), subset(rows.V, sv), subset(rows.VD, sv)};
    for (int round = 0; round < options_.max_causes; ++round) {
      Round r = fitRound(rows, screen_rows, sv, base, base_res);
      const int pick = chooseCandidate(base, r.sorted, r.residuals, options_);
      if (round == 0) {
        sel.candidates = r.sorted;
        sel.chosen = pick;
        for (auto& c : r.only_screened) sel.candidates.push_back(std::move(c));
      }
      if (pick < 0) break;
      sel.steps.push_back(stepOf(r, pick, base));
      base = sel.steps.back().result;
      base_res = r.residuals[static_cast<size_t>(pick)];
    }
    return sel;
  }

 private:
  CandidateResult evaluate(const SelectionRows& rows, ExtendedFit fit) const {
    CandidateResult c;
    c.identification = errorStats(model_, fit, rows.I, rows.ID);
    c.verification = errorStats(model_, fit, rows.V, rows.VD);
    c.verify_mse_m2 = std::pow(c.verification.rms_mm * 1e-3, 2);
    c.score = c.verify_mse_m2 * (1.0 + options_.penalty_per_param * fit.numEstimatedExtension() /
                                           static_cast<double>(totalRows(rows.I)));
    c.fit = std::move(fit);
    return c;
  }

  // Parameters the identification rows leave unexcited (where the verification rows excite them) are held.
  IdentifiabilityOptions heldFor(const SelectionRows& rows, const std::vector<Extension>& exts,
                                 std::vector<ExcitationDeficit>* deficits) const {
    IdentifiabilityOptions io = options_.identifiability;
    if (options_.excitation_ratio > 0) {
      *deficits = excitationDeficits(model_, start_, exts, rows.I, rows.ID, rows.V, rows.VD, options_.excitation_ratio);
      for (const auto& d : *deficits) io.held.push_back(d.column);
    }
    return io;
  }

  // Which candidates a round fits in full. The linearized screen (RoundScreen) judges every candidate by one step; the
  // screen_keep best, and those it cannot judge (a warm-up whose time constant is searched in the fit), are fitted in
  // full; screen_keep 0: every candidate. `screened` ends with those judged but not fitted.
  struct Plan {
    std::vector<Extension> to_fit;
    std::map<size_t, size_t> warm;  // to_fit index -> screened index: the screen's step starts the fit
    size_t fitted_screened = 0;
    std::vector<std::pair<Extension, RoundScreen::Screened>> screened;
  };
  Plan planRound(const SelectionRows& rows, const SelectionRows& screen_rows, const CandidateResult& base) const {
    Plan plan;
    const std::vector<Extension>& chosen = base.fit.extensions;
    std::optional<RoundScreen> screen;
    if (options_.screen_keep > 0)
      screen.emplace(model_, start_, base.fit, screen_rows.I, screen_rows.ID, screen_rows.V, screen_rows.VD,
                     options_.identifiability.rank_tolerance);
    for (const Extension& ext : to_try_) {
      if (conflicts(ext, chosen)) continue;
      if (!screen || needsTimeConstant(ext, rows.ID)) {
        plan.to_fit.push_back(ext);
        continue;
      }
      auto sc = screen->screen(ext, options_.penalty_per_param);
      if (sc) plan.screened.emplace_back(ext, std::move(*sc));
    }
    auto& screened = plan.screened;
    std::sort(screened.begin(), screened.end(), [](const auto& a, const auto& b) { return a.second.score < b.second.score; });
    // The best, and those whose screened score lies within screen_margin of it (at most screen_keep); then, within
    // the margin, each candidate with fewer parameters than every one taken so far (parsimony may prefer it:
    // chooseCandidate takes a simpler significant candidate unless a larger one beats it clearly).
    std::vector<bool> take(screened.size(), false);
    int fewest = std::numeric_limits<int>::max();
    for (size_t i = 0; i < screened.size(); ++i) {
      if (i > 0 && screened[i].second.score > (1.0 + options_.screen_margin) * screened[0].second.score) break;
      const int k = screened[i].second.result.fit.numEstimatedExtension();
      if (static_cast<int>(i) < options_.screen_keep || k < fewest) {
        take[i] = true;
        fewest = std::min(fewest, k);
      }
    }
    // Taken first in the order of the screen; the others follow (only_screened).
    std::vector<std::pair<Extension, RoundScreen::Screened>> ordered;
    for (int pass = 0; pass < 2; ++pass)
      for (size_t i = 0; i < screened.size(); ++i)
        if (take[i] == (pass == 0)) ordered.push_back(std::move(screened[i]));
    screened = std::move(ordered);
    plan.fitted_screened = static_cast<size_t>(std::count(take.begin(), take.end(), true));
    for (size_t i = 0; i < plan.fitted_screened; ++i) {
      plan.to_fit.push_back(screened[i].first);
      plan.warm[plan.to_fit.size() - 1] = i;
    }
    return plan;
  }

  // A round: the planned candidates fitted in full on the rows, each with base's extensions, and sorted by score.
  Round fitRound(const SelectionRows& rows, const SelectionRows& screen_rows, const std::vector<int>& sv,
                 const CandidateResult& base, const std::vector<Eigen::Vector3d>& base_res) const {
    Plan plan = planRound(rows, screen_rows, base);
    std::vector<CandidateResult> cands;
    std::vector<std::vector<Eigen::Vector3d>> residuals;
    std::vector<Extension> added;
    for (size_t f = 0; f < plan.to_fit.size(); ++f) {
      const Extension& ext = plan.to_fit[f];
      std::vector<Extension> exts = base.fit.extensions;
      exts.push_back(ext);
      std::vector<ExcitationDeficit> held;
      const IdentifiabilityOptions io = heldFor(rows, exts, &held);
      // From the screen's step where there is one (a few Gauss-Newton iterations fewer), else from the base.
      const auto w = plan.warm.find(f);
      const ExtendedFit* step = w != plan.warm.end() ? &plan.screened[w->second].second.result.fit : nullptr;
      CandidateResult c = step ? evaluate(rows, fitExtended(model_, start_, rows.I, rows.ID, exts, options_.solver, io,
                                                            &step->params, &step->extension_params))
                               : evaluate(rows, fitExtended(model_, start_, rows.I, rows.ID, exts, options_.solver, io,
                                                            &base.fit.params));
      c.held = std::move(held);
      progress_();
      // Nothing the model so far could not already do.
      if (c.fit.numEstimatedExtension() <= base.fit.numEstimatedExtension()) continue;
      residuals.push_back(positionResiduals(model_, c.fit, rows.V, rows.VD));
      c.z = pairedZ(base_res, residuals.back());
      cands.push_back(std::move(c));
      added.push_back(ext);
    }
    Round r;
    // The screened ones not fitted: in the first round's table with their step's figures, never chosen.
    for (size_t i = plan.fitted_screened; i < plan.screened.size(); ++i) {
      CandidateResult c = std::move(plan.screened[i].second.result);
      c.z = pairedZ(subset(base_res, sv), plan.screened[i].second.residuals);
      c.screened = true;
      r.only_screened.push_back(std::move(c));
      progress_();
    }
    std::vector<size_t> order(cands.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return cands[a].score < cands[b].score; });
    for (size_t i : order) {
      r.sorted.push_back(std::move(cands[i]));
      r.residuals.push_back(std::move(residuals[i]));
      r.added.push_back(added[i]);
    }
    return r;
  }

  // The step a round's pick makes, with the (at most three) others that did about as well.
  SelectionStep stepOf(const Round& r, int pick, const CandidateResult& base) const {
    SelectionStep step;
    for (size_t i = 0; i < r.sorted.size() && step.alike.size() < 3; ++i) {
      const CandidateResult& c = r.sorted[i];
      if (static_cast<int>(i) == pick || !(c.score < base.score) || c.z <= options_.min_z ||
          1.0 - c.verify_mse_m2 / base.verify_mse_m2 <= options_.min_gain)
        continue;
      if (pairedZ(r.residuals[i], r.residuals[static_cast<size_t>(pick)]) <= options_.parsimony_z)
        step.alike.push_back(r.added[i]);
    }
    step.result = r.sorted[static_cast<size_t>(pick)];
    step.added = step.result.fit.extensions.back();  // with its fitted time constant
    step.z = step.result.z;
    step.gain_pct = 100.0 * (1.0 - step.result.verification.mean_mm / base.verification.mean_mm);
    return step;
  }

  const RobotModel& model_;
  const Eigen::VectorXd& start_;
  const DiagnosisOptions& options_;
  const std::vector<Extension> to_try_;
  const std::function<void()> progress_;
};

DiagnosisResult diagnoseAtNoise(const RobotModel& model, const Eigen::VectorXd& start, const DiagnosisData& data,
                                const DiagnosisOptions& options, std::chrono::steady_clock::time_point t0) {
  std::vector<Extension> to_try;
  for (Cause cause : options.causes)
    for (int j = causeModel(cause).subject() == CauseModel::Subject::kJointOrLengths ? -1 : 0; j < model.numJoints(); ++j)
      if (applicable(model, Extension{cause, j}, data.has_thermal)) to_try.push_back(Extension{cause, j});
  int fits_done = 0;
  const int fits_total = 2 + static_cast<int>(to_try.size()) * options.max_causes;
  const ForwardSelection selection(model, start, options, std::move(to_try), [&] {
    if (options.progress) options.progress(std::min(++fits_done, fits_total - 1), fits_total);
  });

  const auto& I = data.identification;
  const auto& V = data.verification;
  const auto& ID = data.identification_drivers;
  const auto& VD = data.verification_drivers;
  DiagnosisResult out;
  // The selection on every row first; then the model it chose screens for gross errors (a robust fit on the
  // identification rows, the verification rows against it), and where it flags rows the selection runs again without
  // them (at most three selections). Screening only under the geometric model would take a strong effect's largest
  // rows (a warm-up's first hour) for gross errors and hide the very rows that show the cause.
  OutlierScreen id_screen, ver_screen;
  Selection sel;
  for (int pass = 0; pass < 3; ++pass) {
    const std::vector<int> ik = keptRows(static_cast<int>(I.size()), id_screen.rows);
    const std::vector<int> vk = keptRows(static_cast<int>(V.size()), ver_screen.rows);
    sel = selection.run(subset(I, ik), subset(ID, ik), subset(V, vk), subset(VD, vk));
    const CandidateResult& best = sel.steps.empty() ? sel.geometric : sel.steps.back().result;
    OutlierScreen id2;
    IdentifiabilityOptions io = options.identifiability;
    for (const auto& d : best.held) io.held.push_back(d.column);
    const ExtendedFit final_fit = fitExtendedRobust(model, start, I, ID, best.fit.extensions, options.solver, io,
                                                    &best.fit.params, options.outliers, &id2);
    OutlierScreen ver2 = screenFitRows(model, final_fit, V, VD, options.outliers);
    const bool same = id2.rows == id_screen.rows && ver2.rows == ver_screen.rows;
    id_screen = std::move(id2);
    ver_screen = std::move(ver2);
    if (same) break;
  }
  const std::vector<int> ik = keptRows(static_cast<int>(I.size()), id_screen.rows);
  const std::vector<int> vk = keptRows(static_cast<int>(V.size()), ver_screen.rows);
  const std::vector<Observation> Vk = subset(V, vk);
  const std::vector<Drivers> VDk = subset(VD, vk);
  out.geometric = sel.geometric;
  out.candidates = std::move(sel.candidates);
  out.selection = std::move(sel.steps);
  out.chosen = sel.chosen;
  // Where the causes' data never were: a cause that does not lower the error on the other blocks of the workspace is
  // left out, with those chosen beside it after.
  if (options.region_check && !out.selection.empty()) {
    std::vector<Observation> rows = subset(I, ik);
    std::vector<Drivers> rows_drivers = subset(ID, ik);
    rows.insert(rows.end(), Vk.begin(), Vk.end());
    rows_drivers.insert(rows_drivers.end(), VDk.begin(), VDk.end());
    out.region_checks =
        checkRegions(model, start, rows, rows_drivers, out.geometric.fit, out.selection, options, &out.region_note);
    if (!out.region_checks.empty() && !out.region_checks.back().transfers) {
      const size_t k = out.region_checks.size() - 1;
      for (size_t i = k; i < out.selection.size(); ++i) out.not_transferred.push_back(out.selection[i].added);
      out.selection.resize(k);
      if (k == 0) out.chosen = -1;
    }
  }
  if (!out.selection.empty()) {
    out.cause = out.selection.front().added.cause;
    if (out.selection.front().added.joint >= 0) out.joints = {out.selection.front().added.joint};
  }
  out.identification_outliers = id_screen;
  out.verification_outliers = ver_screen;
  const CandidateResult& best = out.best();
  out.geometric_verification_all_rows = errorStats(model, out.geometric.fit, V, VD);
  out.verification_all_rows = errorStats(model, best.fit, V, VD);
  out.gain_pct = 100.0 * (1.0 - best.verification.mean_mm / out.geometric.verification.mean_mm);
  out.structure_before = residualStructure(model, out.geometric.fit, Vk, VDk, data.has_thermal, options.structure_alpha);
  out.structure_after = out.selection.empty()
                            ? out.structure_before
                            : residualStructure(model, best.fit, Vk, VDk, data.has_thermal, options.structure_alpha);
  const DriverStructure* left = out.structureLeft();
  if (out.selection.empty()) out.verdict = left ? Verdict::kUnexplained : Verdict::kNoise;
  else out.verdict = left ? Verdict::kPartlyExplained : Verdict::kNamed;
  // A drift (or structure against the thermal driver) against the base frame drifting with the same driver.
  out.drift_check = checkDrift(model, start, subset(I, ik), subset(ID, ik), Vk, VDk, data.has_thermal, best, left, options);
  ExtendedFit start_fit;
  start_fit.params = start;
  out.start_verification = errorStats(model, start_fit, Vk, VDk);
  out.unusable = unusableFit(out.start_verification, best.verification, best.identification, options.max_extrapolation_ratio);
  if (!out.unusable.empty()) out.verdict = Verdict::kUnusable;
  out.noise = estimateNoise(model, best.fit, subset(I, ik), subset(ID, ik), Vk, VDk);
  out.noise_rms_mm = std::sqrt(3.0) * out.noise.sigma_position_mm;
  out.unexplained_rms_mm =
      std::sqrt(std::max(0.0, best.verification.rms_mm * best.verification.rms_mm - out.noise_rms_mm * out.noise_rms_mm));
  if (options.progress) options.progress(fits_total, fits_total);
  out.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  out.identifiability_noise_scale = options.identifiability.noise_scale;
  return out;
}
}  // namespace

std::string unusableFit(const ErrorStats& start_held_out, const ErrorStats& held_out, const ErrorStats& identification,
                        double max_ratio) {
  char buf[300];
  if (held_out.mean_mm > start_held_out.mean_mm) {
    std::snprintf(buf, sizeof buf,
                  "the fitted model is worse than the start model on the held-out rows (mean %.4f mm against %.4f mm)",
                  held_out.mean_mm, start_held_out.mean_mm);
    return buf;
  }
  if (max_ratio > 0 && held_out.max_mm > max_ratio * identification.max_mm) {
    std::snprintf(buf, sizeof buf,
                  "it extrapolates: held-out max %.3f mm is %.1fx the identification max %.3f mm (limit %gx): the "
                  "held-out rows reach where the identification rows do not pin the model down",
                  held_out.max_mm, held_out.max_mm / identification.max_mm, identification.max_mm, max_ratio);
    return buf;
  }
  return "";
}

CauseSignature causeSignature(const RobotModel& model, const ExtendedFit& geometric, const ExtendedFit& extended,
                              const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                              const std::string& thermal_source) {
  const Extension ext = extended.extension();
  if (ext.cause == Cause::kNone) throw std::invalid_argument("causeSignature: the extended fit has no cause");
  const CauseModel& cause = causeModel(ext.cause);
  if (!cause.diagnosed())
    throw std::invalid_argument(std::string("causeSignature: ") + cause.name() + " is not a cause diagnose names");
  CauseSignature sig;
  const int j = ext.joint;
  sig.x_label = cause.signatureXLabel(model, j, thermal_source);
  sig.y_label = cause.signatureYLabel(j);
  const std::vector<Eigen::Vector3d> before = positionResiduals(model, geometric, obs, drivers);
  const std::vector<Eigen::Vector3d> after = positionResiduals(model, extended, obs, drivers);
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numParams());
  for (size_t i = 0; i < obs.size(); ++i) {
    forwardKinematics(model, data, geometric.params, obs[i].q_rad);
    computePoseJacobian(model, data, J);
    const SignatureRow row{model, geometric.params, obs[i].q_rad, drivers[i], j, i, J};
    const SignatureAxis axis = cause.signatureAxis(row);
    const Eigen::Vector3d& d = axis.direction;
    if (axis.unit) {
      sig.y_before.push_back(d.dot(before[i]) * axis.scale);
      sig.y_after.push_back(d.dot(after[i]) * axis.scale);
    } else {
      const double dd = std::max(d.squaredNorm(), 1e-30);
      sig.y_before.push_back(d.dot(before[i]) / dd * axis.scale);
      sig.y_after.push_back(d.dot(after[i]) / dd * axis.scale);
    }
    sig.x.push_back(cause.signatureX(row));
  }
  return sig;
}

std::string describeVerdict(const DiagnosisResult& d) {
  if (d.verdict == Verdict::kUnusable) return "no recommendation: " + d.unusable;
  const DriverStructure* left = d.structureLeft();
  char share[160] = "";
  if (left) std::snprintf(share, sizeof share, "structure left against %s (%.0f %%)", left->driver.c_str(), 100 * left->share);
  std::string out;
  switch (d.verdict) {
    case Verdict::kNoise: out = "none: the geometric model leaves no structure against any driver"; break;
    case Verdict::kUnexplained: out = std::string("none of the library's causes; ") + share; break;
    case Verdict::kPartlyExplained: out = "partly explained by " + modelLabel(d.causes()) + "; " + share; break;
    case Verdict::kNamed: out = modelLabel(d.causes()); break;
    case Verdict::kUnusable: break;
  }
  if (!d.not_transferred.empty() && !d.region_checks.empty()) {
    const RegionCheck& c = d.region_checks.back();
    char b[300];
    std::snprintf(b, sizeof b,
                  "; left out: %s (fitted on part of the rows, it made the error beyond them, by %s, worse: "
                  "mean %.4f mm with it against %.4f mm without)",
                  modelLabel(d.not_transferred).c_str(), c.split.c_str(), c.mean_with_mm, c.mean_without_mm);
    out += b;
  }
  using DO = DriftCheck::Outcome;
  if (const DO o = d.drift_check.outcome; o != DO::kNotRun && o != DO::kToldApart && o != DO::kNotAFrameDrift)
    out += "; " + d.drift_check.text;
  return out;
}

}  // namespace cellcal
