// calibrateCampaign with several set-ups: one kinematic model and one set of model-extension parameters (the robot's),
// a base and a tool frame per set-up (setups.hpp), errors per set-up. Every set-up registered and split on its own.
#include <algorithm>
#include <chrono>
#include <cstdint>

#include "campaign_internal.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/outliers.hpp"

namespace cellcal::internal {
namespace {

// kAuto with several set-ups: `diagnose` on each set-up's rows (as for one); the causes it chooses must be the same
// in every set-up (the model is the robot's), else the user names the model (ConfigError with each set-up's choice).
std::vector<Extension> causesNamedInEverySetUp(const CampaignProblem& problem) {
  std::vector<std::string> labels;
  std::vector<Extension> first;
  std::string first_label;
  bool same = true;
  for (size_t s = 0; s < problem.setups.size(); ++s) {
    const DiagnosisResult d = diagnoseForAuto(problem, problem.setups[s], "set-up " + std::to_string(s + 1));
    std::vector<Extension> chosen = d.best().fit.extensions;
    for (auto& e : chosen) e.time_constant_h = 0;  // searched per fit; the joint fit takes the cause itself
    std::sort(chosen.begin(), chosen.end(),
              [](const Extension& x, const Extension& y) { return extensionSpec(x) < extensionSpec(y); });
    const std::string label = chosen.empty() ? "geometric" : modelLabel(chosen);
    labels.push_back("set-up " + std::to_string(s + 1) + ": " + label);
    if (s == 0) {
      first = chosen;
      first_label = label;
    }
    same = same && label == first_label;
  }
  std::string all;
  for (const auto& l : labels) all += (all.empty() ? "" : "; ") + l;
  if (!same)
    throw ConfigError("--model auto: the set-ups name different models (" + all +
                      "); name the one to fit with --model (a usage error, exit 2)");
  return first;
}

}  // namespace

CampaignReport calibrateSetups(const CampaignProblem& problem) {
  CampaignReport rep;
  rep.several_setups = true;
  const auto& ins = problem.setups;
  const RobotModel& robot = ins[0].robot;
  SetupsProblem pr;
  pr.model = &robot;
  pr.identifiability.rank_tolerance = problem.identifiability.rank_tolerance;
  pr.identifiability.prior_sigma = problem.identifiability.prior_sigma;
  if (problem.model == CampaignModel::kAuto)
    pr.extensions = causesNamedInEverySetUp(problem);
  else if (problem.model == CampaignModel::kNamed)
    pr.extensions = problem.extensions;
  for (const auto& in : ins) {
    pr.starts.push_back(in.start);
    pr.observations.push_back(in.data.identification);
    pr.drivers.push_back(in.data.identification_drivers);
  }
  std::string why;
  if (!pr.IsValid(&why)) throw ConfigError("several set-ups: " + why + " (a usage error, exit 2)");
  const auto t1 = std::chrono::steady_clock::now();
  std::vector<OutlierScreen> ident_screens;
  const SetupsFit& fit = rep.setups_fit = fitSetupsRobust(pr, {}, problem.outliers, &ident_screens);
  rep.extensions = pr.extensions;
  rep.extension_names = extensionParamNames(robot, pr.extensions);
  rep.model_label = modelLabel(pr.extensions);
  rep.converged = fit.converged;
  rep.iterations = fit.iterations;
  rep.estimated = fit.estimated.size();
  rep.message = fit.message;
  rep.solve_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  const int f0 = robot.baseParam(FrameParam::kX), np = robot.numParams();
  // What the rows leave open: kinematic parameters (held for all set-ups) and frame parameters (per set-up).
  const auto& cand = robot.canonicalParams();
  for (int c : cand) {
    if (std::count(fit.estimated.begin(), fit.estimated.end(), c)) continue;
    rep.held_names.push_back(c < f0 ? robot.paramNameHuman(c) : "set-up1." + robot.paramNameHuman(c));
  }
  for (size_t s = 1; s < ins.size(); ++s)
    for (int k = 0; k < 12; ++k) {
      const int col = np + 12 * static_cast<int>(s - 1) + k;
      if (std::count(cand.begin(), cand.end(), f0 + k) && !std::count(fit.estimated.begin(), fit.estimated.end(), col))
        rep.held_names.push_back("set-up" + std::to_string(s + 1) + "." + robot.paramNameHuman(f0 + k));
    }
  for (size_t s = 0; s < ins.size(); ++s) {
    SetupReport sr;
    const ExtendedFit before = geometricFit(ins[s].start), after = setupFit(pr, fit, s);
    // Gross errors as for one set-up: the identification rows the fit left out, the verification rows judged against
    // the calibrated model, each set-up against its own robust scale; the figures without them.
    sr.errors = campaignErrors(robot, before, after, ins[s].data, ident_screens[s], problem.outliers);
    sr.rows_left_out_backlash = after.rows_left_out;
    sr.frames = fit.params[s].segment(f0, 12);
    const std::string u = unusableFit(sr.errors.verification_kept_before, sr.errors.verification_kept_after,
                                      sr.errors.identification_kept_after);
    if (!u.empty()) rep.unusable += (rep.unusable.empty() ? "" : "; ") + ("set-up " + std::to_string(s + 1) + ": " + u);
    rep.setups.push_back(std::move(sr));
  }
  if (rep.exitCode() != 0) return rep;
  // What a robot file saves: the kinematics with the frames of the set-up given last (the newest placement). Its
  // covariance is that of a fit on that set-up's rows alone (the other set-ups pin the kinematics further:
  // conservative).
  const size_t last = ins.size() - 1;
  ExtendedFit f = setupFit(pr, fit, last);
  f.estimated = fit.estimated_kinematic;
  f.estimated_extension = fit.estimated_extension;
  for (int c : fit.estimated) {
    const int k = c < np ? c - f0 : (c - np) % 12;
    const size_t owner = c < f0 ? SIZE_MAX : c < np ? 0 : static_cast<size_t>((c - np) / 12 + 1);
    if (owner == last) f.estimated.push_back(f0 + k);
  }
  std::sort(f.estimated.begin(), f.estimated.end());
  const auto& d = ins[last].data;
  const std::vector<int> kept = keptRows(static_cast<int>(d.identification.size()), ident_screens[last].rows);
  rep.calibration = robotCalibration(
      robot, f, predictionModel(robot, f, subset(d.identification, kept), subset(d.identification_drivers, kept)));
  rep.calibration.provenance = problem.provenance;
  rep.calibration.provenance.emplace_back("split", ins[last].split);
  rep.calibration.provenance.emplace_back("model", rep.model_label);
  rep.saved_params = fit.params[last];
  return rep;
}

}  // namespace cellcal::internal
