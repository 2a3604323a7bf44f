// `cellcal calibrate`: batch calibration of one measurement file; `cellcal import ipa`: the ipa UR10 series to CSV v1.
#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cellcal/core/calibration.hpp"
#include "cellcal/core/ipa_dataset.hpp"
#include "cellcal/core/kinematics.hpp"
#include "cellcal/core/measurement_csv.hpp"
#include "cellcal/core/registration.hpp"
#include "cellcal/core/robot_yaml.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

struct ErrorStats {
  double mean_mm = 0, rms_mm = 0, max_mm = 0, mean_deg = 0, rms_deg = 0, max_deg = 0;
  int oriented = 0;
};

ErrorStats errorStats(const RobotModel& m, const Eigen::VectorXd& p, const std::vector<Observation>& obs) {
  KinematicsData d(m);
  ErrorStats s;
  for (const auto& o : obs) {
    const Pose T = forwardKinematics(m, d, p, o.q_rad);
    const double e = (o.measured_in_tracker.translation() - T.translation()).norm() * 1e3;
    s.mean_mm += e;
    s.rms_mm += e * e;
    s.max_mm = std::max(s.max_mm, e);
    if (o.kind == MeasurementKind::kPose6D) {
      const double a = logSO3(o.measured_in_tracker.linear() * T.linear().transpose()).norm() * 180 / kPi;
      s.mean_deg += a;
      s.rms_deg += a * a;
      s.max_deg = std::max(s.max_deg, a);
      ++s.oriented;
    }
  }
  const double n = std::max<double>(1, obs.size());
  s.mean_mm /= n;
  s.rms_mm = std::sqrt(s.rms_mm / n);
  if (s.oriented) {
    s.mean_deg /= s.oriented;
    s.rms_deg = std::sqrt(s.rms_deg / s.oriented);
  }
  return s;
}

nlohmann::json toJson(const ErrorStats& s) {
  nlohmann::json j = {{"mean_mm", s.mean_mm}, {"rms_mm", s.rms_mm}, {"max_mm", s.max_mm}};
  if (s.oriented) j.update({{"mean_deg", s.mean_deg}, {"rms_deg", s.rms_deg}, {"max_deg", s.max_deg}});
  return j;
}

struct CalibrateArgs {
  std::string robot, data, json, model = "geometric", split = "alternate", solver = "gn";
  double sigma_position_mm = 0.025, sigma_orientation_deg = 0.01, rank_tolerance = IdentifiabilityOptions{}.rank_tolerance;
  bool position_only = false, skip_bad_rows = false, no_register = false;
};

