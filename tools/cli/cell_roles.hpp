// `cellcal cell`'s roles beside the four processes it launches: the launcher (cell_launcher.cpp: start the
// processes, merge their --stats-json), the cell's application (cell_application.cpp: publishes TargetPoses and
// servo setpoints) and its judge (cell_judge.cpp: scores every calibration and compensated target against the
// simulator's truth), both on the launcher's one participant, and the in-process reference (cell_reference.cpp: core's
// CalibrationEngine on the same inputs, no DDS).
#pragma once

#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "cellcal/components/child_process.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace cellcal::components {
class DdsNode;
}  // namespace cellcal::components

namespace cellcal::cli {

struct CellArgs {
  components::ProcessOptions common;
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
  // --rsi-hz R: a KUKA RSI stream per robot, answered by a cellcal_rsi_bridge process fed by the cell's calibrations
  // (cell_rsi.cpp); --rsi-rt-priority: SCHED_FIFO for the bridges and the simulated controllers.
  double rsi_hz = 0;
  int rsi_rt_priority = 0;
  bool rsi_pass_through = false;  // --rsi-pass-through: the bridges answer zero corrections (the floor, for a bench)
  // --targets-program FILE: the application's targets are the nominal poses of a robot program's rows (CSV v1's joint
  // columns with pose and cycle, as `cellcal plan iso9283` writes it), each row once in order, instead of random
  // configurations. --landed-csv FILE: every such target compensation applied, read by the simulated tracker where
  // the robot lands (truth, noise and repeatability), as CSV v1 rows with the program row's joints (the pose asked
  // for), pose and cycle, one file per robot (`_<robot_id>` before .csv when the cell has several).
  std::string targets_program, landed_csv;
};

// The launcher.

// A process of the cell: its name, the file it writes its counts to at exit, and the process.
struct Child {
  std::string name, stats_file;
  components::ChildProcess process;
};

// The cell's processes, each with its output in <work_dir>/<name>.log. The recorder first: the robot program waits
// for its RobotTruth reader too, so the recording starts with the program.
// `rsi_ports`: with --rsi-hz, the UDP port of each robot's RSI bridge (CellRsi::ports).
std::vector<Child> startProcesses(const CellConfig& cell, const CellArgs& a, const std::string& state_dir,
                                  const std::vector<int>& rsi_ports = {});
// Adds each process's exit code and its --stats-json (topic counts summed with the launcher's own, the engine's,
// compensation's and recorder's counters) to the summary; returns how many processes failed.
int mergeProcessStats(std::vector<Child>& children, nlohmann::json topics, nlohmann::json* summary);

// The judge's view of one robot: truth, hold-out poses, calibrations, targets.
struct Judge {
  Judge(const CellRobot* r, SimulatedCell s) : robot(r), sim(std::move(s)) {}
  const CellRobot* robot;
  SimulatedCell sim;
  std::vector<Eigen::VectorXd> holdout;
  double cell_time_s = 0;
  std::uint64_t version = 0;
  CalibratedModel identified;  // the latest calibration received (with its model extensions, if any)
  double verify_mm = std::nan(""), nominal_mm = std::nan("");
  std::vector<double> correction_mm, correction_deg, compensated_error_mm, uncompensated_error_mm;
  std::uint64_t applied = 0, refused = 0;
  std::uint64_t applied_beyond_data = 0;  // applied, flagged beyond_data
  // The targets passed through, per outcome (outcomeText): how many, and the last one's reason as it was said.
  std::map<std::string, std::pair<std::uint64_t, std::string>> refused_why;
  std::string health = "uncalibrated";  // of the latest CalibrationState
  std::uint64_t applied_version = 0;    // the calibration the compensation publisher applied last
  size_t landed_reported = 0;           // compensated_error_mm up to here is in a printed line
  // Every calibration received, by version (kept with --rsi-hz: the stream's check replays them).
  std::map<std::uint64_t, CalibratedModel> calibrations;
  // Per calibration received: version, poses used, cell time (h), hold-out error against the truth then (mm).
  std::vector<std::array<double, 4>> history;
  // --landed-csv: the program's targets read where the robot landed, and the tracker noise's draws for them.
  MeasurementFile landed;
  std::mt19937_64 landed_rng{0};

