// What `cellcal calibrate --json` writes of a campaign's report.
#include <algorithm>
#include <cmath>

#include "calibrate_report.hpp"
#include "diagnosis_output.hpp"

namespace cellcal::cli {
namespace {

using nlohmann::json;

json errorsJson(const CampaignErrors& e, double threshold, const CampaignInput& in) {
  return {{"identification", {{"before", errorStatsJson(e.identification_before)}, {"after", errorStatsJson(e.identification_after)}}},
          {"verification", {{"before", errorStatsJson(e.verification_before)}, {"after", errorStatsJson(e.verification_after)}}},
          {"verification_without_outliers",
           {{"before", errorStatsJson(e.verification_kept_before)}, {"after", errorStatsJson(e.verification_kept_after)}}},
          {"outliers", {{"identification", outliersJson(e.identification_outliers, in.identification_lines)},
                        {"verification", outliersJson(e.verification_outliers, in.verification_lines)},
                        {"threshold_robust_sigmas", threshold}}}};
}

json unusableJson(const std::string& u) { return u.empty() ? json(nullptr) : json(u); }

// The set-up change that begins a block found in a file (null for the first block, or a set-up not found so).
json blockChangeJson(const CampaignInput& in) {
  if (in.found_block < 2) return nullptr;
  return foundChangeJson(in.found_changes[static_cast<size_t>(in.found_block - 2)]);
}

json setupsJson(const CalibrateArgs& a, const CampaignProblem& problem, const CampaignReport& rep) {
  const auto& ins = problem.setups;
  const RobotModel& robot = ins[0].robot;
  const SetupsFit& fit = rep.setups_fit;
  const int f0 = robot.baseParam(FrameParam::kX);
  json per = json::array();
  for (size_t s = 0; s < ins.size(); ++s) {
    const CampaignInput& in = ins[s];
    json frames = json::object();
    for (int k = 0; k < 12; ++k) frames[robot.paramNameHuman(f0 + k)] = robot.toHuman(f0 + k, rep.setups[s].frames[k]);
    json j = {{"data", in.name}, {"rows", in.file.rows.size()}, {"measurement", in.measurementName()},
              {"registration_rms_mm", in.registration_rms_mm}, {"model_error_sigma", modelErrorJson(in)},
              {"rows_left_out_backlash", rep.setups[s].rows_left_out_backlash},
              {"found_setup_change", blockChangeJson(in)}};
    j.update(errorsJson(rep.setups[s].errors, problem.outliers.threshold, in));
    j["frames"] = frames;
    per.push_back(j);
  }
  json params = json::array();
  for (int i = 0; i < f0; ++i) {
    const bool est = std::count(fit.estimated_kinematic.begin(), fit.estimated_kinematic.end(), i) > 0;
    params.push_back({{"name", robot.paramNameHuman(i)}, {"initial", robot.toHuman(i, ins[0].start[i])},
                      {"value", robot.toHuman(i, fit.params[0][i])}, {"estimated", est}});
  }
  json ext = json::object();
  for (int k : fit.estimated_extension) ext[rep.extension_names[k]] = fit.extension_params[k];
  return {{"robot", robot.name}, {"setups", per}, {"parameters", params}, {"model", a.model},
          {"model_fitted", rep.model_label}, {"extension_params", ext}, {"converged", fit.converged},
          {"iterations", fit.iterations}, {"unusable", unusableJson(rep.unusable)}};
}

json identifiabilityJson(const RobotModel& robot, const Eigen::VectorXd& start, const IdentifiabilityReport& ir) {
  json gauge_held = json::array(), rank = json::array(), plausible = json::array();
  const std::vector<int> gauge = frameGauge(robot, start);
  for (const auto& d : ir.dropped) {
    if (std::binary_search(gauge.begin(), gauge.end(), d.index)) {
      gauge_held.push_back(robot.paramNameHuman(d.index));
      continue;
    }
    if (!d.below_prior) {
      rank.push_back(robot.paramNameHuman(d.index));
      continue;
    }
    plausible.push_back({{"name", robot.paramNameHuman(d.index)},
                         {"data_sigma", std::isfinite(d.data_sigma_si) ? json(std::abs(robot.toHuman(d.index, d.data_sigma_si)))
                                                                        : json(nullptr)},
                         {"plausible_sigma", std::abs(robot.toHuman(d.index, d.prior_sigma_si))}});
  }
  return {{"noise_scale", ir.noise_scale}, {"carried_by_frames", gauge_held}, {"not_identifiable", rank},
          {"held_within_plausible", plausible}};
}

// What the region folds of one joint or driver found (FoldStats), under `key`: `value` (the joint, or the extension).
json foldJson(const FoldStats& t, const char* key, const json& value) {
  return {{key, value}, {"folds", t.folds}, {"judged_rows", t.judged_rows}, {"ratio_rms_without", t.ratio_rms_without},
          {"ratio_rms_with", t.ratio_rms_with}, {"inner_folds", t.inner_folds}, {"inner_judged_rows", t.inner_rows},
          {"width_power", t.width_power}};
}

json beyondJson(const CalibrateArgs& a, const CampaignReport& rep) {
  json ranges = json::array();
  for (const auto& b : rep.beyond) {
    json gaps = json::array();
    for (const auto& [lo, hi] : b.gaps_rad) gaps.push_back({lo * 180 / kPi, hi * 180 / kPi});
    ranges.push_back({{"joint", b.joint + 1}, {"lower_deg", b.lower_rad * 180 / kPi}, {"upper_deg", b.upper_rad * 180 / kPi},
                      {"sigma_at_1_rad_deg", b.sigma_at_1_rad * 180 / kPi}, {"growth", b.growth},
                      {"checked_deg", b.checked_rad * 180 / kPi}, {"gaps_deg", gaps}});
  }
  json folds = json::array();
  if (rep.transfer)
    for (const auto& t : rep.transfer->joints)
      folds.push_back(foldJson(t, "joint", t.beyond.joint + 1));
  json driver_ranges = json::array();
  for (const auto& d : rep.beyond_drivers)
    driver_ranges.push_back({{"extension", extensionSpec(d.extension)}, {"driver", d.label}, {"lower", d.lower},
                             {"upper", d.upper}, {"sigma_at_1_mm", d.sigma_at_1_m * 1e3}, {"growth", d.growth},
                             {"checked_below", d.checked_below}, {"checked_above", d.checked_above}});
  if (rep.transfer)
    for (const auto& t : rep.transfer->drivers)
      folds.push_back(foldJson(t, "extension", extensionSpec(t.range.extension)));
  return {{"ranges", ranges}, {"driver_ranges", driver_ranges}, {"carried", a.frames_only}, {"folds", folds},
          {"not_measured", rep.transfer ? rep.transfer->not_measured : std::vector<std::string>{}},
          {"text", rep.transfer ? rep.transfer->text : ""}};
}

json residualMapJson(const CampaignReport& rep) {
  if (!rep.residual_map) return nullptr;
  const ResidualMap& map = *rep.residual_map;
  const ResidualMapCheck& c = rep.residual_map_check;
  std::vector<double> scales;
  for (Eigen::Index j = 0; j < map.lengthScales_rad().size(); ++j) scales.push_back(map.lengthScales_rad()[j] * 180 / kPi);
  return {{"rows", map.rows()}, {"fit_time_s", c.fit_time_s}, {"max_distance", map.maxDistance()},
          {"length_scales_deg", scales}, {"signal_sigma_mm", map.signalSigma_m() * 1e3},
          {"noise_sigma_mm", map.noiseSigma_m() * 1e3}, {"verification_rows_near", c.verification_rows_near},
          {"near_mean_with_mm", c.near_mean_with_mm}, {"near_mean_without_mm", c.near_mean_without_mm},
          {"near_sigma_mean_mm", c.near_sigma_mean_mm}, {"all_mean_with_mm", c.all_mean_with_mm},
          {"all_mean_without_mm", c.all_mean_without_mm}};
}

}  // namespace

// Tool frame parameters held at the robot file's values (frames only), each with the sigma the rows would give it
// (null: none).
json framesHeldJson(const RobotModel& robot, const CampaignReport& rep) {
  json held = json::array();
  for (const auto& [c, sigma] : rep.frames_held)
    held.push_back({{"name", robot.paramNameHuman(c)},
                    {"rows_sigma", std::isfinite(sigma) ? json(robot.toHuman(c, sigma)) : json(nullptr)}});
  return held;
}

json campaignJson(const CalibrateArgs& a, const CampaignProblem& problem, const CampaignReport& rep) {
  if (rep.several_setups) return setupsJson(a, problem, rep);
  const CampaignInput& in = problem.setups.front();
  const RobotModel& robot = in.robot;
  const ExtendedFit& after = rep.after;
  const PredictionModel& pm = rep.prediction;
  // Every model alike: names and values in mm and deg (the unit in the name), stddev from the fit's covariance
  // (reading sigmas), null where the parameter was not estimated.
  json params = json::array();
  for (int i = 0; i < robot.numParams(); ++i) {
    const double sd = after.paramStddev(i), saved = savedSigma(pm, i);
    params.push_back({{"name", robot.paramNameHuman(i)}, {"initial", robot.toHuman(i, in.start[i])},
                      {"value", robot.toHuman(i, after.params[i])},
                      {"stddev", std::isnan(sd) ? json(nullptr) : json(robot.toHuman(i, sd))},
                      {"stddev_saved", std::isnan(saved) ? json(nullptr) : json(robot.toHuman(i, saved))},
                      {"estimated", !std::isnan(sd)}});
  }
  json ext = json::object(), ext_sd = json::object();
  for (int k : after.estimated_extension) {
    ext[after.extension_names[k]] = after.extension_params[k];
    ext_sd[after.extension_names[k]] = after.extensionStddev(k);
  }
  const PredictionCheck& t = rep.check;
  const auto& c = rep.carried;
  json j = {{"data", a.input.data}, {"robot", robot.name}, {"rows", in.file.rows.size()},
            {"skipped_rows", in.file.skipped_rows}, {"split", a.input.split},
            {"identification_rows", in.data.identification.size()}, {"verification_rows", in.data.verification.size()},
            {"measurement", in.measurementName()}, {"model", a.model}, {"model_fitted", rep.model_label},
            {"region_check", rep.diagnosis ? regionCheckJson(*rep.diagnosis) : json(nullptr)},
            {"drift_check", rep.diagnosis ? driftCheckJson(*rep.diagnosis) : json(nullptr)}, {"solver", a.solver},
            {"converged", rep.converged}, {"iterations", rep.iterations},
            {"registration_rms_mm", in.registration_rms_mm}, {"model_error_sigma", modelErrorJson(in)},
            {"registration_note", in.registration_note.empty() ? json(nullptr) : json(in.registration_note)},
            {"setup_change", in.setup_hint.empty() ? json(nullptr)
                                                   : json{{"line", in.setup_change_line}, {"text", in.setup_hint}}},
            {"registration_time_s", in.registration_s}, {"solve_time_s", rep.solve_s},
            {"parameters", params}, {"extension_params", ext}, {"extension_stddev", ext_sd},
            {"held", heldJson(rep.held)}, {"identifiability", identifiabilityJson(robot, in.start, rep.geometric.identifiability)},
            {"prediction", json{{"identification_rms_mm", t.identification_rms_mm},
                                {"identification_max_mm", t.identification_max_mm},
                                {"verification_rms_mm", t.verification_rms_mm},
                                {"verification_max_mm", t.verification_max_mm},
                                {"variance_factor_position", pm.variance_factor_position},
                                {"variance_factor_orientation", pm.variance_factor_orientation},
                                {"actual_over_predicted_rms", t.ratio_rms},
                                {"verification_rows_outside_calibrated_region", t.extrapolated},
                                {"verification_rows_beyond_checked_range", t.beyond_checked}}},
            {"frames_variance_factor", a.frames_only ? json(rep.frames_variance_factor) : json(nullptr)},
            {"carried_extensions", c ? json{{"extensions", modelLabel(c->extended.extensions)},
                                            {"mean_extended_mm", c->mean_extended_mm},
                                            {"mean_geometric_mm", c->mean_geometric_mm},
                                            {"z", c->z},
                                            {"transfer", c->extensions_transfer},
                                            {"used", after.extensions.empty() ? "geometric" : "extended"},
                                            {"text", c->text}}
                                     : json(nullptr)},
            {"frames_held", framesHeldJson(robot, rep)},
            {"against_nominal", rep.against_nominal
                                    ? json{{"mean_carried_mm", rep.against_nominal->mean_carried_mm},
                                           {"mean_nominal_mm", rep.against_nominal->mean_nominal_mm},
                                           {"z", rep.against_nominal->z},
                                           {"used", rep.nominalDeployed() ? "nominal" : "carried"}}
                                    : json(nullptr)},
            {"beyond_data", beyondJson(a, rep)}, {"implausible", rep.implausible},
            {"residual_map", residualMapJson(rep)}, {"unusable", unusableJson(rep.unusable)}};
  j.update(errorsJson(rep.errors, problem.outliers.threshold, in));
  return j;
}

}  // namespace cellcal::cli
