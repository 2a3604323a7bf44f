// cellcal_joint_state_adapter: publishes the robot's joint angles (cellcal/joint_state).
//   --source sim  the simulated robot of the cell file (one stream per robot; also its truth on
//                 cellcal/sim/robot_truth, for the simulated tracker and the launcher)
//   --source csv  the joints of a measurement file (CSV v1), replayed in time (common/csv_replay.hpp); give the
//                 tracker adapter the same file and --start-unix-ns
//   --source udp  one line per reading from a controller bridge (docs/udp-sources.md):
//                 <robot_id> <stamp_ns|0> <settled 0|1> <q1_rad> ... <qN_rad>
#include <unistd.h>

#include <algorithm>
#include <iostream>
#include <map>
#include <thread>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/csv_replay.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/components/udp_lines.hpp"
#include "cellcal/core/sim_program.hpp"

using namespace cellcal;
using namespace cellcal::components;

namespace {

struct Options {
  ProcessOptions common;
  std::string source = "sim";
  double duration_s = 0;
  double start_cell_time_s = 0;
  int wait_for_readers = 0;
  std::string udp_address = "127.0.0.1";
  int udp_port = 5610;
  CsvReplayOptions csv;
};

int runSim(const CellConfig& cell, DdsNode& node, const Options& o, nlohmann::json& extra) {
  auto js = node.writer<msg::JointState>();
  auto truth = node.writer<sim::RobotTruth>();
  std::vector<SimulatedCell> cells;
  std::vector<SimRobotProgram> programs;
  for (size_t i = 0; i < cell.robots.size(); ++i) cells.push_back(makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i)));
  for (const auto& c : cells) programs.emplace_back(c, cell.simulation);
  if (o.wait_for_readers > 0) {
    // Start the program only once someone listens: JointState matched by >= 1 reader (the engine) and
    // RobotTruth by >= N (the simulated tracker, and the launcher when it watches). At most 10 s.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    fdds::PublicationMatchedStatus a, b;
    while (std::chrono::steady_clock::now() < deadline && !stopRequested()) {
      js.entity()->get_publication_matched_status(a);
      truth.entity()->get_publication_matched_status(b);
      if (a.current_count >= 1 && b.current_count >= o.wait_for_readers) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));  // let the readers' side of the match settle
    std::cerr << "joint_state_adapter: readers matched: joint_state " << a.current_count << ", robot_truth "
              << b.current_count << "\n";
  }
  const double period_s = 1.0 / cell.simulation.joint_rate_hz;
  const auto start = std::chrono::steady_clock::now();
  auto anchor = start;          // wall time of tick `anchor_tick`
  std::uint64_t anchor_tick = 0;
  std::uint64_t seq = 0, ticks = 0, late = 0;
  std::cerr << "joint_state_adapter: sim, " << cell.robots.size() << " robot(s) at " << cell.simulation.joint_rate_hz
            << " Hz, cell time x" << cell.time_compression << ", domain " << node.domainId() << "\n";
  for (std::uint64_t k = 0;; ++k) {
    const auto due = anchor + std::chrono::nanoseconds(static_cast<std::int64_t>((k - anchor_tick) * period_s * 1e9));
    if (!sleepUntil(due)) break;
    const auto now_steady = std::chrono::steady_clock::now();
    if (o.duration_s > 0 && std::chrono::duration<double>(now_steady - start).count() >= o.duration_s) break;
    if (now_steady - due > std::chrono::duration<double>(2 * period_s)) {
      // Fell behind (a loaded machine): simulated time is tick-based, so it slows down instead of skipping poses
      // the tracker would never see, and the schedule restarts from now instead of bursting.
      ++late;
      anchor = now_steady;
      anchor_tick = k;
    }
    const double cell_time = o.start_cell_time_s + k * period_s * cell.time_compression;
    const std::int64_t now = wallNs();
    ++seq;
    for (size_t i = 0; i < cell.robots.size(); ++i) {
      const SimRobotState st = programs[i].at(cell_time);
      auto m = toJointState(cell.robots[i].robot_id, now, seq, st.q_rad, st.settled);
      js.write(m);
      sim::RobotTruth t;
      t.robot_id(cell.robots[i].robot_id);
      t.source_stamp_ns(static_cast<std::uint64_t>(now));
      t.sequence_number(seq);
      t.cell_time_s(cell_time);
      t.position_rad(m.position_rad());
      t.settled(st.settled);
      t.pose_id(st.pose_id);
      t.settled_for_s(st.settled_for_s);
      t.settle_duration_s(st.settle_duration_s);
      truth.write(t);
    }
    ++ticks;
  }
  extra["ticks"] = ticks;
  extra["ticks_skipped_late"] = late;
  return 0;
}

