// `cellcal bench-cell`'s parts: the bench's arguments, the processes under test and the robots it plays
// (bench_cell_play.cpp), and the figures it draws from what it received (bench_cell_figures.cpp).
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "cellcal/components/child_process.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::cli::bench_cell {

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
  bool pass_through = false;  // the compensation publisher answers unchanged (--pass-through): the transport's floor
};

// utime + stime of a process, seconds.
double cpuSeconds(pid_t pid);
// A memory figure of /proc/<pid>/status in MB: "VmHWM:" (peak resident) or "VmRSS:" (resident now).
double statusMb(pid_t pid, const std::string& field);
double peakRssMb(pid_t pid);
double rssMb(pid_t pid);

// The bench cell in dir: --robots TX60s side by side on the loopback profile, engine state in <dir>/state.
std::string writeBenchCellFile(const fs::path& dir, const BenchArgs& a);

// The processes under test, their logs and counts in dir: the engine, the compensation publisher and, with
// --record, a recorder of every topic beside them (does it keep up?).
struct BenchProcesses {
  BenchProcesses(const fs::path& dir, const std::string& cfg, const std::string& record, bool pass_through)
      : engine(bin("cellcal_calibration_engine"), {"--config", cfg, "--quiet", "--stats-json", (dir / "engine.json").string()},
               (dir / "engine.log").string()),
        compensation(bin("cellcal_compensation_publisher"), compensationArgs(dir, cfg, pass_through),
                     (dir / "comp.log").string()) {
    if (!record.empty())
      recorder.emplace(fs::read_symlink("/proc/self/exe").string(),
                       std::vector<std::string>{"record", "--config", cfg, "--out", fs::absolute(record).string(),
                                                "--quiet", "--json", (dir / "record.json").string()},
                       (dir / "record.log").string());
  }
  static std::vector<std::string> compensationArgs(const fs::path& dir, const std::string& cfg, bool pass_through) {
    std::vector<std::string> args = {"--config", cfg, "--wait-for-calibration-s", "0", "--stats-json",
                                     (dir / "comp.json").string()};
    if (pass_through) args.push_back("--pass-through");
    return args;
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
void waitForReaders(const std::vector<fdds::DataWriter*>& writers, int readers, const fs::path& dir);
// Plays the robots for --duration-s: per tick a joint state and a tracker reading per robot (each robot stands still
// 30 of every 50 ms, offset from the others by a fraction of a pose), a TargetPose per robot every
// rate/targets_hz ticks; samples memory and error once a second.
BenchPlayed play(const BenchArgs& a, const CellConfig& cell, const BenchRobots& robots, BenchReceived& rx,
                 Writer<msg::JointState>& js, Writer<msg::TrackerPose>& tp, Writer<msg::TargetPose>& tg,
                 Writer<msg::ServoSetpoint>& sv,
                 const BenchProcesses& p);

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
BenchLatencies latencies(const BenchReceived& rx);
// Soak figures: memory and error at the end of the first third of the run (warm-up done) and at its end.
nlohmann::json soakFigures(const BenchPlayed& played, double uncalibrated_mm, std::uint64_t bad_states,
                           const BenchSample** third_out);
// The samples as CSV (--series-csv); nothing when `path` is empty.
void writeSeriesCsv(const std::string& path, const std::vector<BenchSample>& series);
// The recorder's counts (record.json) against what was published; adds them to out.
void reportRecorder(const fs::path& dir, const BenchArgs& a, std::uint64_t published, double cpu, double rss,
                    nlohmann::json* out);

}  // namespace cellcal::cli::bench_cell
