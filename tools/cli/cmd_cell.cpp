// `cellcal cell`: the four-process cell on localhost against the simulated robot(s) of the cell file.
// Launches cellcal_calibration_engine, cellcal_compensation_publisher, cellcal_tracker_adapter (sim) and
// cellcal_joint_state_adapter (sim) as separate processes, and joins the domain itself as the cell's application
// and its judge: it publishes TargetPoses, and scores every published calibration against the simulator's truth
// on a hold-out pose set (the engine never sees the truth).
#include <array>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <atomic>
#include <optional>
#include <set>
#include <thread>

#include "cellcal/components/child_process.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"
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
  bool servo = false;  // also a servo stream: a joint setpoint per robot with each target
  int holdout_poses = 100;
  bool quiet = false;
  bool in_process_reference = true;
  std::string record;  // MCAP file: a recorder process records every topic
  // --host PROCESS=NETNS: run that process in that network namespace (`ip netns exec`), as on another host
  // (tools/netns/cellnet.sh makes them); the others run where the launcher does.
  std::vector<std::string> host_specs;
  std::map<std::string, std::string> hosts;  // from host_specs
  // --shards N: the robots split into N consecutive groups, each served by its own engine, compensation publisher
  // and adapters (each with --robots: content-filtered readers), named <process>_<k>.
  int shards = 1;
};

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

// A process of the cell: its name, the file it writes its counts to at exit, and the process.
struct Child {
  std::string name, stats_file;
  ChildProcess process;
};

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
  // The compensation publisher's reasons, grouped without their figures: how many, and the last one as it was said.
  std::map<std::string, std::pair<std::uint64_t, std::string>> refused_why;
  std::string health = "uncalibrated";  // of the latest CalibrationState
  std::uint64_t applied_version = 0;    // the calibration the compensation publisher applied last
  size_t landed_reported = 0;           // compensated_error_mm up to here is in a printed line
  std::map<std::uint64_t, std::pair<std::int64_t, Eigen::VectorXd>> sent;  // seq -> (send time, nominal joints)
  // Per calibration received: version, poses used, cell time (h), hold-out error against the truth then (mm).
  std::vector<std::array<double, 4>> history;

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

// What the cell's processes say of one robot's readings, from their --stats-json: the program's pose each reading
// of the simulated tracker measured (reading sequence k: element k - 1), and the sequence numbers of the readings the
// engine applied, of its `poses_used` in all (more than applied: it resumed from a state).
struct ReadingsApplied {
  std::vector<long long> pose_of_reading;
  std::vector<std::pair<std::uint64_t, std::int64_t>> applied;  // (tracker sequence number, stamp_ns)
  std::uint64_t poses_used = 0;
};