  // Each hold-out pose's position error under model m at cell time t_h (mm), and their mean.
  std::vector<double> errors(const CalibratedModel& m, double t_h) const {
    const RobotModel& model = sim.model();
    KinematicsData d(model);
    std::vector<double> out;
    for (const auto& q : holdout) {
      const Eigen::VectorXd p = extendedParams(model, m.params, m.extensions, m.extension_params, q, Drivers{});
      out.push_back((forwardKinematics(model, d, p, q).translation() - sim.truePose(q, t_h).translation()).norm() * 1e3);
    }
    return out;
  }
  double verify(const CalibratedModel& m, double t_h) const { return mean(errors(m, t_h)); }
  double verifyNominal(double t_h) const { return verify(CalibratedModel::geometric(sim.nominalParams()), t_h); }
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
                             const std::map<long long, Eigen::VectorXd>& followed);

// The readings of one robot the simulated tracker made and the engine applied (mergeProcessStats put both processes'
// stats in the summary); nullopt when a process did not say.
std::optional<ReadingsApplied> readingsApplied(const nlohmann::json& summary, const std::string& robot_id);
// The poses the simulated program took from the engine's proposals (the joint-state adapter's followed_poses).
std::map<long long, Eigen::VectorXd> followedPoses(const nlohmann::json& summary, const std::string& robot_id);

// The targets the application sent whose answers the judge has not scored yet, per robot: target sequence -> when it
// was sent and the nominal joints it was made from. Touched on the launcher's main thread only.
struct SentTarget {
  std::int64_t stamp_ns = 0;
  Eigen::VectorXd q_nominal;
  std::optional<std::string> pose;  // --targets-program: the program row's pose and cycle
  std::optional<long long> cycle;
};
using SentTargets = std::map<std::string, std::map<std::uint64_t, SentTarget>>;

// The two roles share the launcher's participant. Each is constructed first (its state), then the participant, then
// attach() creates its writers and readers on it: the participant goes first at the end, and with it every callback
// into a role (Fast DDS examples: entities deleted in the reverse of their creation).
//
//   CellApplication app(cell, a);
//   CellJudge judge(cell, a, app.sent());
//   DdsNode node(cell, "cellcal_cell_launcher", identity::kApplication);
//   app.attach(node), judge.attach(node);

// The cell's application: per robot and call, a TargetPose (the nominal pose of a random configuration, to be
// compensated) and, with --servo, a joint setpoint with it (the robot holding the target's joints, one per cycle); it
// counts the servo corrections it gets back (cell_application.cpp).
class CellApplication {
 public:
  CellApplication(const CellConfig& cell, const CellArgs& a);
  ~CellApplication();
  void attach(components::DdsNode& node);
  void sendTargets();
  SentTargets& sent();
  // The servo stream's counts (--servo) into the summary and its printed line.
  void summarize(nlohmann::json* summary) const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

// The cell's judge: scores every calibration and compensated target it receives against the simulator's truth
// (cell_judge.cpp).
class CellJudge {
 public:
  CellJudge(const CellConfig& cell, const CellArgs& a, SentTargets& sent);
  ~CellJudge();
  void attach(components::DdsNode& node);
  // --duration-s counts from the moment the robot program runs (start-up and discovery excluded), so a loaded
  // machine still sees the whole program; at most 30 s are allowed for start-up.
  double runningSeconds();
  void score();  // scores what arrived since the last call; a line per calibration update unless --quiet
  // The summary of the run (processes and their topic counts: mergeProcessStats) and its printed lines.
  void summarize(nlohmann::json* summary) const;
  // The simulated cell's time of robot `robot` (index in the cell file), s; and its view, read after the node is gone.
  double cellTimeS(std::size_t robot);
  const Judge& judge(std::size_t robot) const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

// --rsi-hz: per robot, a simulated KUKA controller (lab/rsi_controller.hpp) on a thread of the launcher sends RSI's
// <Rob> every cycle to that robot's cellcal_rsi_bridge process (started with the cell's processes, ports()) and
// counts the answers late or missing; at the end, where the corrected robot landed against the simulator's truth, and
// the stream replayed in memory through core's RsiSession with the versions the bridge took (its stats) and the
// calibrations the judge received: every answer must equal the bridge's to 1e-12 rad.
class CellRsi {
 public:
  // Throws ConfigError when SCHED_FIFO is asked for and refused.
  CellRsi(const CellConfig& cell, const CellArgs& a);
  ~CellRsi();
  // Each robot's bridge port on 127.0.0.1: one the kernel gave as free when this was made.
  const std::vector<int>& ports() const;
  void start();                                        // the controllers' threads (connect, then stream)
  void setCellTimeS(std::size_t robot, double cell_time_s);
  void stop();                                         // the streams end; joins
  // The streams' figures into summary["rsi"] and their printed lines, the bridges' counts from summary["rsi_bridges"]
  // (mergeProcessStats); false when an answer differs from the replay.
  bool summarize(const CellJudge& judge, nlohmann::json* summary) const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace cellcal::cli
