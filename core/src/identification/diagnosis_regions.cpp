// The region check of diagnosis.hpp: chosen causes judged where their fit's rows never were.
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "calibration_internal.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/cause.hpp"

namespace cellcal {

std::vector<bool> regionSplit(const std::vector<Observation>& obs) {
  std::vector<bool> side(obs.size(), false);
  if (obs.size() < 8) return side;
  const auto n = static_cast<double>(obs.size());
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& o : obs) mean += o.measured_in_tracker.translation() / n;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& o : obs) {
    const Eigen::Vector3d d = o.measured_in_tracker.translation() - mean;
    cov += d * d.transpose() / n;
  }
  // Eigenvalues ascending: the last column is the direction of the largest spread.
  const Eigen::Vector3d axis = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvectors().col(2);
  std::vector<double> x(obs.size());
  for (size_t i = 0; i < obs.size(); ++i) x[i] = axis.dot(obs[i].measured_in_tracker.translation() - mean);
  std::vector<double> sorted = x;
  const auto mid = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
  std::nth_element(sorted.begin(), mid, sorted.end());
  for (size_t i = 0; i < obs.size(); ++i) side[i] = x[i] >= *mid;
  return side;
}

std::string regionSplitName(const Extension& cause) {
  const int j = cause.cause == Cause::kNone ? -1 : causeModel(cause.cause).regionJoint(cause);
  return j >= 0 ? "q" + std::to_string(j + 1) : "workspace";
}

std::vector<internal::Fold> internal::regionFolds(const std::vector<Observation>& obs, const Extension& cause,
                                                 double joint_end) {
  // By the workspace: each half fitted, the other judged. By a joint: the rows up to its angle's upper quantile
  // fitted and those beyond it judged, and the same at the lower end.
  if (regionSplitName(cause) == "workspace") {
    const std::vector<bool> side = regionSplit(obs);
    std::vector<int> half[2];
    for (size_t i = 0; i < obs.size(); ++i) half[side[i] ? 1 : 0].push_back(static_cast<int>(i));
    return {{half[0], half[1]}, {half[1], half[0]}};
  }
  std::vector<double> x;
  for (const auto& o : obs) x.push_back(o.q_rad[cause.joint]);
  return endFolds(x, joint_end);
}

std::vector<internal::Fold> internal::endFolds(const std::vector<double>& x, double end) {
  if (x.empty()) return {Fold{}, Fold{}};
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  const double lo = sorted[static_cast<size_t>(end * (sorted.size() - 1))];
  const double hi = sorted[static_cast<size_t>((1 - end) * (sorted.size() - 1))];
  Fold up, down;
  for (size_t i = 0; i < x.size(); ++i) {
    const int r = static_cast<int>(i);
    (x[i] > hi ? up.second : up.first).push_back(r);
    (x[i] < lo ? down.second : down.first).push_back(r);
  }
  return {up, down};
}

namespace {

// The judged rows of one model in a region check.
struct JudgedRows {
  std::vector<Eigen::Vector3d> residuals;
  std::vector<double> variance_m2;  // of the position error, from the fit's parameters' uncertainty
};

}  // namespace

std::vector<RegionCheck> checkRegions(const RobotModel& model, const Eigen::VectorXd& start,
                                      const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                      const ExtendedFit& geometric, const std::vector<SelectionStep>& steps,
                                      const DiagnosisOptions& options, std::string* note) {
  if (note) note->clear();
  auto thin = [&](const std::vector<int>& rows) { return subset(rows, internal::evenlyThinned(rows.size(), options.region_fit_rows)); };
  std::vector<Extension> kept;
  const ExtendedFit* kept_fit = &geometric;
  std::vector<RegionCheck> out;
  for (const SelectionStep& step : steps) {
    RegionCheck c;
    c.cause = step.added;
    c.split = regionSplitName(step.added);
    const std::vector<internal::Fold> folds = internal::regionFolds(obs, step.added, options.region_joint_end);
    c.judged_rows[0] = static_cast<int>(folds[0].second.size());
    c.judged_rows[1] = static_cast<int>(folds[1].second.size());
    bool enough = true;
    for (const auto& f : folds)
      enough = enough && static_cast<int>(f.first.size()) >= options.region_min_rows && f.second.size() >= 8;
    if (!enough) {
      if (note) {
        char b[240];
        std::snprintf(b, sizeof b,
                      "not run for %s: split by %s, it would fit %zu and %zu observations and judge %d and %d (at least "
                      "%d and 8 needed)",
                      extensionLabel(step.added).c_str(), c.split.c_str(), folds[0].first.size(), folds[1].first.size(),
                      c.judged_rows[0], c.judged_rows[1], options.region_min_rows);
        *note = b;
      }
      break;
    }
    // A model's judged rows, both folds together: their residuals, and what the fold's fit leaves uncertain there.
    auto judged = [&](const std::vector<Extension>& exts, const Eigen::VectorXd* warm, const Eigen::VectorXd* warm_ext) {
      JudgedRows out;
      for (const auto& fold : folds) {
        const std::vector<int> fit_rows = thin(fold.first);
        const std::vector<Observation> FO = subset(obs, fit_rows), JO = subset(obs, fold.second);
        const std::vector<Drivers> FD = subset(drivers, fit_rows), JD = subset(drivers, fold.second);
        IdentifiabilityOptions io = options.identifiability;
        if (options.excitation_ratio > 0)
          for (const auto& d : excitationDeficits(model, start, exts, FO, FD, JO, JD, options.excitation_ratio))
            io.held.push_back(d.column);
        const ExtendedFit fit = fitExtended(model, start, FO, FD, exts, options.solver, io, warm, warm_ext);
        const std::vector<Eigen::Vector3d> r = positionResiduals(model, fit, JO, JD);
        out.residuals.insert(out.residuals.end(), r.begin(), r.end());
        for (double s : estimatePositionSigmas(model, fit, FO, FD, JO, JD)) out.variance_m2.push_back(s * s);
      }
      return out;
    };
    const JudgedRows without = judged(kept, &kept_fit->params, kept.empty() ? nullptr : &kept_fit->extension_params);
    std::vector<Extension> exts = kept;
    exts.push_back(step.added);
    const JudgedRows with = judged(exts, &step.result.fit.params, &step.result.fit.extension_params);
    const internal::ResidualMeans m0 = internal::residualMeans(without.residuals), m1 = internal::residualMeans(with.residuals);
    c.mean_without_mm = m0.mean_mm;
    c.mean_with_mm = m1.mean_mm;
    c.sigma_without_mm = 1e3 * std::sqrt(mean(without.variance_m2));
    c.sigma_with_mm = 1e3 * std::sqrt(mean(with.variance_m2));
    // Row by row, each model's squared error less its fit's variance there: what its form gets wrong.
    std::vector<double> d(without.residuals.size());
    for (size_t i = 0; i < d.size(); ++i)
      d[i] = (without.residuals[i].squaredNorm() - without.variance_m2[i]) -
             (with.residuals[i].squaredNorm() - with.variance_m2[i]);
    c.gain_pct = 100.0 * mean(d) / m0.mse_m2;
    c.z = meanZ(d);
    c.transfers = !(c.gain_pct < 0 && c.z < -options.region_z);
    out.push_back(c);
    if (!c.transfers) break;
    kept = exts;
    kept_fit = &step.result.fit;
  }
  return out;
}

