// `cellcal calibrate`: batch calibration of one measurement file.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>
#include <nlohmann/json.hpp>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {
namespace {

struct CalibrateArgs {
  InputArgs input;
  std::string json, model = "geometric", solver = "gn";
  double rank_tolerance = IdentifiabilityOptions{}.rank_tolerance;
};

ExtendedFit asFit(const Eigen::VectorXd& params) {
  ExtendedFit f;
  f.params = params;
  return f;
}

int runCalibrate(const CalibrateArgs& a) {
  const LoadedInput in = loadInput(a.input);
  const RobotModel& robot = in.robot;
  const auto& ident = in.data.identification;
  const auto& verify = in.data.verification;
  const Eigen::VectorXd& start = in.start;
  using Clock = std::chrono::steady_clock;
  const auto t1 = Clock::now();
  CalibrationProblem p{&robot, start, ident, std::nullopt, {}, {}};
  p.identifiability.rank_tolerance = a.rank_tolerance;
  p.outliers = outlierOptions(a.input);
  std::string why;
  if (!p.IsValid(&why)) throw std::runtime_error(why);
  const CalibrationResult r = a.solver == "lm" ? solveLevenbergMarquardt(p) : solveGaussNewton(p);
  ExtendedFit after = asFit(r.params);
  OutlierScreen ident_outliers = r.outliers;
  std::string model_label = "geometric";
  bool converged = r.converged;
  int iterations = r.iterations;
  size_t estimated = r.estimated.size();
  std::string message = r.message;
  if (a.model != "geometric") {
    if (a.model == "auto") {
      DiagnosisOptions o;
      o.identifiability = p.identifiability;
      o.outliers = p.outliers;
      const DiagnosisResult d = diagnose(robot, start, in.data, o);
      after = d.best().fit;
      ident_outliers = d.identification_outliers;
    } else {
      after = fitExtendedRobust(robot, start, ident, in.data.identification_drivers, parseModel(a.model, robot), {},
                                p.identifiability, &r.params, p.outliers, &ident_outliers);
    }
    model_label = after.extensions.empty() ? "geometric (auto: no cause found)" : modelLabel(after.extensions);
    converged = after.converged;
    iterations = after.iterations;
    estimated = after.estimated.size() + after.estimated_extension.size();
    message = after.message;
  }
  const auto t2 = Clock::now();
  const double reg_s = in.registration_s, solve_s = std::chrono::duration<double>(t2 - t1).count();
  const ExtendedFit before = asFit(start);
  const auto& idr = in.data.identification_drivers;
  const auto& vdr = in.data.verification_drivers;
  const ErrorStats ib = errorStats(robot, before, ident, idr), ia = errorStats(robot, after, ident, idr);
  const ErrorStats vb = errorStats(robot, before, verify, vdr), va = errorStats(robot, after, verify, vdr);
  // Gross errors among the verification rows, judged against the calibrated model, and the figures without them.
  const OutlierScreen verify_outliers = screenRows(robot, after, verify, vdr, p.outliers);
  const std::vector<int> vk = keptRows(static_cast<int>(verify.size()), verify_outliers.rows);
  std::vector<Observation> verify_kept;
  std::vector<Drivers> vdr_kept;
  for (int i : vk) {
    verify_kept.push_back(verify[static_cast<size_t>(i)]);
    vdr_kept.push_back(vdr[static_cast<size_t>(i)]);
  }
  const ErrorStats vbk = errorStats(robot, before, verify_kept, vdr_kept), vak = errorStats(robot, after, verify_kept, vdr_kept);
  std::printf("%s: %zu rows (%s split: %zu identify, %zu verify), %s, robot %s\n", a.input.data.c_str(),
              in.file.rows.size(), a.input.split.c_str(), ident.size(), verify.size(),
              in.measurementText().c_str(), robot.name.c_str());
  if (!a.input.no_register)
    std::printf("registration of base and tool frames: rms %.3f mm (%.1f ms)\n", in.registration_rms_mm, reg_s * 1e3);
  std::printf("calibration, model %s (%s): %s after %d iterations, %zu parameters estimated (%.1f ms)\n",
              model_label.c_str(), a.model == "geometric" && a.solver == "lm" ? "Levenberg-Marquardt" : "Gauss-Newton",
              converged ? "converged" : "NOT converged", iterations, estimated, solve_s * 1e3);
  if (!converged) std::printf("  solver: %s\n", message.c_str());
  std::printf("\n                 position mm: mean     rms     max   orientation deg: mean    rms     max\n");
  auto row = [](const char* name, const ErrorStats& s) {
    std::printf("  %-24s %8.4f %7.4f %7.4f %17.4f %7.4f %7.4f\n", name, s.mean_mm, s.rms_mm, s.max_mm, s.mean_deg,
                s.rms_deg, s.max_deg);
  };
  row("identification before", ib);
  row("identification after", ia);
  row("verification before", vb);
  row("verification after", va);
  if (!verify_outliers.rows.empty()) {
    row("  without gross errors", vbk);
    row("  without gross errors", vak);
  }
  std::printf("\n('before': nominal kinematics with the registered frames; 'after': every identifiable parameter)\n");
  if (!ident_outliers.rows.empty() || !verify_outliers.rows.empty()) {
    std::printf("gross errors (more than %.0f robust sigmas of %.4f mm per axis):\n", p.outliers.threshold,
                ident_outliers.sigma_position_m * 1e3);
    if (!ident_outliers.rows.empty())
      std::printf("  identification: %zu rows left out of the fit: %s\n", ident_outliers.rows.size(),
                  linesText(ident_outliers.rows, in.identification_lines).c_str());
    if (!verify_outliers.rows.empty())
      std::printf("  verification:   %zu rows: %s\n", verify_outliers.rows.size(),
                  linesText(verify_outliers.rows, in.verification_lines).c_str());
  }
  if (!r.identifiability.dropped.empty()) {
    std::printf("not identifiable from these data (held at their start value):");
    for (const auto& d : r.identifiability.dropped) std::printf(" %s", robot.paramName(d.index).c_str());
    std::printf("\n");
  }
  if (!after.estimated_extension.empty()) {
    std::printf("extension parameters:");
    for (int k : after.estimated_extension)
      std::printf(" %s=%.6g (sd %.2g)", after.extension_names[k].c_str(), after.extension_params[k],
                  after.extensionStddev(k));
    std::printf("\n");
  }
  if (!a.json.empty()) {
    nlohmann::json params = nlohmann::json::array();
    if (a.model == "geometric") {
      for (const auto& np : r.parameters(robot, start))
        params.push_back({{"name", np.name}, {"initial", np.initial}, {"value", np.value}, {"stddev", np.stddev},
                          {"estimated", np.estimated}});
    } else {  // SI names and values; stddev from the extended fit's covariance (reading sigmas)
      for (int i = 0; i < robot.numParams(); ++i) {
        const double sd = after.paramStddev(i);
        params.push_back({{"name", robot.paramName(i)}, {"initial", start[i]}, {"value", after.params[i]},
                          {"stddev", std::isnan(sd) ? nlohmann::json(nullptr) : nlohmann::json(sd)},
                          {"estimated", !std::isnan(sd)}});
      }
    }
    nlohmann::json ext = nlohmann::json::object(), ext_sd = nlohmann::json::object();
    for (int k : after.estimated_extension) {
      ext[after.extension_names[k]] = after.extension_params[k];
      ext_sd[after.extension_names[k]] = after.extensionStddev(k);
    }
    nlohmann::json j = {{"data", a.input.data}, {"robot", robot.name}, {"rows", in.file.rows.size()},
                        {"skipped_rows", in.file.skipped_rows}, {"split", a.input.split},
                        {"identification_rows", ident.size()}, {"verification_rows", verify.size()},
                        {"measurement", in.measurementJson()},
                        {"model", a.model}, {"model_fitted", model_label}, {"solver", a.solver},
                        {"converged", converged}, {"iterations", iterations},
                        {"registration_rms_mm", in.registration_rms_mm}, {"registration_time_s", reg_s},
                        {"solve_time_s", solve_s},
                        {"identification", {{"before", errorStatsJson(ib)}, {"after", errorStatsJson(ia)}}},
                        {"verification", {{"before", errorStatsJson(vb)}, {"after", errorStatsJson(va)}}},
                        {"verification_without_outliers", {{"before", errorStatsJson(vbk)}, {"after", errorStatsJson(vak)}}},
                        {"outliers", {{"identification", outliersJson(ident_outliers, in.identification_lines)},
                                      {"verification", outliersJson(verify_outliers, in.verification_lines)},
                                      {"threshold_robust_sigmas", p.outliers.threshold}}},
                        {"parameters", params}, {"extension_params", ext}, {"extension_stddev", ext_sd}};
    std::ofstream(a.json) << j.dump(2) << "\n";
  }
  return converged ? 0 : 3;
}

}  // namespace