// The same robot program and tracker model, through core's CalibrationEngine in this process (no DDS): what the
// cell should reach on the same inputs. The hold-out error at `cell_time_end_s`, how many poses were fed and which.
// With `readings`: exactly the readings the engine applied, replayed at the stamps it saw (every reading the tracker
// made draws its noise in order, as the tracker did; those the engine did not apply are not fed). Without them, or
// when they do not account for the engine's poses: every pose the program measured up to `cell_time_end_s`, stamped
// by cell time (`inputs` says which).
struct Reference {
  double verify_mm = std::nan("");
  int poses = 0;
  std::string inputs;  // "applied_readings" or "program"
  std::string why_program;  // when readings were given and could not be used
};
// `followed`: the poses the simulated program took from the engine's proposals (pose id -> joints; the joint-state
// adapter's followed_poses), in place of the program's own.
Reference inProcessReference(const CellConfig& cell, const CellRobot& robot, int index, double cell_time_end_s,
                             const Judge& judge, const ReadingsApplied* readings,
                             const std::map<long long, Eigen::VectorXd>& followed) {
  const SimulatedCell sim = makeSimulatedCell(robot, cell.simulation, index);
  const SimRobotProgram program(sim, cell.simulation);
  EngineSettings es = cell.engine;
  CalibrationEngine engine(robot, es, cell.time_compression);
  std::mt19937_64 rng(sim.config().seed * 6364136223846793005ULL + 1442695040888963407ULL);
  const std::int64_t epoch = 1'700'000'000'000'000'000;
  auto wall = [&](double t) { return epoch + static_cast<std::int64_t>(t / cell.time_compression * 1e9); };
  const double pt = cell.simulation.pose_time_s, sf = cell.simulation.settle_fraction;
  // Per pose id: its joints (the program's, or the configuration it followed) and the cell time the tracker read it.
  std::vector<Eigen::VectorXd> joints_of;
  std::vector<double> read_at_s;
  for (int g = 0; g < program.campaigns(); ++g)
    for (int k = 0; k < program.posesIn(g); ++k) {
      const auto f = followed.find(static_cast<long long>(joints_of.size()));
      joints_of.push_back(f != followed.end() ? f->second : program.campaignConfigurations(g)[k]);
      read_at_s.push_back(program.campaignStart_s(g) + k * pt + (1 - sf + cell.simulation.tracker_delay_fraction * sf) * pt);
    }
  std::uint64_t seq = 0;
  // One reading of pose `id`: fed stamped `stamp_ns` (0: by cell time), or only drawn (nullopt).
  auto reading = [&](std::size_t id, std::optional<std::int64_t> stamp_ns) {
    const double t_read = read_at_s[id];
    const Eigen::VectorXd& q = joints_of[id];
    const Observation obs = sim.measure(q, t_read / 3600.0, rng, robot.measurement);
    ++seq;
    if (!stamp_ns) return;
    const std::int64_t t = *stamp_ns != 0 ? *stamp_ns : wall(t_read);
    engine.onJointState({t - 1000, seq, q, true}, t);
    engine.onTrackerSample(toTrackerSample(toTrackerPose(robot.target_id, t, seq, obs)), t);
    engine.onJointState({t + 1000, ++seq, q, true}, t);
    engine.process(t + 2000);
  };
  Reference ref;
  if (readings) {
    const std::map<std::uint64_t, std::int64_t> applied(readings->applied.begin(), readings->applied.end());
    const auto made = readings->pose_of_reading.size();
    if (readings->applied.size() != readings->poses_used)
      ref.why_program = "the engine applied " + std::to_string(readings->applied.size()) + " readings in this run of its " +
                        std::to_string(readings->poses_used) + " poses (resumed from a state, or more than it lists)";
    else if (!applied.empty() && applied.rbegin()->first > made)
      ref.why_program = "the engine applied reading #" + std::to_string(applied.rbegin()->first) + ", the tracker lists " +
                        std::to_string(made);
    for (const long long id : readings->pose_of_reading)
      if (ref.why_program.empty() && (id < 0 || id >= static_cast<long long>(joints_of.size())))
        ref.why_program = "the tracker measured pose " + std::to_string(id) + ", not in the program";
    if (ref.why_program.empty()) {
      for (size_t i = 0; i < made; ++i) {
        const auto a = applied.find(i + 1);
        reading(static_cast<std::size_t>(readings->pose_of_reading[i]),
                a == applied.end() ? std::nullopt : std::optional<std::int64_t>(a->second));
      }
      ref.inputs = "applied_readings";
    }
  }
  if (ref.inputs.empty()) {
    ref.inputs = "program";
    for (std::size_t id = 0; id < joints_of.size() && read_at_s[id] <= cell_time_end_s; ++id) reading(id, 0);
  }
  const CalibrationSnapshot& snap = engine.snapshot();
  ref.verify_mm = judge.verify(IdentifiedModel{snap.params, snap.extensions, snap.extension_params}, cell_time_end_s / 3600.0);
  ref.poses = static_cast<int>(snap.poses_used);
  return ref;
}

// The readings of one robot the simulated tracker made and the engine applied (mergeProcessStats put both processes'
// stats in the summary); nullopt when a process did not say.
std::optional<ReadingsApplied> readingsApplied(const nlohmann::json& summary, const std::string& robot_id) {
  std::optional<ReadingsApplied> out;
  const nlohmann::json trackers = summary.value("trackers", nlohmann::json::object()),
                       engines = summary.value("engines", nlohmann::json::object());
  for (const auto& [name, t] : trackers.items())
    if (t.contains("pose_of_reading") && t["pose_of_reading"].contains(robot_id)) {
      out.emplace();
      out->pose_of_reading = t["pose_of_reading"][robot_id].get<std::vector<long long>>();
    }
  if (!out) return std::nullopt;
  for (const auto& [name, e] : engines.items())
    if (e.contains("robots") && e["robots"].contains(robot_id) && e["robots"][robot_id].contains("applied_readings")) {
      out->applied = e["robots"][robot_id]["applied_readings"].get<std::vector<std::pair<std::uint64_t, std::int64_t>>>();
      out->poses_used = e["robots"][robot_id].value("poses_used", 0ULL);
      return out;
    }
  return std::nullopt;
}

