// `cellcal bench-cell`: latency and sustained load of the engine and compensation processes, through real
// processes on localhost. This process plays N robots and their trackers: joint states and tracker readings at
// --rate-hz each per robot (the tracker streams all the time; the robot stands still 30 of every 50 ms), and
// TargetPoses at --targets-hz per robot. It measures, side by side in one run:
//   tracker reading published -> CalibrationState received   (p50/p99 over the poses)
//   TargetPose published -> CompensatedTarget received         (p50/p99)
// whether the engine kept up (every sample received, one update per stand-still, latency not growing), and the
// CPU (share of one core) and peak RSS of the engine and compensation processes. For soaks (minutes to hours): RSS of
// each process and the received calibrations' error against the simulated truth, sampled once a second, compared
// between the end of the first third of the run and its end.
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <optional>
#include <sstream>
#include <thread>

#include "cellcal/components/child_process.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/host_limits.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

namespace fs = std::filesystem;
using namespace cellcal::components;

struct BenchArgs {
  int robots = 8;
  double rate_hz = 1000;
  double targets_hz = 100;
  double duration_s = 20;
  int domain_id = 220;
  std::uint64_t seed = 1;  // the simulated robots' hidden errors, their poses and the tracker noise
  std::string json;
  std::string record;  // MCAP file of a recorder running beside the cell
  std::string series_csv;  // once a second: RSS of the processes, calibration error against the truth
  std::string dds_profile = "cellcal_loopback";
  bool servo = false;  // the targets as a servo stream (ServoSetpoint -> ServoCorrection)
};

void addOptions(CLI::App& cmd, BenchArgs& a) {
  cmd.add_option("--robots", a.robots, "robots (each with a joint-state and a tracker stream)")->check(CLI::Range(1, 64))->capture_default_str();
  cmd.add_option("--rate-hz", a.rate_hz, "rate of each stream")->check(CLI::Range(10.0, 5000.0))->capture_default_str();
  cmd.add_option("--targets-hz", a.targets_hz, "TargetPoses per second and robot")->check(positive())->capture_default_str();
  cmd.add_option("--duration-s", a.duration_s, "measuring time")->check(positive())->capture_default_str();
  cmd.add_option("--domain-id", a.domain_id, "DDS domain")->check(CLI::Range(0, 232))->capture_default_str();
  cmd.add_flag("--servo", a.servo,
               "send the targets as a servo loop's stream instead (cellcal/servo_setpoint, joint setpoints stamped "
               "with the cycle, best effort; answered on cellcal/servo_correction)");
  cmd.add_option("--dds-profile", a.dds_profile,
                 "participant profile of every process (config/dds/cellcal_qos.xml): cellcal_loopback (UDP on "
                 "127.0.0.1), cellcal_loopback_shm (shared memory first)")
      ->capture_default_str();
  cmd.add_option("--seed", a.seed, "seed of the simulated robots (hidden errors), their poses and the tracker noise")
      ->capture_default_str();
  cmd.add_option("--json", a.json, "write the figures as JSON")->check(outputFile());
  cmd.add_option("--record", a.record, "also run `cellcal record` of every topic into this MCAP file");
  cmd.add_option("--series-csv", a.series_csv,
                 "write, once a second: RSS of the engine, compensation and this process, and the mean error of the "
                 "received calibrations against the simulated truth (a soak's record)");
}

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

// The processes under test, their logs and counts in dir: the engine, the compensation publisher and, with
// --record, a recorder of every topic beside them (does it keep up?).
struct BenchProcesses {
  BenchProcesses(const fs::path& dir, const std::string& cfg, const std::string& record)
      : engine(bin("cellcal_calibration_engine"), {"--config", cfg, "--quiet", "--stats-json", (dir / "engine.json").string()},
               (dir / "engine.log").string()),
        compensation(bin("cellcal_compensation_publisher"),
                     {"--config", cfg, "--wait-for-calibration-s", "0", "--stats-json", (dir / "comp.json").string()},
                     (dir / "comp.log").string()) {
    if (!record.empty())
      recorder.emplace(fs::read_symlink("/proc/self/exe").string(),
                       std::vector<std::string>{"record", "--config", cfg, "--out", fs::absolute(record).string(),
                                                "--quiet", "--json", (dir / "record.json").string()},
                       (dir / "record.log").string());
  }
  static std::string bin(const std::string& name) { return (fs::read_symlink("/proc/self/exe").parent_path() / name).string(); }
  void stop() {
    std::vector<ChildProcess*> all = {&engine, &compensation};
    if (recorder) all.push_back(&*recorder);
    stopAll(all, SIGINT, 60);
  }
  ChildProcess engine, compensation;
  std::optional<ChildProcess> recorder;
};

