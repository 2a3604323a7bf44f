// `cellcal cell`: the four-process cell on localhost against the simulated robot(s) of the cell file.
// Launches cellcal_calibration_engine, cellcal_compensation_publisher, cellcal_tracker_adapter (sim) and
// cellcal_joint_state_adapter (sim) as separate processes, and joins the domain itself as the cell's application
// and its judge: it publishes TargetPoses, and scores every published calibration against the simulator's truth
// on a hold-out pose set (the engine never sees the truth).
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <sys/prctl.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/calibration_engine.hpp"
#include "cellcal/core/compensation.hpp"
#include "cellcal/core/inverse_kinematics.hpp"
#include "cellcal/core/kinematics.hpp"
#include "cellcal/core/sim_program.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

namespace fs = std::filesystem;
using namespace cellcal::components;

struct CellArgs {
  ProcessOptions common;
  double duration_s = 32;  // the default cell: 4 campaigns, the last one ends at ~30.6 s
  std::string summary_json;
  std::string work_dir = "cellcal-cell";
  bool resume = false;
  double targets_hz = 20;
  int holdout_poses = 100;
  bool quiet = false;
  bool in_process_reference = true;
  std::string record;  // MCAP file: a recorder process records every topic
};

struct Child {
  std::string name;
  pid_t pid = -1;
  std::string stats_file, log_file;
  int exit_code = -1;
};

// Starts bin/cellcal_<name> (or `cellcal <args>` when `self`) with its output in <work_dir>/<name>.log.
Child spawn(const std::string& name, const std::vector<std::string>& args, const std::string& work_dir, bool self = false) {
  Child c;
  c.name = name;
  c.stats_file = (fs::path(work_dir) / (name + ".stats.json")).string();
  c.log_file = (fs::path(work_dir) / (name + ".log")).string();
  const fs::path exe = self ? fs::read_symlink("/proc/self/exe")
                            : fs::read_symlink("/proc/self/exe").parent_path() / ("cellcal_" + name);
  if (!fs::exists(exe)) throw std::runtime_error(exe.string() + " not found (build all targets)");
  std::vector<std::string> full = {exe.string()};
  full.insert(full.end(), args.begin(), args.end());
  full.push_back("--stats-json");
  full.push_back(c.stats_file);
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid < 0) throw std::runtime_error("fork failed");
  if (pid == 0) {
    // The cell goes down with the launcher, even when it is SIGKILLed (SIGTERM: each component's clean stop).
    ::prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (::getppid() != parent) ::_exit(1);  // the launcher died before prctl
    const int fd = ::open(c.log_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      ::close(fd);
    }
    std::vector<char*> argv;
    for (auto& a : full) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    std::perror("execv");
    ::_exit(127);
  }
  c.pid = pid;
  return c;
}

