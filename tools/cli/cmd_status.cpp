// `cellcal status [--watch]`: the cell at a glance, from its topics (identity observer under DDS Security). Per robot:
// calibration version and health, poses used, the a-priori verification estimate and the predicted error, the
// correction sizes the compensation publisher sent, rejected samples by reason, alarms and stale inputs.
#include <ctime>
#include <iomanip>
#include <iostream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/components/profile_probe.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

using namespace cellcal::components;

struct StatusArgs {
  ProcessOptions common;
  bool watch = false;
  double wait_s = 3;      // once: how long to listen before printing (transient-local samples come at once)
  double period_s = 1;    // --watch: redraw period
  double duration_s = 0;  // --watch: stop after this long (0: until SIGINT)
  std::string json;
};

void addOptions(CLI::App& cmd, StatusArgs& a) {
  addCommonOptions(cmd, a.common);
  cmd.add_flag("-w,--watch", a.watch, "redraw the view every --period-s until Ctrl-C (a live terminal view)");
  cmd.add_option("--wait-s", a.wait_s, "without --watch: listen this long, then print once")->check(nonNegative())->capture_default_str();
  cmd.add_option("--period-s", a.period_s, "--watch: redraw period")->check(CLI::Range(0.1, 60.0))->capture_default_str();
  cmd.add_option("--duration-s", a.duration_s, "--watch: stop after this long (0: until Ctrl-C)")->check(nonNegative());
  cmd.add_option("--json", a.json, "also write the last view as JSON to this file")->check(outputFile());
}


struct RobotView {
  bool has_state = false, has_diagnostics = false;
  std::uint64_t version = 0, poses_used = 0, state_stamp_ns = 0;
  std::string health = "-", model, extensions;
  double verification_mm = std::nan(""), residual_mm = std::nan(""), predicted_mm = std::nan("");
  double predicted_workspace_mm = std::nan("");
  // The engine's held-out errors of its recent poses, as its diagnostics gave them: mean, 99.7th percentile, max, count.
  double held_out_mean_mm = std::nan(""), verification_p997_mm = std::nan(""), verification_max_mm = std::nan("");
  std::uint32_t verification_poses = 0;
  std::map<std::string, std::uint64_t> rejections;
  bool drift_alarm = false;
  std::string health_cause = "-", health_reason, stale_inputs, persist_error, last_rejection, clock_warning;
  std::uint64_t answers = 0, applied = 0;
  std::uint64_t applied_beyond_data = 0;  // applied, flagged beyond_data
  double last_correction_mm = std::nan(""), last_correction_deg = std::nan(""), max_correction_mm = 0;
  std::string last_reason;
};

std::string fmt(double v, int precision, const char* unit) {
  if (!std::isfinite(v)) return "-";
  std::ostringstream o;
  o << std::fixed << std::setprecision(precision) << v << unit;
  return o.str();
}

nlohmann::json toJson(const std::map<std::string, RobotView>& robots) {
  nlohmann::json j = nlohmann::json::object();
  auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
  for (const auto& [id, r] : robots)
    j[id] = {{"version", r.version},
             {"health", r.health},
             {"health_cause", r.health_cause},
             {"health_reason", r.health_reason},
             {"poses_used", r.poses_used},
             {"verification_mean_position_mm", num(r.verification_mm)},
             {"held_out_mm", r.verification_poses == 0 ? nlohmann::json()
                                                       : nlohmann::json{{"poses", r.verification_poses},
                                                                        {"mean_mm", num(r.held_out_mean_mm)},
                                                                        {"p997_mm", num(r.verification_p997_mm)},
                                                                        {"max_mm", num(r.verification_max_mm)}}},
             {"residual_rms_position_mm", num(r.residual_mm)},
             {"predicted_sigma_position_mm", num(r.predicted_mm)},
             {"predicted_sigma_workspace_mm", num(r.predicted_workspace_mm)},
             {"model_extensions", r.extensions},
             {"rejections", r.rejections},
             {"drift_alarm", r.drift_alarm},
             {"stale_inputs", r.stale_inputs},
             {"clock_warning", r.clock_warning},
             {"persist_error", r.persist_error},
             {"compensated_targets", r.answers},
             {"applied", r.applied},
             {"applied_beyond_data", r.applied_beyond_data},
             {"last_correction_mm", num(r.last_correction_mm)},
             {"last_correction_deg", num(r.last_correction_deg)},
             {"max_correction_mm", r.max_correction_mm},
             {"last_reason", r.last_reason}};
  return j;
}

