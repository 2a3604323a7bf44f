// The extended fit (extended_fit.hpp): Gauss-Newton on the geometric and the extension parameters, its warm-up time
// constant, its robust form, its covariance, and the error figures of a fit. diagnose (diagnosis.cpp) compares such
// fits; the helpers it shares with them are in extended_fit_internal.hpp.
#include "cellcal/core/identification/extended_fit.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "calibration_internal.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/model/cause.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "extended_fit_internal.hpp"

namespace cellcal {

namespace internal {

// B_i of every observation; a backlash's play state evaluated at the width in `evaluated_at` (empty: width 0).
std::vector<Eigen::MatrixXd> bases(const RobotModel& model, const Eigen::VectorXd& params,
                                   const std::vector<Extension>& exts, const std::vector<Observation>& obs,
                                   const std::vector<Drivers>& drivers, const Eigen::VectorXd& evaluated_at) {
  if (drivers.size() != obs.size()) throw std::invalid_argument("diagnosis: one Drivers entry per observation needed");
  std::vector<Eigen::MatrixXd> B;
  B.reserve(obs.size());
  for (size_t i = 0; i < obs.size(); ++i)
    B.push_back(extensionBasis(model, params, exts, obs[i].q_rad, drivers[i], evaluated_at));
  return B;
}

std::vector<Eigen::MatrixXd> bases(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                                   const std::vector<Drivers>& drivers) {
  return bases(model, fit.params, fit.extensions, obs, drivers, fit.extension_params);
}

// Stacked whitened residual and Jacobian [d/dparams (all), d/de (all)] of the extended model.
void stackExtended(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& e,
                   const std::vector<Observation>& obs, const std::vector<Eigen::MatrixXd>& B, Eigen::VectorXd& r,
                   Eigen::MatrixXd* J) {
  KinematicsData data(model);
  const int m = totalRows(obs);
  const auto np = model.numParams();
  const auto k = e.size();
  r.resize(m);
  if (J) J->resize(m, np + k);
  Eigen::MatrixXd Ji;
  Eigen::Matrix<double, 6, 1> ri;
  int row = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    const Eigen::VectorXd pi = k ? Eigen::VectorXd(params + B[i] * e) : params;
    const int rows = whitenedResidual(model, data, pi, obs[i], ri, J ? &Ji : nullptr);
    r.segment(row, rows) = ri.head(rows);
    if (J) {
      J->block(row, 0, rows, np) = Ji.topRows(rows);
      if (k) J->block(row, np, rows, k) = Ji.topRows(rows) * B[i];
    }
    row += rows;
  }
}


Eigen::VectorXd rowParams(const CalibratedModel& fit, const Eigen::MatrixXd& B) {
  return fit.extension_params.size() ? Eigen::VectorXd(fit.params + B * fit.extension_params) : fit.params;
}

bool needsTimeConstant(const Extension& e, const std::vector<Drivers>& drivers) {
  return followsThermalDriver(e.cause) && e.time_constant_h == 0.0 && !drivers.empty() && drivers.front().thermal_is_time;
}

// The warm-up time constant of extension `t` (a thermal drift on a time driver) that leaves the least residual, on
// the model linearized at (p0, e = 0) over the columns `cols` (kinematic indices, then np + extension index).
// Variable projection: the thermal columns are s_i(tau) times their value at s = 1, so per observation the products
// with the other columns are formed once and each tau costs a small solve. Returns infinity for a straight line.
double searchTimeConstant(const RobotModel& model, const Eigen::VectorXd& start, const Eigen::VectorXd& p0,
                          const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                          std::vector<Extension> exts, int t, const std::vector<int>& cols) {
  const int np = model.numParams();
  int offset = 0;
  for (int k = 0; k < t; ++k) offset += numExtensionParams(model, exts[k]);
  const int kt = numExtensionParams(model, exts[t]);
  // Basis with s = 1 for the thermal extension: its driver set to 1 h and read as a temperature (no warm-up).
  std::vector<Drivers> unit = drivers;
  for (auto& d : unit) {
    d.thermal = 1.0;
    d.thermal_is_time = false;
  }
  const std::vector<Eigen::MatrixXd> B =
      bases(model, start, exts, obs, unit, Eigen::VectorXd::Zero(numExtensionParams(model, exts)));
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackExtended(model, p0, Eigen::VectorXd::Zero(numExtensionParams(model, exts)), obs, B, r, &J);
  std::vector<int> other, thermal;
  for (int c : cols) (c >= np + offset && c < np + offset + kt ? thermal : other).push_back(c);
  if (thermal.empty()) return INFINITY;  // not identifiable: nothing to choose
  const auto p = static_cast<Eigen::Index>(other.size()), q = static_cast<Eigen::Index>(thermal.size());
  Eigen::MatrixXd G(J.rows(), p), C(J.rows(), q);
  for (Eigen::Index k = 0; k < p; ++k) G.col(k) = J.col(other[k]);
  for (Eigen::Index k = 0; k < q; ++k) C.col(k) = J.col(thermal[k]);
  // Column scales (for a well-conditioned solve) and the per-observation products.
  Eigen::VectorXd scale(p + q);
  for (Eigen::Index k = 0; k < p; ++k) scale[k] = 1.0 / std::max(G.col(k).norm(), 1e-300);
  const Eigen::MatrixXd GtG = G.transpose() * G;
  const Eigen::VectorXd Gtr = G.transpose() * r;
  const size_t n = obs.size();
  std::vector<Eigen::MatrixXd> GtC(n), CtC(n);
  std::vector<Eigen::VectorXd> Ctr(n);
  Eigen::VectorXd hours(static_cast<Eigen::Index>(n));
  double span = 0;
  for (size_t i = 0, row = 0; i < n; ++i) {
    const auto rows = static_cast<Eigen::Index>(obs[i].rows());
    const auto Gi = G.middleRows(static_cast<Eigen::Index>(row), rows);
    const auto Ci = C.middleRows(static_cast<Eigen::Index>(row), rows);
    GtC[i] = Gi.transpose() * Ci;
    CtC[i] = Ci.transpose() * Ci;
    Ctr[i] = Ci.transpose() * r.segment(static_cast<Eigen::Index>(row), rows);
    hours[static_cast<Eigen::Index>(i)] = drivers[i].thermal;
    span = std::max(span, drivers[i].thermal);
    row += static_cast<size_t>(rows);
  }
  if (!(span > 0)) return INFINITY;
  auto residual = [&](double tau) {
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(p + q, p + q);
    Eigen::VectorXd b(p + q);
    H.topLeftCorner(p, p) = GtG;
    b.head(p) = Gtr;
    b.tail(q).setZero();
    double cnorm = 0;
    for (size_t i = 0; i < n; ++i) {
      const double si = warmUpDriver(hours[static_cast<Eigen::Index>(i)], tau);
      H.topRightCorner(p, q) += si * GtC[i];
      H.bottomRightCorner(q, q) += si * si * CtC[i];
      b.tail(q) += si * Ctr[i];
      cnorm += si * si * CtC[i].trace();
    }
    H.bottomLeftCorner(q, p) = H.topRightCorner(p, q).transpose();
    for (Eigen::Index k = 0; k < q; ++k) scale[p + k] = 1.0 / std::sqrt(std::max(cnorm / q, 1e-300));
    const Eigen::MatrixXd Hs = scale.asDiagonal() * H * scale.asDiagonal();
    const Eigen::VectorXd y = Hs.ldlt().solve(scale.asDiagonal() * b);
    return r.squaredNorm() - y.dot(scale.asDiagonal() * b);
  };
  // Grid: span * 2^k, k = -5..2, and the straight line; then golden section on log tau around the best grid point.
  std::vector<double> grid;
  for (int k = -5; k <= 2; ++k) grid.push_back(span * std::ldexp(1.0, k));
  double best_tau = INFINITY, best = residual(INFINITY);
  size_t best_k = grid.size();
  for (size_t k = 0; k < grid.size(); ++k) {
    const double v = residual(grid[k]);
    if (v < best) best = v, best_tau = grid[k], best_k = k;
  }
  if (best_k == grid.size()) return INFINITY;
  double lo = std::log(grid[best_k > 0 ? best_k - 1 : 0]), hi = std::log(grid[std::min(best_k + 1, grid.size() - 1)]);
  const double phi = 0.5 * (std::sqrt(5.0) - 1.0);
  double x1 = hi - phi * (hi - lo), x2 = lo + phi * (hi - lo);
  double f1 = residual(std::exp(x1)), f2 = residual(std::exp(x2));
  for (int it = 0; it < 16; ++it) {
    if (f1 < f2) {
      hi = x2, x2 = x1, f2 = f1;
      x1 = hi - phi * (hi - lo);
      f1 = residual(std::exp(x1));
    } else {
      lo = x1, x1 = x2, f1 = f2;
      x2 = lo + phi * (hi - lo);
      f2 = residual(std::exp(x2));
    }
  }
  const double x = f1 < f2 ? x1 : x2;
  if (std::min(f1, f2) < best) best_tau = std::exp(x);
  return best_tau;
}

// How far a row the fit cannot fully predict may be off without a gross error: before a backlash joint first moves
// its play state is unknown and the model predicts the middle of the gap, up to half the width off (m, at the target).
double unknownPlayAllowance(const RobotModel& model, const CalibratedModel& fit, const Observation& obs, const Drivers& d) {
  double allowance = 0;
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numParams());
  for (size_t e = 0, c = 0; e < fit.extensions.size(); c += static_cast<size_t>(numExtensionParams(model, fit.extensions[e])), ++e) {
    const Extension& x = fit.extensions[e];
    if (!followsPath(x.cause) || playStateUnknown({x}, d) == false) continue;
    forwardKinematics(model, data, fit.params, obs.q_rad);
    computePoseJacobian(model, data, J);
    allowance += 0.5 * std::abs(fit.extension_params[static_cast<Eigen::Index>(c)]) *
                 J.block<3, 1>(0, model.jointParam(x.joint, JointParam::kThetaOffset)).norm();
  }
  return allowance;
}

