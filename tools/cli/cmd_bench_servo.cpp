// `cellcal bench-servo`: the RSI bridge inside the controller's cycle, measured in the whole cell. It runs `cellcal
// cell --rsi-hz` on a cell of --robots simulated robots (the engine, compensation publisher and adapters as processes,
// a cellcal_rsi_bridge process per robot, the simulated controllers as threads of the launcher, each on its own clock)
// while the engine calibrates the robots and publishes new versions, beside --hogs busy processes; with
// --rt-priority the bridges and the controllers run SCHED_FIFO. Before it, the compensator's correct() and the inverse
// kinematics are timed in this process, side by side. The figures come from the cell's summary: cycles answered in
// their cycle, late ones, the answer's latency, the versions the bridges switched to, the answers replayed in memory
// (equal to the bit), where the robots landed.
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>

#include "cellcal/components/child_process.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/servo/realtime_compensator.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

namespace fs = std::filesystem;
using components::ChildProcess;
using Clock = std::chrono::steady_clock;

struct Args {
  int robots = 1;
  double rate_hz = 250, duration_s = 10;
  int hogs = 0, rt_priority = 0, domain_id = 213;
  std::uint64_t seed = 1;
  bool pass_through = false;
  std::string json;
};

// The cell file: --robots TX60s, campaigns every 2 h of cell time (10 s at x720) for the whole run, so the engine
// publishes new versions while the streams run.
std::string cellFile(const fs::path& dir, const Args& a) {
  std::ofstream y(dir / "cell.yaml");
  y << "dds: { domain_id: " << a.domain_id << ", profiles_file: " << components::configDir()
    << "/dds/cellcal_qos.xml, participant_profile: cellcal_loopback }\ntime_compression: 720\nrobots:\n";
  for (int k = 0; k < a.robots; ++k)
    y << "  - { robot_id: tx60_" << k << ", target_id: tx60_" << k << "_target, robot_file: " << components::configDir()
      << "/robots/staubli_tx60.yaml, measurement: pose6d }\n";
  y << "engine: { state_dir: " << (dir / "state").string() << " }\n"
    << "simulation: { seed: " << a.seed << ", groups: " << static_cast<int>(a.duration_s / 10) + 2
    << ", hours_between_groups: 2 }\n";
  return (dir / "cell.yaml").string();
}

// correct() and the inverse kinematics timed here, side by side (p50, p99.9 of correct; p50 of the IK).
nlohmann::json inMemory(const RobotModel& m) {
  RealtimeCompensator rt(m, RealtimeSettings{});
  std::string why;
  Eigen::VectorXd p = m.nominal;
  for (int j = 0; j < m.numJoints(); ++j) p[m.jointParam(j, JointParam::kThetaOffset)] += degToRad(0.03);
  rt.publish(ServoVersion::prepare(m, 1, IdentifiedModel(CalibratedModel::geometric(p)), &why));
  std::vector<double> correct_us, ik_us;
  for (int k = 0; k < 20000; ++k) {
    double q[kMaxServoJoints];
    for (int j = 0; j < m.numJoints(); ++j) q[j] = degToRad(20 * std::sin(1e-3 * k + j) + (j == 2 ? 90 : 0));
    auto t0 = Clock::now();
    rt.correct(k * 4'000'000LL, q, m.numJoints());
    correct_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
    if (k % 10) continue;
    const Eigen::VectorXd qv = Eigen::Map<Eigen::VectorXd>(q, m.numJoints());
    const Pose target = forwardKinematics(m, p, Eigen::VectorXd(qv.array() + 0.01));
    t0 = Clock::now();
    solveInverseKinematics(m, p, target, qv);
    ik_us.push_back(std::chrono::duration<double, std::micro>(Clock::now() - t0).count());
  }
  return {{"correct_us", {{"p50", percentile(correct_us, 0.5)}, {"p999", percentile(correct_us, 0.999)}}},
          {"ik_us", {{"p50", percentile(ik_us, 0.5)}}}};
}

