#include "tracker_adapter.hpp"

#include <cmath>
#include <iostream>
#include <map>
#include <mutex>
#include <thread>

#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/udp_lines.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::components {

TrackerAdapter::TrackerAdapter(const Options& options)
    : SourceAdapter(options.input, identity::kTrackerAdapter), options_(options), writer_(node_.writer<msg::TrackerPose>()) {}

void TrackerAdapter::runSim() {
  struct Robot {
    const CellRobot* robot;
    SimulatedCell sim;
    std::mt19937_64 rng;
    long long pose_id = -1;
    int readings = 0;
    std::uint64_t seq = 0;
  };
  std::map<std::string, Robot> robots;
  for (size_t i = 0; i < cell_.robots.size(); ++i) {
    SimulatedCell sc = makeSimulatedCell(cell_.robots[i], cell_.simulation, cell_.robots[i].index);
    const std::uint64_t seed = sc.config().seed * 6364136223846793005ULL + 1442695040888963407ULL;
    robots.emplace(cell_.robots[i].robot_id, Robot{&cell_.robots[i], std::move(sc), std::mt19937_64(seed)});
  }
  std::mutex mutex;
  std::uint64_t measured = 0;
  // Per robot, the program's pose each reading measured (reading sequence k: element k - 1): what an in-process
  // reference needs to replay exactly the readings an engine applied.
  std::map<std::string, std::vector<long long>> pose_of_reading;
  const SimulationSettings& sim = cell_.simulation;
  if (options_.wait_for_readers > 0) {
    // The robot program waits for this adapter's RobotTruth reader (joint_state_adapter --wait-for-readers): made
    // only once the readings have somewhere to go.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    fdds::PublicationMatchedStatus m;
    while (std::chrono::steady_clock::now() < deadline && !stopRequested()) {
      writer_.entity()->get_publication_matched_status(m);
      if (m.current_count >= options_.wait_for_readers) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    std::cerr << "tracker_adapter: readers matched: tracker_pose " << m.current_count << " of "
              << options_.wait_for_readers << "\n";
  }
  node_.reader<sim::RobotTruth>([&](const sim::RobotTruth& t, const fdds::SampleInfo&) {
    std::lock_guard<std::mutex> lock(mutex);
    auto it = robots.find(t.robot_id().to_string());
    if (it == robots.end()) return;
    Robot& r = it->second;
    if (t.pose_id() < 0 || !t.settled() || t.settled_for_s() < sim.tracker_delay_fraction * t.settle_duration_s()) return;
    if (t.pose_id() != r.pose_id) {
      r.pose_id = t.pose_id();
      r.readings = 0;
    }
    if (r.readings >= sim.tracker_readings_per_pose) return;
    ++r.readings;
    const Eigen::VectorXd q = Eigen::Map<const Eigen::VectorXd>(t.position_rad().data(), static_cast<Eigen::Index>(t.position_rad().size()));
    const Observation obs = r.sim.measure(q, t.cell_time_s() / 3600.0, r.rng, r.robot->measurement);
    // A tracker triggered in sync with the controller: the reading is stamped with the instant it measured, the
    // instant of the robot state it saw (so the engine finds the joint state of that very instant).
    // (simulation.tracker_clock_offset_ms: a tracker host whose clock runs ahead, a drill for the engine's warning.)
    const auto offset_ns = static_cast<std::int64_t>(std::llround(sim.tracker_clock_offset_s * 1e9));
    auto m = toTrackerPose(r.robot->target_id, static_cast<std::int64_t>(t.source_stamp_ns()) + offset_ns, ++r.seq, obs);
    writer_.write(m);
    ++measured;
    pose_of_reading[it->first].push_back(t.pose_id());
  });
  std::cerr << "tracker_adapter: sim, " << robots.size() << " target(s), domain " << node_.domainId() << "\n";
  const RunLimit limit(input_.duration_s);
  while (!limit.over()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  node_.shutdown();  // before `robots` goes: no callback after this point
  extra_["readings"] = measured;
  extra_[stats::kPoseOfReading] = pose_of_reading;
}

void TrackerAdapter::runCsv() {
  const CsvReplay r = loadCsvReplay(cell_, input_.csv);
  for (const auto& w : r.file.warnings) std::cerr << "tracker_adapter: skipped: " << w << "\n";
  std::cerr << "tracker_adapter: csv " << input_.csv.path << ": " << r.file.rows.size() << " readings of "
            << r.robot->target_id << ", starting at unix ns " << r.start_unix_ns << ", domain " << node_.domainId() << "\n";
  std::uint64_t seq = 0;
  for (size_t k = 0; k < r.file.rows.size() && !stopRequested(); ++k) {
    const std::int64_t at = r.start_unix_ns + static_cast<std::int64_t>(r.t_s[k] * 1e9);
    while (wallNs() < at && !stopRequested()) std::this_thread::sleep_for(std::chrono::microseconds(200));
    const Observation obs = toObservation(r.file.rows[k], r.robot->measurement, options_.sigma_position_mm * 1e-3,
                                          options_.sigma_orientation_deg * kPi / 180);
    auto m = toTrackerPose(r.robot->target_id, at, ++seq, obs);
    writer_.write(m);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  extra_["readings"] = seq;
  extra_["skipped_rows"] = r.file.skipped_rows;
}

void TrackerAdapter::runUdp() {
  std::map<std::string, std::uint64_t> seq;
  const auto publish = [&](const std::string& text, std::string* why) {
    const auto line = parseTrackerLine(text, cell_, why);
    if (!line) return false;
    auto m = toTrackerPose(*line, line->stamp_ns == 0 ? wallNs() : line->stamp_ns, ++seq[line->robot->target_id]);
    writer_.write(m);
    return true;
  };
  const UdpLineCounts n = serveUdpLines(name_, input_.udp_address, input_.udp_port, input_.duration_s, publish);
  extra_["udp_lines"] = n.lines;
  extra_["udp_bad_lines"] = n.bad;
}

}  // namespace cellcal::components
