// `cellcal bench-cell`: latency and sustained load of the engine and compensation processes, through real
// processes on localhost. This process plays N robots and their trackers: joint states and tracker readings at
// --rate-hz each per robot (the tracker streams all the time; the robot stands still 30 of every 50 ms), and
// TargetPoses at --targets-hz per robot. It measures, side by side in one run:
//   tracker reading published -> CalibrationState received   (p50/p99 over the poses)
//   TargetPose published -> CompensatedTarget received         (p50/p99)
// whether the engine kept up (every sample received, one update per stand-still, latency not growing), and the
// CPU (share of one core) and peak RSS of the engine and compensation processes. For soaks (minutes to hours): RSS of
// each process and the received calibrations' error against the simulated truth, sampled once a second, compared
// between the end of the first third of the run and its end.
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <optional>
#include <sstream>
#include <thread>

#include "bench_cell.hpp"
#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/child_process.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/host_limits.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

using namespace bench_cell;

void addOptions(CLI::App& cmd, BenchArgs& a) {
  cmd.add_option("--robots", a.robots, "robots (each with a joint-state and a tracker stream)")->check(CLI::Range(1, 64))->capture_default_str();
  cmd.add_option("--rate-hz", a.rate_hz, "rate of each stream")->check(CLI::Range(10.0, 5000.0))->capture_default_str();
  cmd.add_option("--targets-hz", a.targets_hz, "TargetPoses per second and robot")->check(positive())->capture_default_str();
  cmd.add_option("--duration-s", a.duration_s, "measuring time")->check(positive())->capture_default_str();
  cmd.add_option("--domain-id", a.domain_id, "DDS domain")->check(CLI::Range(0, 232))->capture_default_str();
  cmd.add_flag("--servo", a.servo,
               "send the targets as a servo loop's stream instead (cellcal/servo_setpoint, joint setpoints stamped "
               "with the cycle, best effort; answered on cellcal/servo_correction)");
  cmd.add_flag("--pass-through", a.pass_through,
               "run the compensation publisher with --pass-through (every request answered unchanged): the same "
               "processes, topics and QoS without the compensation, the transport's floor on this host");
  cmd.add_option("--dds-profile", a.dds_profile,
                 "participant profile of every process (config/dds/cellcal_qos.xml): cellcal_loopback (UDP on "
                 "127.0.0.1), cellcal_loopback_shm (shared memory first)")
      ->capture_default_str();
  cmd.add_option("--seed", a.seed, "seed of the simulated robots (hidden errors), their poses and the tracker noise")
      ->capture_default_str();
  cmd.add_option("--json", a.json, "write the figures as JSON")->check(outputFile());
  cmd.add_option("--record", a.record, "also run `cellcal record` of every topic into this MCAP file");
  cmd.add_option("--series-csv", a.series_csv,
                 "write, once a second: RSS of the engine, compensation and this process, and the mean error of the "
                 "received calibrations against the simulated truth (a soak's record)");
}

// What the bench receives: the calibrations (with the latest model of each robot) and the answers to its targets or
// setpoints, each with its arrival time.
void subscribe(DdsNode& node, const BenchRobots& robots, BenchReceived& rx) {
  node.reader<msg::CalibrationState>([&](const msg::CalibrationState& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    const auto it = robots.index_of.find(m.robot_id().to_string());
    std::optional<ReceivedCalibration> c;
    if (it != robots.index_of.end()) c = fromCalibrationState(robots.sims[it->second].model(), m, nullptr);
    std::lock_guard<std::mutex> l(rx.mutex);
    rx.states.push_back({now, static_cast<std::int64_t>(m.last_measurement_stamp_ns()), m.version(), m.robot_id().to_string()});
    if (c) rx.latest[it->second] = c->params;
    else ++rx.bad_states;
  });
  node.reader<msg::CompensatedTarget>([&](const msg::CompensatedTarget& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    std::lock_guard<std::mutex> l(rx.mutex);
    rx.comps.emplace_back(now, m.target_sequence());
  });
  node.reader<msg::ServoCorrection>([&](const msg::ServoCorrection& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    std::lock_guard<std::mutex> l(rx.mutex);
    rx.comps.emplace_back(now, m.setpoint_sequence());
  });
}