// SCHED_FIFO refused (--rt-priority without root or CAP_SYS_NICE) is `cellcal cell`'s error (--rsi-rt-priority),
// printed with its output.
int run(const Args& a) {
  const fs::path dir = fs::temp_directory_path() / ("cellcal_bench_servo_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const std::string cfg = cellFile(dir, a);
  const CellConfig cell = loadCellConfig(cfg);
  nlohmann::json out = inMemory(cell.robots[0].model);
  std::vector<std::unique_ptr<ChildProcess>> hogs;
  for (int h = 0; h < a.hogs; ++h)
    hogs.push_back(std::make_unique<ChildProcess>("/bin/sh", std::vector<std::string>{"-c", "while :; do :; done"},
                                                  (dir / "hog.log").string()));
  const std::string summary_file = (dir / "summary.json").string();
  std::vector<std::string> args = {"cell",
                                   "--config",
                                   cfg,
                                   "--duration-s",
                                   std::to_string(a.duration_s),
                                   "--rsi-hz",
                                   std::to_string(a.rate_hz),
                                   "--work-dir",
                                   (dir / "run").string(),
                                   "--summary-json",
                                   summary_file,
                                   "--quiet"};
  if (a.rt_priority > 0) args.insert(args.end(), {"--rsi-rt-priority", std::to_string(a.rt_priority)});
  if (a.pass_through) args.push_back("--rsi-pass-through");
  std::printf("bench-servo: %d robots x %.0f Hz for %.0f s, %d hogs, %s; the cell's logs in %s\n", a.robots, a.rate_hz,
              a.duration_s, a.hogs,
              a.rt_priority > 0 ? ("SCHED_FIFO " + std::to_string(a.rt_priority)).c_str() : "default scheduler",
              (dir / "run").c_str());
  std::fflush(stdout);
  ChildProcess cell_run(fs::read_symlink("/proc/self/exe").string(), args, (dir / "cell.log").string());
  const int code = cell_run.wait(a.duration_s + 300);
  for (auto& h : hogs) h->stop(SIGKILL, 5);
  std::ifstream in(summary_file);
  const nlohmann::json s = nlohmann::json::parse(in, nullptr, false);
  if (code != 0 || s.is_discarded() || !s.contains("rsi")) {
    std::ifstream log(dir / "cell.log");
    std::cerr << "bench-servo: cellcal cell exited with " << code << "; its output:\n" << log.rdbuf();
    return 1;
  }
  const nlohmann::json& r = s["rsi"];
  for (const char* k :
       {"cycles", "answered", "late", "late_stalls", "streams_late_per_stall", "latency_us", "versions_switched",
        "compared_cycles", "max_difference_rad", "equal_to_in_memory", "landed_error_compensated_mean_mm",
        "landed_error_uncompensated_mean_mm", "predicted_sigma_mean_mm"})
    out[k] = r[k];
  nlohmann::json per_robot = nlohmann::json::array();  // where the late cycles were: the controller's or the bridge's
  const nlohmann::json bridges = s.value("rsi_bridges", nlohmann::json::object());
  for (std::size_t k = 0; k < r["robots"].size(); ++k) {
    const nlohmann::json& rb = r["robots"][k];
    const nlohmann::json bridge = bridges.value("rsi_bridge_" + std::to_string(k + 1), nlohmann::json::object());
    per_robot.push_back({{"robot_id", rb["robot_id"]},
                         {"late", rb["late"]},
                         {"bridge_latency_us", bridge.value("latency_us", nlohmann::json())},
                         {"bridge_missed_cycles", bridge.value("missed_cycles", 0)}});
  }
  out["per_robot"] = per_robot;
  out.update({{"robots", a.robots},
              {"pass_through", a.pass_through},
              {"rate_hz", a.rate_hz},
              {"duration_s", a.duration_s},
              {"hogs", a.hogs},
              {"rt_priority", a.rt_priority},
              {"verify_after_mm", s["verify_after_mm"]},
              {"calibration_updates", s["calibration_updates"]}});
  const bool late = r["late"].get<std::uint64_t>() > 0, slow = r["latency_us"]["p99"].get<double>() >= 500;
  char replayed[160];
  std::snprintf(replayed, sizeof replayed, "answers equal the in-memory compensator's to %.1e rad over %llu cycles",
                r["max_difference_rad"].get<double>(), r["compared_cycles"].get<unsigned long long>());
  std::printf(
      "bench-servo: %llu cycles, %llu answered in their cycle, %llu late or missing; answer p50 %.0f us, p99 "
      "%.0f us, max %.0f us; %llu version switches; %s; landed %.4f mm (uncompensated %.4f mm, calibration hold-out "
      "%.4f mm); in memory correct() p50 %.2f us, p99.9 %.2f us, inverse kinematics p50 %.2f us\n",
      r["cycles"].get<unsigned long long>(), r["answered"].get<unsigned long long>(),
      r["late"].get<unsigned long long>(), r["latency_us"]["p50"].get<double>(), r["latency_us"]["p99"].get<double>(),
      r["latency_us"]["max"].get<double>(), r["versions_switched"].get<unsigned long long>(),
      a.pass_through ? "pass-through: zero corrections, nothing replayed" : replayed,
      r["landed_error_compensated_mean_mm"].get<double>(), r["landed_error_uncompensated_mean_mm"].get<double>(),
      s["verify_after_mm"].get<double>(), out["correct_us"]["p50"].get<double>(),
      out["correct_us"]["p999"].get<double>(), out["ik_us"]["p50"].get<double>());
  if (late)
    std::printf("bench-servo: the late cycles fell in %llu stall(s) of 10 ms, %.1f of the %d streams late in each\n",
                r["late_stalls"].get<unsigned long long>(), r["streams_late_per_stall"].get<double>(), a.robots);
  std::printf("bench-servo: targets: every cycle in time %s, answer p99 under 0.5 ms %s\n", late ? "NOT MET" : "met",
              slow ? "NOT MET" : "met");
  if (!a.json.empty()) std::ofstream(a.json) << out.dump(2) << "\n";
  fs::remove_all(dir);
  if (!r["equal_to_in_memory"].get<bool>()) return 1;
  return late || slow ? 3 : 0;
}

}  // namespace

