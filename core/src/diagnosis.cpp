#include "cellcal/core/diagnosis.hpp"

#include <Eigen/QR>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>

#include "calibration_internal.hpp"
#include "cellcal/core/kinematics.hpp"

namespace cellcal {

namespace {

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

std::vector<Eigen::MatrixXd> bases(const RobotModel& model, const ExtendedFit& fit, const std::vector<Observation>& obs,
                                   const std::vector<Drivers>& drivers) {
  return bases(model, fit.params, fit.extensions, obs, drivers, fit.extension_params);
}

bool hasBacklash(const std::vector<Extension>& exts) {
  for (const auto& e : exts)
    if (e.cause == Cause::kBacklash) return true;
  return false;
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

// Paired improvement of squared position errors from residual set a to residual set b, in standard errors.
double pairedZ(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b) {
  const auto n = static_cast<double>(a.size());
  double mean = 0, sq = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double d = a[i].squaredNorm() - b[i].squaredNorm();
    mean += d;
    sq += d * d;
  }
  mean /= n;
  const double var = n > 1 ? std::max(0.0, (sq - n * mean * mean) / (n - 1)) : 0.0;
  return var > 0 ? mean / std::sqrt(var / n) : (mean > 0 ? INFINITY : 0.0);
}

Eigen::VectorXd rowParams(const ExtendedFit& fit, const Eigen::MatrixXd& B) {
  return fit.extension_params.size() ? Eigen::VectorXd(fit.params + B * fit.extension_params) : fit.params;
}

}  // namespace

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
                        const Eigen::VectorXd* warm_start) {
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
    bool unknown = false;
    for (const auto& e : extensions)
      if (e.cause == Cause::kBacklash)
        unknown = unknown || drivers[i].motion_direction.size() <= e.joint || drivers[i].motion_direction[e.joint] == 0.0;
    if (unknown) {
      ++left_out;
    } else {
      kept_obs.push_back(obs[i]);
      kept_drivers.push_back(drivers[i]);
    }
  }
  if (left_out > 0) {
    if (kept_obs.empty()) throw std::invalid_argument("fitExtended: no row has a known backlash play state");
    ExtendedFit fit = fitExtended(model, start, kept_obs, kept_drivers, extensions, solver, identifiability, warm_start);
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
  const std::vector<int> cols = independentColumns(J, order, identifiability);
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
  Eigen::VectorXd x0(m);
  for (Eigen::Index c = 0; c < m; ++c) x0[c] = cols[c] < np ? p0[cols[c]] : 0.0;
  internal::GaussNewtonOutcome gn = internal::gaussNewton(eval, x0, solver);
  unpack(gn.x, fit.params, fit.extension_params);
  int iterations = gn.iterations;
  // A backlash basis depends on its own width (the play state): re-evaluate it at the fitted width and refit until
  // the width settles (a fixed point; it moves only through rows whose moves were smaller than the width).
  for (int pass = 0; pass < 8 && hasBacklash(extensions); ++pass) {
    const Eigen::VectorXd moved = fit.extension_params.cwiseAbs() - evaluated_at.cwiseAbs();
    if ((moved.array().abs() <= 1e-3 * fit.extension_params.array().abs() + 1e-12).all()) break;
    evaluated_at = fit.extension_params;
    B = bases(model, start, extensions, obs, drivers, evaluated_at);
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

double ExtendedFit::paramStddev(int i) const {
  const auto it = std::find(estimated.begin(), estimated.end(), i);
  if (it == estimated.end() || covariance.rows() == 0) return std::nan("");
  const auto c = it - estimated.begin();
  return std::sqrt(covariance(c, c));
}

double ExtendedFit::extensionStddev(int k) const {
  const auto it = std::find(estimated_extension.begin(), estimated_extension.end(), k);
  if (it == estimated_extension.end() || covariance.rows() == 0) return std::nan("");
  const auto c = static_cast<Eigen::Index>(estimated.size()) + (it - estimated_extension.begin());
  return std::sqrt(covariance(c, c));
}

std::vector<Eigen::Vector3d> positionResiduals(const RobotModel& model, const ExtendedFit& fit,
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

ErrorStats errorStats(const RobotModel& model, const ExtendedFit& fit, const std::vector<Observation>& obs,
                      const std::vector<Drivers>& drivers) {
  const std::vector<Eigen::MatrixXd> B = bases(model, fit, obs, drivers);
  KinematicsData data(model);
  ErrorStatsAccumulator acc;
  for (size_t i = 0; i < obs.size(); ++i) acc.add(obs[i], forwardKinematics(model, data, rowParams(fit, B[i]), obs[i].q_rad));
  return acc.stats();
}

void ErrorStatsAccumulator::add(const Observation& obs, const Pose& predicted) {
  ErrorStats& s = sums_;
  const double e = (obs.measured_in_tracker.translation() - predicted.translation()).norm() * 1e3;
  ++s.rows;
  s.mean_mm += e;
  s.rms_mm += e * e;
  s.max_mm = std::max(s.max_mm, e);
  if (obs.kind == MeasurementKind::kPose6D) {
    const double a = logSO3(obs.measured_in_tracker.linear() * predicted.linear().transpose()).norm() * 180 / kPi;
    ++s.oriented;
    s.mean_deg += a;
    s.rms_deg += a * a;
    s.max_deg = std::max(s.max_deg, a);
  }
}

ErrorStats ErrorStatsAccumulator::stats() const {
  ErrorStats s = sums_;
  const double n = std::max(1, s.rows);
  s.mean_mm /= n;
  s.rms_mm = std::sqrt(s.rms_mm / n);
  if (s.oriented) {
    s.mean_deg /= s.oriented;
    s.rms_deg = std::sqrt(s.rms_deg / s.oriented);
  }
  return s;
}

bool DiagnosisOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (!(penalty_per_param >= 0)) return fail("penalty_per_param must be >= 0");
  if (!(min_gain >= 0 && min_gain < 1)) return fail("min_gain must be in [0, 1)");
  if (!(min_z >= 0)) return fail("min_z must be >= 0");
  if (!(parsimony_z >= 0)) return fail("parsimony_z must be >= 0");
  for (Cause c : causes)
    if (c == Cause::kNone) return fail("causes: 'none' is not an extension (it is the default outcome)");
  std::string e;
  if (!solver.IsValid(&e)) return fail("solver: " + e);
  if (!identifiability.IsValid(&e)) return fail("identifiability: " + e);
  return true;
}

std::vector<DriverStructure> residualStructure(const RobotModel& model, const ExtendedFit& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                               bool has_thermal) {
  const auto n = static_cast<Eigen::Index>(obs.size());
  const std::vector<Eigen::Vector3d> res = positionResiduals(model, fit, obs, drivers);
  Eigen::MatrixXd Y(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) Y.row(i) = res[i].transpose();
  const Eigen::MatrixXd Yc = Y.rowwise() - Y.colwise().mean();
  const double sst = Yc.squaredNorm();
  std::vector<DriverStructure> out;
  if (n < 8 || sst <= 0) return out;
  auto score = [&](const std::string& name, const Eigen::MatrixXd& X) {
    const Eigen::Index p = X.cols();
    if (n <= p + 2) return;
    Eigen::MatrixXd A(n, p + 1);
    A.col(0).setOnes();
    A.rightCols(p) = X;
    const Eigen::MatrixXd coef = A.colPivHouseholderQr().solve(Y);
    const double sse = (Y - A * coef).squaredNorm();
    const double r2 = 1.0 - sse / sst;
    out.push_back({name, 1.0 - (1.0 - r2) * static_cast<double>(n - 1) / static_cast<double>(n - p - 1)});
  };
  const int nj = model.numJoints();
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(nj);
  for (int j = 0; j < nj; ++j) {
    Eigen::MatrixXd X(n, 4);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double q = obs[i].q_rad[j];
      X.row(i) << std::sin(q), std::cos(q), std::sin(2 * q), std::cos(2 * q);
    }
    score("q" + std::to_string(j + 1), X);
  }
  for (int j = 0; j < nj; ++j) {
    const Extension ext{Cause::kJointCompliance, j};
    if (!applicable(model, ext, false)) continue;
    // Torque of the robot file's masses, or of a unit mass at the target.
    Eigen::MatrixXd X(n, 2);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double t = complianceDriver(model, fit.params, obs[i].q_rad, j);
      X.row(i) << t, t * t;
    }
    score("gravity_torque_" + std::to_string(j + 1), X);
  }
  if (has_thermal) {
    Eigen::MatrixXd X(n, 2);
    for (Eigen::Index i = 0; i < n; ++i) X.row(i) << drivers[i].thermal, drivers[i].thermal * drivers[i].thermal;
    score("thermal", X);
  }
  for (int j = 0; j < nj; ++j) {
    Eigen::MatrixXd X(n, 1);
    for (Eigen::Index i = 0; i < n; ++i) X(i, 0) = drivers[i].motion_direction.size() > j ? drivers[i].motion_direction[j] : 0;
    if (X.cwiseAbs().maxCoeff() > 0) score("direction_" + std::to_string(j + 1), X);
  }
  {
    Eigen::MatrixXd X(n, 9);
    for (Eigen::Index i = 0; i < n; ++i) {
      const std::vector<Pose> F = chainFrames(model, fit.params, obs[i].q_rad);
      const Eigen::Vector3d p = F[0].inverse() * F.back().translation();
      X.row(i) << p.x(), p.y(), p.z(), p.x() * p.x(), p.y() * p.y(), p.z() * p.z(), p.x() * p.y(), p.x() * p.z(),
          p.y() * p.z();
    }
    score("workspace", X);
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.r2_adjusted > b.r2_adjusted; });
  return out;
}

