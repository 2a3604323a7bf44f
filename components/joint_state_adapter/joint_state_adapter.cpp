#include "joint_state_adapter.hpp"

#include <algorithm>
#include <iostream>
#include <map>
#include <mutex>
#include <thread>

#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/ros2.hpp"
#include "cellcal/components/udp_lines.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::components {

JointStateAdapter::JointStateAdapter(const Options& options)
    : SourceAdapter(options.input, identity::kJointStateAdapter), options_(options), joints_(node_.writer<msg::JointState>()) {}

void JointStateAdapter::runSim() {
  auto truth = node_.writer<sim::RobotTruth>();
  std::vector<SimulatedCell> cells;
  std::vector<SimRobotProgram> programs;
  for (size_t i = 0; i < cell_.robots.size(); ++i) cells.push_back(makeSimulatedCell(cell_.robots[i], cell_.simulation, cell_.robots[i].index));
  for (const auto& c : cells) programs.emplace_back(c, cell_.simulation);
  for (size_t i = 0; i < cells.size(); ++i)
    std::cerr << "joint_state_adapter: " << cell_.robots[i].robot_id << ": simulating " << simulatedRobotText(cells[i]) << "\n";
  // simulation.follow_pose_requests: the program takes its poses from the engine's newest proposals.
  const bool follow = cell_.simulation.follow_pose_requests;
  std::mutex program_mutex;
  std::uint64_t requests_received = 0, requests_refused = 0;
  if (follow) {
    node_.reader<msg::PoseRequest>([&](const msg::PoseRequest& m, const fdds::SampleInfo&) {
      std::lock_guard<std::mutex> lock(program_mutex);
      ++requests_received;
      for (size_t i = 0; i < cell_.robots.size(); ++i) {
        if (cell_.robots[i].robot_id != m.robot_id().to_string()) continue;
        std::string why;
        auto qs = fromPoseRequest(m, cell_.robots[i].model.numJoints(), &why);
        if (!qs) {
          ++requests_refused;
          std::cerr << "joint_state_adapter: ignored: " << why << "\n";
          return;
        }
        programs[i].offer(std::move(*qs));
      }
    });
    std::cerr << "joint_state_adapter: the simulated program follows the engine's pose requests (cellcal/pose_request)\n";
  }
  if (options_.wait_for_readers > 0) {
    // Start the program only once someone listens: JointState matched by >= 1 reader (the engine) and
    // RobotTruth by >= N (the simulated tracker, and the launcher when it watches). At most 10 s.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    fdds::PublicationMatchedStatus a, b;
    while (std::chrono::steady_clock::now() < deadline && !stopRequested()) {
      joints_.entity()->get_publication_matched_status(a);
      truth.entity()->get_publication_matched_status(b);
      if (a.current_count >= 1 && b.current_count >= options_.wait_for_readers) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));  // let the readers' side of the match settle
    std::cerr << "joint_state_adapter: readers matched: joint_state " << a.current_count << ", robot_truth "
              << b.current_count << "\n";
  }
  const double period_s = 1.0 / cell_.simulation.joint_rate_hz;
  const RunLimit limit(input_.duration_s);
  auto anchor = std::chrono::steady_clock::now();          // wall time of tick `anchor_tick`
  std::uint64_t anchor_tick = 0;
  std::uint64_t seq = 0, ticks = 0, late = 0;
  std::cerr << "joint_state_adapter: sim, " << cell_.robots.size() << " robot(s) at " << cell_.simulation.joint_rate_hz
            << " Hz, cell time x" << cell_.time_compression << ", domain " << node_.domainId() << "\n";
  for (std::uint64_t k = 0;; ++k) {
    const auto due = anchor + std::chrono::nanoseconds(static_cast<std::int64_t>((k - anchor_tick) * period_s * 1e9));
    if (!sleepUntil(due)) break;
    const auto now_steady = std::chrono::steady_clock::now();
    if (limit.timeUp()) break;
    if (now_steady - due > std::chrono::duration<double>(2 * period_s)) {
      // Fell behind (a loaded machine): simulated time is tick-based, so it slows down instead of skipping poses
      // the tracker would never see, and the schedule restarts from now instead of bursting.
      ++late;
      anchor = now_steady;
      anchor_tick = k;
    }
    const double cell_time = options_.start_cell_time_s + k * period_s * cell_.time_compression;
    const std::int64_t now = wallNs();
    ++seq;
    for (size_t i = 0; i < cell_.robots.size(); ++i) {
      SimRobotState st;
      if (follow) {
        std::lock_guard<std::mutex> lock(program_mutex);
        st = programs[i].advance(cell_time);
      } else {
        st = programs[i].at(cell_time);
      }
      auto m = toJointState(cell_.robots[i].robot_id, now, seq, st.q_rad, st.settled);
      joints_.write(m);
      sim::RobotTruth t;
      t.robot_id(cell_.robots[i].robot_id);
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
  node_.shutdown();  // no pose request after this point
  extra_["ticks"] = ticks;
  extra_["ticks_skipped_late"] = late;
  if (follow) {
    // Per robot, [pose id, joints...] of each pose taken from a proposal: what the launcher's reference replays.
    nlohmann::json followed = nlohmann::json::object();
    for (size_t i = 0; i < programs.size(); ++i) {
      nlohmann::json list = nlohmann::json::array();
      for (const auto& [id, q] : programs[i].followed()) {
        nlohmann::json row = {id};
        for (Eigen::Index j = 0; j < q.size(); ++j) row.push_back(q[j]);
        list.push_back(row);
      }
      followed[cell_.robots[i].robot_id] = list;
    }
    extra_[stats::kFollowedPoses] = followed;
    extra_["pose_requests_received"] = requests_received;
    extra_["pose_requests_refused"] = requests_refused;
  }
}

void JointStateAdapter::runCsv() {
  const CsvReplay r = loadCsvReplay(cell_, input_.csv);
  for (const auto& w : r.file.warnings) std::cerr << "joint_state_adapter: skipped: " << w << "\n";
  std::cerr << "joint_state_adapter: csv " << input_.csv.path << ": " << r.file.rows.size() << " rows for "
            << r.robot->robot_id << ", starting at unix ns " << r.start_unix_ns << ", domain " << node_.domainId() << "\n";
  const double period_s = 1.0 / cell_.simulation.joint_rate_hz;
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
      joints_.write(m);
    }
    std::this_thread::sleep_for(std::chrono::duration<double>(period_s));
  }
  extra_["rows"] = r.file.rows.size();
  extra_["skipped_rows"] = r.file.skipped_rows;
}

