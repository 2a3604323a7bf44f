// `cellcal cell`'s launcher: the cell's processes started in order, and their --stats-json merged at the end.
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "cellcal/components/process_stats.hpp"
#include "cell_roles.hpp"

namespace cellcal::cli {

namespace fs = std::filesystem;
using namespace cellcal::components;

namespace {

// Starts bin/cellcal_<name> (or `cellcal <args>` when `self`) with its output in <work_dir>/<name>.log; with `netns`,
// in that network namespace (`ip netns exec` execs the program in place: same pid, same death signal).
// `role`: the program when the name is a shard's (calibration_engine_2 runs cellcal_calibration_engine).
Child spawn(const std::string& name, std::vector<std::string> args, const std::string& work_dir, bool self = false,
            const std::string& netns = "", const std::string& role = "") {
  const fs::path exe = self ? fs::read_symlink("/proc/self/exe")
                            : fs::read_symlink("/proc/self/exe").parent_path() / ("cellcal_" + (role.empty() ? name : role));
  const std::string stats = (fs::path(work_dir) / (name + ".stats.json")).string();
  args.insert(args.end(), {"--stats-json", stats});
  const std::string log = (fs::path(work_dir) / (name + ".log")).string();
  if (netns.empty()) return Child{name, stats, ChildProcess(exe.string(), args, log)};
  const std::string ip = ipProgram();
  if (ip.empty()) throw std::runtime_error("--host: no ip command (Debian package iproute2)");
  args.insert(args.begin(), {"netns", "exec", netns, exe.string()});
  return Child{name, stats, ChildProcess(ip, args, log)};
}

}  // namespace

// The cell's processes, each with its output in <work_dir>/<name>.log. The recorder first: the robot program waits
// for its RobotTruth reader too, so the recording starts with the program.
std::vector<Child> startProcesses(const CellConfig& cell, const CellArgs& a, const std::string& state_dir,
                                  const std::vector<int>& rsi_ports) {
  const std::vector<std::string> common = {"--config", fs::absolute(a.common.config_path).string(), "--domain-id",
                                           std::to_string(cell.dds.domain_id), "--dds-profile",
                                           cell.dds.participant_profile};
  auto with = [&](std::vector<std::string> before, std::vector<std::string> after) {
    before.insert(before.end(), common.begin(), common.end());
    before.insert(before.end(), after.begin(), after.end());
    return before;
  };
  auto host = [&](const std::string& name) {
    const auto it = a.hosts.find(name);
    return it == a.hosts.end() ? std::string() : it->second;
  };
  std::vector<Child> children;
  if (!a.record.empty())
    children.push_back(spawn("recorder", with({"record"}, {"--out", fs::absolute(a.record).string(), "--quiet"}),
                             a.work_dir, true, host("recorder")));
  // One group of robots per shard (all of them without --shards): its name suffix and --robots.
  const std::size_t n = static_cast<std::size_t>(a.shards), robots = cell.robots.size();
  std::vector<std::pair<std::string, std::vector<std::string>>> shards;
  for (std::size_t k = 0; k < n; ++k) {
    std::vector<std::string> only;
    if (n > 1) {
      std::string ids;
      for (std::size_t i = k * robots / n; i < (k + 1) * robots / n; ++i)
        ids += (ids.empty() ? "" : ",") + cell.robots[i].robot_id;
      only = {"--robots", ids};
    }
    shards.emplace_back(n > 1 ? "_" + std::to_string(k + 1) : "", only);
  }
  auto each = [&](const std::string& role, std::vector<std::string> args) {
    for (const auto& [suffix, only] : shards) {
      std::vector<std::string> shard_args = with({}, args);
      shard_args.insert(shard_args.end(), only.begin(), only.end());
      children.push_back(spawn(role + suffix, shard_args, a.work_dir, false, host(role + suffix), role));
    }
  };
  each("calibration_engine", {"--state-dir", state_dir, "--quiet"});
  each("compensation_publisher", {});
  // Each tracker adapter measures once its readings have every reader: the engines and the recorder.
  each("tracker_adapter", {"--source", "sim", "--wait-for-readers", std::to_string(n + (a.record.empty() ? 0 : 1))});
  // The robot starts its program once the engine and the tracker listen (discovery on loopback takes a moment):
  // RobotTruth's readers are every tracker adapter, this launcher and the recorder.
  each("joint_state_adapter",
       {"--source", "sim", "--wait-for-readers", std::to_string(n + 1 + (a.record.empty() ? 0 : 1))});
  // --rsi-hz: one RSI bridge per robot, listening for its simulated controller (cell_rsi.cpp) on loopback.
  for (std::size_t i = 0; i < rsi_ports.size(); ++i) {
    std::vector<std::string> args = {"--robot", cell.robots[i].robot_id, "--listen",
                                     "127.0.0.1:" + std::to_string(rsi_ports[i]), "--controller", "127.0.0.1",
                                     "--cycle-ms", std::to_string(1000.0 / a.rsi_hz)};
    if (a.rsi_rt_priority > 0) args.insert(args.end(), {"--rt-priority", std::to_string(a.rsi_rt_priority)});
    if (a.rsi_pass_through) args.push_back("--pass-through");
    children.push_back(spawn("rsi_bridge_" + std::to_string(i + 1), with({}, args), a.work_dir, false, "", "rsi_bridge"));
  }
  return children;
}

// Adds each process's exit code and its --stats-json (topic counts summed with the launcher's own, the engine's,
// compensation's and recorder's counters) to the summary; returns how many processes failed.
int mergeProcessStats(std::vector<Child>& children, nlohmann::json topics, nlohmann::json* summary) {
  auto& s = *summary;
  s["processes"] = nlohmann::json::array();
  int failures = 0;
  std::uint64_t calibration_updates = 0;
  for (auto& c : children) {
    const int code = c.process.exitCode();
    s["processes"].push_back({{"name", c.name}, {"pid", c.process.pid()}, {"exit_code", code}});
    if (code != 0) {
      ++failures;
      std::fprintf(stderr, "cell: %s exited with code %d (see %s)\n", c.name.c_str(), code, c.process.logFile().c_str());
    }
    std::ifstream in(c.stats_file);
    if (!in) continue;
    const nlohmann::json p = nlohmann::json::parse(in, nullptr, false);
    if (p.is_discarded()) continue;
    if (c.name.rfind("rsi_bridge", 0) == 0) {  // its own counts, no DDS topics of its own (cell_rsi.cpp reads them)
      s["rsi_bridges"][c.name] = p;
      continue;
    }
    for (const auto& [topic, counts] : p[stats::kTopics].items()) {
      if (!topics.contains(topic)) topics[topic] = {{stats::kPublished, 0ULL}, {stats::kReceived, 0ULL}};
      auto& t = topics[topic];
      t[stats::kPublished] = t[stats::kPublished].get<std::uint64_t>() + counts.value(stats::kPublished, 0ULL);
      t[stats::kReceived] = t[stats::kReceived].get<std::uint64_t>() + counts.value(stats::kReceived, 0ULL);
    }
    const nlohmann::json& extra = p[stats::kExtra];
    // Shards (calibration_engine_2, ...): updates summed, each one's counts kept.
    if (c.name.rfind("calibration_engine", 0) == 0) {
      calibration_updates += extra.value(stats::kUpdates, 0ULL);
      s["engine"] = extra;
      s["engines"][c.name] = extra;
    }
    if (c.name.rfind("compensation_publisher", 0) == 0) {
      s["compensation"] = extra;
      s["compensation_publishers"][c.name] = extra;
    }
    if (c.name == "recorder") s["recorder"] = extra;
    if (c.name.rfind("tracker_adapter", 0) == 0) s["trackers"][c.name] = extra;
    if (c.name.rfind("joint_state_adapter", 0) == 0) s["joint_adapters"][c.name] = extra;
  }
  s["topics"] = topics;
  s["calibration_updates"] = calibration_updates;
  return failures;
}

}  // namespace cellcal::cli
