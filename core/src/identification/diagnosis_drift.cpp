// The drift check of diagnosis.hpp: a drift diagnose finds judged against the base frame drifting with the same driver.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "calibration_internal.hpp"
#include "cellcal/core/identification/diagnosis.hpp"

namespace cellcal {

const char* driftOutcomeName(DriftCheck::Outcome o) {
  switch (o) {
    case DriftCheck::Outcome::kNotRun: return "not_run";
    case DriftCheck::Outcome::kToldApart: return "told_apart";
    case DriftCheck::Outcome::kAlike: return "alike";
    case DriftCheck::Outcome::kFrameDriftBetter: return "frame_drift_better";
    case DriftCheck::Outcome::kBoth: return "both";
    case DriftCheck::Outcome::kFrameDriftExplains: return "frame_drift_explains";
    case DriftCheck::Outcome::kNotAFrameDrift: return "not_a_frame_drift";
  }
  return "?";
}

DriftCheck checkDrift(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& identification,
                      const std::vector<Drivers>& identification_drivers, const std::vector<Observation>& verification,
                      const std::vector<Drivers>& verification_drivers, bool has_thermal, const CandidateResult& best,
                      const DriverStructure* structure_left, const DiagnosisOptions& options) {
  DriftCheck check;
  if (!options.drift_check || !has_thermal || identification.empty() || verification.empty()) return check;
  const std::vector<Extension>& chosen = best.fit.extensions;
  const bool drift_chosen = std::any_of(chosen.begin(), chosen.end(), [](const Extension& e) { return e.cause == Cause::kThermalDrift; });
  const bool time_left = structure_left && (structure_left->driver == "time" || structure_left->driver == "thermal");
  if (!drift_chosen && !time_left) return check;
  check.chosen = chosen;
  IdentifiabilityOptions io = options.identifiability;
  for (const auto& d : best.held)
    if (d.column < model.numParams()) io.held.push_back(d.column);  // kinematic holds only: extension columns move
  auto fit = [&](const std::vector<Extension>& exts) {
    return fitExtended(model, start, identification, identification_drivers, exts, options.solver, io, &best.fit.params);
  };
  auto residuals = [&](const ExtendedFit& f) { return positionResiduals(model, f, verification, verification_drivers); };
  auto mean_mm = [](const std::vector<Eigen::Vector3d>& r) { return internal::residualMeans(r).mean_mm; };
  // `b` adds to `a`: z above parsimony_z (one comparison, not a choice among many as in the selection, which asks
  // min_z) and a gain above min_gain.
  auto adds = [&](const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b, double* z) {
    return internal::improves(a, b, options.parsimony_z, options.min_gain, z);
  };
  const Extension frame{Cause::kFrameDrift, -1};
  const std::vector<Eigen::Vector3d> r_chosen = residuals(best.fit);
  check.mean_chosen_mm = mean_mm(r_chosen);
  char b[700];
  if (!drift_chosen) {
    std::vector<Extension> with = chosen;
    with.push_back(frame);
    const ExtendedFit f = fit(with);
    check.alternative = f.extensions;
    const std::vector<Eigen::Vector3d> r = residuals(f);
    check.mean_alternative_mm = mean_mm(r);
    if (adds(r_chosen, r, &check.z_frame)) {
      check.outcome = DriftCheck::Outcome::kFrameDriftExplains;
      std::snprintf(b, sizeof b,
                    "the structure against %s is (mostly) a drift of the base frame, the robot in the tracker's frame (the "
                    "robot or the tracker moving in the cell, or the tracker's scale drifting): a frame drift lowers the "
                    "held-out mean from %.4f to %.4f mm (%.1f standard errors); check the mounts and the tracker, and "
                    "register the frames again (calibrate --frames-only)",
                    structure_left->driver.c_str(), check.mean_chosen_mm, check.mean_alternative_mm, check.z_frame);
    } else {
      check.outcome = DriftCheck::Outcome::kNotAFrameDrift;
      std::snprintf(b, sizeof b,
                    "the structure against %s is not a drift of the base frame either: that leaves %.4f mm against "
                    "%.4f mm (%+.1f standard errors)",
                    structure_left->driver.c_str(), check.mean_alternative_mm, check.mean_chosen_mm, check.z_frame);
    }
    check.text = b;
    return check;
  }
  // The frame drift instead of the drifts, and beside them.
  std::vector<Extension> instead, both = chosen;
  std::string drifts;
  for (const Extension& e : chosen) {
    if (e.cause != Cause::kThermalDrift) instead.push_back(e);
    else drifts += (drifts.empty() ? "" : " + ") + extensionLabel(e);
  }
  instead.push_back(frame);
  both.push_back(frame);
  const ExtendedFit f_instead = fit(instead), f_both = fit(both);
  check.alternative = f_instead.extensions;
  check.both = f_both.extensions;
  const std::vector<Eigen::Vector3d> r_instead = residuals(f_instead), r_both = residuals(f_both);
  check.mean_alternative_mm = mean_mm(r_instead);
  check.mean_both_mm = mean_mm(r_both);
  const bool drift_adds = adds(r_instead, r_both, &check.z_drift);
  const bool frame_adds = adds(r_chosen, r_both, &check.z_frame);
  if (drift_adds && !frame_adds) {
    check.outcome = DriftCheck::Outcome::kToldApart;
    std::snprintf(b, sizeof b,
                  "%s is told from a drift of the base frame: that alone leaves %.4f mm against %.4f mm, and %.4f mm "
                  "beside it (%.1f standard errors from the drift, %+.1f from the frame)",
                  drifts.c_str(), check.mean_alternative_mm, check.mean_chosen_mm, check.mean_both_mm, check.z_drift,
                  check.z_frame);
  } else if (!drift_adds && !frame_adds) {
    check.outcome = DriftCheck::Outcome::kAlike;
    std::snprintf(b, sizeof b,
                  "%s cannot be told from a drift of the base frame (the robot or the tracker moving in the cell): that "
                  "leaves %.4f mm against %.4f mm, and neither adds to the other; a thermometer on the robot or a check "
                  "of the mounts decides",
                  drifts.c_str(), check.mean_alternative_mm, check.mean_chosen_mm);
  } else if (!drift_adds) {
    check.outcome = DriftCheck::Outcome::kFrameDriftBetter;
    std::snprintf(b, sizeof b,
                  "the drift looks like the base frame's rather than %s: a frame drift leaves %.4f mm against %.4f mm "
                  "(%.1f standard errors better with it, %+.1f with the drift beside it); the robot or the tracker "
                  "moved in the cell: check their mounts and register the frames again (calibrate --frames-only) "
                  "rather than model it",
                  drifts.c_str(), check.mean_alternative_mm, check.mean_chosen_mm, check.z_frame, check.z_drift);
  } else {
    check.outcome = DriftCheck::Outcome::kBoth;
    std::snprintf(b, sizeof b,
                  "besides %s the base frame drifts too (the robot or the tracker moving in the cell): with both "
                  "%.4f mm against %.4f mm (%.1f standard errors); check the mounts",
                  drifts.c_str(), check.mean_both_mm, check.mean_chosen_mm, check.z_frame);
  }
  check.text = b;
  return check;
}

}  // namespace cellcal
