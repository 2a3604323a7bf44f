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
// distance beyond the fitted rows' range (rad), |dp/dq_joint|^2 (m^2 / rad^2) and the width of the joint's range the
// judging fit was fitted on as a share of the campaign's (width_share^width_power scales the sigma: see below).
struct Judged {
  double actual2 = 0, predicted2 = 0, noise2 = 0, beyond_rad = 0, gain2 = 0, width_share = 1;
  double variance(double sigma, int growth, int width_power = 0) const {
    const double s = sigma * std::pow(beyond_rad, growth) * std::pow(width_share, width_power);
    return predicted2 + noise2 + (beyond_rad > 0 ? s * s * gain2 : 0.0);
  }
};

// A BeyondRange's form: sigma (rad at 1 rad beyond, for a fit on the campaign's whole range), growth with the distance
// beyond the range and power of the fitted range's width.
struct Form {
  double sigma = 0;
  int growth = 0, width_power = 0;
};

double ratioRms(const std::vector<Judged>& rows, const Form& f) {
  double sum = 0;
  for (const auto& j : rows) sum += j.actual2 / j.variance(f.sigma, f.growth, f.width_power);
  return std::sqrt(sum / static_cast<double>(rows.size()));
}

// Negative log-likelihood (up to a constant) of the rows' 3D position errors, each axis N(0, variance / 3).
double nll(const std::vector<Judged>& rows, const Form& f) {
  double sum = 0;
  for (const auto& j : rows) {
    const double v = j.variance(f.sigma, f.growth, f.width_power) / 3;
    sum += 1.5 * std::log(v) + 0.5 * j.actual2 / v;
  }
  return sum;
}

// The sigma of the given growth and width power that minimizes nll: a log grid, then golden section around its best.
Form fitSigma(const std::vector<Judged>& rows, int growth, int width_power) {
  constexpr double lo = 1e-9, hi = 10.0;
  constexpr int n = 90;
  auto at = [&](double x) { return nll(rows, {std::exp(x), growth, width_power}); };
  double best_x = std::log(lo), best = std::numeric_limits<double>::infinity();
  const double step = (std::log(hi) - std::log(lo)) / n;
  for (int i = 0; i <= n; ++i) {
    const double x = std::log(lo) + i * step, f = at(x);
    if (f < best) best = f, best_x = x;
  }
  double a = best_x - step, b = best_x + step;
  const double g = (std::sqrt(5.0) - 1) / 2;
  for (int it = 0; it < 60; ++it) {
    const double c = b - g * (b - a), d = a + g * (b - a);
    if (at(c) < at(d))
      b = d;
    else
      a = c;
  }
  return {std::exp(0.5 * (a + b)), growth, width_power};
}

// The best form of the given width powers by nll, against no further error at all (sigma 0); its nll in *best_nll
// when given.
Form bestForm(const std::vector<Judged>& rows, int min_power, int max_power, double* best_nll = nullptr) {
  Form best;
  double least = nll(rows, best);
  for (int p = min_power; p <= max_power; ++p)
    for (int growth = 0; growth <= 2; ++growth) {
      const Form f = fitSigma(rows, growth, p);
      const double v = nll(rows, f);
      if (v < least) least = v, best = f;
    }
  if (best_nll) *best_nll = least;
  return best;
}

