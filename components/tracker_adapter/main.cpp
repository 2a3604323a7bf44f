// cellcal_tracker_adapter: publishes 6D poses (or 3D points) of the target on the flange (cellcal/tracker_pose).
//   --source sim  the core simulator's tracker (AT960 noise, the robot's repeatability) measuring the simulated robot
//                 it learns from cellcal/sim/robot_truth: one reading per settled pose of the robot program, stamped
//                 with the instant of the robot state it measured (a tracker triggered in sync with the controller)
//   --source csv  the readings of a measurement file (CSV v1), row k stamped start + t_k (common/csv_replay.hpp)
//   --source udp  one line per reading from a tracker bridge (docs/udp-sources.md):
//                 <target_id> <stamp_ns|0> <valid 0|1> <x_m> <y_m> <z_m> [<qx> <qy> <qz> <qw>]
//                 [<sigma_position_m> <sigma_orientation_rad>]
#include <unistd.h>

#include <iostream>
#include <map>
#include <mutex>
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
  std::string udp_address = "127.0.0.1";
  int udp_port = 5611;
  CsvReplayOptions csv;
  double sigma_position_mm = 0.015;
  double sigma_orientation_deg = 0.005;
};

bool waitFor(const Options& o) {
  const auto start = std::chrono::steady_clock::now();
  while (!stopRequested()) {
    if (o.duration_s > 0 && std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >= o.duration_s) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

int runSim(const CellConfig& cell, DdsNode& node, const Options& o, nlohmann::json& extra) {
  auto writer = node.writer<msg::TrackerPose>();
  struct Robot {
    const CellRobot* robot;
    SimulatedCell sim;
    std::mt19937_64 rng;
    long long pose_id = -1;
    int readings = 0;
    std::uint64_t seq = 0;
  };
  std::map<std::string, Robot> robots;
  for (size_t i = 0; i < cell.robots.size(); ++i) {
    SimulatedCell sc = makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i));
    const std::uint64_t seed = sc.config().seed * 6364136223846793005ULL + 1442695040888963407ULL;
    robots.emplace(cell.robots[i].robot_id, Robot{&cell.robots[i], std::move(sc), std::mt19937_64(seed)});
  }
  std::mutex mutex;
  std::uint64_t measured = 0;
  node.reader<sim::RobotTruth>([&](const sim::RobotTruth& t, const fdds::SampleInfo&) {
    std::lock_guard<std::mutex> lock(mutex);
    auto it = robots.find(t.robot_id().to_string());
    if (it == robots.end()) return;
    Robot& r = it->second;
    if (t.pose_id() < 0 || !t.settled() || t.settled_for_s() < cell.simulation.tracker_delay_fraction * t.settle_duration_s())
      return;
    if (t.pose_id() != r.pose_id) {
      r.pose_id = t.pose_id();
      r.readings = 0;
    }
    if (r.readings >= cell.simulation.tracker_readings_per_pose) return;
    ++r.readings;
    const Eigen::VectorXd q = Eigen::Map<const Eigen::VectorXd>(t.position_rad().data(), static_cast<Eigen::Index>(t.position_rad().size()));
    const Observation obs = r.sim.measure(q, t.cell_time_s() / 3600.0, r.rng, r.robot->measurement);
    // A tracker triggered in sync with the controller: the reading is stamped with the instant it measured, the
    // instant of the robot state it saw (so the engine finds the joint state of that very instant).
    auto m = toTrackerPose(r.robot->target_id, static_cast<std::int64_t>(t.source_stamp_ns()), ++r.seq, obs);
    writer.write(m);
    ++measured;
  });
  std::cerr << "tracker_adapter: sim, " << robots.size() << " target(s), domain " << node.domainId() << "\n";
  waitFor(o);
  node.shutdown();  // no callback after this point
  extra["readings"] = measured;
  return 0;
}

