// `cellcal bench-cell`: the cell file and processes of the bench, and the robots it plays.
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <thread>

#include "bench_cell.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/host_limits.hpp"

namespace cellcal::cli::bench_cell {

// utime + stime of a process, seconds.
double cpuSeconds(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto close = s.rfind(')');
  if (close == std::string::npos) return std::nan("");
  std::istringstream rest(s.substr(close + 2));
  std::string f;
  double ut = 0, st = 0;
  for (int i = 3; i <= 15 && rest >> f; ++i) {
    if (i == 14) ut = std::stod(f);
    if (i == 15) st = std::stod(f);
  }
  return (ut + st) / static_cast<double>(::sysconf(_SC_CLK_TCK));
}

// A memory figure of /proc/<pid>/status in MB: "VmHWM:" (peak resident) or "VmRSS:" (resident now).
double statusMb(pid_t pid, const std::string& field) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind(field, 0) == 0) return std::stod(line.substr(field.size())) / 1024.0;
  return std::nan("");
}
double peakRssMb(pid_t pid) { return statusMb(pid, "VmHWM:"); }
double rssMb(pid_t pid) { return statusMb(pid, "VmRSS:"); }

// The bench cell in dir: --robots TX60s side by side on the loopback profile, engine state in <dir>/state.
std::string writeBenchCellFile(const fs::path& dir, const BenchArgs& a) {
  const std::string cfg = (dir / "cell.yaml").string();
  std::ofstream y(cfg);
  y << "dds: { domain_id: " << a.domain_id << ", profiles_file: " << configDir()
    << "/dds/cellcal_qos.xml, participant_profile: " << a.dds_profile << " }\nrobots:\n";
  for (int i = 0; i < a.robots; ++i)
    y << "  - { robot_id: r" << i << ", target_id: t" << i << ", robot_file: " << configDir()
      << "/robots/staubli_tx60.yaml, base_in_tracker: { x_mm: 2200, y_mm: " << 400 + 1500 * i
      << ", z_mm: -300, roll_deg: 0, pitch_deg: 0, yaw_deg: 160 } }\n";
  y << "engine: { state_dir: " << (dir / "state").string() << " }\n";
  return cfg;
}

// Waits (at most 15 s) until every writer has `readers` matched readers, then 1 s more.
void waitForReaders(const std::vector<fdds::DataWriter*>& writers, int readers, const fs::path& dir) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(15);
  for (;;) {
    bool all = true;
    for (fdds::DataWriter* w : writers) {
      fdds::PublicationMatchedStatus s;
      w->get_publication_matched_status(s);
      all = all && s.current_count >= readers;
    }
    if (all) break;
    if (std::chrono::steady_clock::now() > deadline) throw std::runtime_error("engine/compensation not discovered (see " + dir.string() + ")");
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::this_thread::sleep_for(std::chrono::seconds(1));
}

// Plays the robots for --duration-s: per tick a joint state and a tracker reading per robot (each robot stands still
// 30 of every 50 ms, offset from the others by a fraction of a pose), a TargetPose per robot every
// rate/targets_hz ticks; samples memory and error once a second.
BenchPlayed play(const BenchArgs& a, const CellConfig& cell, const BenchRobots& robots, BenchReceived& rx,
                 Writer<msg::JointState>& js, Writer<msg::TrackerPose>& tp, Writer<msg::TargetPose>& tg,
                 Writer<msg::ServoSetpoint>& sv,
                 const BenchProcesses& p) {
  BenchPlayed out;
  std::mt19937_64 rng(a.seed * 1000003ULL + 5);
  const int ticks_per_pose = static_cast<int>(std::lround(0.050 * a.rate_hz)), moving_ticks = ticks_per_pose * 2 / 5;
  const int target_every = std::max(1, static_cast<int>(std::lround(a.rate_hz / a.targets_hz)));
  std::uint64_t seq = 0;
  const auto t0 = std::chrono::steady_clock::now();
  const auto period = std::chrono::duration<double>(1.0 / a.rate_hz);
  KinematicsData kd(cell.robots[0].model);
  auto sample = [&](double t_s) {
    std::vector<Eigen::VectorXd> now_params;
    {
      std::lock_guard<std::mutex> l(rx.mutex);
      now_params = rx.latest;
    }
    out.series.push_back({t_s, rssMb(p.engine.pid()), rssMb(p.compensation.pid()), rssMb(::getpid()),
                          robots.meanErrorMm(now_params)});
  };
  const auto ticks_per_sample = static_cast<std::int64_t>(std::lround(a.rate_hz));
  std::int64_t& tick = out.ticks;
  for (;; ++tick) {
    if (tick % ticks_per_sample == 0) sample(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    const auto due = t0 + std::chrono::duration_cast<std::chrono::steady_clock::duration>(period * static_cast<double>(tick));
    if (std::chrono::steady_clock::now() > due + period) ++out.late_ticks;
    std::this_thread::sleep_until(due);
    if (std::chrono::steady_clock::now() - t0 > std::chrono::duration<double>(a.duration_s) || stopRequested()) break;
    const std::int64_t now = wallNs();
    ++seq;
    for (int i = 0; i < a.robots; ++i) {
      const std::int64_t rt = tick + i * ticks_per_pose / a.robots;
      const int phase = static_cast<int>(rt % ticks_per_pose);
      const auto k = static_cast<size_t>(rt / ticks_per_pose);
      if (phase == moving_ticks || (tick == 0 && phase > moving_ticks)) ++out.standstills;
      const Eigen::VectorXd& from = robots.poses[i][k % 64];
      const Eigen::VectorXd& to = robots.poses[i][(k + 1) % 64];
      const bool settled = phase >= moving_ticks;
      const Eigen::VectorXd q = settled ? to : from + (to - from) * (static_cast<double>(phase) / moving_ticks);
      auto j = toJointState(cell.robots[i].robot_id, now, seq, q, settled);
      js.write(j);
      Observation o = robots.sims[i].measure(q, 0.0, rng);
      auto r = toTrackerPose(cell.robots[i].target_id, now, seq, o);
      tp.write(r);
      if (tick % target_every == static_cast<std::int64_t>(i % target_every)) {
        const std::uint64_t target_seq = ++out.target_seq;
        const std::int64_t sent_ns = wallNs();
        {
          std::lock_guard<std::mutex> l(rx.mutex);
          rx.target_sent[target_seq] = sent_ns;
        }
        if (a.servo) {
          static thread_local msg::ServoSetpoint sp;  // reused: the generated constructor registers the IDL's types
          sp.robot_id(cell.robots[i].robot_id);
          sp.sequence_number(target_seq);
          sp.cycle_stamp_ns(static_cast<std::uint64_t>(now));
          sp.source_stamp_ns(static_cast<std::uint64_t>(now));
          sp.cartesian(false);
          sp.joint_position_rad().assign(to.data(), to.data() + to.size());
          sv.write(sp);
        } else {
          msg::TargetPose t;
          t.robot_id(cell.robots[i].robot_id);
          t.sequence_number(target_seq);
          fromPose(forwardKinematics(cell.robots[i].model, kd, cell.robots[i].model.nominal, to), t.position_m(),
                   t.orientation_xyzw());
          t.seed_position_rad(std::vector<double>(to.data(), to.data() + to.size()));
          t.source_stamp_ns(static_cast<std::uint64_t>(sent_ns));
          tg.write(t);
        }
      }
    }
  }
  out.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  sample(out.wall_s);
  return out;
}

}  // namespace cellcal::cli::bench_cell