// The poses the simulated program took from the engine's proposals (the joint-state adapter's followed_poses).
std::map<long long, Eigen::VectorXd> followedPoses(const nlohmann::json& summary, const std::string& robot_id) {
  std::map<long long, Eigen::VectorXd> out;
  const nlohmann::json adapters = summary.value("joint_adapters", nlohmann::json::object());
  for (const auto& [name, j] : adapters.items()) {
    if (!j.contains("followed_poses") || !j["followed_poses"].contains(robot_id)) continue;
    for (const auto& row : j["followed_poses"][robot_id]) {
      const auto v = row.get<std::vector<double>>();
      if (v.size() < 2) continue;
      out[static_cast<long long>(v[0])] = Eigen::Map<const Eigen::VectorXd>(v.data() + 1, static_cast<Eigen::Index>(v.size() - 1));
    }
  }
  return out;
}

// The launcher's own participant: the cell's application (TargetPoses at --targets-hz) and its judge (scores every
// calibration and compensated target it receives against the simulator's truth). DDS callbacks only record
// (receipt time, sample): one receive thread serves every reader, so scoring in a callback would delay the others
// and inflate the latencies measured; score() does the work on the caller's thread.
class CellJudge {
 public:
  CellJudge(const CellConfig& cell, const CellArgs& a) : cell_(cell), a_(a), node_(cell, "cellcal_cell_launcher", identity::kApplication),
        targets_(node_.writer<msg::TargetPose>()), target_rng_(cell.simulation.seed + 777) {
    for (size_t i = 0; i < cell.robots.size(); ++i) {
      Judge j(&cell.robots[i], makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i)));
      std::mt19937_64 rng(cell.simulation.seed * 31 + 12345 + i);
      j.holdout = j.sim.randomConfigurations(a.holdout_poses, rng);
      j.target_qs = j.sim.randomConfigurations(200, rng);
      j.identified.params = j.sim.nominalParams();
      judges_.push_back(std::move(j));
    }
    node_.reader<sim::RobotTruth>([this](const sim::RobotTruth& t, const fdds::SampleInfo&) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!program_start_) program_start_ = std::chrono::steady_clock::now();
      if (Judge* j = find(t.robot_id().to_string())) j->cell_time_s = std::max(j->cell_time_s, t.cell_time_s());
    });
    node_.reader<msg::CalibrationState>([this](const msg::CalibrationState& m, const fdds::SampleInfo&) {
      const std::int64_t now = wallNs();
      std::lock_guard<std::mutex> lock(mutex_);
      states_in_.emplace_back(now, m);
    });
    node_.reader<msg::CompensatedTarget>([this](const msg::CompensatedTarget& m, const fdds::SampleInfo&) {
      const std::int64_t now = wallNs();
      std::lock_guard<std::mutex> lock(mutex_);
      compensated_in_.emplace_back(now, m);
    });
    if (a.servo) {
      servo_.emplace(node_.writer<msg::ServoSetpoint>());
      node_.reader<msg::ServoCorrection>([this](const msg::ServoCorrection& m, const fdds::SampleInfo&) {
        ++servo_answered_;
        if (m.applied()) ++servo_applied_;
      });
    }
  }

  double elapsed() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count(); }

  // --duration-s counts from the moment the robot program runs (start-up and discovery excluded), so a loaded
  // machine still sees the whole program; at most 30 s are allowed for start-up.
  double runningSeconds() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!program_start_) return elapsed() > 30 ? a_.duration_s : 0.0;
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - *program_start_).count();
  }

  // One TargetPose per robot: the nominal pose of a random configuration, to be compensated.
  void sendTargets() {
    for (auto& j : judges_) {
      const Eigen::VectorXd& q = j.target_qs[std::uniform_int_distribution<size_t>(0, j.target_qs.size() - 1)(target_rng_)];
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
      targets_.write(t);
      if (servo_) {  // the robot holding the target's joints, one setpoint per cycle
        servo_sample_.robot_id(j.robot->robot_id);
        servo_sample_.sequence_number(j.target_seq);  // one setpoint per target: the same count
        servo_sample_.source_stamp_ns(static_cast<std::uint64_t>(now));
        servo_sample_.cycle_stamp_ns(static_cast<std::uint64_t>(now));
        servo_sample_.cartesian(false);
        servo_sample_.joint_position_rad().assign(q.data(), q.data() + q.size());
        servo_->write(servo_sample_);
        ++servo_sent_;
      }
    }
  }

  // Scores what arrived since the last call; a line per calibration update unless --quiet.
  void score() {
    std::vector<std::pair<std::int64_t, msg::CalibrationState>> states;
    std::vector<std::pair<std::int64_t, msg::CompensatedTarget>> comps;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      states.swap(states_in_);
      comps.swap(compensated_in_);
    }
    for (const auto& [now, m] : states) scoreCalibration(now, m);
    for (const auto& [now, m] : comps) scoreCompensation(now, m);
  }

  // Leaves the domain (no callback after this) and scores what is left.
  void finish() {
    node_.shutdown();
    score();
  }

  // The summary of the run (processes and their topic counts: mergeProcessStats) and its two printed lines.
  void summarize(nlohmann::json* summary) const {
    nlohmann::json robots = nlohmann::json::array();
    double before = 0, after = 0, reference = 0, at_update = 0;
    int reference_poses = 0;
    const double n = static_cast<double>(judges_.size());
    for (size_t i = 0; i < judges_.size(); ++i) {
      const Judge& j = judges_[i];
      const double t_h = j.cell_time_s / 3600.0;
      const double vb = j.verifyNominal(t_h), va = j.verify(j.identified, t_h);
      const std::optional<ReadingsApplied> readings = readingsApplied(*summary, j.robot->robot_id);
      const std::map<long long, Eigen::VectorXd> followed = followedPoses(*summary, j.robot->robot_id);
      const Reference r = a_.in_process_reference ? inProcessReference(cell_, *j.robot, static_cast<int>(i), j.cell_time_s, j,
                                                                       readings ? &*readings : nullptr, followed)
                                                  : Reference{};
      if (!r.why_program.empty())
        std::printf("cell: %s: the in-process engine replays the program, not the readings applied: %s\n",
                    j.robot->robot_id.c_str(), r.why_program.c_str());
      const double ref = r.verify_mm;
      reference_poses += r.poses;
      before += vb / n;
      after += va / n;
      at_update += j.verify_mm / n;
      reference += ref / n;
      robots.push_back({{"robot_id", j.robot->robot_id},
                        {"final_version", j.version},
                        {"cell_time_h", t_h},
                        {"verify_before_mm", vb},
                        {"verify_after_mm", va},
                        {"verify_after_last_update_mm", j.verify_mm},  // at the cell time of the last update
                        {"in_process_verify_after_mm", ref},
                        {"in_process_poses", r.poses},    // the poses it applied
                        {"in_process_inputs", r.inputs},  // applied_readings: the engine's; program: every pose by then
                        {"poses_followed", followed.size()},  // taken from the engine's proposals
                        // [version, poses used, cell time h, hold-out error mm] of each calibration received
                        {"holdout_by_version", j.history},
                        {"targets_applied", j.applied},
                        {"targets_refused", j.refused},
                        {"targets_refused_why", refusedWhyJson(j)},
                        {"correction_mean_mm", mean(j.correction_mm)},
                        {"correction_mean_deg", mean(j.correction_deg)},
                        {"landed_error_compensated_mean_mm", mean(j.compensated_error_mm)},
                        {"landed_error_uncompensated_mean_mm", mean(j.uncompensated_error_mm)}});
    }
    auto& s = *summary;
    s["robots"] = robots;
    s["verify_before_mm"] = before;
    s["verify_after_mm"] = after;
    s["in_process_verify_after_mm"] = reference;
    s["in_process_poses"] = reference_poses;
    s["verify_after_last_update_mm"] = at_update;
    s["latency_us"] = {{"tracker_to_state_p50", percentile(tracker_to_state_us_, 0.5)},
                       {"tracker_to_state_p99", percentile(tracker_to_state_us_, 0.99)},
                       {"target_to_compensated_p50", percentile(target_to_compensated_us_, 0.5)},
                       {"target_to_compensated_p99", percentile(target_to_compensated_us_, 0.99)},
                       {"tracker_to_state_samples", tracker_to_state_us_.size()},
                       {"target_to_compensated_samples", target_to_compensated_us_.size()}};
    s["domain_id"] = cell_.dds.domain_id;
    s["duration_s"] = elapsed();
    std::printf("cell: %llu calibration updates; hold-out error at the end %.4f mm calibrated vs %.3f mm uncalibrated "
                "(in-process engine on the same poses: %.4f mm); %.4f mm right after the last update\n",
                static_cast<unsigned long long>(s.value("calibration_updates", 0ULL)), after, before, reference, at_update);
    std::printf("cell: latency tracker -> CalibrationState p50 %.0f us, p99 %.0f us; TargetPose -> CompensatedTarget "
                "p50 %.0f us, p99 %.0f us\n",
                percentile(tracker_to_state_us_, 0.5), percentile(tracker_to_state_us_, 0.99),
                percentile(target_to_compensated_us_, 0.5), percentile(target_to_compensated_us_, 0.99));
    if (servo_) {
      s["servo"] = {{"sent", servo_sent_}, {"answered", servo_answered_.load()}, {"applied", servo_applied_.load()}};
      std::printf("cell: servo stream: %llu joint setpoints, %llu answered on cellcal/servo_correction (%llu applied)\n",
                  static_cast<unsigned long long>(servo_sent_), static_cast<unsigned long long>(servo_answered_.load()),
                  static_cast<unsigned long long>(servo_applied_.load()));
    }
    if (cell_.simulation.follow_pose_requests)
      for (const auto& r : robots)
        std::printf("cell: %s: %llu poses of the program taken from the engine's proposals (cellcal/pose_request)\n",
                    r["robot_id"].get<std::string>().c_str(), r["poses_followed"].get<unsigned long long>());
    // Targets passed through uncorrected, and why: per reason, how many and the last answer that gave it.
    for (const auto& j : judges_) {
      if (!j.refused) continue;
      std::printf("cell: %s: %llu of %llu targets passed through uncorrected:\n", j.robot->robot_id.c_str(),
                  static_cast<unsigned long long>(j.refused), static_cast<unsigned long long>(j.refused + j.applied));
      for (const auto& [key, why] : j.refused_why)
        std::printf("cell:   %llu x %s%s\n", static_cast<unsigned long long>(why.first), why.second.c_str(),
                    why.first > 1 ? " (the last of them)" : "");
    }
  }

  nlohmann::json topicStats() const { return node_.stats(); }

 private:
  static double mean(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? std::nan("") : s / static_cast<double>(v.size());
  }

  // {reason without its figures: {count, last}}.
  static nlohmann::json refusedWhyJson(const Judge& j) {
    nlohmann::json out = nlohmann::json::object();
    for (const auto& [key, why] : j.refused_why) out[key] = {{"count", why.first}, {"last", why.second}};
    return out;
  }

  Judge* find(const std::string& id) {
    for (auto& j : judges_)
      if (j.robot->robot_id == id) return &j;
    return nullptr;
  }

  void scoreCalibration(std::int64_t now, const msg::CalibrationState& m) {
    Judge* j = find(m.robot_id().to_string());
    if (!j || m.version() == j->version) return;
    std::string err;
    auto c = fromCalibrationState(j->sim.model(), m, &err);
    if (!c) {
      std::cerr << "cell: " << err << "\n";
      return;
    }
    if (m.last_measurement_stamp_ns() > 0)
      tracker_to_state_us_.push_back((now - static_cast<std::int64_t>(m.last_measurement_stamp_ns())) / 1e3);
    j->version = c->version;
    j->identified = IdentifiedModel{c->params, c->extensions, c->extension_params};
    double cell_time;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      cell_time = j->cell_time_s;
    }
    const double t_h = cell_time / 3600.0;
    j->verify_mm = j->verify(j->identified, t_h);
    j->nominal_mm = j->verifyNominal(t_h);
    j->health = healthName(static_cast<Health>(static_cast<int>(m.health())));
    j->history.push_back({static_cast<double>(c->version), static_cast<double>(c->poses_used), t_h, j->verify_mm});
    if (a_.quiet) return;
    // The calibration as published (its health in capitals when it is not ok: the engine degraded or holds an older
    // version) and what compensation did since the last line: the version it applied, where those targets landed.
    std::string health = j->health;
    if (health != "ok") std::transform(health.begin(), health.end(), health.begin(), ::toupper);
    std::string comp = "compensation: no target corrected since the last line";
    if (j->compensated_error_mm.size() > j->landed_reported) {
      double sum = 0;
      for (size_t k = j->landed_reported; k < j->compensated_error_mm.size(); ++k) sum += j->compensated_error_mm[k];
      const size_t n = j->compensated_error_mm.size() - j->landed_reported;
      char buf[160];
      std::snprintf(buf, sizeof buf, "compensation v%llu: %zu target%s landed %.4f mm from where %s wanted",
                    static_cast<unsigned long long>(j->applied_version), n, n == 1 ? "" : "s",
                    sum / static_cast<double>(n), n == 1 ? "it was" : "they were");
      comp = buf;
      j->landed_reported = j->compensated_error_mm.size();
    }
    std::printf("[%6.2f s] %-8s v%-4llu %-14s poses %-4u cell time %5.2f h | hold-out error %.4f mm (uncalibrated "
                "%.3f mm) | %s\n",
                elapsed(), j->robot->robot_id.c_str(), static_cast<unsigned long long>(c->version), health.c_str(),
                c->poses_used, t_h, j->verify_mm, j->nominal_mm, comp.c_str());
    std::fflush(stdout);
  }

  void scoreCompensation(std::int64_t now, const msg::CompensatedTarget& m) {
    Judge* j = find(m.robot_id().to_string());
    if (!j) return;
    auto it = j->sent.find(m.target_sequence());
    if (it == j->sent.end()) return;
    target_to_compensated_us_.push_back((now - it->second.first) / 1e3);
    const Eigen::VectorXd q_nominal = it->second.second;
    j->sent.erase(it);
    if (!m.applied()) {
      ++j->refused;
      // "calibration v3 is not healthy (health 0) and none was before" and "... v4 ..." are one reason.
      const std::string reason = m.reason().to_string();
      const std::string first = reason.substr(0, reason.find(';'));
      auto& why = j->refused_why[maskFigures(first)];
      ++why.first;
      why.second = first;
      return;
    }
    ++j->applied;
    j->applied_version = m.calibration_version();
    j->correction_mm.push_back(m.correction_position_m() * 1e3);
    j->correction_deg.push_back(m.correction_orientation_rad() * 180 / kPi);
    // Where the real robot lands: the controller (nominal model) drives to the commanded pose.
    const RobotModel& model = j->sim.model();
    const Pose commanded = toPose(m.corrected_position_m(), m.corrected_orientation_xyzw());
    const Pose desired = toPose(m.desired_position_m(), m.desired_orientation_xyzw());
    const Eigen::VectorXd seed = Eigen::Map<const Eigen::VectorXd>(m.joint_position_rad().data(),
                                                                   static_cast<Eigen::Index>(m.joint_position_rad().size()));
    const IkResult ctrl = solveInverseKinematics(model, model.nominal, commanded, seed);
    if (!ctrl.ok()) return;
    const double t_h = j->cell_time_s / 3600.0;
    j->compensated_error_mm.push_back((j->sim.truePose(ctrl.q_rad, t_h).translation() - desired.translation()).norm() * 1e3);
    j->uncompensated_error_mm.push_back((j->sim.truePose(q_nominal, t_h).translation() - desired.translation()).norm() * 1e3);
  }

  const CellConfig& cell_;
  const CellArgs& a_;
  const std::chrono::steady_clock::time_point t0_ = std::chrono::steady_clock::now();
  std::vector<Judge> judges_;
  std::mutex mutex_;  // guards what the callbacks write: the *_in_ queues, program_start_, Judge::cell_time_s
  std::optional<std::chrono::steady_clock::time_point> program_start_;  // first RobotTruth: the robot runs
  std::vector<std::pair<std::int64_t, msg::CalibrationState>> states_in_;
  std::vector<std::pair<std::int64_t, msg::CompensatedTarget>> compensated_in_;
  std::vector<double> tracker_to_state_us_, target_to_compensated_us_;
  std::atomic<std::uint64_t> servo_answered_{0}, servo_applied_{0};  // --servo: corrections received
  DdsNode node_;  // after the state its callbacks use: deleted (and its callbacks stopped) before it
  Writer<msg::TargetPose> targets_;
  std::optional<Writer<msg::ServoSetpoint>> servo_;  // --servo
  msg::ServoSetpoint servo_sample_;
  std::uint64_t servo_sent_ = 0;
  std::mt19937_64 target_rng_;
};

