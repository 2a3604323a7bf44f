// extensionTransfer (prediction.hpp): what a fit's extensions are worth where their data never were.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "calibration_internal.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/cause.hpp"

namespace cellcal {

std::vector<BeyondRange> ExtensionTransfer::beyond() const {
  std::vector<BeyondRange> out;
  for (const auto& j : joints) out.push_back(j.beyond);
  return out;
}

std::vector<DriverRange> ExtensionTransfer::beyondDrivers() const {
  std::vector<DriverRange> out;
  for (const auto& d : drivers) out.push_back(d.range);
  return out;
}

namespace {

// One judged row: actual squared position error, predicted model variance and noise variance (m^2), the range
// variable's distance beyond the fitted rows' range (a joint's angle, rad, or a driver in its unit), the squared gain
// from the sigma to the position (a joint: |dp/dq_joint|^2, m^2 / rad^2; a driver: 1, its sigma is in m) and the width
// of the range the judging fit was fitted on as a share of the campaign's (width_share^width_power scales the sigma:
// see below).
struct Judged {
  double actual2 = 0, predicted2 = 0, noise2 = 0, distance = 0, gain2 = 0, width_share = 1;
  double variance(double sigma, int growth, int width_power = 0) const {
    const double s = sigma * std::pow(distance, growth) * std::pow(width_share, width_power);
    return predicted2 + noise2 + (distance > 0 ? s * s * gain2 : 0.0);
  }
};

// A BeyondRange's or DriverRange's form: sigma (rad or m at 1 unit beyond, for a fit on the campaign's whole range),
// growth with the distance beyond the range and power of the fitted range's width.
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
// judged_rows. x: the range variable at each row of obs (joint's angle where joint >= 0, else an extension's driver).
// Appends their Judged rows (width_share: the fitted rows' range of x over `campaign_width`) and returns the farthest
// one's distance beyond that range; empty `skipped` when judged, else why not.
double judgeFold(const RobotModel& model, const Eigen::VectorXd& start, const CalibratedModel& fit,
                 const std::vector<Observation>& obs, const std::vector<Drivers>& drivers, const std::vector<double>& x,
                 const std::vector<int>& fit_rows_all, const std::vector<int>& judged_rows, int joint,
                 double campaign_width, const DiagnosisOptions& options, std::vector<Judged>* rows,
                 std::string* skipped) {
  skipped->clear();
  if (static_cast<int>(fit_rows_all.size()) < options.region_min_rows || judged_rows.size() < 8) {
    *skipped = joint >= 0 ? "too few rows at an end of the joint's range" : "too few rows at an end of the driver's range";
    return 0;
  }
  double lower = std::numeric_limits<double>::infinity(), upper = -lower;
  for (int r : fit_rows_all) {
    lower = std::min(lower, x[static_cast<size_t>(r)]);
    upper = std::max(upper, x[static_cast<size_t>(r)]);
  }
  // A joint: the fitted rows' range with a unit constant error beyond it, so that predictedPositionSigma over it alone
  // gives |dp/dq_joint| at a judged row (as the prediction will use it).
  PredictionModel unit;
  if (joint >= 0) unit.beyond = {BeyondRange{joint, lower, upper, 1.0, 0, 0, {}}};
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
  const double share = campaign_width > 0 ? (upper - lower) / campaign_width : 1.0;
  const PredictionModel pm = predictionModel(model, ff, FO, FD);
  const std::vector<Eigen::Vector3d> res = positionResiduals(model, ff, JO, JD);
  double side_max = 0;
  for (size_t i = 0; i < JO.size(); ++i) {
    Judged j;
    j.actual2 = res[i].squaredNorm();
    j.predicted2 = std::pow(predictedPositionSigma(model, ff, pm, JO[i].q_rad, JD[i]), 2);
    j.noise2 = 3.0 * pm.variance_factor_position * JO[i].sigma_position_m * JO[i].sigma_position_m;
    j.distance = distanceBeyond(x[static_cast<size_t>(judged_rows[i])], lower, upper);
    j.width_share = share;
    if (j.distance > 0)
      j.gain2 = joint >= 0 ? std::pow(predictedPositionSigma(model, ff, unit, JO[i].q_rad, JD[i]), 2) : 1.0;
    if (std::isfinite(j.actual2) && std::isfinite(j.predicted2) && j.variance(0, 0) > 0) rows->push_back(j);
    side_max = std::max(side_max, j.distance);
  }
  return side_max;
}

// What a range variable's folds say of a fit's extensions beyond it (see extensionTransfer in prediction.hpp): the
// variable's range over obs, how far beyond it the folds judged (0 where an end was not: `skipped` says why) and the
// form of the further error fitted on the judged rows. joint >= 0: x is that joint's angle.
struct RangeJudgement {
  FoldStats stats;
  double lower = 0, upper = 0;
  double checked_above = 0, checked_below = 0;  // each end's own (0 where it was not judged)
  Form form;
  std::string skipped;
  // One distance for both ends (a joint's BeyondRange): the smaller, 0 when an end was not judged.
  double checked() const { return skipped.empty() ? std::min(checked_above, checked_below) : 0.0; }
};
RangeJudgement judgeRange(const RobotModel& model, const Eigen::VectorXd& start, const CalibratedModel& fit,
                          const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                          const std::vector<double>& x, int joint, const DiagnosisOptions& options) {
  RangeJudgement out;
  FoldStats& st = out.stats;
  if (x.empty()) {
    out.skipped = "no rows";
    return out;
  }
  out.lower = *std::min_element(x.begin(), x.end());
  out.upper = *std::max_element(x.begin(), x.end());
  const double width = out.upper - out.lower;
  std::vector<Judged> rows;          // each fold's judged rows
  std::vector<size_t> judged_folds;  // the folds judged (endFolds' order: the upper end, then the lower)
  const std::vector<internal::Fold> folds = internal::endFolds(x, options.region_joint_end);
  for (size_t k = 0; k < folds.size(); ++k) {
    std::string why;
    const double side_max = judgeFold(model, start, fit, obs, drivers, x, folds[k].first, folds[k].second, joint, width,
                                      options, &rows, &why);
    if (!why.empty()) {
      out.skipped = why;
      continue;
    }
    (k == 0 ? out.checked_above : out.checked_below) = side_max;
    ++st.folds;
    judged_folds.push_back(k);
  }
  st.judged_rows = static_cast<int>(rows.size());
  if (rows.empty()) return out;
  st.ratio_rms_without = st.ratio_rms_with = ratioRms(rows, {});
  if (st.ratio_rms_without > 1) {
    out.form = bestForm(rows, 0, 0);
    // Does the error beyond grow with the width of the range fitted? Each judged fold's fitted rows are folded again
    // at the same end (a model fitted on a narrower range, judged the same way); their judged rows and the folds'
    // together, the sigma scaled by (fitted width / the campaign's)^p: p 1 or 2 is kept only where it explains them
    // better than p 0 by a likelihood ratio test at 1 % (nll lower by chi2(1, 0.99) / 2). The sigma is then the
    // folds' own rows' (the nearest the campaign's width) with that p: carried from their width to the campaign's by
    // the law both levels show. Only where the folds' own rows err beyond their prediction, as above.
    std::vector<Judged> both = rows;
    for (size_t k : judged_folds) {
      const std::vector<Observation> FO = subset(obs, folds[k].first);
      const std::vector<Drivers> FD = subset(drivers, folds[k].first);
      const std::vector<double> FX = subset(x, folds[k].first);
      const std::vector<internal::Fold> within = internal::endFolds(FX, options.region_joint_end);
      std::string why;
      const size_t before = both.size();
      judgeFold(model, start, fit, FO, FD, FX, within[k].first, within[k].second, joint, width, options, &both, &why);
      if (why.empty()) ++st.inner_folds;
      st.inner_rows += static_cast<int>(both.size() - before);
    }
    double flat = 0, grown = 0;
    bestForm(both, 0, 0, &flat);
    const Form wide = bestForm(both, 1, 2, &grown);
    if (st.inner_rows > 0 && wide.width_power > 0 && grown < flat - 6.635 / 2)
      out.form = bestForm(rows, wide.width_power, wide.width_power);  // sigma 0: width_power 0
  }
  st.width_power = out.form.width_power;
  st.ratio_rms_with = ratioRms(rows, out.form);
  return out;
}

// The line extensionTransfer gives a range: `name` ("joint 2", "link_deflection link 2 by gravity across link 2 (g)"),
// how far beyond its range it was judged ("judged up to 12.0 deg beyond [-20.0, 90.0] deg, ...") and the further
// error ("joint error of 0.02 deg"), as text.
std::string rangeText(const std::string& name, const RangeJudgement& r, const std::string& judged_text,
                      const std::string& error) {
  const char* judged = judged_text.c_str();
  char grown[240] = "";
  if (r.stats.width_power > 0)
    std::snprintf(grown, sizeof grown, "; it grows with the width of the range fitted: the folds' fitted rows "
                  "folded again err less beyond their narrower range (%d rows), so the folds' error is carried to "
                  "the whole range as width^%d", r.stats.inner_rows, r.stats.width_power);
  char b[1200];
  if (r.form.sigma == 0)
    std::snprintf(b, sizeof b,
                  "%s: fitted short of either end of its range, the model predicts the rows beyond within its "
                  "uncertainty (%d rows, RMS ratio %.2f; %s)",
                  name.c_str(), r.stats.judged_rows, r.stats.ratio_rms_without, judged);
  else
    std::snprintf(b, sizeof b,
                  "%s: fitted short of either end of its range, the model errs %.2fx its predicted uncertainty on the "
                  "rows beyond (%d rows); outside its range it is given a further %s (ratio then %.2f%s; %s)",
                  name.c_str(), r.stats.ratio_rms_without, r.stats.judged_rows, error.c_str(), r.stats.ratio_rms_with,
                  grown, judged);
  return b;
}

}  // namespace

ExtensionTransfer extensionTransfer(const RobotModel& model, const Eigen::VectorXd& start, const CalibratedModel& fit,
                                    const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                    const DiagnosisOptions& options) {
  if (obs.size() != drivers.size()) throw std::invalid_argument("extensionTransfer: one Drivers entry per observation");
  ExtensionTransfer out;
  auto say = [&](const std::string& line) { out.text += (out.text.empty() ? "" : "\n") + line; };
  const bool on_time = std::any_of(drivers.begin(), drivers.end(), [](const Drivers& d) { return d.thermal_is_time; });
  std::vector<int> joints;
  for (const Extension& e : fit.extensions) {
    const CauseModel& cause = causeModel(e.cause);
    const int joint = cause.regionJoint(e);
    if (joint < 0) {  // a driver bounds it, or nothing does
      std::vector<double> x;
      for (size_t i = 0; i < obs.size(); ++i) x.push_back(cause.rangeValue(model, fit.params, e, obs[i].q_rad, drivers[i]));
      const bool finite = !x.empty() && std::all_of(x.begin(), x.end(), [](double v) { return std::isfinite(v); });
      if (!finite || *std::max_element(x.begin(), x.end()) == *std::min_element(x.begin(), x.end())) {
        out.not_measured.push_back(extensionLabel(e) + (finite ? " (its driver is the same at every row)"
                                                               : " (its region is not a joint's range or a driver's)"));
        continue;
      }
      DriverTransfer dt;
      dt.range.extension = e;
      dt.range.label = cause.rangeLabel(e, on_time ? "stamp_s" : "temperature_c");
      const RangeJudgement r = judgeRange(model, start, fit, obs, drivers, x, -1, options);
      static_cast<FoldStats&>(dt) = r.stats;
      dt.range.lower = r.lower;
      dt.range.upper = r.upper;
      dt.range.checked_below = r.checked_below;
      dt.range.checked_above = r.checked_above;
      dt.range.sigma_at_1_m = r.form.sigma;
      dt.range.growth = r.form.growth;
      const std::string name = extensionLabel(e) + " by " + dt.range.label;
      char error[160];
      std::snprintf(error, sizeof error, "position error of %.3g mm%s", r.form.sigma * 1e3,
                    dt.range.growthText().c_str());
      std::string judged = dt.range.judgedText() + " (" + dt.range.rangeText() + "), farther it is extrapolated";
      if (!r.skipped.empty()) judged += "; an end was not judged: " + r.skipped;
      if (r.stats.judged_rows == 0)
        say(name + ": not measured (" + r.skipped + ")");
      else
        say(rangeText(name, r, judged, error));
      out.drivers.push_back(dt);
      continue;
    }
    if (std::find(joints.begin(), joints.end(), joint) != joints.end()) continue;
    joints.push_back(joint);
    std::vector<double> x;
    for (const auto& o : obs) x.push_back(o.q_rad[joint]);
    const RangeJudgement r = judgeRange(model, start, fit, obs, drivers, x, joint, options);
    JointTransfer jt;
    static_cast<FoldStats&>(jt) = r.stats;
    jt.beyond = BeyondRange{joint, r.lower, r.upper, r.form.sigma, r.form.growth, r.checked(), {}};
    jt.beyond.gaps_rad = rangeGaps(x, kBeyondGapShare * (r.upper - r.lower));
    const std::string name = "joint " + std::to_string(joint + 1);
    const bool gaps = !jt.beyond.gaps_rad.empty();
    char judged[600], error[120];
    if (jt.beyond.checked_rad > 0)
      std::snprintf(judged, sizeof judged, "judged up to %.1f deg beyond %s%s%s, farther it is extrapolated",
                    jt.beyond.checked_rad * 180 / kPi, jt.beyond.rangeText().c_str(), gaps ? " and into its gaps" : "",
                    jt.beyond.gapsText().c_str());
    else
      std::snprintf(judged, sizeof judged, "an end was not judged (%s): beyond %s%s%s it is extrapolated",
                    r.skipped.c_str(), jt.beyond.rangeText().c_str(), gaps ? " and in its gaps" : "",
                    jt.beyond.gapsText().c_str());
    std::snprintf(error, sizeof error, "joint error of %.3g deg%s", r.form.sigma * 180 / kPi, jt.beyond.growthText());
    if (r.stats.judged_rows == 0)
      say(name + ": not measured (" + r.skipped + ")");
    else
      say(rangeText(name, r, judged, error));
    out.joints.push_back(jt);
  }
  if (!out.not_measured.empty()) {
    std::string list;
    for (const auto& s : out.not_measured) list += (list.empty() ? "" : ", ") + s;
    say("not measured: " + list);
  }
  return out;
}

}  // namespace cellcal