void stopChildren(std::vector<Child>& children) {
  for (auto& c : children)
    if (c.pid > 0 && c.exit_code < 0) ::kill(c.pid, SIGINT);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(15);
  for (auto& c : children) {
    while (c.exit_code < 0) {
      int status = 0;
      const pid_t r = ::waitpid(c.pid, &status, WNOHANG);
      if (r == c.pid) {
        c.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        break;
      }
      if (std::chrono::steady_clock::now() > deadline) {
        ::kill(c.pid, SIGKILL);
        ::waitpid(c.pid, &status, 0);
        c.exit_code = 137;
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
}

// The judge's view of one robot: truth, hold-out poses, calibrations, targets.
struct Judge {
  Judge(const CellRobot* r, SimulatedCell s) : robot(r), sim(std::move(s)) {}
  const CellRobot* robot;
  SimulatedCell sim;
  std::vector<Eigen::VectorXd> holdout;
  std::vector<Eigen::VectorXd> target_qs;
  double cell_time_s = 0;
  std::uint64_t version = 0;
  IdentifiedModel identified;  // the latest calibration received (with its model extensions, if any)
  double verify_mm = std::nan(""), nominal_mm = std::nan("");
  std::vector<double> correction_mm, correction_deg, compensated_error_mm, uncompensated_error_mm;
  std::uint64_t target_seq = 0, applied = 0, refused = 0;
  std::map<std::uint64_t, std::pair<std::int64_t, Eigen::VectorXd>> sent;  // seq -> (send time, nominal joints)

  double verify(const IdentifiedModel& m, double t_h) const {
    const RobotModel& model = sim.model();
    KinematicsData d(model);
    double s = 0;
    for (const auto& q : holdout) {
      const Eigen::VectorXd p = extendedParams(model, m.params, m.extensions, m.extension_params, q, Drivers{});
      s += (forwardKinematics(model, d, p, q).translation() - sim.truePose(q, t_h).translation()).norm();
    }
    return s / static_cast<double>(holdout.size()) * 1e3;
  }
  double verifyNominal(double t_h) const { return verify(IdentifiedModel{sim.nominalParams(), {}, {}}, t_h); }
};

// The same robot program and tracker model, through core's CalibrationEngine in this process (no DDS): what the
// cell should reach. Poses measured up to `cell_time_end_s`.
double inProcessReference(const CellConfig& cell, const CellRobot& robot, int index, double cell_time_end_s,
                          const Judge& judge) {
  const SimulatedCell sim = makeSimulatedCell(robot, cell.simulation, index);
  const SimRobotProgram program(sim, cell.simulation);
  EngineSettings es = cell.engine;
  CalibrationEngine engine(robot, es, cell.time_compression, /*persist=*/false);
  std::mt19937_64 rng(sim.config().seed * 6364136223846793005ULL + 1442695040888963407ULL);
  const std::int64_t epoch = 1'700'000'000'000'000'000;
  auto wall = [&](double t) { return epoch + static_cast<std::int64_t>(t / cell.time_compression * 1e9); };
  const double pt = cell.simulation.pose_time_s, sf = cell.simulation.settle_fraction;
  std::uint64_t seq = 0;
  for (int g = 0; g < program.campaigns(); ++g)
    for (int k = 0; k < program.posesIn(g); ++k) {
      const double t_read = program.campaignStart_s(g) + k * pt + (1 - sf + cell.simulation.tracker_delay_fraction * sf) * pt;
      if (t_read > cell_time_end_s) break;
      const Eigen::VectorXd& q = program.campaignConfigurations(g)[k];
      engine.onJointState({wall(t_read) - 1000, ++seq, q, true}, wall(t_read));
      TrackerSample s = toTrackerSample(toTrackerPose(robot.target_id, wall(t_read), seq,
                                                      sim.measure(q, t_read / 3600.0, rng, robot.measurement)));
      engine.onTrackerSample(s, wall(t_read));
      engine.onJointState({wall(t_read) + 1000, ++seq, q, true}, wall(t_read));
      engine.process(wall(t_read) + 2000);
    }
  const CalibrationSnapshot& snap = engine.snapshot();
  return judge.verify(IdentifiedModel{snap.params, snap.extensions, snap.extension_params}, cell_time_end_s / 3600.0);
}

int runCell(const CellArgs& a) {
  CellConfig cell = loadCell(a.common);
  fs::create_directories(a.work_dir);
  const std::string state_dir = (fs::path(a.work_dir) / "state").string();
  if (!a.resume) fs::remove_all(state_dir);
  const std::string config_path = fs::absolute(a.common.config_path).string();
  const std::vector<std::string> common = {"--config", config_path, "--domain-id", std::to_string(cell.dds.domain_id),
                                           "--dds-profile", cell.dds.participant_profile};
  std::vector<Judge> judges;
  for (size_t i = 0; i < cell.robots.size(); ++i) {
    Judge j(&cell.robots[i], makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i)));
    std::mt19937_64 rng(cell.simulation.seed * 31 + 12345 + i);
    j.holdout = j.sim.randomConfigurations(a.holdout_poses, rng);
    j.target_qs = j.sim.randomConfigurations(200, rng);
    j.identified.params = j.sim.nominalParams();
    judges.push_back(std::move(j));
  }
  std::mutex mutex;
  std::vector<double> tracker_to_state_us, target_to_compensated_us;
  std::uint64_t updates_seen = 0;
  const auto t0 = std::chrono::steady_clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); };

  DdsNode node(cell, "cellcal_cell_launcher", identity::kApplication);
  auto targets = node.writer<msg::TargetPose>();
  auto findJudge = [&](const std::string& id) -> Judge* {
    for (auto& j : judges)
      if (j.robot->robot_id == id) return &j;
    return nullptr;
  };
  std::optional<std::chrono::steady_clock::time_point> program_start;  // first RobotTruth: the robot runs
  node.reader<sim::RobotTruth>([&](const sim::RobotTruth& t, const fdds::SampleInfo&) {
    std::lock_guard<std::mutex> lock(mutex);
    if (!program_start) program_start = std::chrono::steady_clock::now();
    if (Judge* j = findJudge(t.robot_id().to_string())) j->cell_time_s = std::max(j->cell_time_s, t.cell_time_s());
  });
  // DDS callbacks only record (receipt time, sample): one receive thread serves every reader, so scoring in a
  // callback would delay the others and inflate the latencies measured.
  std::vector<std::pair<std::int64_t, msg::CalibrationState>> states_in;
  std::vector<std::pair<std::int64_t, msg::CompensatedTarget>> compensated_in;
  node.reader<msg::CalibrationState>([&](const msg::CalibrationState& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    std::lock_guard<std::mutex> lock(mutex);
    states_in.emplace_back(now, m);
  });
  node.reader<msg::CompensatedTarget>([&](const msg::CompensatedTarget& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    std::lock_guard<std::mutex> lock(mutex);
    compensated_in.emplace_back(now, m);
  });
  auto score = [&]() {
    std::vector<std::pair<std::int64_t, msg::CalibrationState>> states;
    std::vector<std::pair<std::int64_t, msg::CompensatedTarget>> comps;
    {
      std::lock_guard<std::mutex> lock(mutex);
      states.swap(states_in);
      comps.swap(compensated_in);
    }
    for (const auto& [now, m] : states) {
      Judge* j = findJudge(m.robot_id().to_string());
      if (!j || m.version() == j->version) continue;
      std::string err;
      auto c = fromCalibrationState(j->sim.model(), m, &err);
      if (!c) {
        std::cerr << "cell: " << err << "\n";
        continue;
      }
      if (m.last_measurement_stamp_ns() > 0)
        tracker_to_state_us.push_back((now - static_cast<std::int64_t>(m.last_measurement_stamp_ns())) / 1e3);
      ++updates_seen;
      j->version = c->version;
      j->identified = IdentifiedModel{c->params, c->extensions, c->extension_params};
      double cell_time;
      {
        std::lock_guard<std::mutex> lock(mutex);
        cell_time = j->cell_time_s;
      }
      const double t_h = cell_time / 3600.0;
      j->verify_mm = j->verify(j->identified, t_h);
      j->nominal_mm = j->verifyNominal(t_h);
      if (!a.quiet) {
        const double corr = j->correction_mm.empty() ? std::nan("") : j->correction_mm.back();
        std::printf("[%6.2f s] %-8s v%-4llu poses %-4u cell time %5.2f h | hold-out error %.4f mm (uncalibrated %.3f mm) | "
                    "last correction %.3f mm\n",
                    elapsed(), j->robot->robot_id.c_str(), static_cast<unsigned long long>(c->version), c->poses_used,
                    t_h, j->verify_mm, j->nominal_mm, corr);
        std::fflush(stdout);
      }
    }
    for (const auto& [now, m] : comps) {
      Judge* j = findJudge(m.robot_id().to_string());
      if (!j) continue;
      auto it = j->sent.find(m.target_sequence());
      if (it == j->sent.end()) continue;
      target_to_compensated_us.push_back((now - it->second.first) / 1e3);
      const Eigen::VectorXd q_nominal = it->second.second;
      j->sent.erase(it);
      if (!m.applied()) {
        ++j->refused;
        continue;
      }
      ++j->applied;
      j->correction_mm.push_back(m.correction_position_m() * 1e3);
      j->correction_deg.push_back(m.correction_orientation_rad() * 180 / kPi);
      // Where the real robot lands: the controller (nominal model) drives to the commanded pose.
      const RobotModel& model = j->sim.model();
      const Pose commanded = toPose(m.corrected_position_m(), m.corrected_orientation_xyzw());
      const Pose desired = toPose(m.desired_position_m(), m.desired_orientation_xyzw());
      const Eigen::VectorXd seed = Eigen::Map<const Eigen::VectorXd>(
          m.joint_position_rad().data(), static_cast<Eigen::Index>(m.joint_position_rad().size()));
      const IkResult ctrl = solveInverseKinematics(model, model.nominal, commanded, seed);
      if (!ctrl.ok()) continue;
      const double t_h = j->cell_time_s / 3600.0;
      j->compensated_error_mm.push_back((j->sim.truePose(ctrl.q_rad, t_h).translation() - desired.translation()).norm() * 1e3);
      j->uncompensated_error_mm.push_back((j->sim.truePose(q_nominal, t_h).translation() - desired.translation()).norm() * 1e3);
    }
  };

  std::vector<Child> children;
  // The recorder first: the robot program waits for its RobotTruth reader too, so the recording starts with the program.
  if (!a.record.empty())
    children.push_back(spawn("recorder", [&] { auto v = common; v.insert(v.begin(), "record"); v.insert(v.end(), {"--out", fs::absolute(a.record).string(), "--quiet"}); return v; }(), a.work_dir, true));
  children.push_back(spawn("calibration_engine", [&] { auto v = common; v.insert(v.end(), {"--state-dir", state_dir, "--quiet"}); return v; }(), a.work_dir));
  children.push_back(spawn("compensation_publisher", common, a.work_dir));
  children.push_back(spawn("tracker_adapter", [&] { auto v = common; v.insert(v.end(), {"--source", "sim"}); return v; }(), a.work_dir));
  // The robot starts its program once the engine and the tracker listen (discovery on loopback takes a moment).
  children.push_back(spawn("joint_state_adapter", [&] { auto v = common; v.insert(v.end(), {"--source", "sim", "--wait-for-readers", a.record.empty() ? "2" : "3"}); return v; }(), a.work_dir));
  std::printf("cell: %zu processes on domain %d (%s), cell time x%g, %zu robot(s); logs in %s\n", children.size(),
              cell.dds.domain_id, cell.dds.participant_profile.c_str(), cell.time_compression, cell.robots.size(),
              a.work_dir.c_str());
  for (const auto& c : children) std::printf("cell:   %-24s pid %d\n", c.name.c_str(), c.pid);
  std::fflush(stdout);

  std::mt19937_64 target_rng(cell.simulation.seed + 777);
  const auto period = std::chrono::duration<double>(1.0 / a.targets_hz);
  auto next = std::chrono::steady_clock::now();
  bool child_died = false;
  // --duration-s counts from the moment the robot program runs (start-up and discovery excluded), so a loaded
  // machine still sees the whole program; at most 30 s are allowed for start-up.
  auto running_s = [&]() -> double {
    std::lock_guard<std::mutex> lock(mutex);
    if (!program_start) return elapsed() > 30 ? a.duration_s : 0.0;
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - *program_start).count();
  };
  while (running_s() < a.duration_s && !stopRequested()) {
    next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
    std::this_thread::sleep_until(next);
    for (auto& c : children) {
      int status = 0;
      if (c.exit_code < 0 && ::waitpid(c.pid, &status, WNOHANG) == c.pid) {
        c.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        std::fprintf(stderr, "cell: %s exited early with code %d (see %s)\n", c.name.c_str(), c.exit_code, c.log_file.c_str());
        child_died = true;
      }
    }
    if (child_died) break;
    score();
    for (auto& j : judges) {
      const Eigen::VectorXd& q = j.target_qs[std::uniform_int_distribution<size_t>(0, j.target_qs.size() - 1)(target_rng)];
      KinematicsData d(j.sim.model());
      const Pose desired = forwardKinematics(j.sim.model(), d, j.sim.nominalParams(), q);
      msg::TargetPose t;
      t.robot_id(j.robot->robot_id);
      t.sequence_number(++j.target_seq);
      fromPose(desired, t.position_m(), t.orientation_xyzw());
      t.seed_position_rad(std::vector<double>(q.data(), q.data() + q.size()));
      const std::int64_t now = wallNs();
      t.source_stamp_ns(static_cast<std::uint64_t>(now));
      j.sent[j.target_seq] = {now, q};
      targets.write(t);
    }
  }
  stopChildren(children);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  node.shutdown();
  score();

  // Summary.
  nlohmann::json summary;
  summary["processes"] = nlohmann::json::array();
  nlohmann::json topics = node.stats();
  int failures = 0;
  std::uint64_t calibration_updates = 0;
  for (const auto& c : children) {
    summary["processes"].push_back({{"name", c.name}, {"pid", c.pid}, {"exit_code", c.exit_code}});
    if (c.exit_code != 0) {
      ++failures;
      std::fprintf(stderr, "cell: %s exited with code %d (see %s)\n", c.name.c_str(), c.exit_code, c.log_file.c_str());
    }
    std::ifstream in(c.stats_file);
    if (!in) continue;
    const nlohmann::json s = nlohmann::json::parse(in, nullptr, false);
    if (s.is_discarded()) continue;
    for (const auto& [topic, counts] : s["topics"].items()) {
      if (!topics.contains(topic)) topics[topic] = {{"published", 0ULL}, {"received", 0ULL}};
      auto& t = topics[topic];
      t["published"] = t["published"].get<std::uint64_t>() + counts.value("published", 0ULL);
      t["received"] = t["received"].get<std::uint64_t>() + counts.value("received", 0ULL);
    }
    if (c.name == "calibration_engine") {
      calibration_updates = s["extra"].value("updates", 0ULL);
      summary["engine"] = s["extra"];
    }
    if (c.name == "compensation_publisher") summary["compensation"] = s["extra"];
    if (c.name == "recorder") summary["recorder"] = s["extra"];
  }
  summary["topics"] = topics;
  summary["calibration_updates"] = calibration_updates;
  nlohmann::json robots = nlohmann::json::array();
  double before = 0, after = 0, reference = 0, at_update = 0;
  for (size_t i = 0; i < judges.size(); ++i) {
    Judge& j = judges[i];
    const double t_h = j.cell_time_s / 3600.0;
    const double vb = j.verifyNominal(t_h), va = j.verify(j.identified, t_h);
    const double ref = a.in_process_reference ? inProcessReference(cell, *j.robot, static_cast<int>(i), j.cell_time_s, j) : std::nan("");
    before += vb / judges.size();
    after += va / judges.size();
    at_update += j.verify_mm / judges.size();
    reference += ref / judges.size();
    auto mean = [](const std::vector<double>& v) {
      double s = 0;
      for (double x : v) s += x;
      return v.empty() ? std::nan("") : s / v.size();
    };
    robots.push_back({{"robot_id", j.robot->robot_id},
                      {"final_version", j.version},
                      {"cell_time_h", t_h},
                      {"verify_before_mm", vb},
                      {"verify_after_mm", va},
                      {"verify_after_last_update_mm", j.verify_mm},  // at the cell time of the last update
                      {"in_process_verify_after_mm", ref},
                      {"targets_applied", j.applied},
                      {"targets_refused", j.refused},
                      {"correction_mean_mm", mean(j.correction_mm)},
                      {"correction_mean_deg", mean(j.correction_deg)},
                      {"landed_error_compensated_mean_mm", mean(j.compensated_error_mm)},
                      {"landed_error_uncompensated_mean_mm", mean(j.uncompensated_error_mm)}});
  }
  summary["robots"] = robots;
  summary["verify_before_mm"] = before;
  summary["verify_after_mm"] = after;
  summary["in_process_verify_after_mm"] = reference;
  summary["verify_after_last_update_mm"] = at_update;
  summary["latency_us"] = {{"tracker_to_state_p50", percentile(tracker_to_state_us, 0.5)},
                           {"tracker_to_state_p99", percentile(tracker_to_state_us, 0.99)},
                           {"target_to_compensated_p50", percentile(target_to_compensated_us, 0.5)},
                           {"target_to_compensated_p99", percentile(target_to_compensated_us, 0.99)},
                           {"tracker_to_state_samples", tracker_to_state_us.size()},
                           {"target_to_compensated_samples", target_to_compensated_us.size()}};
  summary["domain_id"] = cell.dds.domain_id;
  summary["duration_s"] = elapsed();
  std::printf("cell: %llu calibration updates; hold-out error at the end %.4f mm calibrated vs %.3f mm uncalibrated "
              "(in-process engine on the same poses: %.4f mm); %.4f mm right after the last update\n",
              static_cast<unsigned long long>(calibration_updates), after, before, reference, at_update);
  std::printf("cell: latency tracker -> CalibrationState p50 %.0f us, p99 %.0f us; TargetPose -> CompensatedTarget "
              "p50 %.0f us, p99 %.0f us\n",
              percentile(tracker_to_state_us, 0.5), percentile(tracker_to_state_us, 0.99),
              percentile(target_to_compensated_us, 0.5), percentile(target_to_compensated_us, 0.99));
  if (!a.summary_json.empty()) {
    writeJsonFile(a.summary_json, summary);
    std::printf("cell: summary in %s\n", a.summary_json.c_str());
  }
  return failures == 0 ? 0 : 1;
}

}  // namespace

