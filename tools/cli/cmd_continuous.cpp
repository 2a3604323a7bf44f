// `cellcal continuous`: a measurement file in time order run as a cell would run it (core/continuous_scenario.hpp):
// an initial batch, then every interval a few fresh poses update the RLS estimate; every row is predicted before it
// could be used. Prints a table per interval and the overall figures; --json writes them.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>

#include "cellcal/lab/continuous_scenario.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {
namespace {

struct ContinuousArgs {
  std::string robot, data, json, model;
  double sigma_position_mm = 0.025, sigma_orientation_deg = 0.01;
  bool position_only = false, skip_bad_rows = false, quiet = false;
  double block_h = 6.0;
  double period_s = 0;  // rows without stamp_s: row k at k * period_s (the file's order is the visiting order)
  ContinuousScenarioOptions options;
};

void addOptions(CLI::App& cmd, ContinuousArgs& a) {
  a.robot = defaultRobotFile("ur10.yaml");
  cmd.add_option("--robot", a.robot, "robot YAML file")->check(CLI::ExistingFile)->capture_default_str();
  cmd.add_option("--data", a.data, "measurement file, CSV v1, with stamp_s (or --period-s)")->required()->check(CLI::ExistingFile);
  cmd.add_option("--period-s", a.period_s,
                 "a file without stamp_s: its rows in visiting order, this many seconds apart")
      ->check(positive());
  cmd.add_option("--interval-h", a.options.update_interval_h, "hours between updates")->check(positive())->capture_default_str();
  cmd.add_option("--poses-per-update", a.options.poses_per_update, "fresh poses per update")->check(positive())->capture_default_str();
  cmd.add_option("--initial-h", a.options.initial_h, "the initial batch comes from the first hours")
      ->check(positive())->capture_default_str();
  cmd.add_option("--initial-poses", a.options.initial_poses, "poses of the initial batch, evenly spaced")
      ->check(positive())->capture_default_str();
  cmd.add_option("--drift-scale", a.options.drift_scale,
                 "scale of the engine's drift model (process noise per hour between updates)->check(nonNegative()); 0: none (lambda = 1)")
      ->capture_default_str();
  cmd.add_option("--model", a.model,
                 "extensions in the RLS state as well, e.g. joint_compliance:2 (the cause `diagnose` names)");
  cmd.add_option("--sigma-position-mm", a.sigma_position_mm, "reading sigma (1 sigma)")->check(positive())->capture_default_str();
  cmd.add_option("--sigma-orientation-deg", a.sigma_orientation_deg, "reading sigma (1 sigma)")->check(positive())->capture_default_str();
  cmd.add_flag("--position-only", a.position_only, "use positions only");
  cmd.add_option("--block-h", a.block_h, "also print the errors pooled per block of this many hours (0: no)")
      ->check(nonNegative())->capture_default_str();
  cmd.add_flag("--quiet", a.quiet, "no per-interval table");
  cmd.add_flag("--skip-bad-rows", a.skip_bad_rows, "skip (and count) bad rows instead of stopping");
  cmd.add_option("--json", a.json, "write the results as JSON")->check(outputFile());
}

int runContinuous(const ContinuousArgs& a) {
  const RobotModel robot = loadRobotModel(a.robot);
  MeasurementCsvOptions mo;
  mo.skip_bad_rows = a.skip_bad_rows;
  const MeasurementFile file = readMeasurementCsv(a.data, robot, mo);
  for (const auto& w : file.warnings) std::fprintf(stderr, "skipped: %s\n", w.c_str());
  ContinuousScenario sc;
  sc.model = &robot;
  sc.options = a.options;
  if (!a.model.empty() && a.model != "geometric") sc.options.extensions = parseModel(a.model, robot);
  const MeasurementKind kind = a.position_only ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
  const bool stamped = std::any_of(file.rows.begin(), file.rows.end(), [](const auto& r) { return r.stamp_s.has_value(); });
  if (stamped && a.period_s > 0)
    throw std::runtime_error(a.data + ": has stamp_s; --period-s is for files without stamps");
  for (size_t k = 0; k < file.rows.size(); ++k) {
    const auto& r = file.rows[k];
    if (!r.stamp_s && a.period_s <= 0)
      throw std::runtime_error(a.data + ":" + std::to_string(r.line) +
                               ": stamp_s: needed (time order), or --period-s for a file whose rows are in visiting "
                               "order without stamps");
    const double t_s = r.stamp_s ? *r.stamp_s : static_cast<double>(k) * a.period_s;
    sc.rows.push_back({toObservation(r, kind, a.sigma_position_mm * 1e-3, a.sigma_orientation_deg * kPi / 180), t_s,
                       r.temperature_c});
  }
  const ContinuousScenarioResult res = runContinuousScenario(sc);
  const bool ext = !sc.options.extensions.empty();
  std::printf("cellcal continuous: %s, %zu rows in time order; initial batch %d of the %d rows of the first %.2f h; "
              "then every %.2f h %d poses (RLS, drift process noise x %g)\n",
              a.data.c_str(), sc.rows.size(), std::min<int>(sc.options.initial_poses, res.initial_rows),
              res.initial_rows, sc.options.initial_h, sc.options.update_interval_h, sc.options.poses_per_update,
              sc.options.drift_scale);
  std::printf("a-priori mean position error (mm) of every row of an interval, before its poses update the estimate\n");
  if (!a.quiet)
    std::printf("%8s %8s %7s %5s %9s %9s%s\n", "from_h", "to_h", "temp_C", "rows", "static", "rls", ext ? " rls+ext" : "");
  for (const auto& i : res.intervals) {
    if (a.quiet) break;
    std::printf("%8.2f %8.2f %7.2f %5d %9.4f %9.4f", i.start_h, i.end_h, i.temperature_c, i.rows, i.static_model.mean_mm,
                i.rls.mean_mm);
    if (ext) std::printf(" %8.4f", i.rls_extended.mean_mm);
    std::printf("\n");
  }
  if (a.block_h > 0) {  // the intervals' rows pooled into blocks of block_h hours (row-weighted means)
    std::printf("\nper %.0f h block (row-weighted mean of the intervals' a-priori mean errors, mm)\n", a.block_h);
    std::printf("%8s %8s %6s %9s %9s%s\n", "from_h", "to_h", "rows", "static", "rls", ext ? " rls+ext" : "");
    for (size_t i = 0; i < res.intervals.size();) {
      const double block = std::floor(res.intervals[i].start_h / a.block_h);
      double n = 0, st = 0, rl = 0, ex = 0, to = 0;
      const double from = res.intervals[i].start_h;
      for (; i < res.intervals.size() && std::floor(res.intervals[i].start_h / a.block_h) == block; ++i) {
        const auto& v = res.intervals[i];
        n += v.rows;
        st += v.rows * v.static_model.mean_mm;
        rl += v.rows * v.rls.mean_mm;
        ex += v.rows * v.rls_extended.mean_mm;
        to = v.end_h;
      }
      std::printf("%8.2f %8.2f %6.0f %9.4f %9.4f", from, to, n, st / n, rl / n);
      if (ext) std::printf(" %8.4f", ex / n);
      std::printf("\n");
    }
  }
  auto line = [&](const char* name, const ErrorStats& s) {
    std::printf("%-14s mean %.4f  RMS %.4f  99.7%% %.4f  max %.4f mm", name, s.mean_mm, s.rms_mm, s.p997_mm, s.max_mm);
    if (s.oriented) std::printf("  | mean %.4f  99.7%% %.4f  max %.4f deg", s.mean_deg, s.p997_deg, s.max_deg);
    std::printf("\n");
  };
  std::printf("\nover %d updates, %d poses used, %d rows predicted (%.2f s):\n", res.updates, res.poses_used,
              res.static_overall.rows, res.solve_time_s);
  line("static", res.static_overall);
  line("rls", res.rls_overall);
  if (ext) line("rls+extension", res.rls_extended_overall);
  if (!a.json.empty()) {
    nlohmann::json iv = nlohmann::json::array();
    for (const auto& i : res.intervals) {
      nlohmann::json j = {{"start_h", i.start_h}, {"end_h", i.end_h},     {"rows", i.rows},
                          {"poses_used", i.poses_used}, {"static", errorStatsJson(i.static_model)},
                          {"rls", errorStatsJson(i.rls)}};
      if (!std::isnan(i.temperature_c)) j["temperature_c"] = i.temperature_c;
      if (ext) j["rls_extended"] = errorStatsJson(i.rls_extended);
      iv.push_back(j);
    }
    nlohmann::json out = {{"data", a.data},
                          {"robot", robot.name},
                          {"rows", sc.rows.size()},
                          {"update_interval_h", sc.options.update_interval_h},
                          {"poses_per_update", sc.options.poses_per_update},
                          {"drift_scale", sc.options.drift_scale},
                          {"initial_h", sc.options.initial_h},
                          {"initial_poses", sc.options.initial_poses},
                          {"initial_rows", res.initial_rows},
                          {"model", a.model.empty() ? "geometric" : a.model},
                          {"updates", res.updates},
                          {"poses_used", res.poses_used},
                          {"initial_fit", errorStatsJson(res.initial_fit)},
                          {"static", errorStatsJson(res.static_overall)},
                          {"rls", errorStatsJson(res.rls_overall)},
                          {"intervals", iv},
                          {"solve_time_s", res.solve_time_s}};
    if (ext) out["rls_extended"] = errorStatsJson(res.rls_extended_overall);
    std::ofstream(a.json) << out.dump(2) << "\n";
  }
  return 0;
}

}  // namespace

Runner addContinuousCommand(CLI::App& app) { return addCommand(app, "continuous", addOptions, runContinuous); }

}  // namespace cellcal::cli
