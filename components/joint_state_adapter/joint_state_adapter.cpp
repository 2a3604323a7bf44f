#include "joint_state_adapter.hpp"

#include <algorithm>
#include <iostream>
#include <map>
#include <thread>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/udp_lines.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::components {

JointStateAdapter::JointStateAdapter(const Options& options)
    : SourceAdapter(options.input, identity::kJointStateAdapter), options_(options), joints_(node_.writer<msg::JointState>()) {}

void JointStateAdapter::runSim() {
  auto truth = node_.writer<sim::RobotTruth>();
  std::vector<SimulatedCell> cells;
  std::vector<SimRobotProgram> programs;
  for (size_t i = 0; i < cell_.robots.size(); ++i) cells.push_back(makeSimulatedCell(cell_.robots[i], cell_.simulation, static_cast<int>(i)));
  for (const auto& c : cells) programs.emplace_back(c, cell_.simulation);
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
      const SimRobotState st = programs[i].at(cell_time);
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
  extra_["ticks"] = ticks;
  extra_["ticks_skipped_late"] = late;
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

}  // namespace cellcal::components