// The compensation publisher's own figures: the CPU of a target's callback (take, compensate, write) against the
// process's CPU per target (the rest: DDS's receive and event threads, the kernel's UDP path, wake-ups).
void reportCompensation(const BenchArgs& a, const fs::path& dir, const BenchPlayed& played, double cpu_c, double wall,
                        std::size_t answered, nlohmann::json* out_json) {
  nlohmann::json& out = *out_json;
  const auto cs = nlohmann::json::parse(std::ifstream((dir / "comp.json").string()), nullptr, false);
  if (!cs.is_discarded() && cs[stats::kExtra].contains(stats::kTargetCpuUs)) {
    const auto& tc = a.servo ? cs[stats::kExtra][stats::kServo]["cpu_us"] : cs[stats::kExtra][stats::kTargetCpuUs];
    const double sent = static_cast<double>(played.target_seq);
    const double process_us = sent > 0 ? cpu_c * wall / sent * 1e6 : 0.0;
    const nlohmann::json outcomes = a.servo ? nlohmann::json{{"applied", cs[stats::kExtra][stats::kServo]["applied"]},
                                                             {"answered", cs[stats::kExtra][stats::kServo]["answered"]},
                                                             {"out_of_order", cs[stats::kExtra][stats::kServo]["out_of_order"]}}
                                            : cs[stats::kExtra][stats::kOutcomes];
    std::printf("compensation per %s: callback CPU mean %.1f us, p99 %.0f us, max %.0f us; process CPU %.0f us "
                "a %s; answered %zu of %llu; outcomes %s\n",
                a.servo ? "setpoint" : "target", tc.value("mean", 0.0), tc.value("p99", 0.0), tc.value("max", 0.0),
                process_us, a.servo ? "setpoint" : "target", answered,
                static_cast<unsigned long long>(played.target_seq), outcomes.dump().c_str());
    out["compensation"] = {{"stream", a.servo ? "servo" : "target"}, {"target_callback_cpu_us", tc},
                           {"process_cpu_us_per_target", process_us}, {"outcomes", outcomes}};
  }
}