void JointStateAdapter::runUdp() {
  std::map<std::string, std::uint64_t> seq;
  const auto publish = [&](const std::string& text, std::string* why) {
    const auto line = parseJointLine(text, cell_, why);
    if (!line) return false;
    auto m = toJointState(line->robot->robot_id, line->stamp_ns == 0 ? wallNs() : line->stamp_ns,
                          ++seq[line->robot->robot_id], line->q_rad, line->settled);
    joints_.write(m);
    return true;
  };
  const UdpLineCounts n = serveUdpLines(name_, input_.udp_address, input_.udp_port, input_.duration_s, publish);
  extra_["udp_lines"] = n.lines;
  extra_["udp_bad_lines"] = n.bad;
}

void JointStateAdapter::runRos2() {
  const CellRobot* robot = nullptr;
  if (!input_.csv.robot_id.empty()) {
    robot = cell_.robotById(input_.csv.robot_id);
    if (!robot) throw std::runtime_error("--robot-id " + input_.csv.robot_id + ": not in " + cell_.source);
  } else if (cell_.robots.size() == 1) {
    robot = &cell_.robots.front();
  } else {
    throw std::runtime_error("--source ros2: the cell file has " + std::to_string(cell_.robots.size()) +
                             " robots: say whose joints these are with --robot-id");
  }
  const std::vector<std::string> names =
      options_.ros_joint_names.empty() ? robot->ros2_joint_names : options_.ros_joint_names;
  if (names.empty())
    throw std::runtime_error("--source ros2: no joint names for robot " + robot->robot_id +
                             ": give robots[].ros2_joint_names in the cell file or --ros-joint-names (docs/ros2.md)");
  if (static_cast<int>(names.size()) != robot->model.numJoints())
    throw std::runtime_error("--ros-joint-names: " + std::to_string(names.size()) + " names for a robot of " +
                             std::to_string(robot->model.numJoints()) + " joints");
  std::string err;
  const auto topic = ros2DdsTopic(options_.ros_topic, &err);
  if (!topic) throw std::runtime_error("--ros-topic: " + err);

  std::mutex mutex;
  StandStillDetector still(options_.settle_window_s, cell_.engine.settle_tolerance_rad, options_.settle_velocity_radps);
  std::uint64_t seq = 0, received = 0, published = 0, settled_count = 0, bad = 0;
  std::string last_reason;
  node_.reader<sensor_msgs::msg::dds_::JointState_>(
      [&](const sensor_msgs::msg::dds_::JointState_& js, const fdds::SampleInfo&) {
        std::lock_guard<std::mutex> lock(mutex);
        ++received;
        std::string why;
        const auto q = jointPositionsByName(js.name(), js.position(), names, &why);
        std::optional<Eigen::VectorXd> v;
        if (q && !js.velocity().empty()) {
          v = jointPositionsByName(js.name(), js.velocity(), names, &why);
          if (!v) why = "velocity: " + why;
        }
        if (!q || (!js.velocity().empty() && !v)) {
          ++bad;
          // Said once per kind of fault, not per sample (a driver at 500 Hz would flood the log).
          const std::string reason = maskFigures(why);
          if (reason != last_reason)
            std::cerr << "joint_state_adapter: " << options_.ros_topic << " sample " << received << " skipped: " << why
                      << "\n";
          last_reason = reason;
          return;
        }
        const std::int64_t header_ns =
            static_cast<std::int64_t>(js.header().stamp().sec()) * 1000000000LL + js.header().stamp().nanosec();
        const std::int64_t stamp = header_ns > 0 ? header_ns : wallNs();  // a driver that leaves the stamp at zero
        std::vector<double> vel;
        if (v) vel.assign(v->data(), v->data() + v->size());
        const bool settled = still.update(stamp, *q, vel);
        auto m = toJointState(robot->robot_id, stamp, ++seq, *q, settled);
        if (joints_.write(m)) ++published;
        if (settled) ++settled_count;
      },
      *topic);
  std::cerr << "joint_state_adapter: ros2: " << options_.ros_topic << " (DDS topic " << *topic
            << ", type sensor_msgs::msg::dds_::JointState_) -> " << robot->robot_id << ", joints";
  for (const auto& n : names) std::cerr << " " << n;
  std::cerr << "; settled after " << options_.settle_window_s << " s still, domain " << node_.domainId() << "\n";
  const RunLimit limit(input_.duration_s);
  while (!limit.over()) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  node_.shutdown();  // no callback after this point: the counters are final
  extra_["ros2_received"] = received;
  extra_["ros2_skipped"] = bad;
  extra_["published"] = published;
  extra_["settled"] = settled_count;
}

}  // namespace cellcal::components