namespace {
// A geometric model's frames registered on `identification` as a carried model's are (closed form, then
// refineFrames with the kinematics held): compareCarried and compareWithNominal judge their models alike.
Eigen::VectorXd registeredAlike(const RobotModel& model, const Eigen::VectorXd& params,
                                const std::vector<Observation>& identification,
                                const std::vector<Drivers>& identification_drivers) {
  return refineFrames(model, registerFrames(model, params, identification).params, {}, Eigen::VectorXd(),
                      identification, identification_drivers).params;
}
}  // namespace

CarriedComparison compareCarried(const RobotModel& model, const ExtendedFit& extended, const Eigen::VectorXd& geometric_params,
                                 const std::vector<Observation>& identification,
                                 const std::vector<Drivers>& identification_drivers,
                                 const std::vector<Observation>& verification,
                                 const std::vector<Drivers>& verification_drivers, double z_limit, double min_gain) {
  if (geometric_params.size() != model.numParams()) throw std::invalid_argument("compareCarried: geometric_params has the wrong size");
  if (verification.empty()) throw std::invalid_argument("compareCarried: no verification rows");
  CarriedComparison c;
  c.extended = extended;
  c.geometric.params = registeredAlike(model, geometric_params, identification, identification_drivers);
  c.geometric.converged = true;
  c.geometric.estimated = extended.estimated;  // the frames
  const auto re = positionResiduals(model, c.extended, verification, verification_drivers);
  const auto rg = positionResiduals(model, c.geometric, verification, verification_drivers);
  c.mean_extended_mm = internal::residualMeans(re).mean_mm;
  c.mean_geometric_mm = internal::residualMeans(rg).mean_mm;
  c.extensions_transfer = !internal::improves(re, rg, z_limit, min_gain, &c.z);
  char b[400];
  const std::string label = modelLabel(extended.extensions);
  if (!c.extensions_transfer)
    std::snprintf(b, sizeof b,
                  "the carried extensions (%s) do not transfer to these rows: %.4f mm held-out mean against %.4f mm for "
                  "the campaign's geometric calibration carried the same way (%.1f standard errors worse)",
                  label.c_str(), c.mean_extended_mm, c.mean_geometric_mm, c.z);
  else
    std::snprintf(b, sizeof b,
                  "the carried extensions (%s) hold on these rows: %.4f mm held-out mean against %.4f mm for the "
                  "campaign's geometric calibration carried the same way (%.1f standard errors %s)",
                  label.c_str(), c.mean_extended_mm, c.mean_geometric_mm, std::abs(c.z),
                  c.z <= 0 ? "better" : "worse, within the limit");
  c.text = b;
  return c;
}

NominalComparison compareWithNominal(const RobotModel& model, const ExtendedFit& carried,
                                     const Eigen::VectorXd& nominal_params,
                                     const std::vector<Observation>& identification,
                                     const std::vector<Drivers>& identification_drivers,
                                     const std::vector<Observation>& verification,
                                     const std::vector<Drivers>& verification_drivers) {
  if (nominal_params.size() != model.numParams()) throw std::invalid_argument("compareWithNominal: nominal_params has the wrong size");
  if (verification.empty()) throw std::invalid_argument("compareWithNominal: no verification rows");
  NominalComparison c;
  c.nominal.params = registeredAlike(model, nominal_params, identification, identification_drivers);
  c.nominal.converged = true;
  c.nominal.estimated = carried.estimated;  // the frames
  const auto rc = positionResiduals(model, carried, verification, verification_drivers);
  const auto rn = positionResiduals(model, c.nominal, verification, verification_drivers);
  c.mean_carried_mm = internal::residualMeans(rc).mean_mm;
  c.mean_nominal_mm = internal::residualMeans(rn).mean_mm;
  c.z = internal::pairedZ(rc, rn);
  c.nominal_better = c.mean_nominal_mm < c.mean_carried_mm;
  return c;
}

}  // namespace cellcal
