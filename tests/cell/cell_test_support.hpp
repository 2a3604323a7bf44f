// Multi-process cell tests: real component processes on localhost (loopback profile), each test on its own DDS
// domain (hash of the test name into 1..200, so parallel ctest runs never see each other's samples).
#pragma once

#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "cellcal/components/child_process.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/core/engine/state_file.hpp"
#include "cellcal/core/engine/state_journal.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "test_support.hpp"

namespace cellcal::test {

namespace fs = std::filesystem;

inline int domainForTest() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string name = std::string(info->test_suite_name()) + "." + info->name();
  std::uint32_t h = 2166136261u;
  for (char c : name) h = (h ^ static_cast<unsigned char>(c)) * 16777619u;
  return 1 + static_cast<int>(h % 200);
}

inline std::string testDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path d = fs::temp_directory_path() / ("cellcal_" + std::string(info->name()) + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d.string();
}

struct RobotEntry {
  std::string robot_id, target_id, robot_file = "staubli_tx60.yaml";
  std::string base = "{ x_mm: 2200, y_mm: 400, z_mm: -300, roll_deg: 0, pitch_deg: 0, yaw_deg: 160 }";
  std::string extensions = "";  // e.g. "[joint_compliance:2]"
  std::string calibration_file = "";  // a calibrated robot file the engine starts from (absolute path)
};

// A cell file for a test: loopback profile, its own domain and state folder, a short simulated program.
// `dds_extra`: more keys of the dds map, e.g. ", security_dir: <dir>" (DDS Security with the files
// config/security/make_pki.sh made there) or ", type_information: false".
inline std::string writeCell(const std::string& dir, int domain, std::uint64_t seed, const std::vector<RobotEntry>& robots,
                             const std::string& simulation_extra = "", const std::string& engine_extra = "",
                             const std::string& dds_extra = "", const std::string& name = "cell") {
  std::ostringstream y;
  y << "dds: { domain_id: " << domain << ", profiles_file: " << CELLCAL_CONFIG_DIR
    << "/dds/cellcal_qos.xml, participant_profile: cellcal_loopback" << dds_extra << " }\n"
    << "time_compression: 720\nrobots:\n";
  for (const auto& r : robots)
    y << "  - { robot_id: " << r.robot_id << ", target_id: " << r.target_id << ", robot_file: " << CELLCAL_CONFIG_DIR
      << "/robots/" << r.robot_file << ", base_in_tracker: " << r.base
      << ", tool_in_flange: { x_mm: 30, y_mm: 0, z_mm: 60, roll_deg: 0, pitch_deg: 0, yaw_deg: 0 }"
      << (r.extensions.empty() ? "" : ", extensions: " + r.extensions)
      << (r.calibration_file.empty() ? "" : ", calibration_file: " + r.calibration_file) << " }\n";
  y << "engine:\n  state_dir: " << dir << "/state\n" << engine_extra
    << "simulation:\n  seed: " << seed << "\n"
    << (simulation_extra.find("joint_rate_hz") == std::string::npos ? "  joint_rate_hz: 1000\n" : "") << simulation_extra;
  const std::string path = dir + "/" + name + ".yaml";
  std::ofstream(path) << y.str();
  return path;
}

// A child process whose output goes to <dir>/<name>.log (appended: a name used twice keeps both runs' output).
class Process {
 public:
  Process(const std::string& dir, const std::string& name, std::vector<std::string> args)
      : child_(std::string(CELLCAL_BIN_DIR) + "/" + args[0], std::vector<std::string>(args.begin() + 1, args.end()),
               dir + "/" + name + ".log", /*append=*/true) {}
  bool running() { return child_.running(); }
  // SIGINT (clean stop) or SIGKILL; returns the exit code (-1 on timeout).
  int stop(int sig = SIGINT, double timeout_s = 15) { return child_.stop(sig, timeout_s); }
  int wait(double timeout_s) { return child_.wait(timeout_s); }
  std::string log() const { return readTextFile(child_.logFile()); }
  pid_t pid() const { return child_.pid(); }

 private:
  components::ChildProcess child_;
};

