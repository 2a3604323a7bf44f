// `cellcal calibrate`: batch calibration of one measurement file (or several set-ups): the campaign (campaign.hpp)
// from the options, its report printed (calibrate_text.cpp) and written (calibrate_json.cpp), the robot file saved.
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>

#include "calibrate_report.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"
#include "progress.hpp"

namespace cellcal::cli {
namespace {

void addOptions(CLI::App& cmd, CalibrateArgs& a) {
  addInputOptions(&cmd, a.input);
  cmd.add_option("--json", a.json, "write the results as JSON")->check(outputFile());
  cmd.add_option("--report", a.report,
                 "write report.md into this folder: the held-out errors before and after (a histogram, along each joint, "
                 "over the workspace; SVG by gnuplot) and the parameters with their sigmas (one set-up)");
  cmd.add_option("--model", a.model,
                 "geometric | auto (the cause `diagnose` names) | a list of causes with 1-based joints, e.g. "
                 "backlash:2,joint_compliance:3 (thermal_drift alone: lengths only)")
      ->capture_default_str();
  cmd.add_option("--solver", a.solver, "gn (Gauss-Newton, default) | lm (Levenberg-Marquardt, Ceres; the geometric fit of one set-up)")
      ->check(CLI::IsMember({"gn", "lm"}))
      ->capture_default_str();
  cmd.add_option("--save-robot", a.save_robot,
                 "write the calibrated model as a robot file: identified kinematics, frames, extensions, the covariance "
                 "and where it came from (not written when the exit status is not 0)")->check(outputFile());
  cmd.add_flag("--frames-only", a.frames_only,
               "keep the robot file's kinematics and extensions (e.g. a calibrated robot file) and register only the "
               "base and tool frames on the identification rows: the tracker or the target was moved. Judged against "
               "the kinematics the calibration started from, registered alike: where those do better, they are used");
  cmd.add_flag("--keep-extensions", a.keep_extensions,
               "--frames-only: keep the robot file's model as it is: its extensions where they do not transfer to these "
               "rows (by default the same campaign's geometric calibration, saved beside them, is used instead), and "
               "the model where its nominal kinematics do better (exit 4: not to be deployed)");
  cmd.add_flag("--residual-map", a.residual_map,
               "learn what the calibrated model leaves at the identification rows (a Gaussian process over the joints, "
               "residual_map.hpp) and judge it on the verification rows: applied only within "
               "--residual-map-distance length scales of an identification row, never beyond");
  cmd.add_option("--residual-map-distance", a.residual_map_distance,
                 "the residual map corrects only this near an identification row (in its fitted length scales)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd.add_flag("--no-region-check", a.no_region_check,
               "--model auto: keep every cause the selection chose; by default each is fitted again on one half of the "
               "workspace and judged on the other, and one that does not lower the error there is left out");
  cmd.add_option("--excitation-ratio", a.excitation_ratio,
                 "hold (and name) a parameter whose excitation on the identification rows is below this fraction of "
                 "its largest on a verification row; 0: off")
      ->check(CLI::Range(0.0, 0.99))
      ->capture_default_str();
  cmd.add_option("--rank-tolerance", a.rank_tolerance,
                 "a parameter is estimated only if its scaled Jacobian column leaves the span of the others by more "
                 "than this sine")
      ->capture_default_str();
}

// Exit 3 (not converged) or 4 (not usable) with what was not written; 0 to go on.
int failedExit(const CampaignReport& r, const std::string& save_robot) {
  if (!r.converged) {
    if (!save_robot.empty()) std::printf("%s not written: the solver did not converge\n", save_robot.c_str());
    return 3;
  }
  if (!r.unusable.empty()) {
    std::printf("not usable: %s (exit 4)\n", r.unusable.c_str());
    if (!save_robot.empty()) std::printf("%s not written\n", save_robot.c_str());
    return 4;
  }
  return 0;
}

// Where the saved calibration came from: first in its provenance.
std::vector<std::pair<std::string, std::string>> provenanceOf(const CalibrateArgs& a, const CampaignProblem& p) {
  if (p.setups.size() == 1)
    return {{"date_utc", utcNow()},
            {"tool", a.frames_only ? "cellcal calibrate --frames-only" : "cellcal calibrate"},
            {"robot_file", a.input.robot},
            {"data_file", a.input.data},
            {"data_sha256", fileSha256(a.input.data)}};
  std::string all;
  for (const auto& in : p.setups) all += (all.empty() ? "" : ", ") + in.name;
  const std::string& last = p.setups.back().name;
  return {{"date_utc", utcNow()},        {"tool", "cellcal calibrate (several set-ups)"},
          {"robot_file", a.input.robot}, {"data_files", all},
          {"data_sha256", fileSha256(p.setups.back().path)}, {"frames_of", last}};
}

int runCalibrate(const CalibrateArgs& a) {
  CampaignProblem p;
  p.setups = loadSetups(a.input);  // --data given again, or a file with a setup column
  const bool several = p.setups.size() > 1;
  // Set-ups found in a file without a setup column: said with the usage error.
  const std::string found = foundSetupsText(p.setups.front());
  const std::string why = found.empty() ? " (a usage error, exit 2)" : ": " + found + " (a usage error, exit 2)";
  if (several && a.frames_only) throw ConfigError("--frames-only takes one set-up" + why);
  if (several && !a.report.empty()) throw ConfigError("--report takes one set-up" + why);
  if (several && a.solver == "lm")
    throw ConfigError("--solver lm takes one set-up: several set-ups are fitted by Gauss-Newton" + why);
  if (a.frames_only && a.model != "geometric")
    throw std::runtime_error("--frames-only keeps the robot file's model: no --model");
  const RobotModel& robot = p.setups.front().robot;
  p.model = a.model == "geometric" ? CampaignModel::kGeometric
            : a.model == "auto"    ? CampaignModel::kAuto
                                   : CampaignModel::kNamed;
  if (p.model == CampaignModel::kNamed) p.extensions = parseModel(a.model, robot);
  p.solver = a.solver == "lm" ? CampaignSolver::kLevenbergMarquardt : CampaignSolver::kGaussNewton;
  p.identifiability.rank_tolerance = a.rank_tolerance;
  p.identifiability.prior_sigma = plausibleRanges(a.input, robot);
  p.outliers = outlierOptions(a.input);
  p.excitation_ratio = a.excitation_ratio;
  p.region_check = !a.no_region_check;
  p.frames_only = a.frames_only;
  p.keep_extensions = a.keep_extensions;
  p.residual_map = a.residual_map;
  p.residual_map_options.max_distance = a.residual_map_distance;
  if (!a.save_robot.empty()) p.provenance = provenanceOf(a, p);
  // --model auto: tens of fits on a large file; a bar per stage (drawn only on a terminal).
  std::unique_ptr<ProgressBar> bar;
  std::string stage_shown = "\n";
  p.progress = [&](const std::string& stage, int done, int total) {
    if (stage != stage_shown) {
      stage_shown = stage;
      bar = std::make_unique<ProgressBar>("calibrate --model auto" + (stage.empty() ? "" : ", " + stage));
    }
    bar->update(static_cast<double>(done) / total, std::to_string(done) + "/" + std::to_string(total) + " fits");
  };
  const CampaignReport r = calibrateCampaign(p);
  bar.reset();
  printCampaignReport(a, p, r);
  if (!a.json.empty()) std::ofstream(a.json) << campaignJson(a, p, r).dump(2) << "\n";
  if (!several) std::printf("%s\n", recommendationText(r).c_str());
  if (!a.report.empty() && r.converged) {
    writeCalibrationReport(a.report, a, p, r);
    std::printf("report: %s/report.md\n", a.report.c_str());
  }
  if (const int code = failedExit(r, a.save_robot)) return code;
  if (!a.save_robot.empty()) {
    const CampaignInput& in = several ? p.setups.back() : p.setups.front();
    std::string comment;
    if (several) {  // the set-ups as the provenance names them (provenanceOf)
      comment = "Calibrated " + robot.name + ": written by `cellcal calibrate` from " + std::to_string(p.setups.size()) +
                " set-ups (" + r.calibration.provenanceValue("data_files") + "); base and tool frames of " + in.name;
    } else {
      comment = "Calibrated " + robot.name + ": written by `cellcal calibrate" + (a.frames_only ? " --frames-only" : "") +
                "` from " + a.input.data + " (docs/robot-file.md, calibrated robot files)";
    }
    saveRobotFile(a.save_robot, robot.withParams(r.saved_params), &r.calibration, comment, &p.setups.front().source);
    if (several)
      std::printf("calibrated robot file: %s (frames of set-up %zu)\n", a.save_robot.c_str(), p.setups.size());
    else
      std::printf("calibrated robot file: %s\n", a.save_robot.c_str());
  }
  return 0;
}

}  // namespace

Runner addCalibrateCommand(CLI::App& app) { return addCommand(app, "calibrate", addOptions, runCalibrate); }

}  // namespace cellcal::cli