// Position and orientation errors of `obs` under a fit, screened. Rows the fit cannot fully predict (unknown backlash
// play) do not enter the robust scale, and are judged on what their error exceeds the unknown play by.
OutlierScreen screenFitRows(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                            const std::vector<Drivers>& drivers, const OutlierOptions& options) {
  const std::vector<Eigen::MatrixXd> B = bases(model, fit, obs, drivers);
  KinematicsData data(model);
  std::vector<Eigen::Vector3d> pos, all;
  std::vector<double> ori;
  std::vector<int> judged, unknown;
  for (size_t i = 0; i < obs.size(); ++i) {
    const Pose& T = forwardKinematics(model, data, rowParams(fit, B[i]), obs[i].q_rad);
    all.push_back(obs[i].measured_in_tracker.translation() - T.translation());
    if (playStateUnknown(fit.extensions, drivers[i])) {
      unknown.push_back(static_cast<int>(i));
      continue;
    }
    pos.push_back(all.back());
    ori.push_back(obs[i].kind == MeasurementKind::kPose6D
                      ? logSO3(obs[i].measured_in_tracker.linear() * T.linear().transpose()).norm()
                      : std::nan(""));
    judged.push_back(static_cast<int>(i));
  }
  const OutlierScreen s = screenOutliers(pos, ori, options);
  OutlierScreen out = s;
  out.z.assign(obs.size(), 0.0);
  for (size_t k = 0; k < judged.size(); ++k) out.z[static_cast<size_t>(judged[k])] = s.z[k];
  for (int i : unknown) {
    const double excess = all[static_cast<size_t>(i)].norm() -
                          unknownPlayAllowance(model, fit, obs[static_cast<size_t>(i)], drivers[static_cast<size_t>(i)]);
    out.z[static_cast<size_t>(i)] = s.sigma_position_m > 0 ? std::max(0.0, excess) / s.sigma_position_m : 0.0;
  }
  out.rows.clear();
  for (size_t i = 0; i < obs.size(); ++i)
    if (options.enabled && out.z[i] > options.threshold) out.rows.push_back(static_cast<int>(i));
  return out;
}


}  // namespace internal