// The cell's processes, each with its output in <work_dir>/<name>.log. The recorder first: the robot program waits
// for its RobotTruth reader too, so the recording starts with the program.
std::vector<Child> startProcesses(const CellConfig& cell, const CellArgs& a, const std::string& state_dir) {
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
    for (const auto& [topic, counts] : p["topics"].items()) {
      if (!topics.contains(topic)) topics[topic] = {{"published", 0ULL}, {"received", 0ULL}};
      auto& t = topics[topic];
      t["published"] = t["published"].get<std::uint64_t>() + counts.value("published", 0ULL);
      t["received"] = t["received"].get<std::uint64_t>() + counts.value("received", 0ULL);
    }
    // Shards (calibration_engine_2, ...): updates summed, each one's counts kept.
    if (c.name.rfind("calibration_engine", 0) == 0) {
      calibration_updates += p["extra"].value("updates", 0ULL);
      s["engine"] = p["extra"];
      s["engines"][c.name] = p["extra"];
    }
    if (c.name.rfind("compensation_publisher", 0) == 0) {
      s["compensation"] = p["extra"];
      s["compensation_publishers"][c.name] = p["extra"];
    }
    if (c.name == "recorder") s["recorder"] = p["extra"];
    if (c.name.rfind("tracker_adapter", 0) == 0) s["trackers"][c.name] = p["extra"];
    if (c.name.rfind("joint_state_adapter", 0) == 0) s["joint_adapters"][c.name] = p["extra"];
  }
  s["topics"] = topics;
  s["calibration_updates"] = calibration_updates;
  return failures;
}