// The simulated robots the bench plays (hidden geometric errors, fixed in time; 64 poses each) and a hold-out set
// of 32 configurations each to judge received calibrations against the truth.
struct BenchRobots {
  BenchRobots(const CellConfig& cell, const BenchArgs& a) {
    for (int i = 0; i < a.robots; ++i) {
      SimulationSettings settings;
      settings.seed = a.seed;
      sims.push_back(makeSimulatedCell(cell.robots[i], settings, i));
      std::mt19937_64 rng(a.seed * 1000003ULL + 1000 + i);
      poses.push_back(sims.back().randomConfigurations(64, rng));
      holdout.push_back(sims.back().randomConfigurations(32, rng));
      index_of[cell.robots[i].robot_id] = i;
    }
  }
  std::vector<Eigen::VectorXd> nominal() const {
    std::vector<Eigen::VectorXd> p;
    for (const auto& s : sims) p.push_back(s.nominalParams());
    return p;
  }
  // Mean position error over every robot's hold-out poses with these parameters, mm.
  double meanErrorMm(const std::vector<Eigen::VectorXd>& params) const {
    double s = 0;
    size_t n = 0;
    for (size_t i = 0; i < sims.size(); ++i) {
      KinematicsData d(sims[i].model());
      for (const auto& q : holdout[i]) {
        s += (forwardKinematics(sims[i].model(), d, params[i], q).translation() - sims[i].truePose(q, 0.0).translation()).norm();
        ++n;
      }
    }
    return s / static_cast<double>(n) * 1e3;
  }
  std::vector<SimulatedCell> sims;
  std::vector<std::vector<Eigen::VectorXd>> poses, holdout;
  std::map<std::string, int> index_of;
};

// What the bench's participant receives, written by the DDS callbacks (under mutex).
struct BenchReceived {
  struct State {
    std::int64_t at;
    std::int64_t stamp;
    std::uint64_t version;
    std::string robot;
  };
  std::mutex mutex;
  std::vector<State> states;
  std::vector<std::pair<std::int64_t, std::uint64_t>> comps;  // receipt, target sequence (unique over robots)
  std::vector<Eigen::VectorXd> latest;                        // per robot: the newest calibration (nominal before)
  std::uint64_t bad_states = 0;
  std::map<std::uint64_t, std::int64_t> target_sent;          // written by the publisher loop
};

// Once a second: resident memory of the processes and the calibrations' error against the truth.
struct BenchSample {
  double t_s, engine_rss_mb, compensation_rss_mb, publisher_rss_mb, error_mm;
};

// What the publisher loop did.
struct BenchPlayed {
  std::int64_t ticks = 0;
  std::uint64_t target_seq = 0, standstills = 0, late_ticks = 0;
  double wall_s = 0;
  std::vector<BenchSample> series;
};

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

// CPU time of a process over the run, as a share of one core.
struct CpuMeter {
  explicit CpuMeter(pid_t p) : pid(p), start_s(p > 0 ? cpuSeconds(p) : 0) {}
  double share(double wall_s) const { return pid > 0 ? (cpuSeconds(pid) - start_s) / wall_s : 0; }
  pid_t pid;
  double start_s;
};