using namespace internal;

std::string extensionLabel(const Extension& e) {
  return e.cause == Cause::kNone ? causeName(e.cause) : causeModel(e.cause).label(e);
}

std::string modelLabel(const std::vector<Extension>& exts) {
  std::string s;
  for (const auto& e : exts) s += (s.empty() ? "" : " + ") + extensionLabel(e);
  return s.empty() ? "geometric" : s;
}

IdentifiabilityOptions internal::withExtensionRanges(const IdentifiabilityOptions& options, const RobotModel& model,
                                                     const Eigen::VectorXd& params, const std::vector<Extension>& exts,
                                                     Eigen::Index ext0) {
  if (options.prior_sigma.size() == 0 || exts.empty()) return options;
  const Eigen::VectorXd ext = extensionPriorSigma(model, params, exts, kPlausibleExtensionJointErrorRad);
  IdentifiabilityOptions out = options;
  out.prior_sigma = Eigen::VectorXd::Zero(ext0 + ext.size());
  const Eigen::Index own = std::min<Eigen::Index>(options.prior_sigma.size(), ext0);
  out.prior_sigma.head(own) = options.prior_sigma.head(own);
  out.prior_sigma.tail(ext.size()) = ext;
  return out;
}

ExtendedFit geometricFit(const CalibrationResult& r) {
  ExtendedFit f;
  static_cast<CalibratedModel&>(f) = CalibratedModel::geometric(r.params, r.estimated, r.covariance);
  f.converged = r.converged;
  f.iterations = r.iterations;
  f.message = r.message;
  return f;
}

