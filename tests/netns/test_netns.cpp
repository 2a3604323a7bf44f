// The cell across hosts: three network namespaces made by tools/netns/cellnet.sh (tracker-pc, robot-pc, cell-server,
// joined by veth links to a bridge), each process in its host over UDP (participant profile cellcal_udp: no shared
// memory, multicast discovery across the bridge). The launcher (`cellcal cell`, the application and the judge) runs on
// the cell server with the engine and the compensation publisher. Each test makes its namespaces and removes them;
// where the machine refuses namespaces (not root, no veth or bridge) the tests skip and say why. docs/deployment.md.
#include <gtest/gtest.h>

#include <cstdio>
#include <regex>
#include <sstream>

#include "cell/cell_test_support.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

const std::string kScript = std::string(CELLCAL_SOURCE_DIR) + "/tools/netns/cellnet.sh";

// Runs a shell command; its exit code and output.
int shell(const std::string& cmd, std::string* out = nullptr) {
  std::string text;
  FILE* p = ::popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return -1;
  char buf[512];
  while (std::fgets(buf, sizeof buf, p)) text += buf;
  const int status = ::pclose(p);
  if (out) *out = text;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

class NetnsCell : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string why;
    if (shell(kScript + " check", &why) != 0) GTEST_SKIP() << "network namespaces not available: " << why;
    prefix_ = "cn" + std::to_string(::getpid() % 100000);
    std::string out;
    ASSERT_EQ(shell(kScript + " up " + prefix_, &out), 0) << out;
    made_ = true;
  }
  void TearDown() override {
    if (!made_) return;
    std::string out;
    EXPECT_EQ(shell(kScript + " down " + prefix_, &out), 0) << out;
    shell("ip netns list", &out);
    EXPECT_EQ(out.find(prefix_ + "-"), std::string::npos) << "namespaces left behind:\n" << out;
  }
  std::string ns(const std::string& host) const { return prefix_ + "-" + host; }
  // `cellcal cell` on the cell server, the adapters on their hosts.
  std::vector<std::string> cellAcrossHosts(const std::string& cfg, const std::string& dir, const std::string& duration_s,
                                           bool quiet) const {
    std::vector<std::string> a = {"netns", "exec", ns("cell-server"), std::string(CELLCAL_BIN_DIR) + "/cellcal", "cell",
                                  "--config", cfg, "--dds-profile", "cellcal_udp", "--duration-s", duration_s,
                                  "--work-dir", dir + "/run", "--summary-json", dir + "/summary.json",
                                  "--host", "tracker_adapter=" + ns("tracker-pc"),
                                  "--host", "joint_state_adapter=" + ns("robot-pc")};
    if (quiet) a.push_back("--quiet");
    return a;
  }
  static std::string ipCommand() {
    for (const char* p : {"/usr/sbin/ip", "/usr/bin/ip", "/sbin/ip", "/bin/ip"})
      if (::access(p, X_OK) == 0) return p;
    return "ip";
  }

  std::string prefix_;
  bool made_ = false;
};

// The same cell (same robot errors, seed and program) on one host over loopback and across the three hosts: the same
// calibration, latencies reported for both.
TEST_F(NetnsCell, ConvergesAcrossThreeHostsAsOnOneHost) {
  const std::string dir = testDir();
  const std::string cfg = writeCell(dir, domainForTest(), testSeed(), {{"tx60", "tx60_target"}});
  const auto one = runCell(dir + "/one", cfg, "12");
  ASSERT_FALSE(one.is_discarded());
  fs::create_directories(dir + "/hosts");
  components::ChildProcess across(ipCommand(), cellAcrossHosts(cfg, dir + "/hosts", "12", true), dir + "/hosts/cell.log");
  ASSERT_EQ(across.wait(90), 0) << readTextFile(dir + "/hosts/cell.log");
  const auto hosts = readJson(dir + "/hosts/summary.json");
  ASSERT_FALSE(hosts.is_discarded()) << readTextFile(dir + "/hosts/cell.log");
  for (const auto& p : hosts["processes"]) EXPECT_EQ(p["exit_code"], 0) << p.dump();
  // Every reading crossed from tracker-pc and robot-pc to the cell server.
  EXPECT_EQ(hosts["topics"]["cellcal/tracker_pose"]["published"], hosts["topics"]["cellcal/tracker_pose"]["received"]);
  const int n_one = one["calibration_updates"], n_hosts = hosts["calibration_updates"];
  EXPECT_GE(n_hosts, n_one - 2);
  EXPECT_LE(n_hosts, n_one + 2);
  const double e_one = one["verify_after_last_update_mm"], e_hosts = hosts["verify_after_last_update_mm"];
  EXPECT_LT(e_hosts, 0.05);
  EXPECT_NEAR(e_hosts, e_one, 0.1 * e_one + 0.002) << "same inputs, different calibration";
  std::printf("  one host (loopback): %d updates, hold-out %.4f mm, tracker->state p50 %.0f us p99 %.0f us\n"
              "  three hosts (veth + bridge, UDP): %d updates, hold-out %.4f mm, tracker->state p50 %.0f us p99 %.0f us, "
              "target->compensated p50 %.0f us\n",
              n_one, e_one, one["latency_us"]["tracker_to_state_p50"].get<double>(),
              one["latency_us"]["tracker_to_state_p99"].get<double>(), n_hosts, e_hosts,
              hosts["latency_us"]["tracker_to_state_p50"].get<double>(),
              hosts["latency_us"]["tracker_to_state_p99"].get<double>(),
              hosts["latency_us"]["target_to_compensated_p50"].get<double>());
}