int runCell(const CellArgs& a) {
  installStopHandlers();
  const CellConfig cell = loadCell(a.common);
  if (static_cast<std::size_t>(a.shards) > cell.robots.size())
    throw ConfigError("--shards " + std::to_string(a.shards) + ": the cell has " + std::to_string(cell.robots.size()) +
                      " robot(s)");
  fs::create_directories(a.work_dir);
  const std::string state_dir = (fs::path(a.work_dir) / "state").string();
  if (!a.resume) fs::remove_all(state_dir);
  CellJudge judge(cell, a);
  std::vector<Child> children = startProcesses(cell, a, state_dir);
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
  bool child_died = false;
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
    judge.sendTargets();
  }
  // Stopped in the reverse of their start: the cell's processes, which flush what they published last (a reliable
  // writer waits for its acknowledgements on a clean exit), then the recorder, so the recording holds it.
  std::vector<ChildProcess*> cell_processes, recorder;
  for (auto& c : children) (c.name == "recorder" ? recorder : cell_processes).push_back(&c.process);
  stopAll(cell_processes);
  stopAll(recorder);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  judge.finish();

  nlohmann::json summary;
  const int failures = mergeProcessStats(children, judge.topicStats(), &summary);
  judge.summarize(&summary);
  if (!a.summary_json.empty()) {
    writeJsonFile(a.summary_json, summary);
    std::printf("cell: summary in %s\n", a.summary_json.c_str());
  }
  return failures == 0 ? 0 : 1;
}

}  // namespace

Runner addCellCommand(CLI::App& app) { return addCommand(app, "cell", addOptions, runCell); }

}  // namespace cellcal::cli