DiagnosisResult diagnose(const RobotModel& model, const Eigen::VectorXd& start, const DiagnosisData& data,
                         const DiagnosisOptions& options) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument("DiagnosisOptions: " + err);
  if (data.identification.size() < 8 || data.verification.empty())
    throw std::invalid_argument("diagnose: needs at least 8 identification and 1 verification observation");
  const auto t0 = std::chrono::steady_clock::now();
  const auto& I = data.identification;
  const auto& V = data.verification;
  const auto& ID = data.identification_drivers;
  const auto& VD = data.verification_drivers;

  auto evaluate = [&](ExtendedFit fit) {
    CandidateResult c;
    c.identification = errorStats(model, fit, I, ID);
    c.verification = errorStats(model, fit, V, VD);
    c.verify_mse_m2 = std::pow(c.verification.rms_mm * 1e-3, 2);
    c.score = c.verify_mse_m2 * (1.0 + options.penalty_per_param * fit.numEstimatedExtension() /
                                           static_cast<double>(totalRows(I)));
    c.fit = std::move(fit);
    return c;
  };
  std::vector<Extension> to_try;
  for (Cause cause : options.causes)
    for (int j = cause == Cause::kThermalDrift ? -1 : 0; j < model.numJoints(); ++j)
      if (applicable(model, Extension{cause, j}, data.has_thermal)) to_try.push_back(Extension{cause, j});
  int fits_done = 0;
  const int fits_total = 1 + static_cast<int>(to_try.size());
  DiagnosisResult out;
  out.geometric = evaluate(fitExtended(model, start, I, ID, Extension{}, options.solver, options.identifiability));
  if (options.progress) options.progress(++fits_done, fits_total);
  const std::vector<Eigen::Vector3d> geo_res = positionResiduals(model, out.geometric.fit, V, VD);

  std::vector<std::vector<Eigen::Vector3d>> residuals;  // verification residuals, parallel to out.candidates
  for (const Extension& ext : to_try) {
      CandidateResult c = evaluate(fitExtended(model, start, I, ID, ext, options.solver, options.identifiability,
                                               &out.geometric.fit.params));
      if (options.progress) options.progress(++fits_done, fits_total);
      if (c.fit.numEstimatedExtension() == 0) continue;  // nothing the geometric model could not already do
      residuals.push_back(positionResiduals(model, c.fit, V, VD));
      c.z = pairedZ(geo_res, residuals.back());
      out.candidates.push_back(std::move(c));
    }
  std::vector<size_t> order(out.candidates.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(),
            [&](size_t a, size_t b) { return out.candidates[a].score < out.candidates[b].score; });
  {
    std::vector<CandidateResult> c;
    std::vector<std::vector<Eigen::Vector3d>> r;
    for (size_t i : order) {
      c.push_back(std::move(out.candidates[i]));
      r.push_back(std::move(residuals[i]));
    }
    out.candidates = std::move(c);
    residuals = std::move(r);
  }
  auto significant = [&](size_t i) {
    const CandidateResult& c = out.candidates[i];
    return c.score < out.geometric.score && 1.0 - c.verify_mse_m2 / out.geometric.verify_mse_m2 > options.min_gain &&
           c.z > options.min_z;
  };
  if (!out.candidates.empty() && significant(0)) {
    // Parsimony: a simpler significant candidate (fewer parameters) replaces the choice unless the choice beats it by
    // min_z standard errors on the verification rows; repeated until no simpler one qualifies.
    size_t pick = 0;
    for (bool changed = true; changed;) {
      changed = false;
      for (size_t i = 0; i < out.candidates.size(); ++i) {
        if (i == pick || !significant(i)) continue;
        if (out.candidates[i].fit.numEstimatedExtension() >= out.candidates[pick].fit.numEstimatedExtension()) continue;
        if (pairedZ(residuals[i], residuals[pick]) > options.parsimony_z) continue;
        pick = i;
        changed = true;
        break;  // candidates are in score order: the best-scoring simpler one
      }
    }
    out.chosen = static_cast<int>(pick);
    const CandidateResult& b = out.candidates[pick];
    out.cause = b.fit.extension().cause;
    if (b.fit.extension().joint >= 0) out.joints = {b.fit.extension().joint};
  }
  const CandidateResult& best = out.best();
  out.gain_pct = 100.0 * (1.0 - best.verification.mean_mm / out.geometric.verification.mean_mm);
  out.structure_before = residualStructure(model, out.geometric.fit, V, VD, data.has_thermal);
  out.structure_after = residualStructure(model, best.fit, V, VD, data.has_thermal);
  double noise_ms = 0;
  for (const auto& o : V) noise_ms += 3.0 * o.sigma_position_m * o.sigma_position_m;
  out.noise_rms_mm = std::sqrt(noise_ms / static_cast<double>(V.size())) * 1e3;
  out.unexplained_rms_mm =
      std::sqrt(std::max(0.0, best.verification.rms_mm * best.verification.rms_mm - out.noise_rms_mm * out.noise_rms_mm));
  out.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