int runCalibrate(const CalibrateArgs& a) {
  if (a.model != "geometric")
    throw std::runtime_error("--model " + a.model + ": only 'geometric' so far (extended models come with `cellcal diagnose`)");
  const RobotModel robot = loadRobotModel(a.robot);
  MeasurementCsvOptions mo;
  mo.skip_bad_rows = a.skip_bad_rows;
  const MeasurementFile file = readMeasurementCsv(a.data, robot, mo);
  for (const auto& w : file.warnings) std::fprintf(stderr, "skipped: %s\n", w.c_str());
  for (const auto& c : file.ignored_columns) std::fprintf(stderr, "%s: column '%s' ignored\n", a.data.c_str(), c.c_str());
  const MeasurementKind kind = a.position_only ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
  std::vector<Observation> ident, verify;
  for (size_t i = 0; i < file.rows.size(); ++i) {
    const Observation o = toObservation(file.rows[i], kind, a.sigma_position_mm * 1e-3, a.sigma_orientation_deg * kPi / 180);
    const bool to_verify = a.split == "alternate" ? (i % 2 == 1) : (i >= file.rows.size() / 2);
    (to_verify ? verify : ident).push_back(o);
  }
  if (ident.size() < 8 || verify.empty()) throw std::runtime_error(a.data + ": too few rows (" + std::to_string(file.rows.size()) + ")");
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  Eigen::VectorXd start = robot.nominal;
  double reg_rms = std::nan("");
  if (!a.no_register) {
    const RegistrationResult reg = registerFrames(robot, robot.nominal, ident);
    start = reg.params;
    reg_rms = reg.rms_position_m * 1e3;
  }
  const auto t1 = Clock::now();
  CalibrationProblem p{&robot, start, ident, std::nullopt, {}};
  p.identifiability.rank_tolerance = a.rank_tolerance;
  std::string why;
  if (!p.IsValid(&why)) throw std::runtime_error(why);
  const CalibrationResult r = a.solver == "lm" ? solveLevenbergMarquardt(p) : solveGaussNewton(p);
  const auto t2 = Clock::now();
  const double reg_s = std::chrono::duration<double>(t1 - t0).count(), solve_s = std::chrono::duration<double>(t2 - t1).count();
  const ErrorStats ib = errorStats(robot, start, ident), ia = errorStats(robot, r.params, ident);
  const ErrorStats vb = errorStats(robot, start, verify), va = errorStats(robot, r.params, verify);
  std::printf("%s: %zu rows (%s split: %zu identify, %zu verify), %s, robot %s\n", a.data.c_str(), file.rows.size(),
              a.split.c_str(), ident.size(), verify.size(), kind == MeasurementKind::kPose6D ? "6D" : "position only",
              robot.name.c_str());
  if (!a.no_register) std::printf("registration of base and tool frames: rms %.3f mm (%.1f ms)\n", reg_rms, reg_s * 1e3);
  std::printf("geometric calibration (%s): %s after %d iterations, %zu parameters estimated (%.1f ms)\n",
              a.solver == "lm" ? "Levenberg-Marquardt" : "Gauss-Newton", r.converged ? "converged" : "NOT converged", r.iterations, r.estimated.size(), solve_s * 1e3);
  if (!r.converged) std::printf("  solver: %s\n", r.message.c_str());
  std::printf("\n                 position mm: mean     rms     max   orientation deg: mean    rms     max\n");
  auto row = [](const char* name, const ErrorStats& s) {
    std::printf("  %-24s %8.4f %7.4f %7.4f %17.4f %7.4f %7.4f\n", name, s.mean_mm, s.rms_mm, s.max_mm, s.mean_deg,
                s.rms_deg, s.max_deg);
  };
  row("identification before", ib);
  row("identification after", ia);
  row("verification before", vb);
  row("verification after", va);
  std::printf("\n('before': nominal kinematics with the registered frames; 'after': every identifiable parameter)\n");
  if (!r.identifiability.dropped.empty()) {
    std::printf("not identifiable from these data (held at their start value):");
    for (const auto& d : r.identifiability.dropped) std::printf(" %s", robot.paramName(d.index).c_str());
    std::printf("\n");
  }
  if (!a.json.empty()) {
    nlohmann::json params = nlohmann::json::array();
    for (const auto& np : r.parameters(robot, start))
      params.push_back({{"name", np.name}, {"initial", np.initial}, {"value", np.value}, {"stddev", np.stddev}, {"estimated", np.estimated}});
    nlohmann::json j = {{"data", a.data}, {"robot", robot.name}, {"rows", file.rows.size()}, {"skipped_rows", file.skipped_rows},
                        {"split", a.split}, {"identification_rows", ident.size()}, {"verification_rows", verify.size()},
                        {"measurement", kind == MeasurementKind::kPose6D ? "pose6d" : "position3d"},
                        {"model", a.model}, {"solver", a.solver}, {"converged", r.converged}, {"iterations", r.iterations},
                        {"registration_rms_mm", reg_rms}, {"registration_time_s", reg_s}, {"solve_time_s", solve_s},
                        {"identification", {{"before", toJson(ib)}, {"after", toJson(ia)}}},
                        {"verification", {{"before", toJson(vb)}, {"after", toJson(va)}}},
                        {"parameters", params}};
    std::ofstream(a.json) << j.dump(2) << "\n";
  }
  return r.converged ? 0 : 3;
}

}  // namespace