int runCsv(const CellConfig& cell, DdsNode& node, const Options& o, nlohmann::json& extra) {
  auto writer = node.writer<msg::TrackerPose>();
  const CsvReplay r = loadCsvReplay(cell, o.csv);
  for (const auto& w : r.file.warnings) std::cerr << "tracker_adapter: skipped: " << w << "\n";
  std::cerr << "tracker_adapter: csv " << o.csv.path << ": " << r.file.rows.size() << " readings of "
            << r.robot->target_id << ", starting at unix ns " << r.start_unix_ns << ", domain " << node.domainId() << "\n";
  std::uint64_t seq = 0;
  for (size_t k = 0; k < r.file.rows.size() && !stopRequested(); ++k) {
    const std::int64_t at = r.start_unix_ns + static_cast<std::int64_t>(r.t_s[k] * 1e9);
    while (wallNs() < at && !stopRequested()) std::this_thread::sleep_for(std::chrono::microseconds(200));
    const Observation obs = toObservation(r.file.rows[k], r.robot->measurement, o.sigma_position_mm * 1e-3,
                                          o.sigma_orientation_deg * kPi / 180);
    auto m = toTrackerPose(r.robot->target_id, at, ++seq, obs);
    writer.write(m);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  extra["readings"] = seq;
  extra["skipped_rows"] = r.file.skipped_rows;
  return 0;
}

int runUdp(const CellConfig& cell, DdsNode& node, const Options& o, nlohmann::json& extra) {
  auto writer = node.writer<msg::TrackerPose>();
  UdpLineSocket sock(o.udp_address, o.udp_port);
  std::cerr << "tracker_adapter: udp " << o.udp_address << ":" << sock.port() << ", domain " << node.domainId() << "\n";
  std::map<std::string, std::uint64_t> seq;
  std::uint64_t lines = 0, bad = 0;
  const auto start = std::chrono::steady_clock::now();
  while (!stopRequested()) {
    if (o.duration_s > 0 && std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >= o.duration_s) break;
    for (const std::string& line : sock.receive(50)) {
      ++lines;
      const auto f = splitFields(line);
      std::string why;
      const CellRobot* robot = f.empty() ? nullptr : cell.robotByTarget(f[0]);
      std::int64_t stamp = 0, valid = 0;
      double v[9] = {0, 0, 0, 0, 0, 0, 1, 0, 0};
      const size_t n = f.size();
      if (!robot) {
        why = f.empty() ? "empty line" : "unknown target_id '" + f[0] + "'";
      } else if (n != 6 && n != 8 && n != 10 && n != 12) {
        why = "expected 6, 8, 10 or 12 fields, got " + std::to_string(n);
      } else if (!parseInt64(f[1], &stamp) || stamp < 0) {
        why = "field 2 (stamp_ns): '" + f[1] + "' is not a non-negative integer";
      } else if (!parseInt64(f[2], &valid) || (valid != 0 && valid != 1)) {
        why = "field 3 (valid): expected 0 or 1, got '" + f[2] + "'";
      } else {
        for (size_t k = 3; k < n && why.empty(); ++k)
          if (!parseDouble(f[k], &v[k - 3])) why = "field " + std::to_string(k + 1) + ": '" + f[k] + "' is not a finite number";
      }
      if (!why.empty()) {
        ++bad;
        std::cerr << "tracker_adapter: udp line " << lines << " ignored: " << why << "\n";
        continue;
      }
      msg::TrackerPose m;
      m.target_id(robot->target_id);
      m.source_stamp_ns(static_cast<std::uint64_t>(stamp == 0 ? wallNs() : stamp));
      m.sequence_number(++seq[robot->target_id]);
      m.position_m({v[0], v[1], v[2]});
      const bool oriented = n >= 10;
      m.has_orientation(oriented);
      m.orientation_xyzw(oriented ? std::array<double, 4>{v[3], v[4], v[5], v[6]} : std::array<double, 4>{0, 0, 0, 1});
      const double sp = n == 8 ? v[3] : n == 12 ? v[7] : 0, so = n == 8 ? v[4] : n == 12 ? v[8] : 0;
      std::array<double, 36> cov{};
      for (int i = 0; i < 3; ++i) {
        cov[i * 7] = sp * sp;
        cov[(i + 3) * 7] = so * so;
      }
      m.covariance(cov);
      m.valid(valid == 1);
      writer.write(m);
    }
  }
  extra["udp_lines"] = lines;
  extra["udp_bad_lines"] = bad;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"cellcal tracker adapter: publishes target poses measured by the laser tracker on cellcal/tracker_pose"};
  app.footer(manFooter(
      "cellcal/sim/robot_truth (--source sim only)",
      "cellcal/tracker_pose",
      "  cellcal_tracker_adapter --source udp --udp-port 5611             a tracker bridge sends one line per reading\n"
      "  cellcal_tracker_adapter --source csv --csv m.csv --start-unix-ns $START   replay a measurement file\n",
      "  --csv: a measurement file (docs/measurement-csv.md); --source udp: the line format in docs/udp-sources.md\n"));
  Options o;
  addCommonOptions(app, o.common);
  app.add_option("--source", o.source, "sim | csv | udp")->check(CLI::IsMember({"sim", "csv", "udp"}))->capture_default_str();
  app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  addCsvReplayOptions(app, o.csv);
  app.add_option("--sigma-position-mm", o.sigma_position_mm, "csv: 1-sigma position noise of the tracker")->capture_default_str();
  app.add_option("--sigma-orientation-deg", o.sigma_orientation_deg, "csv: 1-sigma orientation noise")->capture_default_str();
  app.add_option("--udp-address", o.udp_address, "udp: address to bind")->capture_default_str();
  app.add_option("--udp-port", o.udp_port, "udp: port to bind (0: any)")->capture_default_str();
  return runMain("cellcal_tracker_adapter", argc, argv, app, [&] {
    const CellConfig cell = loadCell(o.common);
    nlohmann::json extra;
    int rc = 0;
    {
      DdsNode node(cell, "cellcal_tracker_adapter", identity::kTrackerAdapter);
      rc = o.source == "sim" ? runSim(cell, node, o, extra)
           : o.source == "csv" ? runCsv(cell, node, o, extra)
                               : runUdp(cell, node, o, extra);
      writeJsonFile(o.common.stats_json, {{"name", "tracker_adapter"}, {"pid", ::getpid()}, {"topics", node.stats()}, {"source", o.source}, {"extra", extra}});
    }
    return rc;
  });
}
