// `cellcal cell`: the four-process cell on localhost against the simulated robot(s) of the cell file.
// Launches cellcal_calibration_engine, cellcal_compensation_publisher, cellcal_tracker_adapter (sim) and
// cellcal_joint_state_adapter (sim) as separate processes, and joins the domain itself as the cell's application
// and its judge (cell_roles.hpp): it publishes TargetPoses, and scores every published calibration against the
// simulator's truth on a hold-out pose set (the engine never sees the truth).
#include <cstdio>
#include <filesystem>
#include <optional>
#include <set>
#include <thread>

#include "cell_roles.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/lab/sim_program.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

namespace fs = std::filesystem;
using namespace cellcal::components;

void addOptions(CLI::App& cmd, CellArgs& a) {
  addCommonOptions(cmd, a.common);
  cmd.add_option("--duration-s", a.duration_s, "how long the robot program runs (wall clock, from its first sample)")
      ->check(positive())
      ->capture_default_str();
  cmd.add_option("--summary-json", a.summary_json, "write the summary (processes, topics, accuracy, latencies)");
  cmd.add_option("--work-dir", a.work_dir, "logs, per-process stats and the engine's state")->capture_default_str();
  cmd.add_flag("--resume", a.resume, "keep the engine state of a previous run (default: start uncalibrated)");
  cmd.add_option("--targets-hz", a.targets_hz, "TargetPoses published per second and robot")
      ->check(positive())
      ->capture_default_str();
  cmd.add_flag("--servo", a.servo,
               "also stream a joint setpoint per robot with each target (cellcal/servo_setpoint, answered on "
               "cellcal/servo_correction), as a servo loop would at its controller's rate");
  cmd.add_option("--rsi-hz", a.rsi_hz,
                 "also a KUKA RSI stream per robot at this rate (250: RSI's 4 ms; 500): a cellcal_rsi_bridge process "
                 "per robot answers a simulated controller inside its cycle with the cell's calibrations; the summary "
                 "says late cycles and where the robot landed; default: the cell file's simulation.rsi_hz")
      ->check(CLI::Range(0.0, 1000.0));
  cmd.add_option("--rsi-rt-priority", a.rsi_rt_priority,
                 "SCHED_FIFO priority of the RSI bridges and simulated controllers (needs root or CAP_SYS_NICE)")
      ->check(CLI::Range(0, 99));
  cmd.add_flag("--rsi-pass-through", a.rsi_pass_through,
               "the RSI bridges answer every cycle with a zero correction and no compensator: the floor of the "
               "transport and the host (cellcal bench-servo --pass-through)");
  cmd.add_option("--targets-program", a.targets_program,
                 "the targets are this robot program's rows (`cellcal plan iso9283`), each once in order")
      ->check(CLI::ExistingFile);
  cmd.add_option("--landed-csv", a.landed_csv,
                 "write the program's compensated targets as the simulated tracker read them where the robot landed "
                 "(CSV with pose and cycle, for `cellcal iso9283 --data`)");
  cmd.add_flag("--quiet", a.quiet, "no line per update");
  cmd.add_option("--record", a.record, "also run `cellcal record` on every topic into this MCAP file");
  cmd.add_option("--shards", a.shards,
                 "split the robots into this many groups, each with its own engine, compensation publisher and "
                 "adapters (--robots; named calibration_engine_1, ...): a cell too large for one engine, or one "
                 "cell server per group")
      ->check(CLI::Range(1, 16))
      ->capture_default_str();
  cmd.add_option("--host", a.host_specs,
                 "PROCESS=NETNS: run that process (tracker_adapter, joint_state_adapter, calibration_engine, "
                 "compensation_publisher, recorder) in that network namespace, as on another host "
                 "(tools/netns/cellnet.sh, docs/deployment.md); repeatable")
      ->delimiter(',')
      ->check([](const std::string& v) {
        const auto eq = v.find('=');
        static const std::set<std::string> names = {"tracker_adapter", "joint_state_adapter", "calibration_engine",
                                                    "compensation_publisher", "recorder"};
        std::string process = eq == std::string::npos ? v : v.substr(0, eq);
        const auto us = process.find_last_of('_');  // a shard's: calibration_engine_2
        if (us != std::string::npos && us + 1 < process.size() &&
            process.find_first_not_of("0123456789", us + 1) == std::string::npos)
          process = process.substr(0, us);
        if (eq == std::string::npos || eq + 1 == v.size() || !names.count(process))
          return "expected PROCESS=NETNS with PROCESS one of tracker_adapter, joint_state_adapter, calibration_engine, "
                 "compensation_publisher, recorder (with --shards: calibration_engine_2, ...); got '" + v + "'";
        return std::string();
      })
      ->each([&a](const std::string& h) { a.hosts[h.substr(0, h.find('='))] = h.substr(h.find('=') + 1); });
}