Runner addCalibrateCommand(CLI::App& app) {
  auto a = std::make_shared<CalibrateArgs>();
  CLI::App* cmd = app.add_subcommand(
      "calibrate",
      "Batch geometric calibration of a measurement file (CSV v1): registers the base and tool frames, identifies every "
      "identifiable kinematic parameter (Gauss-Newton, or --solver lm) on the identification rows, and reports mean/RMS/max "
      "position and orientation errors on identification and verification rows, before and after. Split: "
      "'alternate' = even rows (0-based) identify, odd rows verify; 'halves' = first half identifies, second verifies");
  cmd->add_option("--robot", a->robot, "robot file (YAML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--data", a->data, "measurement file (CSV v1, docs/measurement-csv.md)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--json", a->json, "write the results as JSON");
  cmd->add_option("--model", a->model, "geometric (extended models: see `diagnose`, to come)")->capture_default_str();
  cmd->add_option("--split", a->split, "alternate | halves")->check(CLI::IsMember({"alternate", "halves"}))->capture_default_str();
  cmd->add_option("--sigma-position-mm", a->sigma_position_mm, "1-sigma position noise of a reading")->capture_default_str();
  cmd->add_option("--sigma-orientation-deg", a->sigma_orientation_deg, "1-sigma orientation noise")->capture_default_str();
  cmd->add_option("--solver", a->solver, "gn (Gauss-Newton, default) | lm (Levenberg-Marquardt, Ceres)")
      ->check(CLI::IsMember({"gn", "lm"}))
      ->capture_default_str();
  cmd->add_option("--rank-tolerance", a->rank_tolerance,
                  "a parameter is estimated only if its scaled Jacobian column leaves the span of the others by more "
                  "than this sine")
      ->capture_default_str();
  cmd->add_flag("--position-only", a->position_only, "use positions only, even where orientations are given");
  cmd->add_flag("--skip-bad-rows", a->skip_bad_rows, "skip (and count) bad rows instead of stopping");
  cmd->add_flag("--no-register", a->no_register, "trust the robot file's base and tool frames as the start");
  return [a, cmd]() -> int {
    if (!*cmd) return 0;
    return runCalibrate(*a);
  };
}

Runner addImportCommand(CLI::App& app) {
  auto robot = std::make_shared<std::string>(defaultRobotFile("ur10.yaml"));
  auto in = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  CLI::App* imp = app.add_subcommand("import", "Convert measurements from other formats to CSV v1");
  imp->require_subcommand(1);
  CLI::App* ipa = imp->add_subcommand("ipa", "A series of ../shared/datasets/ipa-robot-accuracy (UR10, Leica + T-Mac)");
  ipa->add_option("series", *in, "Series_A/measurements_grid.csv or Series_B/measurements_joint_configurations.csv")
      ->required()
      ->check(CLI::ExistingFile);
  ipa->add_option("--out", *out, "CSV v1 file to write")->required();
  ipa->add_option("--robot", *robot, "robot file (joint limits are checked)")->capture_default_str();
  return [=]() -> int {
    if (!*ipa) return 0;
    const RobotModel r = loadRobotModel(*robot);
    std::string notes;
    const MeasurementFile f = readIpaSeries(*in, r, &notes);
    std::ofstream o(*out);
    if (!o) throw std::runtime_error(*out + ": cannot write");
    writeMeasurementCsv(o, f, r.numJoints(),
                        "converted by `cellcal import ipa` from " + *in +
                            "\nipa-robot-accuracy (Landgraf et al., IEEE CASE 2021), MIT licence\n" + notes);
    std::printf("%s -> %s\n", notes.c_str(), out->c_str());
    return 0;
  };
}

}  // namespace cellcal::cli