// The tracker PC's link is cut for 10 s while the robot works: the engine reports the tracker stale, makes no update
// without it, resumes once the link is back, and applies every reading once (versions one by one, never more updates
// than readings received).
TEST_F(NetnsCell, ATrackerLinkCutIsReportedAndTheCellResumes) {
  const std::string dir = testDir();
  const std::string cfg = writeCell(dir, domainForTest(), testSeed(), {{"tx60", "tx60_target"}});
  fs::create_directories(dir + "/hosts");
  components::ChildProcess cell(ipCommand(), cellAcrossHosts(cfg, dir + "/hosts", "30", false), dir + "/hosts/cell.log");
  // The robot program starts once the processes have found each other; cut 8 s in, heal 10 s later.
  std::this_thread::sleep_for(std::chrono::seconds(8));
  ASSERT_TRUE(cell.running()) << readTextFile(dir + "/hosts/cell.log");
  std::string out;
  ASSERT_EQ(shell(kScript + " link " + prefix_ + " tracker-pc down", &out), 0) << out;
  const auto cut = std::chrono::steady_clock::now();
  std::this_thread::sleep_for(std::chrono::seconds(10));
  ASSERT_EQ(shell(kScript + " link " + prefix_ + " tracker-pc up", &out), 0) << out;
  const auto healed = std::chrono::steady_clock::now();
  ASSERT_EQ(cell.wait(90), 0) << readTextFile(dir + "/hosts/cell.log");
  const std::string log = readTextFile(dir + "/hosts/cell.log");
  const std::string engine_log = readTextFile(dir + "/hosts/run/calibration_engine.log");
  const auto s = readJson(dir + "/hosts/summary.json");
  ASSERT_FALSE(s.is_discarded()) << log;

  // The launcher prints "[ 12.34 s] tx60     v17 ..." per update, seconds since it started.
  std::vector<std::pair<double, int>> updates;
  const std::regex line(R"(\[\s*([0-9.]+) s\] tx60\s+v([0-9]+))");
  for (std::sregex_iterator it(log.begin(), log.end(), line), end; it != end; ++it)
    updates.emplace_back(std::stod((*it)[1]), std::stoi((*it)[2]));
  ASSERT_GT(updates.size(), 10u) << log;
  for (size_t i = 1; i < updates.size(); ++i) EXPECT_GT(updates[i].second, updates[i - 1].second) << log;
  const int readings_rx = s["topics"]["cellcal/tracker_pose"]["received"];
  EXPECT_LE(s["calibration_updates"].get<int>(), readings_rx) << s.dump();
  // Times on the launcher's clock: it started about when `cell` did, within the 8 s slept before the cut.
  const double launcher_cut_s = 8.0, launcher_heal_s = launcher_cut_s +
      std::chrono::duration<double>(healed - cut).count();
  int during = 0, after = 0;
  for (const auto& [t, v] : updates) {
    if (t > launcher_cut_s + 1.0 && t < launcher_heal_s - 0.5) ++during;  // 1 s: readings in flight at the cut
    if (t > launcher_heal_s + 0.5) ++after;
  }
  EXPECT_EQ(during, 0) << "updates while the tracker was cut off\n" << log;
  EXPECT_GT(after, 5) << "no updates after the link healed\n" << log;
  EXPECT_NE(engine_log.find("stale input: tracker_pose"), std::string::npos) << engine_log;
  EXPECT_LT(s["verify_after_last_update_mm"].get<double>(), 0.05) << s.dump();
  std::printf("  tracker link cut for %.1f s: %d updates before, %d during, %d after; engine: \"%s\"\n",
              launcher_heal_s - launcher_cut_s, static_cast<int>(updates.size()) - during - after, during, after,
              engine_log.find("stale input: tracker_pose") == std::string::npos
                  ? "(no stale line)"
                  : engine_log.substr(engine_log.find("stale input: tracker_pose"), 60).c_str());
}

}  // namespace
}  // namespace cellcal