// Latencies of tracker reading -> CalibrationState (each new version once; first and last thirds, to see whether it
// grows) and TargetPose -> CompensatedTarget.
struct BenchLatencies {
  std::vector<double> state_us, comp_us, first_third, last_third;
  std::uint64_t versions = 0;
};
BenchLatencies latencies(const BenchReceived& rx) {
  BenchLatencies l;
  std::map<std::string, std::uint64_t> last_version;
  for (const auto& s : rx.states) {
    if (s.version <= last_version[s.robot] || s.stamp == 0) continue;
    last_version[s.robot] = s.version;
    l.state_us.push_back((s.at - s.stamp) / 1e3);
  }
  for (size_t i = 0; i < l.state_us.size(); ++i) {
    if (i < l.state_us.size() / 3) l.first_third.push_back(l.state_us[i]);
    if (i >= 2 * l.state_us.size() / 3) l.last_third.push_back(l.state_us[i]);
  }
  for (const auto& [at, sq] : rx.comps)
    if (auto it = rx.target_sent.find(sq); it != rx.target_sent.end()) l.comp_us.push_back((at - it->second) / 1e3);
  for (const auto& [r, v] : last_version) l.versions += v;
  return l;
}

// Soak figures: memory and error at the end of the first third of the run (warm-up done) and at its end.
nlohmann::json soakFigures(const BenchPlayed& played, double uncalibrated_mm, std::uint64_t bad_states,
                           const BenchSample** third_out) {
  const auto& series = played.series;
  const double wall = played.wall_s;
  const BenchSample& third = *std::min_element(series.begin(), series.end(), [&](const BenchSample& x, const BenchSample& y) {
    return std::abs(x.t_s - wall / 3) < std::abs(y.t_s - wall / 3);
  });
  *third_out = &third;
  const BenchSample& end = series.back();
  const double minutes = std::max(1e-9, (end.t_s - third.t_s) / 60.0);
  return {{"uncalibrated_error_mm", uncalibrated_mm},
          {"error_mm_first_third", third.error_mm},
          {"error_mm_end", end.error_mm},
          {"bad_calibration_states", bad_states},
          {"rss_mb_first_third", {{"engine", third.engine_rss_mb}, {"compensation_publisher", third.compensation_rss_mb}, {"bench_publisher", third.publisher_rss_mb}}},
          {"rss_mb_end", {{"engine", end.engine_rss_mb}, {"compensation_publisher", end.compensation_rss_mb}, {"bench_publisher", end.publisher_rss_mb}}},
          {"rss_growth_mb_per_min_after_first_third",
           {{"engine", (end.engine_rss_mb - third.engine_rss_mb) / minutes},
            {"compensation_publisher", (end.compensation_rss_mb - third.compensation_rss_mb) / minutes},
            {"bench_publisher", (end.publisher_rss_mb - third.publisher_rss_mb) / minutes}}},
          {"minutes_compared", minutes}};
}

void writeSeriesCsv(const std::string& path, const std::vector<BenchSample>& series) {
  if (path.empty()) return;
  std::ofstream csv(path);
  if (!csv) throw std::runtime_error(path + ": cannot be written");
  csv << "t_s,engine_rss_mb,compensation_rss_mb,bench_publisher_rss_mb,mean_error_mm\n";
  for (const auto& x : series)
    csv << x.t_s << ',' << x.engine_rss_mb << ',' << x.compensation_rss_mb << ',' << x.publisher_rss_mb << ','
        << x.error_mm << '\n';
}

// The recorder's counts (record.json) against what was published; adds them to out.
void reportRecorder(const fs::path& dir, const BenchArgs& a, std::uint64_t published, double cpu, double rss,
                    nlohmann::json* out) {
  const auto rj = nlohmann::json::parse(std::ifstream((dir / "record.json").string()), nullptr, false);
  if (rj.is_discarded()) throw std::runtime_error("the recorder wrote no counts (see " + (dir / "record.log").string() + ")");
  const std::uint64_t rec_js = rj["topics"]["cellcal/joint_state"].value("received", 0ULL);
  const std::uint64_t rec_tp = rj["topics"]["cellcal/tracker_pose"].value("received", 0ULL);
  std::printf("recorder: %llu messages to %s; joint states %llu of %llu, tracker readings %llu of %llu; %llu lost "
              "(writer sequence gaps); CPU %.2f of a core, peak RSS %.1f MB\n",
              static_cast<unsigned long long>(rj.value("messages", 0ULL)), a.record.c_str(),
              static_cast<unsigned long long>(rec_js), static_cast<unsigned long long>(published),
              static_cast<unsigned long long>(rec_tp), static_cast<unsigned long long>(published),
              static_cast<unsigned long long>(rj.value("lost", 0ULL)), cpu, rss);
  (*out)["recorder"] = {{"messages", rj["messages"]}, {"joint_states_received", rec_js}, {"tracker_readings_received", rec_tp},
                        {"lost", rj["lost"]}, {"cpu_share_of_one_core", cpu}, {"peak_rss_mb", rss}};
}