// One fold: `model` fitted on fit_rows of obs (at most region_fit_rows of them; excitation deficits held) predicts
// judged_rows. Appends their Judged rows (width_share: the fitted rows' range of the joint over `campaign_width_rad`)
// and returns the farthest one's distance beyond that range; empty `skipped` when judged, else why not.
double judgeFold(const RobotModel& model, const Eigen::VectorXd& start, const CalibratedModel& fit,
                 const std::vector<Observation>& obs, const std::vector<Drivers>& drivers, const std::vector<int>& fit_rows_all,
                 const std::vector<int>& judged_rows, int joint, double campaign_width_rad, const DiagnosisOptions& options,
                 std::vector<Judged>* rows, std::string* skipped) {
  skipped->clear();
  if (static_cast<int>(fit_rows_all.size()) < options.region_min_rows || judged_rows.size() < 8) {
    *skipped = "too few rows at an end of the joint's range";
    return 0;
  }
  // The fitted rows' range of the joint, with a unit constant error beyond it: beyondRad gives a judged row's
  // distance, and predictedPositionSigma over it alone |dp/dq_joint| there (as the prediction will use it).
  PredictionModel unit;
  BeyondRange fitted{joint, std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(), 1.0};
  for (int r : fit_rows_all) {
    fitted.lower_rad = std::min(fitted.lower_rad, obs[static_cast<size_t>(r)].q_rad[joint]);
    fitted.upper_rad = std::max(fitted.upper_rad, obs[static_cast<size_t>(r)].q_rad[joint]);
  }
  unit.beyond = {fitted};
  const std::vector<int> fit_rows = subset(fit_rows_all, internal::evenlyThinned(fit_rows_all.size(), options.region_fit_rows));
  const std::vector<Observation> FO = subset(obs, fit_rows), JO = subset(obs, judged_rows);
  const std::vector<Drivers> FD = subset(drivers, fit_rows), JD = subset(drivers, judged_rows);
  IdentifiabilityOptions io = options.identifiability;
  if (options.excitation_ratio > 0)
    for (const auto& d : excitationDeficits(model, start, fit.extensions, FO, FD, JO, JD, options.excitation_ratio))
      io.held.push_back(d.column);
  ExtendedFit ff;
  try {
    ff = fitExtended(model, start, FO, FD, fit.extensions, options.solver, io, &fit.params, &fit.extension_params);
  } catch (const std::invalid_argument&) {  // e.g. no row of a known backlash play state on this side
    *skipped = "a fold could not be fitted";
    return 0;
  }
  if (!ff.converged) {
    *skipped = "a fold's fit did not converge";
    return 0;
  }
  const double share = campaign_width_rad > 0 ? (fitted.upper_rad - fitted.lower_rad) / campaign_width_rad : 1.0;
  const PredictionModel pm = predictionModel(model, ff, FO, FD);
  const std::vector<Eigen::Vector3d> res = positionResiduals(model, ff, JO, JD);
  double side_max = 0;
  for (size_t i = 0; i < JO.size(); ++i) {
    Judged j;
    j.actual2 = res[i].squaredNorm();
    j.predicted2 = std::pow(predictedPositionSigma(model, ff, pm, JO[i].q_rad, JD[i]), 2);
    j.noise2 = 3.0 * pm.variance_factor_position * JO[i].sigma_position_m * JO[i].sigma_position_m;
    j.beyond_rad = fitted.beyondRad(JO[i].q_rad[joint]);
    j.width_share = share;
    if (j.beyond_rad > 0) j.gain2 = std::pow(predictedPositionSigma(model, ff, unit, JO[i].q_rad, JD[i]), 2);
    if (std::isfinite(j.actual2) && std::isfinite(j.predicted2) && j.variance(0, 0) > 0) rows->push_back(j);
    side_max = std::max(side_max, j.beyond_rad);
  }
  return side_max;
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
    const double width_rad = jt.beyond.upper_rad - jt.beyond.lower_rad;
    std::vector<Judged> rows;  // each fold's judged rows
    std::vector<size_t> judged_folds;  // the folds judged (regionFolds' order: the upper end, then the lower)
    std::string skipped;
    // The smaller of the two ends' farthest judged row; 0 when an end was not judged (`skipped` says why: one number
    // stands for both ends).
    double checked = std::numeric_limits<double>::infinity();
    const std::vector<internal::Fold> folds = internal::regionFolds(obs, e, options.region_joint_end);
    for (size_t k = 0; k < folds.size(); ++k) {
      std::string why;
      const double side_max = judgeFold(model, start, fit, obs, drivers, folds[k].first, folds[k].second, e.joint,
                                        width_rad, options, &rows, &why);
      if (!why.empty()) {
        skipped = why;
        continue;
      }
      checked = std::min(checked, side_max);
      ++jt.folds;
      judged_folds.push_back(k);
    }
    jt.judged_rows = static_cast<int>(rows.size());
    jt.beyond.checked_rad = std::isfinite(checked) && skipped.empty() ? checked : 0.0;
    char b[700];
    if (rows.empty()) {
      std::snprintf(b, sizeof b, "joint %d: not measured (%s)", e.joint + 1, skipped.c_str());
      out.text += (out.text.empty() ? "" : "\n") + std::string(b);
      out.joints.push_back(jt);
      continue;
    }
    jt.ratio_rms_without = jt.ratio_rms_with = ratioRms(rows, {});
    Form form;
    if (jt.ratio_rms_without > 1) {
      form = bestForm(rows, 0, 0);
      // Does the error beyond grow with the width of the range fitted? Each judged fold's fitted rows are folded
      // again at the same end (a model fitted on a narrower range, judged the same way); their judged rows and the
      // folds' together, the sigma scaled by (fitted width / the campaign's)^p: p 1 or 2 is kept only where it
      // explains them better than p 0 by a likelihood ratio test at 1 % (nll lower by chi2(1, 0.99) / 2). The sigma
      // is then the folds' own rows' (the nearest the campaign's width) with that p: carried from their width to the
      // campaign's by the law both levels show. Only where the folds' own rows err beyond their prediction, as above.
      std::vector<Judged> both = rows;
      for (size_t k : judged_folds) {
        const std::vector<Observation> FO = subset(obs, folds[k].first);
        const std::vector<Drivers> FD = subset(drivers, folds[k].first);
        const std::vector<internal::Fold> within = internal::regionFolds(FO, e, options.region_joint_end);
        std::string why;
        const size_t before = both.size();
        judgeFold(model, start, fit, FO, FD, within[k].first, within[k].second, e.joint, width_rad, options, &both, &why);
        if (why.empty()) ++jt.inner_folds;
        jt.inner_rows += static_cast<int>(both.size() - before);
      }
      double flat = 0, grown = 0;
      bestForm(both, 0, 0, &flat);
      const Form wide = bestForm(both, 1, 2, &grown);
      if (jt.inner_rows > 0 && wide.width_power > 0 && grown < flat - 6.635 / 2)
        form = bestForm(rows, wide.width_power, wide.width_power);  // sigma 0: width_power 0
    }
    jt.beyond.sigma_at_1_rad = form.sigma;
    jt.beyond.growth = form.growth;
    jt.width_power = form.width_power;
    jt.ratio_rms_with = ratioRms(rows, form);
    char judged[160];
    if (jt.beyond.checked_rad > 0)
      std::snprintf(judged, sizeof judged, "judged up to %.1f deg beyond [%.1f, %.1f] deg, farther it is extrapolated",
                    jt.beyond.checked_rad * 180 / kPi, jt.beyond.lower_rad * 180 / kPi, jt.beyond.upper_rad * 180 / kPi);
    else
      std::snprintf(judged, sizeof judged, "an end was not judged (%s): beyond [%.1f, %.1f] deg it is extrapolated",
                    skipped.c_str(), jt.beyond.lower_rad * 180 / kPi, jt.beyond.upper_rad * 180 / kPi);
    char grown[240] = "";
    if (jt.width_power > 0)
      std::snprintf(grown, sizeof grown, "; it grows with the width of the range fitted: the folds' fitted rows "
                    "folded again err less beyond their narrower range (%d rows), so the folds' error is carried to "
                    "the whole range as width^%d", jt.inner_rows, jt.width_power);
    if (jt.beyond.sigma_at_1_rad == 0)
      std::snprintf(b, sizeof b,
                    "joint %d: fitted short of either end of its range, the model predicts the rows beyond within its "
                    "uncertainty (%d rows, RMS ratio %.2f; %s)",
                    e.joint + 1, jt.judged_rows, jt.ratio_rms_without, judged);
    else
      std::snprintf(b, sizeof b,
                    "joint %d: fitted short of either end of its range, the model errs %.2fx its predicted uncertainty "
                    "on the rows beyond (%d rows); outside its range it is given a further joint error of %.3g deg%s "
                    "(ratio then %.2f%s; %s)",
                    e.joint + 1, jt.ratio_rms_without, jt.judged_rows, jt.beyond.sigma_at_1_rad * 180 / kPi,
                    jt.beyond.growthText(), jt.ratio_rms_with, grown, judged);
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