ExtendedFit geometricFit(const Eigen::VectorXd& params) {
  ExtendedFit f;
  static_cast<CalibratedModel&>(f) = CalibratedModel::geometric(params);
  return f;
}

ExtendedFit fitExtended(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                        const std::vector<Drivers>& drivers, const Extension& extension, const SolverOptions& solver,
                        const IdentifiabilityOptions& identifiability, const Eigen::VectorXd* warm_start) {
  std::vector<Extension> list;
  if (extension.cause != Cause::kNone) list.push_back(extension);
  return fitExtended(model, start, obs, drivers, list, solver, identifiability, warm_start);
}

ExtendedFit fitExtended(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                        const std::vector<Drivers>& drivers, const std::vector<Extension>& extensions,
                        const SolverOptions& solver, const IdentifiabilityOptions& identifiability,
                        const Eigen::VectorXd* warm_start, const Eigen::VectorXd* warm_extension) {
  for (const auto& e : extensions)
    if (e.cause == Cause::kNone || !applicable(model, e, true))
      throw std::invalid_argument(std::string("fitExtended: ") + causeName(e.cause) + " does not apply to joint " +
                                  std::to_string(e.joint + 1));
  std::string err;
  if (!solver.IsValid(&err)) throw std::invalid_argument("SolverOptions: " + err);
  if (start.size() != model.numParams()) throw std::invalid_argument("fitExtended: start has the wrong size");
  if (obs.empty()) throw std::invalid_argument("fitExtended: no observations");
  if (drivers.size() != obs.size()) throw std::invalid_argument("fitExtended: one Drivers entry per observation needed");
  // Rows where a backlash joint has not moved yet since the data began: which side of the gap it rests on is unknown
  // to anyone (a half-width error the model cannot predict), so they do not take part in the fit.
  std::vector<Observation> kept_obs;
  std::vector<Drivers> kept_drivers;
  int left_out = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    if (playStateUnknown(extensions, drivers[i])) {
      ++left_out;
    } else {
      kept_obs.push_back(obs[i]);
      kept_drivers.push_back(drivers[i]);
    }
  }
  if (left_out > 0) {
    if (kept_obs.empty()) throw std::invalid_argument("fitExtended: no row has a known backlash play state");
    ExtendedFit fit =
        fitExtended(model, start, kept_obs, kept_drivers, extensions, solver, identifiability, warm_start, warm_extension);
    fit.rows_left_out = left_out;
    return fit;
  }
  ExtendedFit fit;
  fit.extensions = extensions;
  fit.extension_names = extensionParamNames(model, extensions);
  const int k = numExtensionParams(model, extensions);
  const int np = model.numParams();
  Eigen::VectorXd evaluated_at = Eigen::VectorXd::Zero(k);  // the widths the backlash bases are evaluated at
  std::vector<Eigen::MatrixXd> B = bases(model, start, extensions, obs, drivers, evaluated_at);
  const Eigen::VectorXd p0 = warm_start ? *warm_start : start;

  // Which columns to estimate: canonical kinematic parameters first, extension parameters last.
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackExtended(model, p0, Eigen::VectorXd::Zero(k), obs, B, r, &J);
  std::vector<int> order = identificationPriority(model);
  for (int c = 0; c < k; ++c) order.push_back(np + c);
  const IdentifiabilityOptions io = internal::withExtensionRanges(identifiability, model, start, extensions, np);
  std::vector<int> cols = independentColumns(J, order, io);
  // Warm-up time constants (thermal drift on a time driver): chosen on the linearized model, then the columns again.
  bool chose = false;
  for (size_t t = 0; t < fit.extensions.size(); ++t)
    if (needsTimeConstant(fit.extensions[t], drivers)) {
      fit.extensions[t].time_constant_h =
          searchTimeConstant(model, start, p0, obs, drivers, fit.extensions, static_cast<int>(t), cols);
      chose = true;
    }
  if (chose) {
    B = bases(model, start, fit.extensions, obs, drivers, evaluated_at);
    stackExtended(model, p0, Eigen::VectorXd::Zero(k), obs, B, r, &J);
    cols = independentColumns(J, order, io);
  }
  for (int c : cols) (c < np ? fit.estimated : fit.estimated_extension).push_back(c < np ? c : c - np);

  const auto m = static_cast<Eigen::Index>(cols.size());
  auto unpack = [&](const Eigen::VectorXd& x, Eigen::VectorXd& params, Eigen::VectorXd& e) {
    params = p0;
    e = Eigen::VectorXd::Zero(k);
    for (Eigen::Index c = 0; c < m; ++c) (cols[c] < np ? params[cols[c]] : e[cols[c] - np]) = x[c];
  };
  auto eval = [&](const Eigen::VectorXd& x, Eigen::VectorXd& b, Eigen::MatrixXd* A) {
    Eigen::VectorXd params, e;
    unpack(x, params, e);
    Eigen::MatrixXd Jfull;
    stackExtended(model, params, e, obs, B, b, A ? &Jfull : nullptr);
    if (A) {
      A->resize(Jfull.rows(), m);
      for (Eigen::Index c = 0; c < m; ++c) A->col(c) = Jfull.col(cols[c]);
    }
  };
  const bool warm_e = warm_extension && warm_extension->size() == k && warm_extension->allFinite();
  Eigen::VectorXd x0(m);
  for (Eigen::Index c = 0; c < m; ++c) x0[c] = cols[c] < np ? p0[cols[c]] : warm_e ? (*warm_extension)[cols[c] - np] : 0.0;
  internal::GaussNewtonOutcome gn = internal::gaussNewton(eval, x0, solver);
  unpack(gn.x, fit.params, fit.extension_params);
  int iterations = gn.iterations;
  // A backlash basis depends on its own width (the play state): re-evaluate it at the fitted width and refit until
  // the width settles (a fixed point; it moves only through rows whose moves were smaller than the width).
  for (int pass = 0; pass < 8 && hasBacklash(fit.extensions); ++pass) {
    const Eigen::VectorXd moved = fit.extension_params.cwiseAbs() - evaluated_at.cwiseAbs();
    if ((moved.array().abs() <= 1e-3 * fit.extension_params.array().abs() + 1e-12).all()) break;
    evaluated_at = fit.extension_params;
    B = bases(model, start, fit.extensions, obs, drivers, evaluated_at);
    gn = internal::gaussNewton(eval, gn.x, solver);
    unpack(gn.x, fit.params, fit.extension_params);
    iterations += gn.iterations;
  }
  fit.converged = gn.converged;
  fit.iterations = iterations;
  fit.message = gn.message;
  Eigen::VectorXd b;
  Eigen::MatrixXd A;
  eval(gn.x, b, &A);
  const Eigen::MatrixXd info = A.transpose() * A;
  fit.covariance = info.ldlt().solve(Eigen::MatrixXd::Identity(m, m));
  return fit;
}