int runBench(const BenchArgs& a) {
  // Targets go out on the streams' ticks: at most one per tick, every rate/targets ticks.
  if (a.targets_hz > a.rate_hz)
    throw ConfigError("--targets-hz " + std::to_string(a.targets_hz) + " above --rate-hz " + std::to_string(a.rate_hz) +
                      ": targets are sent on the streams' ticks (at most one per tick and robot); raise --rate-hz");
  installStopHandlers();
  const fs::path dir = fs::temp_directory_path() / ("cellcal_bench_cell_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const CellConfig cell = loadCellConfig(writeBenchCellFile(dir, a));
  BenchProcesses p(dir, cell.source, a.record);
  const pid_t engine = p.engine.pid(), comp = p.compensation.pid();
  const pid_t recorder = p.recorder ? p.recorder->pid() : -1;

  BenchRobots robots(cell, a);
  BenchReceived rx;
  rx.latest = robots.nominal();
  DdsNode node(cell, "cellcal_bench_cell", identity::kReplay);
  auto js = node.writer<msg::JointState>();
  auto tp = node.writer<msg::TrackerPose>();
  auto tg = node.writer<msg::TargetPose>();
  node.reader<msg::CalibrationState>([&](const msg::CalibrationState& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    const auto it = robots.index_of.find(m.robot_id().to_string());
    std::optional<ReceivedCalibration> c;
    if (it != robots.index_of.end()) c = fromCalibrationState(robots.sims[it->second].model(), m, nullptr);
    std::lock_guard<std::mutex> l(rx.mutex);
    rx.states.push_back({now, static_cast<std::int64_t>(m.last_measurement_stamp_ns()), m.version(), m.robot_id().to_string()});
    if (c) rx.latest[it->second] = c->params;
    else ++rx.bad_states;
  });
  node.reader<msg::CompensatedTarget>([&](const msg::CompensatedTarget& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    std::lock_guard<std::mutex> l(rx.mutex);
    rx.comps.emplace_back(now, m.target_sequence());
  });
  auto sv = node.writer<msg::ServoSetpoint>();
  node.reader<msg::ServoCorrection>([&](const msg::ServoCorrection& m, const fdds::SampleInfo&) {
    const std::int64_t now = wallNs();
    std::lock_guard<std::mutex> l(rx.mutex);
    rx.comps.emplace_back(now, m.setpoint_sequence());
  });
  waitForReaders({js.entity(), tp.entity(), a.servo ? sv.entity() : tg.entity()}, recorder > 0 ? 2 : 1, dir);

  const CpuMeter cpu_engine(engine), cpu_comp(comp), cpu_self(::getpid()), cpu_recorder(recorder);
  // Datagrams the kernel drops for a full socket buffer (this network namespace; the processes here dominate it).
  const auto kernel_drops0 = udpReceiveBufferErrors();
  const double uncalibrated_mm = robots.meanErrorMm(rx.latest);
  std::printf("bench-cell: %d robots, joint states and tracker readings at %.0f Hz each per robot, targets at %.0f Hz "
              "per robot, %.0f s...\n", a.robots, a.rate_hz, a.targets_hz, a.duration_s);
  std::fflush(stdout);
  const BenchPlayed played = play(a, cell, robots, rx, js, tp, tg, sv, p);
  const double wall = played.wall_s;
  const auto kernel_drops1 = udpReceiveBufferErrors();
  const auto rmem_max = readKernelLimit("/proc/sys/net/core/rmem_max");
  const double cpu_e = cpu_engine.share(wall), cpu_c = cpu_comp.share(wall), cpu_s = cpu_self.share(wall);
  const double rss_engine = peakRssMb(engine), rss_comp = peakRssMb(comp);
  const double cpu_r = cpu_recorder.share(wall);
  const double rss_recorder = recorder > 0 ? peakRssMb(recorder) : 0;
  p.stop();
  node.shutdown();

  const BenchLatencies l = latencies(rx);
  const auto es = nlohmann::json::parse(std::ifstream((dir / "engine.json").string()), nullptr, false);
  const std::uint64_t js_pub = static_cast<std::uint64_t>(played.ticks) * a.robots, js_rx = es.is_discarded() ? 0 : es["topics"]["cellcal/joint_state"].value("received", 0ULL);
  const std::uint64_t tp_rx = es.is_discarded() ? 0 : es["topics"]["cellcal/tracker_pose"].value("received", 0ULL);
  nlohmann::json out = {
      {"robots", a.robots}, {"rate_hz_per_stream", a.rate_hz}, {"targets_hz_per_robot", a.targets_hz}, {"duration_s", wall},
      {"tracker_to_state_us", {{"p50", percentile(l.state_us, 0.5)}, {"p99", percentile(l.state_us, 0.99)}, {"samples", l.state_us.size()},
                               {"p50_first_third", percentile(l.first_third, 0.5)}, {"p50_last_third", percentile(l.last_third, 0.5)}}},
      {"target_to_compensated_us", {{"p50", percentile(l.comp_us, 0.5)}, {"p99", percentile(l.comp_us, 0.99)}, {"samples", l.comp_us.size()},
                                    {"sent", played.target_seq}}},
      {"joint_states", {{"published", js_pub}, {"received_by_engine", js_rx}}},
      {"tracker_readings", {{"published", js_pub}, {"received_by_engine", tp_rx}}},
      {"standstills", played.standstills}, {"calibration_updates", l.versions}, {"bench_ticks_late", played.late_ticks},
      {"cpu_share_of_one_core", {{"engine", cpu_e}, {"compensation_publisher", cpu_c}, {"bench_publisher", cpu_s}}},
      {"peak_rss_mb", {{"engine", rss_engine}, {"compensation_publisher", rss_comp}}},
      {"cores", std::thread::hardware_concurrency()}};
  out["host"] = {{"net_core_rmem_max_bytes", rmem_max ? nlohmann::json(*rmem_max) : nlohmann::json()},
                 {"profile_udp_receive_buffer_bytes", node.udpReceiveBufferBytes()},
                 {"udp_datagrams_dropped_by_kernel",
                  kernel_drops0 && kernel_drops1 ? nlohmann::json(*kernel_drops1 - *kernel_drops0) : nlohmann::json()}};
  const BenchSample* third_p = nullptr;
  out["soak"] = soakFigures(played, uncalibrated_mm, rx.bad_states, &third_p);
  const BenchSample& third = *third_p;
  const BenchSample& end = played.series.back();
  writeSeriesCsv(a.series_csv, played.series);
  std::printf("                                     p50 us    p99 us   samples\n");
  std::printf("tracker reading -> CalibrationState %8.0f  %8.0f  %8zu\n", percentile(l.state_us, 0.5), percentile(l.state_us, 0.99), l.state_us.size());
  std::printf("%s %8.0f  %8.0f  %8zu\n", a.servo ? "ServoSetpoint -> ServoCorrection   " : "TargetPose -> CompensatedTarget    ", percentile(l.comp_us, 0.5), percentile(l.comp_us, 0.99), l.comp_us.size());
  std::printf("engine received %llu of %llu joint states and %llu of %llu tracker readings; %llu updates for %llu stand-stills\n",
              static_cast<unsigned long long>(js_rx), static_cast<unsigned long long>(js_pub),
              static_cast<unsigned long long>(tp_rx), static_cast<unsigned long long>(js_pub),
              static_cast<unsigned long long>(l.versions), static_cast<unsigned long long>(played.standstills));
  // The compensation publisher's own figures: the CPU of a target's callback (take, compensate, write) against the
  // process's CPU per target (the rest: DDS's receive and event threads, the kernel's UDP path, wake-ups).
  const auto cs = nlohmann::json::parse(std::ifstream((dir / "comp.json").string()), nullptr, false);
  if (!cs.is_discarded() && cs["extra"].contains("target_cpu_us")) {
    const auto& tc = a.servo ? cs["extra"]["servo"]["cpu_us"] : cs["extra"]["target_cpu_us"];
    const double sent = static_cast<double>(played.target_seq);
    const double process_us = sent > 0 ? cpu_c * wall / sent * 1e6 : 0.0;
    const nlohmann::json outcomes = a.servo ? nlohmann::json{{"applied", cs["extra"]["servo"]["applied"]},
                                                             {"answered", cs["extra"]["servo"]["answered"]},
                                                             {"out_of_order", cs["extra"]["servo"]["out_of_order"]}}
                                            : cs["extra"]["outcomes"];
    std::printf("compensation per %s: callback CPU mean %.1f us, p99 %.0f us, max %.0f us; process CPU %.0f us "
                "a %s; answered %zu of %llu; outcomes %s\n",
                a.servo ? "setpoint" : "target", tc.value("mean", 0.0), tc.value("p99", 0.0), tc.value("max", 0.0),
                process_us, a.servo ? "setpoint" : "target", l.comp_us.size(),
                static_cast<unsigned long long>(played.target_seq), outcomes.dump().c_str());
    out["compensation"] = {{"stream", a.servo ? "servo" : "target"}, {"target_callback_cpu_us", tc},
                           {"process_cpu_us_per_target", process_us}, {"outcomes", outcomes}};
  }
  if (!es.is_discarded() && es["extra"].contains("input_queue")) {
    const auto& iq = es["extra"]["input_queue"];
    std::printf("engine input queue (samples waiting for its worker): peak %llu, refused %llu (bound %llu)\n",
                iq.value("peak", 0ULL), iq.value("refused", 0ULL), iq.value("max", 0ULL));
    out["engine_input_queue"] = iq;
  }
  if (kernel_drops0 && kernel_drops1)
    std::printf("UDP datagrams the kernel dropped for a full socket buffer during the run: %llu (net.core.rmem_max "
                "%s bytes; the profile asks for %u)\n",
                static_cast<unsigned long long>(*kernel_drops1 - *kernel_drops0),
                rmem_max ? std::to_string(*rmem_max).c_str() : "?", node.udpReceiveBufferBytes());
  std::printf("tracker -> state p50 first third %.0f us, last third %.0f us (growing = falling behind)\n",
              percentile(l.first_third, 0.5), percentile(l.last_third, 0.5));
  std::printf("CPU (share of one core): engine %.2f, compensation %.2f, this publisher %.2f; peak RSS engine %.1f MB, "
              "compensation %.1f MB; %u cores\n",
              cpu_e, cpu_c, cpu_s, rss_engine, rss_comp, std::thread::hardware_concurrency());
  std::printf("memory (RSS MB) at %.0f s / at %.0f s: engine %.1f / %.1f, compensation %.1f / %.1f, this publisher "
              "%.1f / %.1f\n",
              third.t_s, end.t_s, third.engine_rss_mb, end.engine_rss_mb, third.compensation_rss_mb,
              end.compensation_rss_mb, third.publisher_rss_mb, end.publisher_rss_mb);
  std::printf("calibration error against the truth (mean of %d robots x 32 hold-out poses): uncalibrated %.3f mm, at "
              "%.0f s %.4f mm, at the end %.4f mm\n",
              a.robots, uncalibrated_mm, third.t_s, third.error_mm, end.error_mm);
  if (recorder > 0) reportRecorder(dir, a, js_pub, cpu_r, rss_recorder, &out);
  if (!a.json.empty()) writeJsonFile(a.json, out);
  fs::remove_all(dir);
  return 0;
}

}  // namespace

Runner addBenchCellCommand(CLI::App& app) { return addCommand(app, "bench-cell", addOptions, runBench); }

}  // namespace cellcal::cli