Runner addBenchServoCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand("bench-servo", "");
  components::applyManPage(*cmd, "cellcal-bench-servo");
  auto a = std::make_shared<Args>();
  cmd->add_option("--robots", a->robots, "robots, each with its bridge and controller")
      ->check(CLI::Range(1, 16))
      ->capture_default_str();
  cmd->add_option("--rate-hz", a->rate_hz, "controller cycles per second: 250 (RSI's 4 ms), 500")
      ->check(CLI::IsMember({250.0, 500.0, 125.0, 1000.0}))
      ->capture_default_str();
  cmd->add_option("--duration-s", a->duration_s, "measuring time")->check(positive())->capture_default_str();
  cmd->add_option("--hogs", a->hogs, "busy processes beside it")->check(CLI::Range(0, 16))->capture_default_str();
  cmd->add_option("--rt-priority", a->rt_priority,
                  "SCHED_FIFO priority of the simulated controllers and the bridges (0: none)")
      ->check(CLI::Range(0, 99))
      ->capture_default_str();
  cmd->add_flag("--pass-through", a->pass_through,
                "the bridges answer zero corrections with no compensator: the floor of the transport and this host");
  cmd->add_option("--seed", a->seed, "the simulated robots' hidden errors and paths")->capture_default_str();
  cmd->add_option("--domain-id", a->domain_id, "DDS domain")->check(CLI::Range(0, 232))->capture_default_str();
  cmd->add_option("--json", a->json, "write the figures as JSON")->check(outputFile());
  return [a] { return run(*a); };
}

}  // namespace cellcal::cli
