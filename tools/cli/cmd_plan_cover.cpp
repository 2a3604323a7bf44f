// `cellcal plan cover`: which of a robot program's targets compensation with a calibrated robot file corrects, and
// the ones it passes through because the model's extensions were never judged there, as a program to measure
// (core/engine/compensation.hpp, compensateProgram).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/pose_plan.hpp"
#include "measurement_input.hpp"
#include "plan_common.hpp"

namespace cellcal::cli {
namespace {

struct PlanCoverArgs {
  std::string robot, config, robot_id, calibration, program, out;
  TrackerArgs tracker;
  double max_predicted_sigma_mm = 1, max_correction_mm = 5, around_deg = 5;
  int around = 5;
  std::uint64_t seed = 1;
  bool beyond_data = false;
};

void addCoverOptions(CLI::App& cmd, PlanCoverArgs& a) {
  addRobotOrCellOptions(cmd, a.robot, a.config, a.robot_id,
                        "the robot as its controller knows it (its nominal robot file or URDF): the program's targets "
                        "are the poses it commands");
  cmd.add_option("--calibration", a.calibration, "the calibrated robot file compensation applies (calibrate --save-robot)")
      ->required()
      ->check(CLI::ExistingFile);
  cmd.add_option("--program", a.program, "the robot program: CSV v1's joint columns (q1_rad..), pose optional")
      ->required()
      ->check(CLI::ExistingFile);
  cmd.add_option("--max-predicted-sigma-mm", a.max_predicted_sigma_mm,
                 "compensation.max_predicted_sigma_mm: a target whose predicted error is above it is passed through "
                 "(0: no guard; never-judged targets are then corrected with their error not known)")
      ->check(nonNegative())
      ->capture_default_str();
  cmd.add_option("--max-correction-mm", a.max_correction_mm, "compensation.max_correction_mm")->check(positive())->capture_default_str();
  addTrackerOptions(cmd, a.tracker);
  cmd.add_option("--around", a.around, "configurations to measure around each target to measure (0: the target alone)")
      ->check(CLI::Range(0, 100))
      ->capture_default_str();
  cmd.add_option("--around-deg", a.around_deg, "how far around: each joint within +- this of the target's")
      ->check(positive())
      ->capture_default_str();
  cmd.add_option("--seed", a.seed, "seed of the configurations around")->capture_default_str();
  cmd.add_flag("--beyond-data", a.beyond_data,
               "also measure the targets corrected beyond the data the extensions were fitted on, within the distance "
               "they were judged (their predicted error leans on what the region folds measured there)");
  cmd.add_option("--out", a.out, "the program's configurations passed through where the extensions were never judged "
                 "(with --beyond-data also those corrected beyond their data) and the tracker can measure, each followed by "
                 "those around it: joint columns (CSV v1) plus pose")
      ->required()
      ->check(outputFile());
}

// A calibrated robot file of the robot rf describes (robot_label names it in errors).
RobotFile loadCalibrationOf(const std::string& path, const RobotFile& rf, const std::string& robot_label) {
  RobotFile cal = loadRobotFile(path);
  if (!cal.calibration)
    throw ConfigError(path + ": not a calibrated robot file (no calibration section): calibrate --save-robot writes one");
  if (cal.model.numJoints() != rf.model.numJoints() || cal.model.numParams() != rf.model.numParams())
    throw ConfigError(path + ": another robot than " + robot_label + " (" + std::to_string(cal.model.numJoints()) +
                      " joints, " + std::to_string(cal.model.numParams()) + " parameters against " +
                      std::to_string(rf.model.numJoints()) + " and " + std::to_string(rf.model.numParams()) + ")");
  return cal;
}

// The controller: the nominal kinematics with the frames the calibration registered (the tracker frame its targets
// are in), as the compensation publisher sees a cell registered by that campaign.
RobotModel controllerOf(const RobotFile& rf, const RobotFile& cal) {
  RobotModel controller = rf.model;
  const int f0 = controller.baseParam(FrameParam::kX);
  controller.nominal.tail(controller.numParams() - f0) = cal.model.nominal.tail(controller.numParams() - f0);
  return controller;
}

int runPlanCover(const PlanCoverArgs& a) {
  std::string robot_label;
  const RobotFile rf = robotOrCellRobot(a.robot, a.config, a.robot_id, &robot_label);
  const RobotFile cal = loadCalibrationOf(a.calibration, rf, robot_label);
  const RobotModel controller = controllerOf(rf, cal);
  IdentifiedModel model(calibratedModel(cal));
  attachRobotFile(cal, model);
  MeasurementCsvOptions po;
  po.joints_only = true;
  const MeasurementFile program = readMeasurementCsv(a.program, rf.model, po);
  std::vector<Eigen::VectorXd> qs;
  for (const auto& row : program.rows) qs.push_back(row.q_rad);
  CompensationSettings settings;
  settings.max_predicted_sigma_m = a.max_predicted_sigma_mm * 1e-3;
  settings.max_correction_m = a.max_correction_mm * 1e-3;
  const ProgramCompensation pc = compensateProgram(controller, model, qs, settings);
  std::string tracker_from;
  const std::optional<TrackerSetup> tracker = trackerSetup(cal.model, a.tracker, &tracker_from);
  auto label = [&](size_t i) {
    return program.rows[i].pose ? *program.rows[i].pose : "row " + std::to_string(i + 1);
  };
  std::printf("plan cover: %zu configurations of %s compensated with %s (as the compensation publisher would: predicted "
              "error guard %.3g mm)\n", qs.size(), a.program.c_str(), a.calibration.c_str(), a.max_predicted_sigma_mm);
  std::vector<double> sigma;
  for (const auto& r : pc.results)
    if (r.applied && std::isfinite(r.predicted_sigma_position_m)) sigma.push_back(r.predicted_sigma_position_m * 1e3);
  std::sort(sigma.begin(), sigma.end());
  std::printf("  corrected: %d", pc.applied);
  if (!sigma.empty()) std::printf(" (predicted 1-sigma error %.3g-%.3g mm)", sigma.front(), sigma.back());
  std::printf("\n");
  // The never-judged targets, passed through (the guard on) or corrected blind (--max-predicted-sigma-mm 0): each
  // said, and the ones the tracker can measure kept to measure.
  std::vector<size_t> to_measure;
  int occluded = 0;
  // Target i said (its label, `what`, and why the tracker cannot measure it), and with `measure` kept to measure where
  // the tracker can.
  auto say = [&](size_t i, const std::string& what, bool measure) {
    const Visibility v = tracker ? visibility(cal.model, cal.model.nominal, qs[i], *tracker) : Visibility::kVisible;
    std::printf("    %s: %s%s\n", label(i).c_str(), what.c_str(),
                v == Visibility::kVisible ? "" : (std::string("; the tracker cannot measure it: ") + visibilityName(v)).c_str());
    if (!measure) return;
    if (v == Visibility::kVisible) to_measure.push_back(i);
    else ++occluded;
  };
  const int blind = static_cast<int>(std::count_if(pc.results.begin(), pc.results.end(),
                                                   [](const CompensationResult& r) { return r.applied && !r.unjudged.empty(); }));
  for (const bool applied : {true, false}) {
    const int n = applied ? blind : pc.unjudged;
    if (applied && n == 0) continue;
    std::printf(applied ? "  corrected with their error not known, where the model's extensions were never judged (the "
                          "guard off): %d\n"
                        : "  passed through where the model's extensions were never judged: %d\n", n);
    for (size_t i = 0; i < qs.size(); ++i) {
      const CompensationResult& r = pc.results[i];
      if (r.unjudged.empty() || r.applied != applied) continue;
      say(i, applied ? "corrected with its error not known: " + describe(r.unjudged) : describe(r), true);
    }
  }
  // Corrected beyond the extensions' data, within the judged distance: said, and measured with --beyond-data.
  std::printf("  of the corrected, beyond the data the model's extensions were fitted on (within the distance they "
              "were judged): %d%s\n", pc.beyond_data, pc.beyond_data && !a.beyond_data ? " (--beyond-data: measure them too)" : "");
  for (size_t i = 0; i < qs.size(); ++i) {
    const CompensationResult& r = pc.results[i];
    if (pc.beyond_data_at[i].empty()) continue;
    char sigma_text[48] = "";
    if (std::isfinite(r.predicted_sigma_position_m))
      std::snprintf(sigma_text, sizeof sigma_text, " (predicted %.3g mm)", r.predicted_sigma_position_m * 1e3);
    say(i, describe(pc.beyond_data_at[i]) + sigma_text, a.beyond_data);
  }
  std::sort(to_measure.begin(), to_measure.end());  // in the program's order
  std::printf("  passed through or refused otherwise: %d\n", pc.refused);
  for (size_t i = 0; i < qs.size(); ++i)
    if (!pc.results[i].applied && pc.results[i].unjudged.empty())
      std::printf("    %s: %s: %s\n", label(i).c_str(), outcomeName(pc.results[i].outcome), describe(pc.results[i]).c_str());
  // Each target, then the configurations around it (a single row is too little for the fit to follow the error
  // there: docs/planning.md).
  std::mt19937_64 rng(a.seed);
  std::vector<Eigen::VectorXd> qm;
  std::vector<std::string> names;
  int short_of = 0;
  for (size_t i : to_measure) {
    qm.push_back(qs[i]);
    names.push_back(label(i));
    const std::vector<Eigen::VectorXd> near =
        configurationsAround(cal.model, cal.model.nominal, qs[i], a.around, degToRad(a.around_deg), tracker, rng);
    short_of += a.around - static_cast<int>(near.size());
    for (size_t k = 0; k < near.size(); ++k) {
      qm.push_back(near[k]);
      names.push_back(label(i) + " around " + std::to_string(k + 1));
    }
  }
  std::vector<ProgramRow> measure;
  for (size_t k = 0; k < qm.size(); ++k) measure.push_back({&qm[k], names[k], 0});
  writeProgram(a.out,
               std::to_string(to_measure.size()) + " configurations of " + a.program + " that compensation with " +
                   a.calibration + (a.beyond_data ? " passes through where its extensions were never judged or corrects "
                                                      "beyond their data"
                                                    : " passes through where its extensions were never judged") +
                   ", each followed by " +
                   std::to_string(a.around) + " around it (cellcal plan cover): measure them and calibrate again with "
                   "the campaign's rows and --residual-map",
               rf.model.numJoints(), measure);
  std::printf("  to measure: %zu of those %d (%s%s), each with %d configurations within %.3g deg of its joints "
              "(%d fewer near a limit or out of sight): %zu rows -> %s: measured and calibrated again beside the "
              "campaign's rows with --residual-map, they lie within the data and the map carries what the model "
              "leaves there\n",
              to_measure.size(), pc.unjudged + blind + (a.beyond_data ? pc.beyond_data : 0), tracker ? "the tracker at " : "the tracker's place not known, not checked",
              tracker ? (tracker_from + (occluded ? ", " + std::to_string(occluded) + " it cannot measure" : "")).c_str() : "",
              a.around, a.around_deg, short_of, measure.size(), a.out.c_str());
  return 0;
}

}  // namespace

Runner addPlanCoverCommand(CLI::App& plan) { return addCommand(plan, "cover", addCoverOptions, runPlanCover); }

}  // namespace cellcal::cli
