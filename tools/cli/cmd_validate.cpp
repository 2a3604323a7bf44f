// `cellcal validate`: the engine host (components/engine_host.hpp) over a recording's inputs in log order, each
// calibration compared with the one recorded.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <iostream>
#include <limits>
#include <map>
#include <numeric>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/engine_host.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/recording/recording.hpp"
#include "commands.hpp"
#include "progress.hpp"
#include "validate_figures.hpp"

namespace cellcal::cli {
namespace {

using namespace cellcal::components;
using namespace cellcal::recording;

struct ValidateArgs {
  ProcessOptions common;
  std::string file, json, figures;
  double tolerance_m = 1e-9, tolerance_rad = 1e-9;
  bool require_match = false, no_progress = false;
};

void addOptions(CLI::App& cmd, ValidateArgs& a) {
  addCommonOptions(cmd, a.common);
  cmd.add_option("file", a.file, "MCAP recording")->required()->check(CLI::ExistingFile);
  cmd.add_option("--json", a.json, "write the comparison and every calibration as JSON")->check(outputFile());
  cmd.add_option("--tolerance-m", a.tolerance_m, "lengths (and verification errors) equal within this")->check(nonNegative())->capture_default_str();
  cmd.add_option("--tolerance-rad", a.tolerance_rad, "angles equal within this")->check(nonNegative())->capture_default_str();
  cmd.add_flag("--require-match", a.require_match, "exit 3 when a calibration differs from the recorded one");
  cmd.add_flag("--no-progress", a.no_progress, "no progress bar");
  cmd.add_option("--figures", a.figures,
                 "write <robot>_accuracy.png (a-priori verification and residual over time) and <robot>_joint_drift.png "
                 "(identified joint zero offsets over time) into this directory (gnuplot)");
}

struct Difference {
  double length_m = 0, angle_rad = 0, other = 0, verification_m = 0;
  std::string worst;  // the parameter that differs most (relative to its tolerance)
  double worst_ratio = 0;
  std::string different_model;  // when the two are not the same model (other extensions): what each has
};

Difference compare(const RobotModel& model, const std::vector<Extension>& exts, const ReceivedCalibration& a,
                   const ReceivedCalibration& b,
                   double tol_m, double tol_rad) {
  Difference d;
  auto consider = [&](const std::string& name, double delta) {
    delta = std::abs(delta);
    const bool length = name.size() > 2 && name.compare(name.size() - 2, 2, "_m") == 0;
    const bool angle = name.size() > 4 && name.compare(name.size() - 4, 4, "_rad") == 0;
    double& slot = length ? d.length_m : angle ? d.angle_rad : d.other;
    slot = std::max(slot, delta);
    const double ratio = delta / (length ? tol_m : tol_rad);
    if (ratio > d.worst_ratio) d.worst_ratio = ratio, d.worst = name;
  };
  for (int i = 0; i < model.numParams(); ++i) consider(model.paramName(i), a.params[i] - b.params[i]);
  const auto names = extensionParamNames(model, exts);
  if (a.extension_params.size() == b.extension_params.size())
    for (Eigen::Index i = 0; i < a.extension_params.size(); ++i)
      consider(names[static_cast<size_t>(i)], a.extension_params[i] - b.extension_params[i]);
  std::vector<std::string> specs_a, specs_b;
  for (const auto& e : a.extensions) specs_a.push_back(extensionSpec(e));
  for (const auto& e : b.extensions) specs_b.push_back(extensionSpec(e));
  if (specs_a != specs_b || a.extension_params.size() != b.extension_params.size()) {
    d.worst = "model extensions differ", d.worst_ratio = INFINITY;
    d.different_model = "the recording's calibrations are of the model " + modelLabel(b.extensions) +
                        ", the engine replayed with this cell file's settings gives " + modelLabel(a.extensions) +
                        ": give --config the cell file the recording was made with";
  }
  const bool both_nan = std::isnan(a.verification_mean_position_m) && std::isnan(b.verification_mean_position_m);
  d.verification_m = both_nan ? 0 : std::abs(a.verification_mean_position_m - b.verification_mean_position_m);
  if (std::isnan(d.verification_m)) d.verification_m = INFINITY;
  return d;
}

// The robot whose target this is (the cell file was checked: every target belongs to one robot).
std::string robotOfTarget(const CellConfig& cell, const std::string& target_id) {
  for (const auto& r : cell.robots)
    if (r.target_id == target_id) return r.robot_id;
  return "";
}

// What the engine process would publish for one robot, as a consumer receives it (through the wire type), and what the
// recording holds.
struct Run {
  std::vector<ReceivedCalibration> reproduced;
  // Beside each reproduced calibration: the a-priori error of the pose that made it (NaN: none did), mm. These are
  // the run's held-out errors.
  std::vector<double> prior_mm;
  std::map<std::uint64_t, ReceivedCalibration> recorded;  // first CalibrationState of each version
  std::uint64_t joint_states = 0, tracker_readings = 0;
};

// Messages the replay could not use, counted, the first named.
struct Unused {
  std::uint64_t unknown_keys = 0, undecodable = 0, state_errors = 0;
  std::string first_error;
  void note(std::uint64_t& counter, const std::string& what) {
    ++counter;
    if (first_error.empty()) first_error = what;
  }
};

// The recording's inputs into the host in log order (it reproduces into runs), its CalibrationStates into runs.
Unused replay(const ValidateArgs& a, const Recording& rec, const CellConfig& cell, EngineHost& host,
              std::map<std::string, Run>& runs) {
  Unused unused;
  auto note = [&](std::uint64_t& counter, const std::string& what) { unused.note(counter, what); };
  std::uint64_t& unknown_keys = unused.unknown_keys;
  std::uint64_t& undecodable = unused.undecodable;
  std::uint64_t& state_errors = unused.state_errors;
  ProgressBar bar("validate", !a.no_progress);
  // Decoded into reused samples: constructing one costs more than decoding it (see DdsNode::Listener).
  msg::JointState js;
  msg::TrackerPose tp;
  msg::CalibrationState cs;
  for (size_t i = 0; i < rec.in_log_order.size(); ++i) {
    const mcap::Message& m = *rec.in_log_order[i].message;
    const std::string& topic = *rec.in_log_order[i].topic;
    const auto now = static_cast<std::int64_t>(m.log_time_ns);
    auto where = [&] { return a.file + ": " + topic + " message " + std::to_string(i) + " (log time " + std::to_string(m.log_time_ns) + ")"; };
    std::string error;
    if (topic == TopicOf<msg::JointState>::name) {
      if (!decodeCdr(m.data, &js, &error)) { note(undecodable, where() + ": " + error); continue; }
      if (!host.onJointState(js.robot_id().to_string(), toJointSample(js), now)) {
        note(unknown_keys, where() + ": robot_id '" + js.robot_id().to_string() + "' not in " + cell.source);
        continue;
      }
      ++runs[js.robot_id().to_string()].joint_states;
    } else if (topic == TopicOf<msg::TrackerPose>::name) {
      if (!decodeCdr(m.data, &tp, &error)) { note(undecodable, where() + ": " + error); continue; }
      if (!host.onTrackerSample(tp.target_id().to_string(), toTrackerSample(tp), now)) {
        note(unknown_keys, where() + ": target_id '" + tp.target_id().to_string() + "' not in " + cell.source);
        continue;
      }
      ++runs[robotOfTarget(cell, tp.target_id().to_string())].tracker_readings;
    } else if (topic == TopicOf<msg::CalibrationState>::name) {
      if (!decodeCdr(m.data, &cs, &error)) { note(undecodable, where() + ": " + error); continue; }
      auto it = runs.find(cs.robot_id().to_string());
      if (it == runs.end()) { note(unknown_keys, where() + ": robot_id '" + cs.robot_id().to_string() + "' not in " + cell.source); continue; }
      if (cs.version() == 0 || it->second.recorded.count(cs.version())) continue;  // republished
      auto rc = fromCalibrationState(host.robots().at(it->first).robot->model, cs, &error);
      if (!rc) { note(state_errors, where() + ": " + error); continue; }
      it->second.recorded[rc->version] = std::move(*rc);
    }
    // The engine process also polls every robot every EngineHost::kTickPeriod (readings whose joint state never came
    // time out).
    host.tickIfDue(now);
    if ((i & 1023) == 0)
      bar.update(static_cast<double>(i) / static_cast<double>(rec.in_log_order.size()),
                 std::to_string(i) + "/" + std::to_string(rec.in_log_order.size()) + " messages");
  }
  host.tick(static_cast<std::int64_t>(rec.end_ns) + 1000000000LL);
  bar.done();
  return unused;
}

// The run's held-out errors (mm: every update's pose, predicted before it was used; NaN beside a calibration no pose
// made), printed and as JSON: their mean, 99.7th percentile and max (null when there are none).
nlohmann::json heldOutSummary(const std::string& id, const std::vector<double>& prior_mm) {
  std::vector<double> pe;
  for (double e : prior_mm)
    if (std::isfinite(e)) pe.push_back(e);
  if (pe.empty()) return nullptr;
  const double mean = std::accumulate(pe.begin(), pe.end(), 0.0) / static_cast<double>(pe.size());
  const double p997 = percentile(pe, 0.997), max = *std::max_element(pe.begin(), pe.end());
  std::printf("validate: %s: held-out position errors of the %zu updates (each pose predicted before it was used): "
              "mean %.4f, 99.7%% %.4f, max %.4f mm\n",
              id.c_str(), pe.size(), mean, p997, max);
  return {{"updates", pe.size()}, {"mean_mm", mean}, {"p997_mm", p997}, {"max_mm", max}};
}

// One robot's reproduced calibrations against the recorded ones: printed, and returned as JSON; all_match false when a
// version differs or was recorded but not reproduced.
nlohmann::json compareRobot(const ValidateArgs& a, const std::string& id, const Run& run, const EngineHost::Robot& hosted,
                            bool* all_match) {
  const RobotModel& model = hosted.robot->model;
  const auto& exts = hosted.engine->snapshot().extensions;
  std::uint64_t compared = 0, mismatched = 0, not_recorded = 0;
  Difference worst;
  std::string first_mismatch;
  nlohmann::json series = nlohmann::json::array();
  std::set<std::uint64_t> reproduced_versions;
  for (size_t k = 0; k < run.reproduced.size(); ++k) {
    const ReceivedCalibration& c = run.reproduced[k];
    reproduced_versions.insert(c.version);
    const double prior_mm = run.prior_mm[k];
    nlohmann::json row = {{"version", c.version}, {"poses_used", c.poses_used},
                          {"verification_mm", std::isfinite(c.verification_mean_position_m) ? nlohmann::json(c.verification_mean_position_m * 1e3) : nlohmann::json()},
                          {"held_out_mm", std::isfinite(prior_mm) ? nlohmann::json(prior_mm) : nlohmann::json()}};
    auto it = run.recorded.find(c.version);
    if (it == run.recorded.end()) {
      ++not_recorded;
      series.push_back(row);
      continue;
    }
    ++compared;
    const Difference d = compare(model, exts, c, it->second, a.tolerance_m, a.tolerance_rad);
    row["recorded_verification_mm"] = std::isfinite(it->second.verification_mean_position_m) ? nlohmann::json(it->second.verification_mean_position_m * 1e3) : nlohmann::json();
    row["max_difference_m"] = d.length_m;
    row["max_difference_rad"] = d.angle_rad;
    series.push_back(row);
    worst.length_m = std::max(worst.length_m, d.length_m);
    worst.angle_rad = std::max(worst.angle_rad, d.angle_rad);
    worst.other = std::max(worst.other, d.other);
    worst.verification_m = std::max(worst.verification_m, d.verification_m);
    const bool ok = d.length_m <= a.tolerance_m && d.angle_rad <= a.tolerance_rad && d.other <= a.tolerance_rad &&
                    d.verification_m <= a.tolerance_m && std::isfinite(d.worst_ratio);
    if (!ok) {
      ++mismatched;
      if (first_mismatch.empty())
        first_mismatch = "v" + std::to_string(c.version) + ": " +
                         (!d.different_model.empty()
                              ? d.different_model
                              : d.worst + " differs by " + std::to_string(d.worst_ratio) +
                                    "x the tolerance; a-priori error by " + std::to_string(d.verification_m * 1e3) + " mm");
    }
  }
  std::uint64_t missing = 0;
  for (const auto& [v, c] : run.recorded)
    if (!reproduced_versions.count(v)) ++missing;
  *all_match = !(mismatched || missing);
  const ReceivedCalibration* last_rep = run.reproduced.empty() ? nullptr : &run.reproduced.back();
  const ReceivedCalibration* last_rec = run.recorded.empty() ? nullptr : &run.recorded.rbegin()->second;
  std::printf("validate: %s: %llu joint states, %llu tracker readings -> %zu calibrations (last v%llu, %u poses, "
              "running a-priori error %.4f mm: the last 30 poses, each predicted before it was used)\n",
              id.c_str(), static_cast<unsigned long long>(run.joint_states),
              static_cast<unsigned long long>(run.tracker_readings), run.reproduced.size(),
              static_cast<unsigned long long>(last_rep ? last_rep->version : 0), last_rep ? last_rep->poses_used : 0,
              last_rep ? last_rep->verification_mean_position_m * 1e3 : std::nan(""));
  const nlohmann::json held_out = heldOutSummary(id, run.prior_mm);
  // How the engine started shows in its first poses: each predicted a priori, windows of kRecentPoses.
  std::vector<double> first_windows;  // a-priori mean of poses 1-30, 31-60, ...
  for (const auto& c : run.reproduced)
    if (c.poses_used == (first_windows.size() + 1) * CalibrationEngine::kRecentPoses && first_windows.size() < 10)
      first_windows.push_back(c.verification_mean_position_m * 1e3);
  const double first_window_mm = first_windows.empty() ? std::nan("") : first_windows.front();
  const double first_ten_mm = first_windows.size() < 10 ? std::nan("")
                              : std::accumulate(first_windows.begin(), first_windows.end(), 0.0) / 10;
  if (!first_windows.empty()) {
    std::printf("validate: %s: a-priori mean position error of the first %zu poses %.4f mm", id.c_str(),
                CalibrationEngine::kRecentPoses, first_window_mm);
    if (std::isfinite(first_ten_mm))
      std::printf(", of the first %zu %.4f mm", 10 * CalibrationEngine::kRecentPoses, first_ten_mm);
    std::printf(" (started %s)\n",
                hosted.robot->start ? ("from " + hosted.robot->calibration_file).c_str() : "from the nominal model");
  }
  const std::optional<FileVerdict>& verdict = hosted.engine->fileVerdict();  // the file against its nominal kinematics
  if (verdict) std::printf("validate: %s: %s\n", id.c_str(), verdict->text(hosted.robot->calibration_file).c_str());
  if (run.recorded.empty()) {
    std::printf("validate: %s: the recording holds no CalibrationState: nothing to compare with\n", id.c_str());
  } else {
    std::printf("validate: %s: %zu recorded calibrations (last v%llu, running a-priori error %.4f mm): %llu compared, %llu differ, "
                "%llu recorded but not reproduced, %llu reproduced but not recorded\n",
                id.c_str(), run.recorded.size(), static_cast<unsigned long long>(last_rec->version),
                last_rec->verification_mean_position_m * 1e3, static_cast<unsigned long long>(compared),
                static_cast<unsigned long long>(mismatched), static_cast<unsigned long long>(missing),
                static_cast<unsigned long long>(not_recorded));
    std::printf("validate: %s: largest differences: %.3g m, %.3g rad, running a-priori error %.3g m (tolerance %.0e m, %.0e rad)%s\n",
                id.c_str(), worst.length_m, worst.angle_rad, worst.verification_m, a.tolerance_m, a.tolerance_rad,
                first_mismatch.empty() ? "" : ("; first: " + first_mismatch).c_str());
  }
  const auto& c = hosted.engine->counters();
  return {{"joint_states", run.joint_states},
                {"tracker_readings", run.tracker_readings},
                {"paired", c.paired},
                {"rejected", nlohmann::json(rejectionCounts(c))},
                {"reproduced", run.reproduced.size()},
                {"recorded", run.recorded.size()},
                {"compared", compared},
                {"differ", mismatched},
                {"recorded_not_reproduced", missing},
                {"reproduced_not_recorded", not_recorded},
                {"max_difference_m", worst.length_m},
                {"max_difference_rad", worst.angle_rad},
                {"max_difference_verification_m", worst.verification_m},
                {"first_difference", first_mismatch},
                {"final_version", last_rep ? last_rep->version : 0},
                {"held_out_mm", held_out},
                {"first_poses_verification_mm", std::isfinite(first_window_mm) ? nlohmann::json(first_window_mm) : nlohmann::json()},
                {"first_ten_windows_verification_mm", std::isfinite(first_ten_mm) ? nlohmann::json(first_ten_mm) : nlohmann::json()},
                {"started_from", hosted.robot->start ? hosted.robot->calibration_file : std::string("nominal")},
                {"calibration_file_verdict", verdict ? nlohmann::json(verdict->text(hosted.robot->calibration_file)) : nlohmann::json()},
                {"final_verification_mm", last_rep && std::isfinite(last_rep->verification_mean_position_m) ? nlohmann::json(last_rep->verification_mean_position_m * 1e3) : nlohmann::json()},
                {"final_parameters", [&] {
                   nlohmann::json p = nlohmann::json::object();
                   if (!last_rep) return p;
                   for (int i = 0; i < model.numParams(); ++i) p[model.paramName(i)] = last_rep->params[i];
                   const auto names = extensionParamNames(model, exts);
                   for (size_t k = 0; k < names.size(); ++k) p[names[k]] = last_rep->extension_params[static_cast<Eigen::Index>(k)];
                   return p;
                 }()},
                {"calibrations", series}};
}

int runValidate(const ValidateArgs& a) {
  const auto t_read = std::chrono::steady_clock::now();
  const Recording rec = readRecording(a.file);
  const CellConfig cell = loadCell(a.common);
  std::map<std::string, Run> runs;
  for (const auto& r : cell.robots) runs[r.robot_id];
  auto reproduce = [&](EngineHost::Robot& r) {
    std::string error;
    auto c = fromCalibrationState(r.robot->model, toCalibrationState(*r.robot, r.engine->snapshot(), 0, 0), &error);
    if (!c) throw std::logic_error("validate: a calibration does not survive its own conversion: " + error);
    Run& run = runs[r.robot->robot_id];
    const double prior_m = r.engine->snapshot().last_prior_error_position_m;
    const bool made_by_a_pose = run.reproduced.empty() || c->version != run.reproduced.back().version;
    run.prior_mm.push_back(made_by_a_pose ? prior_m * 1e3 : std::nan(""));
    run.reproduced.push_back(std::move(*c));
  };
  EngineHost host(cell, {/*persist=*/false, nullptr}, reproduce);
  // Where each engine stands at its start, as the engine process publishes it before any reading: a calibration
  // file's model is a version of its own (v1), which the recording holds and must be reproduced too.
  for (auto& [id, r] : host.robots())
    if (r.engine->snapshot().version > 0) reproduce(r);
  const double read_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_read).count();
  const auto t0 = std::chrono::steady_clock::now();
  const Unused unused = replay(a, rec, cell, host, runs);
  const auto& [unknown_keys, undecodable, state_errors, first_error] = unused;
  const double process_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double span_s = (rec.end_ns - rec.start_ns) / 1e9;
  const double real_time_factor = span_s / std::max(read_s + process_s, 1e-9);
  std::printf("validate: %s: %zu messages over %.1f s of recording (%s); read in %.3f s, engine logic in %.3f s: "
              "%.0fx real time\n",
              a.file.c_str(), rec.in_log_order.size(), span_s,
              (rec.file.complete ? std::string("complete") : "incomplete: " + rec.file.problem).c_str(), read_s,
              process_s, real_time_factor);
  std::printf("validate: cell file %s\n", cell.source.c_str());
  bool all_match = true;
  nlohmann::json robots = nlohmann::json::object();
  for (auto& [id, run] : runs) {
    if (run.joint_states == 0 && run.tracker_readings == 0 && run.recorded.empty()) continue;
    bool match = true;
    robots[id] = compareRobot(a, id, run, host.robots().at(id), &match);
    all_match = all_match && match;
  }
  if (!a.figures.empty()) {
    for (auto& [id, run] : runs) writeRecordingFigures(a.figures, id, host.robots().at(id).robot->model, run.reproduced, cell.time_compression);
    std::printf("validate: figures in %s (<robot>_accuracy.png, <robot>_joint_drift.png)\n", a.figures.c_str());
  }
  if (unknown_keys || undecodable || state_errors)
    std::printf("validate: %llu messages of unknown robots/targets, %llu undecodable, %llu unusable CalibrationStates "
                "(first: %s)\n",
                static_cast<unsigned long long>(unknown_keys), static_cast<unsigned long long>(undecodable),
                static_cast<unsigned long long>(state_errors), first_error.c_str());
  writeJsonFile(a.json, {{"file", a.file},
                         {"cell_file", cell.source},
                         {"complete", rec.file.complete},
                         {"messages", rec.in_log_order.size()},
                         {"recording_span_s", span_s},
                         {"read_s", read_s},
                         {"engine_s", process_s},
                         {"real_time_factor", real_time_factor},
                         {"unknown_keys", unknown_keys},
                         {"undecodable", undecodable},
                         {"all_match", all_match},
                         {"robots", robots}});
  if (a.require_match && !all_match) {
    std::printf("validate: the calibrations differ from the recorded ones (--require-match)\n");
    return 3;
  }
  size_t calibrations = 0;
  for (const auto& [id, run] : runs) calibrations += run.reproduced.size();
  if (calibrations == 0) {
    std::printf("validate: WARNING: no calibration came out of %s: it holds no paired JointState and TrackerPose of "
                "the cell file's robots (recorded on another domain or profile, or of another cell?) (exit 4)\n",
                a.file.c_str());
    return 4;
  }
  return 0;
}

}  // namespace

Runner addValidateCommand(CLI::App& app) { return addCommand(app, "validate", addOptions, runValidate); }

}  // namespace cellcal::cli