Runner addCellCommand(CLI::App& app) {
  auto a = std::make_shared<CellArgs>();
  CLI::App* cmd = app.add_subcommand(
      "cell",
      "Run the four-process cell on localhost against the simulated robot(s) of the cell file (degrading over "
      "time-compressed hours); print a line per calibration update and a summary");
  cmd->footer(cliFooter("  cellcal cell --duration-s 32                             the demo (make demo)\n  cellcal cell --duration-s 32 --record demo.mcap --summary-json s.json\n  CELLCAL_SECURITY_DIR=pki cellcal cell --duration-s 12    the same under DDS Security (docs/SECURITY.md)\n",
                        "  --config: the cell file (docs/cell-file.md); --work-dir: the log and counts of each process\n"));
  addCommonOptions(*cmd, a->common);
  a->common.participant_profile = "cellcal_loopback";
  cmd->add_option("--duration-s", a->duration_s, "how long the robot program runs (wall clock, from its first sample)")
      ->capture_default_str();
  cmd->add_option("--summary-json", a->summary_json, "write the summary (processes, topics, accuracy, latencies)");
  cmd->add_option("--work-dir", a->work_dir, "logs, per-process stats and the engine's state")->capture_default_str();
  cmd->add_flag("--resume", a->resume, "keep the engine state of a previous run (default: start uncalibrated)");
  cmd->add_option("--targets-hz", a->targets_hz, "TargetPoses published per second and robot")->capture_default_str();
  cmd->add_flag("--quiet", a->quiet, "no line per update");
  cmd->add_option("--record", a->record, "also run `cellcal record` on every topic into this MCAP file");
  return [a, cmd]() -> int {
    if (!*cmd) return 0;
    installStopHandlers();
    return runCell(*a);
  };
}

}  // namespace cellcal::cli