// `elsewhere`: what the other participant profiles saw (describeSightings), when looked at; else a hint.
void render(std::ostream& out, const CellConfig& cell, const std::map<std::string, RobotView>& robots, int engine_writers,
            int compensation_writers, const std::string& elsewhere = "") {
  const std::time_t now = std::time(nullptr);
  char when[32];
  std::strftime(when, sizeof when, "%Y-%m-%d %H:%M:%S", std::localtime(&now));
  out << "cellcal status  " << when << "  domain " << cell.dds.domain_id << " (" << cell.dds.participant_profile
      << ")  engine " << (engine_writers > 0 ? "seen" : "NOT SEEN") << ", compensation "
      << (compensation_writers > 0 ? "seen" : "not seen") << "\n";
  if (engine_writers == 0 && !elsewhere.empty())
    out << "  no engine on domain " << cell.dds.domain_id << " with profile " << cell.dds.participant_profile << "\n"
        << elsewhere;
  else if (engine_writers == 0)
    out << "  (no engine on domain " << cell.dds.domain_id << " with profile " << cell.dds.participant_profile
        << " yet: is the cell running? Its processes join the domain and profile of their cell file; another cell: "
           "--config, --domain-id or --dds-profile)\n";
  out << "\n";
  out << std::left << std::setw(12) << "robot" << std::setw(8) << "version" << std::setw(15) << "health"
      << std::setw(7) << "poses" << std::setw(12) << "a-priori" << std::setw(12) << "predicted" << std::setw(12)
      << "residual" << std::setw(34) << "correction: last (max)" << std::setw(10) << "rejected" << "\n";
  for (const auto& [id, r] : robots) {
    std::uint64_t rejected = 0;
    for (const auto& [reason, n] : r.rejections) rejected += n;
    // What the engine said last, while it is seen; once it is gone, that it was so (no longer known).
    const std::string health = engine_writers > 0 || !r.has_state ? r.health : "? (was " + r.health + ")";
    out << std::left << std::setw(12) << id << std::setw(8) << (r.has_state ? "v" + std::to_string(r.version) : "-")
        << std::setw(15)
        << health << std::setw(7) << r.poses_used << std::setw(12) << fmt(r.verification_mm, 4, " mm")
        << std::setw(12) << fmt(r.predicted_mm, 4, " mm") << std::setw(12) << fmt(r.residual_mm, 4, " mm")
        << std::setw(34)
        // Corrections are not kept on the wire (CompensatedTarget is volatile): what this view saw since it started.
        << (r.applied == 0 ? std::string("none seen yet")
                           : fmt(r.last_correction_mm, 3, " mm") + " " + fmt(r.last_correction_deg, 3, " deg") + " (" +
                                 fmt(r.max_correction_mm, 2, " mm)"))
        << std::setw(10) << rejected << "\n";
  }
  out << "\n";
  for (const auto& [id, r] : robots) {
    std::vector<std::string> notes;
    if (!r.has_state) notes.push_back("no CalibrationState yet");
    if (r.has_state && engine_writers == 0)
      notes.push_back("ENGINE NOT SEEN: v" + std::to_string(r.version) + " " + r.health +
                      " is what it published last (the compensation publisher keeps applying the last ok version)");
    if (!r.health_reason.empty()) notes.push_back("health: " + r.health_reason);
    if (r.drift_alarm) notes.push_back("DRIFT ALARM");
    if (!r.stale_inputs.empty()) notes.push_back("STALE INPUT: " + r.stale_inputs);
    if (!r.clock_warning.empty()) notes.push_back("CLOCKS DISAGREE: " + r.clock_warning);
    if (!r.persist_error.empty()) notes.push_back("STATE NOT SAVED: " + r.persist_error);
    if (!r.rejections.empty()) {
      std::string s = "rejected:";
      for (const auto& [reason, n] : r.rejections) s += " " + reason + " " + std::to_string(n);
      notes.push_back(s);
    }
    if (r.answers > 0)
      notes.push_back("compensation: " + std::to_string(r.applied) + " of " + std::to_string(r.answers) +
                      " targets corrected" +
                      (r.applied_beyond_data ? " (" + std::to_string(r.applied_beyond_data) + " beyond the extensions' data)" : "") +
                      (r.last_reason.empty() ? "" : "; last: " + r.last_reason));
    if (r.verification_poses > 0)
      notes.push_back("held-out position errors of the last " + std::to_string(r.verification_poses) +
                      " poses (each predicted before it was used): mean " + fmt(r.held_out_mean_mm, 4, "") + ", 99.7% " +
                      fmt(r.verification_p997_mm, 4, "") + ", max " + fmt(r.verification_max_mm, 4, " mm"));
    if (!r.extensions.empty()) notes.push_back("model: " + r.extensions);
    // The engine judges health where the cell works; away from it each target meets its own predicted error.
    if (r.has_diagnostics && r.predicted_workspace_mm > cell.compensation.max_predicted_sigma_m * 1e3 &&
        cell.compensation.max_predicted_sigma_m > 0)
      notes.push_back("predicted error over the whole workspace " + fmt(r.predicted_workspace_mm, 4, " mm") +
                      " (1 sigma, worst): targets far from where the robot was measured are passed through; the poses "
                      "on cellcal/pose_request widen where it corrects");
    for (const auto& n : notes) out << "  " << id << ": " << n << "\n";
  }
  for (const auto& rb : cell.robots)
    if (!robots.count(rb.robot_id)) out << "  " << rb.robot_id << ": nothing received yet\n";
}

