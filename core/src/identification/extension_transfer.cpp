// extensionTransfer (prediction.hpp): what a fit's extensions are worth where their data never were.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "calibration_internal.hpp"
#include "cellcal/core/identification/prediction.hpp"

namespace cellcal {

std::vector<BeyondRange> ExtensionTransfer::beyond() const {
  std::vector<BeyondRange> out;
  for (const auto& j : joints) out.push_back(j.beyond);
  return out;
}

namespace {

// One judged row: actual squared position error, predicted model variance and noise variance (m^2), the joint's
// distance beyond the fitted rows' range (rad) and |dp/dq_joint|^2 (m^2 / rad^2).
struct Judged {
  double actual2 = 0, predicted2 = 0, noise2 = 0, beyond_rad = 0, gain2 = 0;
  double variance(double sigma, int growth) const {
    const double s = sigma * std::pow(beyond_rad, growth);
    return predicted2 + noise2 + (beyond_rad > 0 ? s * s * gain2 : 0.0);
  }
};

double ratioRms(const std::vector<Judged>& rows, double sigma, int growth) {
  double sum = 0;
  for (const auto& j : rows) sum += j.actual2 / j.variance(sigma, growth);
  return std::sqrt(sum / static_cast<double>(rows.size()));
}

// Negative log-likelihood (up to a constant) of the rows' 3D position errors, each axis N(0, variance / 3).
double nll(const std::vector<Judged>& rows, double sigma, int growth) {
  double sum = 0;
  for (const auto& j : rows) {
    const double v = j.variance(sigma, growth) / 3;
    sum += 1.5 * std::log(v) + 0.5 * j.actual2 / v;
  }
  return sum;
}

// The sigma (rad at 1 rad) of the given growth that minimizes nll: a log grid, then golden section around its best.
double fitSigma(const std::vector<Judged>& rows, int growth) {
  constexpr double lo = 1e-9, hi = 10.0;
  constexpr int n = 90;
  double best_x = std::log(lo), best = std::numeric_limits<double>::infinity();
  const double step = (std::log(hi) - std::log(lo)) / n;
  for (int i = 0; i <= n; ++i) {
    const double x = std::log(lo) + i * step, f = nll(rows, std::exp(x), growth);
    if (f < best) best = f, best_x = x;
  }
  double a = best_x - step, b = best_x + step;
  const double g = (std::sqrt(5.0) - 1) / 2;
  for (int it = 0; it < 60; ++it) {
    const double c = b - g * (b - a), d = a + g * (b - a);
    if (nll(rows, std::exp(c), growth) < nll(rows, std::exp(d), growth))
      b = d;
    else
      a = c;
  }
  return std::exp(0.5 * (a + b));
}

}  // namespace

ExtensionTransfer extensionTransfer(const RobotModel& model, const Eigen::VectorXd& start, const CalibratedModel& fit,
                                    const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                    const DiagnosisOptions& options) {
  if (obs.size() != drivers.size()) throw std::invalid_argument("extensionTransfer: one Drivers entry per observation");
  ExtensionTransfer out;
  std::vector<int> joints;
  for (const Extension& e : fit.extensions) {
    if (regionSplitName(e) == "workspace") {
      out.not_measured.push_back(extensionLabel(e) + " (its region is not a joint's range)");
      continue;
    }
    if (std::find(joints.begin(), joints.end(), e.joint) != joints.end()) continue;
    joints.push_back(e.joint);
    JointTransfer jt;
    jt.beyond.joint = e.joint;
    jt.beyond.lower_rad = std::numeric_limits<double>::infinity();
    jt.beyond.upper_rad = -std::numeric_limits<double>::infinity();
    for (const auto& o : obs) {
      jt.beyond.lower_rad = std::min(jt.beyond.lower_rad, o.q_rad[e.joint]);
      jt.beyond.upper_rad = std::max(jt.beyond.upper_rad, o.q_rad[e.joint]);
    }
    std::vector<Judged> rows;
    std::string skipped;
    // The smaller of the two ends' farthest judged row; 0 when an end was not judged (`skipped` says why: one number
    // stands for both ends).
    double checked = std::numeric_limits<double>::infinity();
    for (const internal::Fold& fold : internal::regionFolds(obs, e, options.region_joint_end)) {
      if (static_cast<int>(fold.first.size()) < options.region_min_rows || fold.second.size() < 8) {
        skipped = "too few rows at an end of the joint's range";
        continue;
      }
      // The fitted rows' range of the joint, with a unit constant error beyond it: beyondRad gives a judged row's
      // distance, and predictedPositionSigma over it alone |dp/dq_joint| there (as the prediction will use it).
      PredictionModel unit;
      BeyondRange fitted{e.joint, std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(), 1.0};
      for (int r : fold.first) {
        fitted.lower_rad = std::min(fitted.lower_rad, obs[static_cast<size_t>(r)].q_rad[e.joint]);
        fitted.upper_rad = std::max(fitted.upper_rad, obs[static_cast<size_t>(r)].q_rad[e.joint]);
      }
      unit.beyond = {fitted};
      double side_max = 0;
      const std::vector<int> fit_rows = subset(fold.first, internal::evenlyThinned(fold.first.size(), options.region_fit_rows));
      const std::vector<Observation> FO = subset(obs, fit_rows), JO = subset(obs, fold.second);
      const std::vector<Drivers> FD = subset(drivers, fit_rows), JD = subset(drivers, fold.second);
      IdentifiabilityOptions io = options.identifiability;
      if (options.excitation_ratio > 0)
        for (const auto& d : excitationDeficits(model, start, fit.extensions, FO, FD, JO, JD, options.excitation_ratio))
          io.held.push_back(d.column);
      ExtendedFit ff;
      try {
        ff = fitExtended(model, start, FO, FD, fit.extensions, options.solver, io, &fit.params, &fit.extension_params);
      } catch (const std::invalid_argument&) {  // e.g. no row of a known backlash play state on this side
        skipped = "a fold could not be fitted";
        continue;
      }
      if (!ff.converged) {
        skipped = "a fold's fit did not converge";
        continue;
      }
      const PredictionModel pm = predictionModel(model, ff, FO, FD);
      const std::vector<Eigen::Vector3d> res = positionResiduals(model, ff, JO, JD);
      for (size_t i = 0; i < JO.size(); ++i) {
        Judged j;
        j.actual2 = res[i].squaredNorm();
        j.predicted2 = std::pow(predictedPositionSigma(model, ff, pm, JO[i].q_rad, JD[i]), 2);
        j.noise2 = 3.0 * pm.variance_factor_position * JO[i].sigma_position_m * JO[i].sigma_position_m;
        j.beyond_rad = fitted.beyondRad(JO[i].q_rad[e.joint]);
        if (j.beyond_rad > 0) j.gain2 = std::pow(predictedPositionSigma(model, ff, unit, JO[i].q_rad, JD[i]), 2);
        if (std::isfinite(j.actual2) && std::isfinite(j.predicted2) && j.variance(0, 0) > 0) rows.push_back(j);
        side_max = std::max(side_max, j.beyond_rad);
      }
      checked = std::min(checked, side_max);
      ++jt.folds;
    }
    jt.judged_rows = static_cast<int>(rows.size());
    jt.beyond.checked_rad = std::isfinite(checked) && skipped.empty() ? checked : 0.0;
    char b[600];
    if (rows.empty()) {
      std::snprintf(b, sizeof b, "joint %d: not measured (%s)", e.joint + 1, skipped.c_str());
      out.text += (out.text.empty() ? "" : "\n") + std::string(b);
      out.joints.push_back(jt);
      continue;
    }
    jt.ratio_rms_without = jt.ratio_rms_with = ratioRms(rows, 0, 0);
    if (jt.ratio_rms_without > 1) {
      double best = nll(rows, 0, 0);
      for (int growth = 0; growth <= 2; ++growth) {
        const double sigma = fitSigma(rows, growth);
        const double f = nll(rows, sigma, growth);
        if (f < best) best = f, jt.beyond.sigma_at_1_rad = sigma, jt.beyond.growth = growth;
      }
      jt.ratio_rms_with = ratioRms(rows, jt.beyond.sigma_at_1_rad, jt.beyond.growth);
    }
    char judged[160];
    if (jt.beyond.checked_rad > 0)
      std::snprintf(judged, sizeof judged, "judged up to %.1f deg beyond [%.1f, %.1f] deg, farther it is extrapolated",
                    jt.beyond.checked_rad * 180 / kPi, jt.beyond.lower_rad * 180 / kPi, jt.beyond.upper_rad * 180 / kPi);
    else
      std::snprintf(judged, sizeof judged, "an end was not judged (%s): beyond [%.1f, %.1f] deg it is extrapolated",
                    skipped.c_str(), jt.beyond.lower_rad * 180 / kPi, jt.beyond.upper_rad * 180 / kPi);
    if (jt.beyond.sigma_at_1_rad == 0)
      std::snprintf(b, sizeof b,
                    "joint %d: fitted short of either end of its range, the model predicts the rows beyond within its "
                    "uncertainty (%d rows, RMS ratio %.2f; %s)",
                    e.joint + 1, jt.judged_rows, jt.ratio_rms_without, judged);
    else
      std::snprintf(b, sizeof b,
                    "joint %d: fitted short of either end of its range, the model errs %.2fx its predicted uncertainty "
                    "on the rows beyond (%d rows); outside its range it is given a further joint error of %.3g deg%s "
                    "(ratio then %.2f; %s)",
                    e.joint + 1, jt.ratio_rms_without, jt.judged_rows, jt.beyond.sigma_at_1_rad * 180 / kPi,
                    jt.beyond.growthText(), jt.ratio_rms_with, judged);
    out.text += (out.text.empty() ? "" : "\n") + std::string(b);
    out.joints.push_back(jt);
  }
  if (!out.not_measured.empty()) {
    std::string list;
    for (const auto& s : out.not_measured) list += (list.empty() ? "" : ", ") + s;
    out.text += (out.text.empty() ? "" : "\n") + ("not measured: " + list);
  }
  return out;
}

}  // namespace cellcal