int runCsv(const CellConfig& cell, DdsNode& node, const Options& o, nlohmann::json& extra) {
  auto js = node.writer<msg::JointState>();
  const CsvReplay r = loadCsvReplay(cell, o.csv);
  for (const auto& w : r.file.warnings) std::cerr << "joint_state_adapter: skipped: " << w << "\n";
  std::cerr << "joint_state_adapter: csv " << o.csv.path << ": " << r.file.rows.size() << " rows for "
            << r.robot->robot_id << ", starting at unix ns " << r.start_unix_ns << ", domain " << node.domainId() << "\n";
  const double period_s = 1.0 / cell.simulation.joint_rate_hz;
  const double end_s = r.t_s.back() + r.hold_s + 0.5;
  std::uint64_t seq = 0;
  size_t k = 0;
  for (;;) {
    const double tau = (wallNs() - r.start_unix_ns) * 1e-9;
    if (tau > end_s || stopRequested()) break;
    if (tau >= -r.hold_s - 0.5) {
      while (k + 1 < r.t_s.size() && tau > r.t_s[k] + r.hold_s) ++k;
      Eigen::VectorXd q;
      bool settled = false;
      if (std::abs(tau - r.t_s[k]) <= r.hold_s) {
        q = r.file.rows[k].q_rad;
        settled = true;
      } else if (tau < r.t_s[k]) {  // moving toward row k
        const double t0 = k == 0 ? r.t_s[0] - r.hold_s - 0.5 : r.t_s[k - 1] + r.hold_s;
        const double f = std::clamp((tau - t0) / (r.t_s[k] - r.hold_s - t0), 0.0, 1.0);
        const Eigen::VectorXd& from = k == 0 ? r.file.rows[0].q_rad : r.file.rows[k - 1].q_rad;
        q = from + f * (r.file.rows[k].q_rad - from);
      } else {
        q = r.file.rows.back().q_rad;
      }
      auto m = toJointState(r.robot->robot_id, wallNs(), ++seq, q, settled);
      js.write(m);
    }
    std::this_thread::sleep_for(std::chrono::duration<double>(period_s));
  }
  extra["rows"] = r.file.rows.size();
  extra["skipped_rows"] = r.file.skipped_rows;
  return 0;
}

int runUdp(const CellConfig& cell, DdsNode& node, const Options& o, nlohmann::json& extra) {
  auto js = node.writer<msg::JointState>();
  UdpLineSocket sock(o.udp_address, o.udp_port);
  std::cerr << "joint_state_adapter: udp " << o.udp_address << ":" << sock.port() << ", domain " << node.domainId() << "\n";
  std::map<std::string, std::uint64_t> seq;
  std::uint64_t lines = 0, bad = 0;
  const auto start = std::chrono::steady_clock::now();
  while (!stopRequested()) {
    if (o.duration_s > 0 && std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >= o.duration_s) break;
    for (const std::string& line : sock.receive(50)) {
      ++lines;
      const auto f = splitFields(line);
      std::string why;
      const CellRobot* robot = f.empty() ? nullptr : cell.robotById(f[0]);
      std::int64_t stamp = 0, settled = 0;
      Eigen::VectorXd q;
      if (!robot) {
        why = f.empty() ? "empty line" : "unknown robot_id '" + f[0] + "'";
      } else if (static_cast<int>(f.size()) != 3 + robot->model.numJoints()) {
        why = "expected 3 + " + std::to_string(robot->model.numJoints()) + " fields, got " + std::to_string(f.size());
      } else if (!parseInt64(f[1], &stamp) || stamp < 0) {
        why = "field 2 (stamp_ns): '" + f[1] + "' is not a non-negative integer";
      } else if (!parseInt64(f[2], &settled) || (settled != 0 && settled != 1)) {
        why = "field 3 (settled): expected 0 or 1, got '" + f[2] + "'";
      } else {
        q.resize(robot->model.numJoints());
        for (int j = 0; j < q.size() && why.empty(); ++j)
          if (!parseDouble(f[3 + j], &q[j])) why = "field " + std::to_string(4 + j) + " (q" + std::to_string(j + 1) + "_rad): '" + f[3 + j] + "' is not a finite number";
      }
      if (!why.empty()) {
        ++bad;
        std::cerr << "joint_state_adapter: udp line " << lines << " ignored: " << why << "\n";
        continue;
      }
      auto m = toJointState(robot->robot_id, stamp == 0 ? wallNs() : stamp, ++seq[robot->robot_id], q, settled == 1);
      js.write(m);
    }
  }
  extra["udp_lines"] = lines;
  extra["udp_bad_lines"] = bad;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"cellcal joint-state adapter: publishes the robot's joint angles on cellcal/joint_state"};
  app.footer(manFooter(
      "nothing",
      "cellcal/joint_state (and cellcal/sim/robot_truth with --source sim)",
      "  cellcal_joint_state_adapter --source udp --udp-port 5610         a controller bridge sends one line per reading\n"
      "  cellcal_joint_state_adapter --source sim                         the simulated robot of the cell file\n",
      "  --csv: a measurement file (docs/measurement-csv.md); --source udp: the line format in docs/udp-sources.md\n"));
  Options o;
  addCommonOptions(app, o.common);
  app.add_option("--source", o.source, "sim | csv | udp")->check(CLI::IsMember({"sim", "csv", "udp"}))->capture_default_str();
  app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  app.add_option("--start-cell-time-s", o.start_cell_time_s, "sim: start the robot program at this cell time");
  app.add_option("--wait-for-readers", o.wait_for_readers,
                 "sim: start the program once JointState has a reader and RobotTruth has N (at most 10 s)");
  addCsvReplayOptions(app, o.csv);
  app.add_option("--udp-address", o.udp_address, "udp: address to bind")->capture_default_str();
  app.add_option("--udp-port", o.udp_port, "udp: port to bind (0: any)")->capture_default_str();
  return runMain("cellcal_joint_state_adapter", argc, argv, app, [&] {
    const CellConfig cell = loadCell(o.common);
    nlohmann::json extra;
    int rc = 0;
    {
      DdsNode node(cell, "cellcal_joint_state_adapter", identity::kJointStateAdapter);
      rc = o.source == "sim" ? runSim(cell, node, o, extra)
           : o.source == "csv" ? runCsv(cell, node, o, extra)
                               : runUdp(cell, node, o, extra);
      writeJsonFile(o.common.stats_json, {{"name", "joint_state_adapter"}, {"pid", ::getpid()}, {"topics", node.stats()}, {"source", o.source}, {"extra", extra}});
    }
    return rc;
  });
}