std::vector<Eigen::Vector3d> positionResiduals(const RobotModel& model, const CalibratedModel& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers) {
  const std::vector<Eigen::MatrixXd> B = bases(model, fit, obs, drivers);
  KinematicsData data(model);
  std::vector<Eigen::Vector3d> out;
  out.reserve(obs.size());
  for (size_t i = 0; i < obs.size(); ++i)
    out.push_back(obs[i].measured_in_tracker.translation() -
                  forwardKinematics(model, data, rowParams(fit, B[i]), obs[i].q_rad).translation());
  return out;
}

ErrorStats errorStats(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                      const std::vector<Drivers>& drivers) {
  const std::vector<Pose> predicted = predictedPoses(model, fit, obs, drivers);
  ErrorStatsAccumulator acc;
  for (size_t i = 0; i < obs.size(); ++i) acc.add(obs[i], predicted[i]);
  return acc.stats();
}

std::vector<Pose> predictedPoses(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                                 const std::vector<Drivers>& drivers) {
  const std::vector<Eigen::MatrixXd> B = bases(model, fit, obs, drivers);
  KinematicsData data(model);
  std::vector<Pose> poses;
  poses.reserve(obs.size());
  for (size_t i = 0; i < obs.size(); ++i) poses.push_back(forwardKinematics(model, data, rowParams(fit, B[i]), obs[i].q_rad));
  return poses;
}