int runBench(const BenchArgs& a) {
  // Targets go out on the streams' ticks: at most one per tick, every rate/targets ticks.
  if (a.targets_hz > a.rate_hz)
    throw ConfigError("--targets-hz " + std::to_string(a.targets_hz) + " above --rate-hz " + std::to_string(a.rate_hz) +
                      ": targets are sent on the streams' ticks (at most one per tick and robot); raise --rate-hz");
  installStopHandlers();
  const fs::path dir = fs::temp_directory_path() / ("cellcal_bench_cell_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const CellConfig cell = loadCellConfig(writeBenchCellFile(dir, a));
  BenchProcesses p(dir, cell.source, a.record, a.pass_through);
  const pid_t engine = p.engine.pid(), comp = p.compensation.pid();
  const pid_t recorder = p.recorder ? p.recorder->pid() : -1;

  BenchRobots robots(cell, a);
  BenchReceived rx;
  rx.latest = robots.nominal();
  DdsNode node(cell, "cellcal_bench_cell", identity::kReplay);
  auto js = node.writer<msg::JointState>();
  auto tp = node.writer<msg::TrackerPose>();
  auto tg = node.writer<msg::TargetPose>();
  auto sv = node.writer<msg::ServoSetpoint>();
  subscribe(node, robots, rx);
  waitForReaders({js.entity(), tp.entity(), a.servo ? sv.entity() : tg.entity()}, recorder > 0 ? 2 : 1, dir);

  const CpuMeter cpu_engine(engine), cpu_comp(comp), cpu_self(::getpid()), cpu_recorder(recorder);
  // Datagrams the kernel drops for a full socket buffer (this network namespace; the processes here dominate it).
  const auto kernel_drops0 = udpReceiveBufferErrors();
  const double uncalibrated_mm = robots.meanErrorMm(rx.latest);
  std::printf("bench-cell: %d robots, joint states and tracker readings at %.0f Hz each per robot, targets at %.0f Hz "
              "per robot, %.0f s%s...\n", a.robots, a.rate_hz, a.targets_hz, a.duration_s,
              a.pass_through ? " (compensation publisher with --pass-through: answered unchanged)" : "");
  std::fflush(stdout);
  const BenchPlayed played = play(a, cell, robots, rx, js, tp, tg, sv, p);
  const double wall = played.wall_s;
  const auto kernel_drops1 = udpReceiveBufferErrors();
  const auto rmem_max = readKernelLimit("/proc/sys/net/core/rmem_max");
  const double cpu_e = cpu_engine.share(wall), cpu_c = cpu_comp.share(wall), cpu_s = cpu_self.share(wall);
  const double rss_engine = peakRssMb(engine), rss_comp = peakRssMb(comp);
  const double cpu_r = cpu_recorder.share(wall);
  const double rss_recorder = recorder > 0 ? peakRssMb(recorder) : 0;
  p.stop();
  node.shutdown();

  const BenchLatencies l = latencies(rx);
  const auto es = nlohmann::json::parse(std::ifstream((dir / "engine.json").string()), nullptr, false);
  const std::uint64_t js_pub = static_cast<std::uint64_t>(played.ticks) * a.robots, js_rx = es.is_discarded() ? 0 : es[stats::kTopics]["cellcal/joint_state"].value(stats::kReceived, 0ULL);
  const std::uint64_t tp_rx = es.is_discarded() ? 0 : es[stats::kTopics]["cellcal/tracker_pose"].value(stats::kReceived, 0ULL);
  nlohmann::json out = {
      {"robots", a.robots}, {"pass_through", a.pass_through}, {"rate_hz_per_stream", a.rate_hz}, {"targets_hz_per_robot", a.targets_hz}, {"duration_s", wall},
      {"tracker_to_state_us", {{"p50", percentile(l.state_us, 0.5)}, {"p99", percentile(l.state_us, 0.99)}, {"samples", l.state_us.size()},
                               {"p50_first_third", percentile(l.first_third, 0.5)}, {"p50_last_third", percentile(l.last_third, 0.5)}}},
      {"target_to_compensated_us", {{"p50", percentile(l.comp_us, 0.5)}, {"p99", percentile(l.comp_us, 0.99)}, {"samples", l.comp_us.size()},
                                    {"sent", played.target_seq}}},
      {"joint_states", {{"published", js_pub}, {"received_by_engine", js_rx}}},
      {"tracker_readings", {{"published", js_pub}, {"received_by_engine", tp_rx}}},
      {"standstills", played.standstills}, {"calibration_updates", l.versions}, {"bench_ticks_late", played.late_ticks},
      {"cpu_share_of_one_core", {{"engine", cpu_e}, {"compensation_publisher", cpu_c}, {"bench_publisher", cpu_s}}},
      {"peak_rss_mb", {{"engine", rss_engine}, {"compensation_publisher", rss_comp}}},
      {"cores", std::thread::hardware_concurrency()}};
  out["host"] = {{"net_core_rmem_max_bytes", rmem_max ? nlohmann::json(*rmem_max) : nlohmann::json()},
                 {"profile_udp_receive_buffer_bytes", node.udpReceiveBufferBytes()},
                 {"udp_datagrams_dropped_by_kernel",
                  kernel_drops0 && kernel_drops1 ? nlohmann::json(*kernel_drops1 - *kernel_drops0) : nlohmann::json()}};
  const BenchSample* third_p = nullptr;
  out["soak"] = soakFigures(played, uncalibrated_mm, rx.bad_states, &third_p);
  const BenchSample& third = *third_p;
  const BenchSample& end = played.series.back();
  writeSeriesCsv(a.series_csv, played.series);
  std::printf("                                     p50 us    p99 us   samples\n");
  std::printf("tracker reading -> CalibrationState %8.0f  %8.0f  %8zu\n", percentile(l.state_us, 0.5), percentile(l.state_us, 0.99), l.state_us.size());
  std::printf("%s %8.0f  %8.0f  %8zu\n", a.servo ? "ServoSetpoint -> ServoCorrection   " : "TargetPose -> CompensatedTarget    ", percentile(l.comp_us, 0.5), percentile(l.comp_us, 0.99), l.comp_us.size());
  std::printf("engine received %llu of %llu joint states and %llu of %llu tracker readings; %llu updates for %llu stand-stills\n",
              static_cast<unsigned long long>(js_rx), static_cast<unsigned long long>(js_pub),
              static_cast<unsigned long long>(tp_rx), static_cast<unsigned long long>(js_pub),
              static_cast<unsigned long long>(l.versions), static_cast<unsigned long long>(played.standstills));
  reportCompensation(a, dir, played, cpu_c, wall, l.comp_us.size(), &out);
  if (!es.is_discarded() && es[stats::kExtra].contains(stats::kInputQueue)) {
    const auto& iq = es[stats::kExtra][stats::kInputQueue];
    std::printf("engine input queue (samples waiting for its worker): peak %llu, refused %llu (bound %llu)\n",
                iq.value("peak", 0ULL), iq.value("refused", 0ULL), iq.value("max", 0ULL));
    out["engine_input_queue"] = iq;
  }
  if (kernel_drops0 && kernel_drops1)
    std::printf("UDP datagrams the kernel dropped for a full socket buffer during the run: %llu (net.core.rmem_max "
                "%s bytes; the profile asks for %u)\n",
                static_cast<unsigned long long>(*kernel_drops1 - *kernel_drops0),
                rmem_max ? std::to_string(*rmem_max).c_str() : "?", node.udpReceiveBufferBytes());
  std::printf("tracker -> state p50 first third %.0f us, last third %.0f us (growing = falling behind)\n",
              percentile(l.first_third, 0.5), percentile(l.last_third, 0.5));
  std::printf("CPU (share of one core): engine %.2f, compensation %.2f, this publisher %.2f; peak RSS engine %.1f MB, "
              "compensation %.1f MB; %u cores\n",
              cpu_e, cpu_c, cpu_s, rss_engine, rss_comp, std::thread::hardware_concurrency());
  std::printf("memory (RSS MB) at %.0f s / at %.0f s: engine %.1f / %.1f, compensation %.1f / %.1f, this publisher "
              "%.1f / %.1f\n",
              third.t_s, end.t_s, third.engine_rss_mb, end.engine_rss_mb, third.compensation_rss_mb,
              end.compensation_rss_mb, third.publisher_rss_mb, end.publisher_rss_mb);
  std::printf("calibration error against the truth (mean of %d robots x 32 hold-out poses): uncalibrated %.3f mm, at "
              "%.0f s %.4f mm, at the end %.4f mm\n",
              a.robots, uncalibrated_mm, third.t_s, third.error_mm, end.error_mm);
  if (recorder > 0) reportRecorder(dir, a, js_pub, cpu_r, rss_recorder, &out);
  if (!a.json.empty()) writeJsonFile(a.json, out);
  fs::remove_all(dir);
  return 0;
}

}  // namespace

Runner addBenchCellCommand(CLI::App& app) { return addCommand(app, "bench-cell", addOptions, runBench); }

}  // namespace cellcal::cli