int runStatus(const StatusArgs& a) {
  installStopHandlers();
  const CellConfig cell = loadCell(a.common);
  DdsNode node(cell, "cellcal_status", identity::kObserver);
  std::mutex mutex;
  std::map<std::string, RobotView> robots;  // a row per robot something was received of (the cell file's others: a note)
  node.reader<msg::CalibrationState>([&](const msg::CalibrationState& m, const fdds::SampleInfo&) {
    std::lock_guard<std::mutex> l(mutex);
    RobotView& r = robots[m.robot_id().to_string()];
    if (r.has_state && m.version() < r.version) return;
    r.has_state = true;
    r.version = m.version();
    r.health = healthText(m.health());
    r.poses_used = m.poses_used();
    r.verification_mm = m.verification_mean_position_m() * 1e3;
    r.residual_mm = m.residual_rms_position_m() * 1e3;
    r.state_stamp_ns = m.source_stamp_ns();
    r.model = m.robot_model().to_string();
    r.extensions.clear();
    for (const auto& e : m.model_extensions()) r.extensions += (r.extensions.empty() ? "" : ", ") + e.to_string();
  });
  node.reader<msg::CalibrationDiagnostics>([&](const msg::CalibrationDiagnostics& d, const fdds::SampleInfo&) {
    std::lock_guard<std::mutex> l(mutex);
    RobotView& r = robots[d.robot_id().to_string()];
    r.has_diagnostics = true;
    r.rejections.clear();
    for (size_t i = 0; i < d.rejection_reasons().size() && i < d.rejection_counts().size(); ++i)
      if (d.rejection_counts()[i] > 0) r.rejections[d.rejection_reasons()[i].to_string()] = d.rejection_counts()[i];
    r.drift_alarm = d.drift_alarm();
    // The diagnostics come every republish period and whenever the health changes: the health they carry is the
    // engine's latest, newer than a CalibrationState's when no version was made since.
    if (!r.has_state || d.source_stamp_ns() >= r.state_stamp_ns) r.health = healthText(d.health());
    r.health_cause = healthCauseText(d.health_cause());
    r.health_reason = d.health_reason();
    r.stale_inputs = d.stale_inputs().to_string();
    r.clock_warning = d.clock_warning().to_string();
    r.persist_error = d.persist_error().to_string();
    r.predicted_mm = d.prediction_sigma_position_m() * 1e3;
    r.predicted_workspace_mm = d.prediction_sigma_workspace_m() * 1e3;
    r.held_out_mean_mm = d.verification_mean_position_m() * 1e3;
    r.verification_p997_mm = d.verification_p997_position_m() * 1e3;
    r.verification_max_mm = d.verification_max_position_m() * 1e3;
    r.verification_poses = d.verification_poses();
    r.last_rejection = d.last_rejection().to_string();
  });
  node.reader<msg::CompensatedTarget>([&](const msg::CompensatedTarget& c, const fdds::SampleInfo&) {
    std::lock_guard<std::mutex> l(mutex);
    RobotView& r = robots[c.robot_id().to_string()];
    ++r.answers;
    r.last_reason = c.reason();
    if (!c.note().empty()) r.last_reason += (r.last_reason.empty() ? "" : "; ") + c.note();
    if (c.applied()) {
      ++r.applied;
      if (c.beyond_data()) ++r.applied_beyond_data;
      r.last_correction_mm = c.correction_position_m() * 1e3;
      r.last_correction_deg = c.correction_orientation_rad() * 180 / kPi;
      r.max_correction_mm = std::max(r.max_correction_mm, r.last_correction_mm);
    }
  });
  const auto start = std::chrono::steady_clock::now();
  if (!a.watch) {
    sleepUntil(start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(a.wait_s)));
  } else {
    // The first frame once the engine's state of every robot of the cell file came (transient local: at discovery),
    // or after --wait-s: not a frame of empty rows while discovery is under way.
    const auto first = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                   std::chrono::duration<double>(a.wait_s));
    auto allStated = [&] {
      std::lock_guard<std::mutex> l(mutex);
      for (const auto& rb : cell.robots)
        if (!robots.count(rb.robot_id) || !robots.at(rb.robot_id).has_state) return false;
      return true;
    };
    while (!allStated() && std::chrono::steady_clock::now() < first && !stopRequested())
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const auto frames_start = std::chrono::steady_clock::now();
    const RunLimit limit(a.duration_s);  // --duration-s of frames
    for (int frame = 0;; ++frame) {
      const auto next = frames_start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                    std::chrono::duration<double>(a.period_s * (frame + 1)));
      {
        std::lock_guard<std::mutex> l(mutex);
        std::ostringstream screen;
        render(screen, cell, robots, node.matchedWriters<msg::CalibrationState>(),
               node.matchedWriters<msg::CompensatedTarget>());
        std::cout << "\033[H\033[2J" << screen.str() << "\n(refreshing every " << a.period_s << " s; Ctrl-C to stop)"
                  << std::flush;
      }
      if (!sleepUntil(next)) break;
      if (limit.timeUp()) break;
    }
    std::cout << "\n";
  }
  const int engine_writers = node.matchedWriters<msg::CalibrationState>();
  const int compensation_writers = node.matchedWriters<msg::CompensatedTarget>();
  node.shutdown();
  writeJsonFile(a.common.stats_json, {{"name", "status"}, {"topics", node.stats()}});
  // No engine: where is the cell? The other participant profiles of the cell's profile file, on this domain.
  std::vector<ProfileSighting> others;
  if (engine_writers == 0 && !stopRequested()) others = probeOtherProfiles(cell);
  std::lock_guard<std::mutex> l(mutex);
  if (!a.watch) render(std::cout, cell, robots, engine_writers, compensation_writers,
                       engine_writers == 0 ? describeSightings(cell, others, "  ") : "");
  else if (engine_writers == 0) std::cout << describeSightings(cell, others, "");
  nlohmann::json elsewhere = nlohmann::json::array();
  for (const auto& o : others)
    elsewhere.push_back({{"profile", o.profile}, {"engine_seen", o.engine_writers > 0},
                         {"compensation_seen", o.compensation_writers > 0}, {"sensor_writers", o.sensor_writers},
                         {"error", o.error}});
  if (!a.json.empty())
    writeJsonFile(a.json, {{"domain_id", cell.dds.domain_id},
                           {"participant_profile", cell.dds.participant_profile},
                           {"engine_seen", engine_writers > 0},
                           {"compensation_seen", compensation_writers > 0},
                           {"other_profiles", elsewhere},
                           {"robots", toJson(robots)}});
  // Exit 3, as `record` and `foxglove` when nothing comes: a script asking whether the cell runs gets "no".
  return engine_writers > 0 ? 0 : 3;
}

}  // namespace

Runner addStatusCommand(CLI::App& app) { return addCommand(app, "status", addOptions, runStatus); }

}  // namespace cellcal::cli