Runner addCalibrateCommand(CLI::App& app) {
  auto a = std::make_shared<CalibrateArgs>();
  CLI::App* cmd = addSubcommand(app, "calibrate",
      "Batch geometric calibration of a measurement file (CSV v1): registers the base and tool frames, identifies every "
      "identifiable kinematic parameter (Gauss-Newton, or --solver lm) on the identification rows, and reports mean/RMS/max "
      "position and orientation errors on identification and verification rows, before and after. Split: "
      "'alternate' = even rows (0-based) identify, odd rows verify; 'halves' = first half identifies, second verifies",
      "  cellcal calibrate --robot config/robots/ur10.yaml --data m.csv --json calib.json\n  cellcal calibrate --robot R.yaml --data m.csv --model auto                   the model diagnose chooses\n  cellcal calibrate --robot R.yaml --data m.csv --model joint_compliance:2     a named extension\n",
      "  --data: a measurement file, CSV v1 (docs/measurement-csv.md); --robot: a robot file (docs/robot-file.md)\n");
  addInputOptions(cmd, a->input);
  cmd->add_option("--json", a->json, "write the results as JSON");
  cmd->add_option("--model", a->model,
                  "geometric | auto (the cause `diagnose` names) | a list of causes with 1-based joints, e.g. "
                  "backlash:2,joint_compliance:3 (thermal_drift alone: lengths only)")
      ->capture_default_str();
  cmd->add_option("--solver", a->solver, "gn (Gauss-Newton, default) | lm (Levenberg-Marquardt, Ceres; geometric model)")
      ->check(CLI::IsMember({"gn", "lm"}))
      ->capture_default_str();
  cmd->add_option("--rank-tolerance", a->rank_tolerance,
                  "a parameter is estimated only if its scaled Jacobian column leaves the span of the others by more "
                  "than this sine")
      ->capture_default_str();
  return [a] { return runCalibrate(*a); };
}

}  // namespace cellcal::cli