int runCell(const CellArgs& options) {
  installStopHandlers();
  const CellConfig cell = loadCell(options.common);
  CellArgs a = options;
  if (a.rsi_hz == 0) a.rsi_hz = cell.simulation.rsi_hz;  // the cell file's, unless --rsi-hz says
  if (static_cast<std::size_t>(a.shards) > cell.robots.size())
    throw ConfigError("--shards " + std::to_string(a.shards) + ": the cell has " + std::to_string(cell.robots.size()) +
                      " robot(s)");
  if (!a.landed_csv.empty() && a.targets_program.empty())
    throw ConfigError("--landed-csv: needs --targets-program (the targets whose landing it reads)");
  fs::create_directories(a.work_dir);
  const std::string state_dir = (fs::path(a.work_dir) / "state").string();
  if (!a.resume) fs::remove_all(state_dir);
  // The launcher's participant: the application and the judge, then the participant they share (deleted first).
  CellApplication application(cell, a);
  CellJudge judge(cell, a, application.sent());
  std::optional<CellRsi> rsi;
  if (a.rsi_hz > 0) rsi.emplace(cell, a);
  DdsNode node(cell, "cellcal_cell_launcher", identity::kApplication);
  application.attach(node);
  judge.attach(node);
  std::vector<Child> children = startProcesses(cell, a, state_dir, rsi ? rsi->ports() : std::vector<int>{});
  std::printf("cell: %zu processes on domain %d (%s), cell time x%g, %zu robot(s); logs in %s\n", children.size(),
              cell.dds.domain_id, cell.dds.participant_profile.c_str(), cell.time_compression, cell.robots.size(),
              a.work_dir.c_str());
  for (const auto& c : children) std::printf("cell:   %-24s pid %d\n", c.name.c_str(), c.process.pid());
  for (size_t i = 0; i < cell.robots.size(); ++i)
    std::printf("cell: %s: simulating %s\n", cell.robots[i].robot_id.c_str(),
                simulatedRobotText(makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i))).c_str());
  std::fflush(stdout);

  const auto period = std::chrono::duration<double>(1.0 / a.targets_hz);
  auto next = std::chrono::steady_clock::now();
  bool child_died = false, rsi_started = false;
  while (judge.runningSeconds() < a.duration_s && !stopRequested() && !child_died) {
    next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
    std::this_thread::sleep_until(next);
    for (auto& c : children)
      if (!c.process.running()) {
        std::fprintf(stderr, "cell: %s exited early with code %d (see %s)\n", c.name.c_str(), c.process.exitCode(),
                     c.process.logFile().c_str());
        child_died = true;
      }
    if (child_died) break;
    judge.score();
    application.sendTargets();
    if (rsi && judge.runningSeconds() > 0) {  // the streams start with the robot program (every process is up)
      if (!rsi_started) rsi->start(), rsi_started = true;
      for (std::size_t i = 0; i < cell.robots.size(); ++i) rsi->setCellTimeS(i, judge.cellTimeS(i));
    }
  }
  if (rsi) rsi->stop();  // before the bridges stop: their last cycles are not late
  // Stopped in the reverse of their start: the cell's processes, which flush what they published last (a reliable
  // writer waits for its acknowledgements on a clean exit), then the recorder, so the recording holds it.
  std::vector<ChildProcess*> cell_processes, recorder;
  for (auto& c : children) (c.name == "recorder" ? recorder : cell_processes).push_back(&c.process);
  stopAll(cell_processes);
  stopAll(recorder);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  node.shutdown();  // no callback after this
  judge.score();    // what is left

  nlohmann::json summary;
  const int failures = mergeProcessStats(children, node.stats(), &summary);
  judge.summarize(&summary);
  application.summarize(&summary);
  const bool rsi_equal = !rsi || rsi->summarize(judge, &summary);
  if (!a.summary_json.empty()) {
    writeJsonFile(a.summary_json, summary);
    std::printf("cell: summary in %s\n", a.summary_json.c_str());
  }
  return failures == 0 && rsi_equal ? 0 : 1;
}

}  // namespace

Runner addCellCommand(CLI::App& app) { return addCommand(app, "cell", addOptions, runCell); }

}  // namespace cellcal::cli