inline bool waitUntil(const std::function<bool()>& cond, double timeout_s) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < end) {
    if (cond()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return cond();
}

inline nlohmann::json readJson(const std::string& path) {
  std::ifstream in(path);
  if (!in) return nlohmann::json();
  return nlohmann::json::parse(in, nullptr, false);
}

// A robot's saved engine state as a running engine, or one killed, left it (the snapshot <robot_id>.state.json and
// the journal beside it, read as the engine would on restart), in the snapshot's JSON form; null when there is none.
inline nlohmann::json readEngineState(const std::string& state_dir, const std::string& robot_id) {
  const auto loaded = cellcal::loadDurableState(cellcal::stateFilePath(state_dir, robot_id));
  if (!loaded.state) return nlohmann::json();
  return nlohmann::json::parse(cellcal::engineStateToJson(*loaded.state));
}

// `cellcal cell` over `cfg` for `duration_s` (args: more of its options), run to its end. Returns the summary with every
// process's exit code checked, or a discarded value (the failure reported with the launcher's log).
inline nlohmann::json runCell(const std::string& dir, const std::string& cfg, const std::string& duration_s,
                              const std::vector<std::string>& args = {}, double timeout_s = 60) {
  std::vector<std::string> argv = {"cellcal", "cell", "--config", cfg, "--duration-s", duration_s, "--work-dir",
                                   dir + "/run", "--summary-json", dir + "/summary.json", "--quiet"};
  argv.insert(argv.end(), args.begin(), args.end());
  Process cell(dir, "cell", argv);
  const int code = cell.wait(timeout_s);
  if (code != 0) {
    ADD_FAILURE() << "cellcal cell exited with " << code << "\n" << cell.log();
    return nlohmann::json::value_t::discarded;
  }
  const auto s = readJson(dir + "/summary.json");
  if (s.is_discarded() || s.is_null()) {
    ADD_FAILURE() << "no summary\n" << cell.log();
    return nlohmann::json::value_t::discarded;
  }
  for (const auto& p : s["processes"]) EXPECT_EQ(p["exit_code"], 0) << p["name"];
  return s;
}

// Every topic of the cell was published and received (cellcal cell's summary).
inline void expectEveryTopicFlowed(const nlohmann::json& summary) {
  for (const char* t : {"cellcal/joint_state", "cellcal/tracker_pose", "cellcal/calibration_state",
                        "cellcal/target_pose", "cellcal/compensated_target"}) {
    EXPECT_GT(summary["topics"][t]["published"].get<int>(), 0) << t;
    EXPECT_GT(summary["topics"][t]["received"].get<int>(), 0) << t;
  }
}

// The test's own participant: every CalibrationState, CompensatedTarget and CalibrationDiagnostics it receives.
struct Probe {
  explicit Probe(const CellConfig& cell) : node(cell, "cellcal_test_probe", components::identity::kObserver) {
    node.reader<msg::CalibrationState>([this](const msg::CalibrationState& m, const components::fdds::SampleInfo&) {
      std::lock_guard<std::mutex> l(mutex);
      states.push_back(m);
    });
    node.reader<msg::CompensatedTarget>([this](const msg::CompensatedTarget& m, const components::fdds::SampleInfo&) {
      std::lock_guard<std::mutex> l(mutex);
      compensated.push_back(m);
    });
    node.reader<msg::CalibrationDiagnostics>([this](const msg::CalibrationDiagnostics& m, const components::fdds::SampleInfo&) {
      std::lock_guard<std::mutex> l(mutex);
      diagnostics.push_back(m);
    });
  }
  std::uint64_t latestVersion(const std::string& robot) {
    std::lock_guard<std::mutex> l(mutex);
    std::uint64_t v = 0;
    for (const auto& s : states)
      if (s.robot_id().to_string() == robot) v = std::max<std::uint64_t>(v, s.version());
    return v;
  }
  // The state the callbacks use comes first: members are destroyed in reverse, the node (and its callbacks) first.
  std::mutex mutex;
  std::vector<msg::CalibrationState> states;
  std::vector<msg::CompensatedTarget> compensated;
  std::vector<msg::CalibrationDiagnostics> diagnostics;
  components::DdsNode node;
};

// A target of the first robot its nominal model reaches at joints 0.3 rad, with those joints as the seed.
inline msg::TargetPose reachableTarget(const CellConfig& cell) {
  const RobotModel& m = cell.robots[0].model;
  KinematicsData d(m);
  const Eigen::VectorXd q = Eigen::VectorXd::Constant(m.numJoints(), 0.3);
  msg::TargetPose t;
  t.robot_id(cell.robots[0].robot_id);
  components::fromPose(forwardKinematics(m, d, m.nominal, q), t.position_m(), t.orientation_xyzw());
  t.seed_position_rad(std::vector<double>(q.data(), q.data() + q.size()));
  return t;
}

// A shard's engine (`cellcal cell --shards`: calibration_engine_<k> in run_dir) received its own shard's joint states
// and tracker readings only: at most what that shard's adapters published (another shard's samples would add to it),
// and at least 90 % of it. Returns "engine k: <topic> received/published; ..." for the test's printout.
inline std::string expectOnlyItsShard(const std::string& run_dir, int k) {
  const std::string n = std::to_string(k);
  const auto engine = readJson(run_dir + "/calibration_engine_" + n + ".stats.json");
  const auto joints = readJson(run_dir + "/joint_state_adapter_" + n + ".stats.json");
  const auto tracker = readJson(run_dir + "/tracker_adapter_" + n + ".stats.json");
  if (engine.is_discarded() || joints.is_discarded() || tracker.is_discarded()) {
    ADD_FAILURE() << "shard " << n << ": a stats file is missing in " << run_dir;
    return "";
  }
  std::string said = " engine " + n + ":";
  for (const auto& [topic, source] : {std::pair<std::string, nlohmann::json>{"cellcal/joint_state", joints},
                                      {"cellcal/tracker_pose", tracker}}) {
    const double got = engine["topics"][topic]["received"].get<double>();
    const double sent = source["topics"][topic]["published"].get<double>();
    EXPECT_LE(got, sent) << "engine " << n << " received another shard's " << topic;
    EXPECT_GE(got, 0.9 * sent) << "engine " << n << ", " << topic;
    said += " " + topic + " " + std::to_string(static_cast<long>(got)) + "/" + std::to_string(static_cast<long>(sent)) + ";";
  }
  return said;
}

}  // namespace cellcal::test