CauseSignature causeSignature(const RobotModel& model, const ExtendedFit& geometric, const ExtendedFit& extended,
                              const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                              const std::string& thermal_source) {
  const Extension ext = extended.extension();
  if (ext.cause == Cause::kNone) throw std::invalid_argument("causeSignature: the extended fit has no cause");
  CauseSignature sig;
  const int j = ext.joint;
  const std::string jn = std::to_string(j + 1);
  const std::string thermal = thermal_source == "temperature_c" ? "temperature - mean (K)" : "time since first row (h)";
  switch (ext.cause) {
    case Cause::kJointCompliance:
      sig.x_label = model.links.empty() ? "gravity torque of 1 kg at the target on joint " + jn + " (N m/kg)"
                                        : "gravity torque on joint " + jn + " (N m)";
      break;
    case Cause::kThermalDrift:
      sig.x_label = thermal;
      break;
    case Cause::kCyclicTransmission:
    case Cause::kJointScale:
      sig.x_label = "q" + jn + " (deg)";
      break;
    case Cause::kBacklash:
      sig.x_label = "direction joint " + jn + " last moved (-1 / +1)";
      break;
    case Cause::kNone:
      break;
  }
  sig.y_label = j >= 0 ? "apparent joint " + jn + " error (deg)" : "apparent growth of the lengths (um/m)";
  const std::vector<Eigen::Vector3d> before = positionResiduals(model, geometric, obs, drivers);
  const std::vector<Eigen::Vector3d> after = positionResiduals(model, extended, obs, drivers);
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numParams());
  for (size_t i = 0; i < obs.size(); ++i) {
    forwardKinematics(model, data, geometric.params, obs[i].q_rad);
    computePoseJacobian(model, data, J);
    Eigen::Vector3d d;
    double scale;
    if (j >= 0) {
      d = J.block<3, 1>(0, model.jointParam(j, JointParam::kThetaOffset));
      scale = 180.0 / kPi;
    } else {
      d.setZero();
      for (int k = 0; k < model.numJoints(); ++k)
        for (JointParam p : {JointParam::kA, JointParam::kD}) {
          const int idx = model.jointParam(k, p);
          d += J.block<3, 1>(0, idx) * geometric.params[idx];
        }
      scale = 1e6;
    }
    const double dd = std::max(d.squaredNorm(), 1e-30);
    sig.y_before.push_back(d.dot(before[i]) / dd * scale);
    sig.y_after.push_back(d.dot(after[i]) / dd * scale);
    double x = 0;
    switch (ext.cause) {
      case Cause::kJointCompliance:
        x = complianceDriver(model, geometric.params, obs[i].q_rad, j);
        break;
      case Cause::kThermalDrift:
        x = drivers[i].thermal;
        break;
      case Cause::kCyclicTransmission:
      case Cause::kJointScale:
        x = obs[i].q_rad[j] * 180.0 / kPi;
        break;
      case Cause::kBacklash: {
        const double spread = std::fmod(0.6180339887 * static_cast<double>(i), 1.0) - 0.5;
        x = (drivers[i].motion_direction.size() > j ? drivers[i].motion_direction[j] : 0.0) + 0.3 * spread;
        break;
      }
      case Cause::kNone:
        break;
    }
    sig.x.push_back(x);
  }
  return sig;
}

}  // namespace cellcal