void ErrorStatsAccumulator::add(const Observation& obs, const Pose& predicted) {
  ErrorStats& s = sums_;
  const double e = (obs.measured_in_tracker.translation() - predicted.translation()).norm() * 1e3;
  ++s.rows;
  s.mean_mm += e;
  s.rms_mm += e * e;
  s.max_mm = std::max(s.max_mm, e);
  position_mm_.push_back(e);
  if (obs.kind == MeasurementKind::kPose6D) {
    const double a = logSO3(obs.measured_in_tracker.linear() * predicted.linear().transpose()).norm() * 180 / kPi;
    ++s.oriented;
    s.mean_deg += a;
    s.rms_deg += a * a;
    s.max_deg = std::max(s.max_deg, a);
    orientation_deg_.push_back(a);
  }
}

ErrorStats ErrorStatsAccumulator::stats() const {
  ErrorStats s = sums_;
  const double n = std::max(1, s.rows);
  s.mean_mm /= n;
  s.rms_mm = std::sqrt(s.rms_mm / n);
  if (!position_mm_.empty()) s.p997_mm = percentile(position_mm_, 0.997);
  if (s.oriented) {
    s.mean_deg /= s.oriented;
    s.rms_deg = std::sqrt(s.rms_deg / s.oriented);
    s.p997_deg = percentile(orientation_deg_, 0.997);
  }
  return s;
}

ExtendedFit fitExtendedRobust(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                              const std::vector<Drivers>& drivers, const std::vector<Extension>& extensions,
                              const SolverOptions& solver, const IdentifiabilityOptions& identifiability,
                              const Eigen::VectorXd* warm_start, const OutlierOptions& outliers, OutlierScreen* screen) {
  std::string err;
  if (!outliers.IsValid(&err)) throw std::invalid_argument(err);
  ExtendedFit fit = fitExtended(model, start, obs, drivers, extensions, solver, identifiability, warm_start);
  OutlierScreen sc = screenFitRows(model, fit, obs, drivers, outliers);
  const int n = static_cast<int>(obs.size());
  std::vector<int> used;
  for (int round = 0; outliers.enabled && round < outliers.max_rounds && sc.rows != used; ++round) {
    if (2 * static_cast<int>(sc.rows.size()) > n) break;  // never fewer than half the rows
    used = sc.rows;
    const std::vector<int> kept = keptRows(n, used);
    // The model as given, fitted to the rows kept (warm-up time constants not given are searched again there).
    fit = fitExtended(model, start, subset(obs, kept), subset(drivers, kept), extensions, solver, identifiability,
                      warm_start);
    sc = screenFitRows(model, fit, obs, drivers, outliers);
  }
  if (screen) *screen = std::move(sc);
  return fit;
}

std::vector<int> conditionalCovariance(const RobotModel& model, const CalibratedModel& fit,
                                       const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                       const std::vector<int>& columns, Eigen::MatrixXd* covariance,
                                       double* variance_factor) {
  for (int c : columns)
    if (c < 0 || c >= model.numParams())
      throw std::invalid_argument("conditionalCovariance: column " + std::to_string(c) + " is not a kinematic parameter");
  const std::vector<Eigen::MatrixXd> B = bases(model, fit, obs, drivers);
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stackExtended(model, fit.params, fit.extension_params.size() ? fit.extension_params : Eigen::VectorXd(), obs, B, r, &J);
  std::vector<int> kept = independentColumns(J, columns, IdentifiabilityOptions{});
  std::vector<int> ordered;  // in the order given
  for (int c : columns)
    if (std::count(kept.begin(), kept.end(), c)) ordered.push_back(c);
  const auto n = static_cast<Eigen::Index>(ordered.size());
  Eigen::MatrixXd A(J.rows(), n);
  for (Eigen::Index c = 0; c < n; ++c) A.col(c) = J.col(ordered[static_cast<size_t>(c)]);
  if (variance_factor)
    *variance_factor = r.size() > n ? r.squaredNorm() / static_cast<double>(r.size() - n)
                                    : std::numeric_limits<double>::quiet_NaN();
  if (covariance) *covariance = (A.transpose() * A).ldlt().solve(Eigen::MatrixXd::Identity(n, n));
  return ordered;
}

OutlierScreen screenRows(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                         const std::vector<Drivers>& drivers, const OutlierOptions& options) {
  return screenFitRows(model, fit, obs, drivers, options);
}

}  // namespace cellcal
