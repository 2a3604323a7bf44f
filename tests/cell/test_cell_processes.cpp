// The cell through real processes on localhost: convergence end to end (the launcher), a late-joining
// compensation publisher, the engine SIGKILLed and restarted, stale/out-of-order joint states, two robots on one
// domain. Hidden robot errors come from a fresh seed per run; the engine never sees the truth.
#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <array>
#include <cmath>
#include <atomic>
#include <fstream>
#include <functional>
#include <map>
#include <random>
#include <mutex>

#include "cell_test_support.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;
using namespace cellcal::components;

const char* kShortProgram = "  initial_poses: 50\n  poses_per_group: 15\n  groups: 2\n  hours_between_groups: 1\n";

TEST(CellProcesses, ConvergesEndToEndThroughFourProcesses) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  const std::string cfg = writeCell(dir, domainForTest(), seed, {{"tx60", "tx60_target"}}, kShortProgram);
  const auto s = runCell(dir, cfg, "9");
  ASSERT_FALSE(s.is_discarded());
  ASSERT_EQ(s["processes"].size(), 4u);
  // 50 + 15 poses measured; on a loaded machine a reading may be lost (best effort), but not many.
  EXPECT_GE(s["calibration_updates"].get<int>(), 52) << s["engine"].dump();
  EXPECT_LE(s["calibration_updates"].get<int>(), 65);
  expectEveryTopicFlowed(s);
  const double before = s["verify_before_mm"], after = s["verify_after_mm"], ref = s["in_process_verify_after_mm"];
  // The 9 s run measures the 50 initial poses and one group of 15; the cell clock then runs on for ~0.8 h of
  // simulated warm-up with no new pose, so the end-of-run error includes drift no engine could have seen (it
  // depends on the seed's drift rate). Convergence is judged at the time of the last update; the end-of-run
  // error against the uncalibrated robot and against the in-process engine at the same time.
  const double at_update = s["verify_after_last_update_mm"];
  // (The end-of-run error itself is not judged against the uncalibrated one: with a fast-drifting seed the unseen
  // warm-up alone can exceed a tenth of it, e.g. seed 13730649175658362321: 0.127 mm against 1.27 mm.)
  EXPECT_GT(before, 0.3);
  EXPECT_LT(at_update, 0.05);
  EXPECT_LT(at_update, before / 10);
  // Through the processes as good as core's engine fed the same readings in-process: the launcher replays exactly
  // the readings the engine applied (their sequence numbers from the engine's stats, their poses from the tracker's).
  const auto& r = s["robots"][0];
  EXPECT_EQ(r["in_process_inputs"], "applied_readings");
  EXPECT_EQ(r["in_process_poses"], s["calibration_updates"]);
  EXPECT_LT(after, 1.05 * ref) << "in-process " << ref;
  EXPECT_LT(r["landed_error_compensated_mean_mm"].get<double>(), r["landed_error_uncompensated_mean_mm"].get<double>() / 5);
  for (const char* k : {"tracker_to_state_p50", "tracker_to_state_p99", "target_to_compensated_p50", "target_to_compensated_p99"})
    EXPECT_GT(s["latency_us"][k].get<double>(), 0) << k;
}

// simulation.follow_pose_requests: the simulated program takes each pose from the engine's newest proposal
// (cellcal/pose_request); every pose it took is one the engine proposed (the test's own reader hears every
// proposal), the tracker measured it, and the in-process engine fed the same configurations reaches the same error.
TEST(CellProcesses, TheSimulatedProgramFollowsTheEnginesPoseRequests) {
  const std::string dir = testDir();
  const std::string cfg = writeCell(dir, domainForTest(), testSeed(), {{"tx60", "tx60_target"}},
                                    std::string(kShortProgram) + "  follow_pose_requests: true\n",
                                    "  pose_requests: { count: 5, candidates: 300, min_period_s: 0 }\n");
  const CellConfig cell = loadCellConfig(cfg);
  const int joints = cell.robots[0].model.numJoints();
  components::DdsNode node(cell, "cellcal_test_pose_requests", components::identity::kObserver);
  std::mutex mutex;
  std::vector<Eigen::VectorXd> proposed;
  std::uint64_t requests = 0;
  node.reader<msg::PoseRequest>([&](const msg::PoseRequest& m, const components::fdds::SampleInfo&) {
    std::lock_guard<std::mutex> l(mutex);
    ++requests;
    const auto qs = fromPoseRequest(m, joints, nullptr);
    if (qs) proposed.insert(proposed.end(), qs->begin(), qs->end());
  });
  const auto s = runCell(dir, cfg, "9");
  ASSERT_FALSE(s.is_discarded());
  node.shutdown();
  expectEveryTopicFlowed(s);
  EXPECT_GT(s["topics"]["cellcal/pose_request"]["published"].get<int>(), 0);
  EXPECT_GE(s["calibration_updates"].get<int>(), 52) << s["engine"].dump();
  const auto& r = s["robots"][0];
  // Each pose is decided when the robot starts moving to it: the first ones may come before the first proposal has
  // reached the program (a pose lasts 42 ms of wall time here; on a busy machine the first delivery can take longer).
  const auto followed = s["joint_adapters"]["joint_state_adapter"]["followed_poses"]["tx60"];
  EXPECT_GE(static_cast<double>(followed.size()), 0.8 * s["calibration_updates"].get<double>());
  EXPECT_EQ(r["poses_followed"].get<std::size_t>(), followed.size());
  std::lock_guard<std::mutex> l(mutex);
  EXPECT_GT(requests, 10u);
  // This test's own reader of cellcal/pose_request (keep last 1, as the topic is) may miss a proposal the program
  // received when a newer one replaced it first on a busy machine (6 of about 60 beside a parallel build, in the fresh-clone CI of 53a5e2e): most, not all,
  // of the followed poses must be among the proposals it saw.
  int seen = 0;
  std::string unseen;
  for (const auto& row : followed) {
    const auto v = row.get<std::vector<double>>();
    ASSERT_EQ(v.size(), static_cast<std::size_t>(joints) + 1);
    const Eigen::VectorXd q = Eigen::Map<const Eigen::VectorXd>(v.data() + 1, joints);
    bool found = false;
    for (const auto& p : proposed) found = found || (p - q).cwiseAbs().maxCoeff() < 1e-12;
    seen += found;
    if (!found) unseen += " " + std::to_string(static_cast<int>(v[0]));
  }
  EXPECT_GE(seen, 0.75 * static_cast<double>(followed.size())) << "poses not among the proposals seen:" << unseen;
  EXPECT_EQ(r["in_process_inputs"], "applied_readings");
  const double at_update = s["verify_after_last_update_mm"], after = s["verify_after_mm"], ref = s["in_process_verify_after_mm"];
  EXPECT_LT(at_update, 0.05);
  EXPECT_LT(after, 1.05 * ref) << "in-process " << ref;
}

TEST(CellProcesses, AModelExtensionTravelsFromTheEngineToCompensation) {
  // The simulated robot has a joint compliance (joint, size and sign drawn at random); the cell file names the
  // extension, as after `cellcal diagnose`. The engine estimates it, CalibrationState carries it, the compensation
  // publisher solves with it, and the judge evaluates the received model: all of it must hold for the hold-out error to
  // reach the floor (a geometric model leaves the compliance: 0.1-0.3 mm for these sizes).
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  const int joint = std::uniform_int_distribution<int>(2, 3)(rng);
  const double size_deg = (rng() % 2 ? 1 : -1) * std::uniform_real_distribution<double>(0.03, 0.05)(rng);
  RobotEntry robot{"tx60", "tx60_target"};
  robot.extensions = "[joint_compliance:" + std::to_string(joint) + "]";
  const std::string cfg = writeCell(dir, domainForTest(), seed, {robot},
                                    std::string(kShortProgram) + "  hidden_effect: { cause: joint_compliance, joint: " +
                                        std::to_string(joint) + ", size_deg: " + std::to_string(size_deg) + " }\n");
  const auto s = runCell(dir, cfg, "9");
  ASSERT_FALSE(s.is_discarded());
  const double after = s["verify_after_mm"], ref = s["in_process_verify_after_mm"];
  const double at_update = s["verify_after_last_update_mm"];
  const std::string what = "joint " + std::to_string(joint) + ", " + std::to_string(size_deg) + " deg";
  std::printf("  compliance %s: %d updates, hold-out at last update %.4f mm, end of run %.4f mm (in-process %.4f), "
              "landed %.4f mm\n",
              what.c_str(), s["calibration_updates"].get<int>(), at_update, after, ref,
              s["robots"][0]["landed_error_compensated_mean_mm"].get<double>());
  // The floor needs the program's poses: on a quiet host the 9 s run reaches the 50 initial ones and a group of 15.
  // A busy host reaches fewer (beside two CPU hogs, one run left 0.057 mm); then the cell is judged against the
  // in-process engine on the same poses alone, and the shortfall is reported.
  const int updates = s["calibration_updates"].get<int>();
  if (updates >= 60) {
    EXPECT_LT(at_update, 0.05) << what;
  } else {
    std::printf("  NOTE: the host let the program reach %d poses in 9 s; the floor is not judged\n", updates);
  }
  EXPECT_LT(after, 1.5 * ref + 0.005) << what << ", in-process " << ref;
  const auto& r = s["robots"][0];
  // Landed error: over the run, at the time of each target (so including drift since the last update).
  EXPECT_LT(r["landed_error_compensated_mean_mm"].get<double>(), 0.12) << what;
  std::ifstream log(dir + "/run/calibration_engine.log");
  const std::string text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("model extensions: joint_compliance:" + std::to_string(joint)), std::string::npos) << text;
}

// A calibrated robot file's judged ranges reach the compensation publisher: a first run of the cell is recorded,
// exported and calibrated with `extension` (`cellcal calibrate --save-robot`); `window` then rewrites the file's
// judged range of it (beyond_data or beyond_drivers) to one drawn at random and says what the publisher must print
// once when it applies the file's model and what a target beyond it is refused for; a second run starts its engine
// from that file. The publisher must say the window once, pass through as never_judged the targets past it,
// with the reason naming the joint or driver, and correct others.
struct JudgedWindow {
  std::string said, refused, what;  // the publisher's line; the reason's start for a target past it; for messages
};
void expectJudgedWindowGuarded(const std::string& extension, const std::string& program,
                               const std::function<JudgedWindow(std::string*, std::mt19937_64&)>& window) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  RobotEntry robot{"tx60", "tx60_target"};
  robot.extensions = "[" + extension + "]";
  const std::string cfg = writeCell(dir, domainForTest(), seed, {robot}, program);
  ASSERT_FALSE(runCell(dir, cfg, "9", {"--record", dir + "/first.mcap"}).is_discarded());
  Process exported(dir, "export", {"cellcal", "export", dir + "/first.mcap", "--config", cfg, "--out", dir + "/first.csv"});
  ASSERT_EQ(exported.wait(60), 0) << exported.log();
  Process calibrated(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml",
                                        "--data", dir + "/first.csv", "--model", extension, "--save-robot",
                                        dir + "/calibrated.yaml"});
  ASSERT_EQ(calibrated.wait(60), 0) << calibrated.log();
  std::ifstream in(dir + "/calibrated.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const JudgedWindow w = window(&text, rng);
  ASSERT_FALSE(w.said.empty()) << "no judged range of " << extension << " in\n" << text;
  std::ofstream(dir + "/calibrated.yaml") << text;
  robot.calibration_file = dir + "/calibrated.yaml";
  std::filesystem::create_directories(dir + "/second");
  const std::string second = writeCell(dir + "/second", domainForTest(), seed, {robot}, program);
  const auto s = runCell(dir + "/second", second, "9");
  ASSERT_FALSE(s.is_discarded());
  const auto& r = s["robots"][0];
  // Passed through beyond the judged range: the outcome never_judged, its reason naming the joint or link.
  int beyond = 0;
  std::string last;
  if (r["targets_refused_why"].contains("never_judged")) {
    beyond = r["targets_refused_why"]["never_judged"]["count"].get<int>();
    last = r["targets_refused_why"]["never_judged"]["last"].get<std::string>();
  }
  // Targets corrected beyond the data within the judged distance: the publisher's count, and the answers the cell's
  // judge received saying so (the answers it did not receive before the end may hold some).
  const long flagged_sent = s["compensation"].value("beyond_data_applied", -1L);
  const long flagged_seen = r["targets_applied_beyond_data"].get<long>();
  const long unseen = s["compensation"]["applied"].get<long>() - r["targets_applied"].get<long>();
  std::printf("  %s: %d targets passed through beyond it, %d corrected (%ld of them beyond the data within the judged "
              "distance, %ld said so), %d refused in all\n", w.what.c_str(), beyond, r["targets_applied"].get<int>(),
              flagged_sent, flagged_seen, r["targets_refused"].get<int>());
  EXPECT_GE(flagged_seen, 0);
  EXPECT_LE(flagged_seen, flagged_sent);
  EXPECT_LE(flagged_sent - flagged_seen, std::max(0L, unseen));
  EXPECT_GT(beyond, 0) << w.what << "\n" << r.dump(1);
  EXPECT_EQ(last.rfind(w.refused, 0), 0u) << last;
  EXPECT_GT(r["targets_applied"].get<int>(), 0) << r.dump(1);
  std::ifstream log(dir + "/second/run/compensation_publisher.log");
  const std::string said((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  EXPECT_NE(said.find(w.said), std::string::npos) << w.said << "\n" << said;
}

// The number after `key` in `text` from `at` on (NaN where it is not before `end`).
double numberAfter(const std::string& text, const std::string& key, size_t at, size_t end) {
  const size_t k = text.find(key, at);
  return k < end ? std::stod(text.substr(k + key.size())) : std::nan("");
}

// A joint's range (beyond_data) of joint_compliance of a joint drawn at random, the window a share of the file's
// range judged a drawn distance beyond it.
TEST(CellProcesses, TargetsBeyondTheRobotFilesJudgedRangesArePassedThrough) {
  std::mt19937_64 draw(testSeed() + 1);
  const int joint = std::uniform_int_distribution<int>(2, 3)(draw);
  const std::string program = std::string(kShortProgram) + "  hidden_effect: { cause: joint_compliance, joint: " +
                              std::to_string(joint) + ", size_deg: 0.04 }\n";
  expectJudgedWindowGuarded("joint_compliance:" + std::to_string(joint), program, [&](std::string* text, std::mt19937_64& rng) {
    JudgedWindow w;
    const std::string key = "- { joint: " + std::to_string(joint) + ", lower_deg: ";
    const size_t at = text->find(key);
    if (at == std::string::npos) return w;
    const size_t end = text->find('}', at);
    const double lower = numberAfter(*text, "lower_deg: ", at, end), upper = numberAfter(*text, "upper_deg: ", at, end);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const double share = 0.2 + 0.3 * u(rng), centre = lower + (upper - lower) * (0.3 + 0.4 * u(rng));
    const double lo = centre - share * (upper - lower) / 2, hi = centre + share * (upper - lower) / 2;
    const double checked = 10 * u(rng);
    char entry[300];
    std::snprintf(entry, sizeof entry, "- { joint: %d, lower_deg: %.6f, upper_deg: %.6f, sigma_at_1_rad_deg: 0, growth: 0, checked_deg: %.6f }",
                  joint, lo, hi, checked);
    text->replace(at, end + 1 - at, entry);
    char said[200];
    std::snprintf(said, sizeof said, "extensions of joint %d were fitted on [%.1f, %.1f] deg and judged %.1f deg beyond it",
                  joint, lo, hi, checked);
    w.said = said;
    w.refused = "joint " + std::to_string(joint) + " at ";
    w.what = "joint " + std::to_string(joint) + " window [" + std::to_string(lo) + ", " + std::to_string(hi) +
             "] deg judged " + std::to_string(checked) + " deg beyond";
    return w;
  });
}

// A driver's range (beyond_drivers) of link_deflection of link 2 (the TX60's upper arm; the simulated robot bends
// nowhere: the fit finds what it finds), the window a share of the gravity across the link the file saw, each end
// judged a drawn distance beyond it.
TEST(CellProcesses, TargetsBeyondTheRobotFilesJudgedLoadArePassedThrough) {
  expectJudgedWindowGuarded("link_deflection:2", kShortProgram, [&](std::string* text, std::mt19937_64& rng) {
    JudgedWindow w;
    const std::string key = "- { extension: link_deflection:2, ";
    const size_t at = text->find(key);
    if (at == std::string::npos) return w;
    const size_t end = text->find('}', at);
    const double lower = numberAfter(*text, "lower: ", at, end), upper = numberAfter(*text, "upper: ", at, end);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const double share = 0.2 + 0.3 * u(rng), centre = lower + (upper - lower) * (0.3 + 0.4 * u(rng));
    DriverRange r;
    r.extension = Extension{Cause::kLinkDeflection, 1};
    r.label = "gravity across link 2 (g)";
    r.lower = centre - share * (upper - lower) / 2;
    r.upper = centre + share * (upper - lower) / 2;
    r.checked_below = 0.05 * u(rng);
    r.checked_above = 0.05 * u(rng);
    char entry[400];
    std::snprintf(entry, sizeof entry, "- { extension: link_deflection:2, driver: \"%s\", lower: %.6f, upper: %.6f, "
                  "sigma_at_1_mm: 0, growth: 0, checked_below: %.6f, checked_above: %.6f }", r.label.c_str(), r.lower,
                  r.upper, r.checked_below, r.checked_above);
    text->replace(at, end + 1 - at, entry);
    // What the file reads back as (the figures to the digits written).
    r.lower = numberAfter(entry, "lower: ", 0, sizeof entry);
    r.upper = numberAfter(entry, "upper: ", 0, sizeof entry);
    r.checked_below = numberAfter(entry, "checked_below: ", 0, sizeof entry);
    r.checked_above = numberAfter(entry, "checked_above: ", 0, sizeof entry);
    w.said = "link_deflection link 2 was fitted on " + r.rangeText() + " and " + r.judgedText();
    w.refused = "gravity across link 2 at ";
    w.what = "link 2 window " + r.rangeText() + ", " + r.judgedText();
    return w;
  });
}

// `cellcal status` beside a running cell: once (JSON) it reports the robot's version, health, poses, verification
// estimate and the corrections sent, agreeing with what a probe of its own receives; --watch redraws.
TEST(CellProcesses, StatusShowsTheRunningCell) {
  const std::string dir = testDir();
  const std::string cfg = writeCell(dir, domainForTest(), testSeed(), {{"tx60", "tx60_target"}},
                                    "  initial_poses: 40\n  poses_per_group: 15\n  groups: 1\n");
  Process cell(dir, "cell", {"cellcal", "cell", "--config", cfg, "--duration-s", "10", "--work-dir", dir + "/run", "--quiet"});
  Probe probe(loadCellConfig(cfg));
  ASSERT_TRUE(waitUntil([&] { return probe.latestVersion("tx60") >= 10; }, 30)) << cell.log();
  Process status(dir, "status", {"cellcal", "status", "--config", cfg, "--wait-s", "2", "--json", dir + "/status.json"});
  ASSERT_EQ(status.wait(30), 0) << status.log();
  Process watch(dir, "watch", {"cellcal", "status", "--config", cfg, "--watch", "--period-s", "0.5", "--duration-s", "2"});
  ASSERT_EQ(watch.wait(30), 0) << watch.log();
  const std::uint64_t seen_by_probe = probe.latestVersion("tx60");
  ASSERT_EQ(cell.wait(60), 0) << cell.log();
  const auto j = readJson(dir + "/status.json");
  ASSERT_FALSE(j.is_discarded()) << status.log();
  EXPECT_TRUE(j["engine_seen"].get<bool>());
  const auto& r = j["robots"]["tx60"];
  EXPECT_GE(r["version"].get<std::uint64_t>(), 10u) << j.dump(1);
  EXPECT_LE(r["version"].get<std::uint64_t>(), seen_by_probe);
  EXPECT_EQ(r["poses_used"].get<std::uint64_t>(), r["version"].get<std::uint64_t>());
  EXPECT_EQ(r["health"], "ok") << j.dump(1);
  EXPECT_EQ(r["health_cause"], "none") << j.dump(1);
  EXPECT_EQ(r["health_reason"], "") << j.dump(1);
  EXPECT_GT(r["verification_mean_position_mm"].get<double>(), 0.0);
  // The held-out errors of the engine's recent poses, as one figure: mean, 99.7th percentile, max.
  const auto& held = r["held_out_mm"];
  ASSERT_TRUE(held.is_object()) << j.dump(1);
  EXPECT_GE(held["poses"].get<int>(), 1);
  EXPECT_LE(held["poses"].get<int>(), 30);
  EXPECT_LE(held["mean_mm"].get<double>(), held["p997_mm"].get<double>());
  EXPECT_LE(held["p997_mm"].get<double>(), held["max_mm"].get<double>());
  EXPECT_LT(r["predicted_sigma_position_mm"].get<double>(), 1.0);
  // 40 random poses spread over the workspace: the engine's figure there is under the bound too, and no note says
  // that targets away from where it measured are passed through.
  EXPECT_GT(r["predicted_sigma_workspace_mm"].get<double>(), 0.0) << j.dump(1);
  EXPECT_LT(r["predicted_sigma_workspace_mm"].get<double>(), 1.0) << j.dump(1);
  EXPECT_GT(r["compensated_targets"].get<int>(), 0);
  // No robot file's extensions here: no target is corrected beyond their data (the judged-window tests count those).
  EXPECT_EQ(r["applied_beyond_data"].get<int>(), 0) << j.dump(1);
  EXPECT_GT(r["max_correction_mm"].get<double>(), 0.1);  // the simulated robot's errors are ~1 mm
  const std::string printed = status.log();
  EXPECT_NE(printed.find("tx60"), std::string::npos) << printed;
  EXPECT_EQ(printed.find("over the whole workspace"), std::string::npos) << printed;
  EXPECT_NE(printed.find("tx60: held-out position errors of the last "), std::string::npos) << printed;
  EXPECT_NE(printed.find("v" + std::to_string(r["version"].get<std::uint64_t>())), std::string::npos) << printed;
  // --watch: redrawn every 0.5 s for 2 s.
  const std::string live = watch.log();
  size_t frames = 0;
  for (size_t at = live.find("cellcal status"); at != std::string::npos; at = live.find("cellcal status", at + 1)) ++frames;
  EXPECT_GE(frames, 3u) << live;
  // Its first frame already shows the engine's calibration (not an empty row while discovery is under way).
  const size_t first_row = live.find("\ntx60 ");
  ASSERT_NE(first_row, std::string::npos) << live;
  EXPECT_EQ(live.compare(first_row + 13, 1, "v"), 0) << live.substr(first_row, 80);
  std::printf("%s", printed.c_str());
}

// A tool that joins with another participant profile than the cell's sees nothing there: `status` and `record` say
// so, look on the profile file's other profiles and name the one the cell is on. The tools' profile here is shared
// memory only, which cannot reach a cell on UDP loopback on any machine.
TEST(CellProcesses, ToolsOnAnotherProfileNameTheProfileTheCellIsOn) {
  const std::string dir = testDir();
  std::string xml = readTextFile(std::string(CELLCAL_CONFIG_DIR) + "/dds/cellcal_qos.xml");
  const auto put = [&](const std::string& before, const std::string& text) {
    const auto at = xml.find(before);
    ASSERT_NE(at, std::string::npos) << before;
    xml.insert(at, text);
  };
  put("</transport_descriptors>",
      "<transport_descriptor><transport_id>test_shm_only</transport_id><type>SHM</type></transport_descriptor>\n");
  put("<participant profile_name=\"cellcal\">",
      "<participant profile_name=\"test_elsewhere\"><rtps><userTransports><transport_id>test_shm_only</transport_id>"
      "</userTransports><useBuiltinTransports>false</useBuiltinTransports></rtps></participant>\n");
  std::ofstream(dir + "/profiles.xml") << xml;
  std::string cell_text = readTextFile(writeCell(dir, domainForTest(), testSeed(), {{"tx60", "tx60_target"}},
                                                 "  initial_poses: 40\n  groups: 1\n"));
  const std::string shipped = std::string(CELLCAL_CONFIG_DIR) + "/dds/cellcal_qos.xml";
  cell_text.replace(cell_text.find(shipped), shipped.size(), dir + "/profiles.xml");
  const std::string cfg = dir + "/cell_profiles.yaml";
  std::ofstream(cfg) << cell_text;

  Process cell(dir, "cell", {"cellcal", "cell", "--config", cfg, "--duration-s", "12", "--work-dir", dir + "/run", "--quiet"});
  Probe probe(loadCellConfig(cfg));
  ASSERT_TRUE(waitUntil([&] { return probe.latestVersion("tx60") >= 3; }, 30)) << cell.log();
  Process status(dir, "status", {"cellcal", "status", "--config", cfg, "--dds-profile", "test_elsewhere", "--wait-s", "2",
                                 "--json", dir + "/status.json"});
  Process record(dir, "record", {"cellcal", "record", "--config", cfg, "--dds-profile", "test_elsewhere",
                                 "--duration-s", "2", "--out", dir + "/nothing.mcap"});
  ASSERT_EQ(status.wait(40), 3) << status.log();  // no engine seen on its profile
  EXPECT_EQ(record.wait(40), 3) << record.log();  // nothing recorded
  ASSERT_EQ(cell.wait(60), 0) << cell.log();
  const auto j = readJson(dir + "/status.json");
  ASSERT_FALSE(j.is_discarded()) << status.log();
  EXPECT_FALSE(j["engine_seen"].get<bool>()) << j.dump(1);
  EXPECT_EQ(j["participant_profile"], "test_elsewhere");
  bool loopback_seen = false;
  for (const auto& o : j["other_profiles"])
    if (o["profile"] == "cellcal_loopback") loopback_seen = o["engine_seen"].get<bool>();
  EXPECT_TRUE(loopback_seen) << j.dump(1);
  for (const std::string& log : {status.log(), record.log()}) {
    EXPECT_NE(log.find("cellcal_loopback: engine seen, compensation seen"), std::string::npos) << log;
    EXPECT_NE(log.find("add --dds-profile "), std::string::npos) << log;
  }
  std::printf("%s", status.log().c_str());
}

// A cell in two shards (`cellcal cell --shards 2`): each engine, compensation publisher and adapter serves half the
// robots (--robots), and its readers take only their samples (content filters). The same cell file and seed in one
// shard and in two give each robot the same calibration, and an engine receives its own half's joint states and
// tracker readings, not the others'.
TEST(CellProcesses, TwoShardsServeHalfTheRobotsEach) {
  const std::string dir = testDir();
  std::vector<RobotEntry> robots;
  for (int i = 1; i <= 4; ++i) robots.push_back({"r" + std::to_string(i), "t" + std::to_string(i)});
  const std::string cfg = writeCell(dir, domainForTest(), testSeed(), robots,
                                    "  initial_poses: 30\n  groups: 1\n  joint_rate_hz: 500\n");
  Process whole(dir, "whole", {"cellcal", "cell", "--config", cfg, "--duration-s", "12", "--work-dir", dir + "/whole",
                               "--summary-json", dir + "/whole.json", "--quiet"});
  ASSERT_EQ(whole.wait(90), 0) << whole.log();
  Process cell(dir, "cell", {"cellcal", "cell", "--config", cfg, "--shards", "2", "--duration-s", "12", "--work-dir",
                             dir + "/run", "--summary-json", dir + "/summary.json", "--quiet"});
  ASSERT_EQ(cell.wait(90), 0) << cell.log();
  const auto one = readJson(dir + "/whole.json");
  const auto s = readJson(dir + "/summary.json");
  ASSERT_FALSE(s.is_discarded() || one.is_discarded()) << cell.log();
  ASSERT_EQ(s["robots"].size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) {
    const auto& r = s["robots"][i];
    const auto& w = one["robots"][i];
    ASSERT_EQ(r["robot_id"], w["robot_id"]);
    EXPECT_GE(r["final_version"].get<int>(), 20) << r.dump();
    EXPECT_NEAR(r["final_version"].get<int>(), w["final_version"].get<int>(), 2) << r["robot_id"];
    // Each engine of each run computes what core's engine computes in-process from the readings it applied.
    for (const auto* run : {&r, &w}) {
      EXPECT_EQ((*run)["in_process_inputs"], "applied_readings") << run->dump();
      EXPECT_LT((*run)["verify_after_mm"].get<double>(), 1.05 * (*run)["in_process_verify_after_mm"].get<double>() + 0.001)
          << r["robot_id"] << ": the engine process differs from core's engine on the same readings";
    }
    // The two runs measure the same program, but the readings are not the same: the simulated cell clock runs with
    // the wall clock, so a loaded machine measures each pose a little later in the robot's warm-up. Measured on a
    // busy CI machine: 0.0262 mm for one engine against 0.0215 mm for two shards (0.0223/0.0224 mm on a quiet one).
    // Splitting the robots between engines must cost no accuracy beyond that.
    const double e_shard = r["verify_after_last_update_mm"], e_whole = w["verify_after_last_update_mm"];
    EXPECT_LT(e_shard, 1.3 * e_whole + 0.003) << r["robot_id"] << ": a shard calibrates worse than one engine";
    EXPECT_LT(e_shard, 0.5 * r["verify_before_mm"].get<double>()) << r.dump();
    EXPECT_GT(r["targets_applied"].get<int>(), 0) << r.dump();
  }
  for (int k = 1; k <= 2; ++k) {
    const std::string n = std::to_string(k);
    expectOnlyItsShard(dir + "/run", k);
    const std::string log = readTextFile(dir + "/run/calibration_engine_" + n + ".log");
    EXPECT_NE(log.find(k == 1 ? "robots r1,r2 only" : "robots r3,r4 only"), std::string::npos) << log;
  }
  for (int i = 1; i <= 4; ++i)
    EXPECT_TRUE(fs::exists(dir + "/run/state/r" + std::to_string(i) + ".state.json")) << i;
  std::printf("one engine: %d updates, hold-out after the last update %.4f mm; two shards: %d updates, %.4f mm; "
              "engine 1 received %s joint states\n",
              one["calibration_updates"].get<int>(), one["verify_after_last_update_mm"].get<double>(),
              s["calibration_updates"].get<int>(), s["verify_after_last_update_mm"].get<double>(),
              readJson(dir + "/run/calibration_engine_1.stats.json")["topics"]["cellcal/joint_state"]["received"].dump().c_str());
}

// --robots names robots of the cell file, each once; --shards at most the robots there are.
TEST(CellProcesses, ShardOptionsAreChecked) {
  const std::string dir = testDir();
  const std::string cfg = writeCell(dir, domainForTest(), testSeed(), {{"tx60", "tx60_target"}});
  Process unknown(dir, "unknown", {"cellcal_calibration_engine", "--config", cfg, "--robots", "tx60,nope"});
  EXPECT_EQ(unknown.wait(30), 2);
  EXPECT_NE(unknown.log().find("--robots: 'nope' is not a robot of"), std::string::npos) << unknown.log();
  EXPECT_NE(unknown.log().find("its robots: tx60"), std::string::npos) << unknown.log();
  Process twice(dir, "twice", {"cellcal_compensation_publisher", "--config", cfg, "--robots", "tx60,tx60"});
  EXPECT_EQ(twice.wait(30), 2);
  EXPECT_NE(twice.log().find("'tx60' is named twice"), std::string::npos) << twice.log();
  Process shards(dir, "shards", {"cellcal", "cell", "--config", cfg, "--shards", "2", "--work-dir", dir + "/run"});
  EXPECT_EQ(shards.wait(30), 2);
  EXPECT_NE(shards.log().find("--shards 2: the cell has 1 robot(s)"), std::string::npos) << shards.log();
}

// One TX60 whose 30-pose campaign the engine runs (it ends after ~1.3 s; then the robot works and the calibration
// stays put), and a probe of the cell: where a test of the compensation publisher starts.
struct CampaignCell {
  CampaignCell(const std::string& dir, std::uint64_t seed)
      : cfg(writeCell(dir, domainForTest(), seed, {{"tx60", "tx60_target"}}, "  initial_poses: 30\n  groups: 1\n")),
        cell(loadCellConfig(cfg)),
        engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet"}),
        tracker(dir, "tracker", {"cellcal_tracker_adapter", "--config", cfg}),
        joints(dir, "joints", {"cellcal_joint_state_adapter", "--config", cfg, "--wait-for-readers", "1"}),
        probe(cell) {}
  // The campaign's versions have come (at most 20 s).
  ::testing::AssertionResult calibrated() {
    if (waitUntil([&] { return probe.latestVersion("tx60") >= 25; }, 20)) return ::testing::AssertionSuccess();
    return ::testing::AssertionFailure() << engine.log() << joints.log();
  }
  const std::string cfg;
  const CellConfig cell;
  Process engine, tracker, joints;
  Probe probe;
};

TEST(CellProcesses, LateCompensationPublisherGetsTheLatestCalibrationAtOnce) {
  const std::string dir = testDir();
  CampaignCell c(dir, testSeed());
  const std::string& cfg = c.cfg;
  const CellConfig& cell = c.cell;
  Probe& probe = c.probe;
  ASSERT_TRUE(c.calibrated());
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  const std::uint64_t latest = probe.latestVersion("tx60");
  Process comp(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg});
  auto targets = probe.node.writer<msg::TargetPose>();
  // Ask at once and keep asking: the first answer must already use the latest calibration.
  msg::TargetPose t = reachableTarget(cell);
  std::uint64_t seq = 0;
  ASSERT_TRUE(waitUntil([&] {
    t.sequence_number(++seq);
    targets.write(t);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    std::lock_guard<std::mutex> l(probe.mutex);
    return !probe.compensated.empty();
  }, 10)) << comp.log();
  std::lock_guard<std::mutex> l(probe.mutex);
  const auto& first = probe.compensated.front();
  EXPECT_TRUE(first.applied()) << first.reason();
  EXPECT_EQ(first.calibration_version(), latest);
  EXPECT_GT(first.correction_position_m(), 1e-5);  // the hidden errors are corrected
}

// --pass-through beside a compensation publisher that corrects, on the same calibration and the same random targets
// and setpoints: the one corrects (the calibration was there to apply), the other answers every request unchanged --
// not applied, the corrected pose the desired one to the bit, the setpoint's own joints -- and says why.
TEST(CellProcesses, APassThroughPublisherAnswersUnchangedBesideOneThatCorrects) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  CampaignCell c(dir, seed);
  const std::string& cfg = c.cfg;
  const CellConfig& cell = c.cell;
  Probe& probe = c.probe;
  ASSERT_TRUE(c.calibrated());
  std::mutex mutex;
  std::vector<msg::ServoCorrection> servo;
  components::DdsNode servo_node(cell, "cellcal_test_servo_reader", components::identity::kObserver);
  servo_node.reader<msg::ServoCorrection>([&](const msg::ServoCorrection& c, const components::fdds::SampleInfo&) {
    std::lock_guard<std::mutex> l(mutex);
    servo.push_back(c);
  });
  Process comp(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg});
  Process pass(dir, "pass", {"cellcal_compensation_publisher", "--config", cfg, "--pass-through"});
  auto targets = probe.node.writer<msg::TargetPose>();
  auto setpoints = probe.node.writer<msg::ServoSetpoint>();
  const RobotModel& m = cell.robots[0].model;
  KinematicsData d(m);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 0.6);
  auto passed = [](const auto& outcome) { return outcome == msg::OUTCOME_PASS_THROUGH; };
  auto counts = [&] {
    std::lock_guard<std::mutex> l(probe.mutex), l2(mutex);
    int p = 0, c = 0, sp = 0;
    for (const auto& t : probe.compensated) (passed(t.outcome()) ? p : c) += 1;
    for (const auto& a : servo) sp += passed(a.outcome());
    return std::array<int, 3>{p, c, sp};
  };
  std::map<std::uint64_t, Eigen::VectorXd> sent_q;
  std::uint64_t seq = 0;
  ASSERT_TRUE(waitUntil([&] {
    const Eigen::VectorXd q = Eigen::VectorXd::NullaryExpr(m.numJoints(), [&] { return u(rng); });
    msg::TargetPose t;
    t.robot_id("tx60");
    t.sequence_number(++seq);
    components::fromPose(forwardKinematics(m, d, m.nominal, q), t.position_m(), t.orientation_xyzw());
    t.seed_position_rad(std::vector<double>(q.data(), q.data() + q.size()));
    targets.write(t);
    msg::ServoSetpoint sp;
    sp.robot_id("tx60");
    sp.sequence_number(seq);
    sp.cycle_stamp_ns(1'000'000'000ULL + seq * 20'000'000ULL);
    sp.joint_position_rad(std::vector<double>(q.data(), q.data() + q.size()));
    setpoints.write(sp);
    sent_q[seq] = q;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const auto n = counts();
    return n[0] >= 30 && n[1] >= 30 && n[2] >= 30;
  }, 20)) << comp.log() << pass.log();
  const auto n = counts();
  std::lock_guard<std::mutex> l(probe.mutex), l2(mutex);
  int corrected = 0;
  for (const auto& t : probe.compensated) {
    if (!passed(t.outcome())) {
      corrected += t.applied() && t.correction_position_m() > 1e-5;
      continue;
    }
    EXPECT_FALSE(t.applied());
    EXPECT_EQ(t.corrected_position_m(), t.desired_position_m());
    EXPECT_EQ(t.corrected_orientation_xyzw(), t.desired_orientation_xyzw());
    EXPECT_TRUE(t.joint_position_rad().empty());
    EXPECT_EQ(t.calibration_version(), 0u);
  }
  int servo_applied = 0;
  for (const auto& a : servo) {
    if (!passed(a.outcome())) {
      servo_applied += a.applied();
      continue;
    }
    EXPECT_FALSE(a.applied());
    const Eigen::VectorXd& q = sent_q.at(a.setpoint_sequence());
    EXPECT_EQ(a.joint_position_rad(), std::vector<double>(q.data(), q.data() + q.size()));
    EXPECT_EQ(a.calibration_version(), 0u);
  }
  std::printf("  %llu targets and setpoints: pass-through answered %d targets and %d setpoints unchanged; the other "
              "publisher corrected %d of %d targets and applied %d setpoints\n",
              static_cast<unsigned long long>(seq), n[0], n[2], corrected, n[1], servo_applied);
  EXPECT_GE(2 * corrected, n[1]) << "the calibration was there to apply: most targets corrected by the other";
  EXPECT_GT(servo_applied, 0);
}

// A servo loop streams joint setpoints at 500 Hz (the robot holding one configuration, so each answer's change from
// the last is the blending alone) while the engine's campaign makes new versions: every answer comes in order
// (setpoint_sequence rising), most setpoints are answered (best effort), the versions named rise, and between two
// answers the commanded joints move by no more than the blend allows: the range they cover over the run times the
// cycles between the two over blend_s (0.5 s here) -- where a switch at once would step by the whole change. A second
// reader of the corrections that sleeps 20 ms in each callback does not hold the stream up.
TEST(CellProcesses, AServoStreamIsAnsweredInOrderAndBlendsBetweenVersions) {
  const std::string dir = testDir();
  const int domain = domainForTest();
  const std::string cfg = writeCell(dir, domain, testSeed(), {{"tx60", "tx60_target"}},
                                    "  initial_poses: 30\n  groups: 1\n", "compensation:\n  blend_s: 0.5\n");
  const CellConfig cell = loadCellConfig(cfg);
  ASSERT_EQ(cell.compensation.blend_s, 0.5);
  Probe probe(cell);
  struct Answer {
    std::uint64_t sequence, cycle_ns, version, from;
    double weight;
    bool applied;
    Eigen::VectorXd q;
  };
  std::mutex mutex;
  std::vector<Answer> answers;
  probe.node.reader<msg::ServoCorrection>([&](const msg::ServoCorrection& c, const components::fdds::SampleInfo&) {
    std::lock_guard<std::mutex> l(mutex);
    answers.push_back({c.setpoint_sequence(), c.cycle_stamp_ns(), c.calibration_version(), c.blend_from_version(),
                       c.blend_weight(), c.applied(),
                       Eigen::Map<const Eigen::VectorXd>(c.joint_position_rad().data(),
                                                         static_cast<Eigen::Index>(c.joint_position_rad().size()))});
  });
  components::DdsNode slow_node(cell, "cellcal_test_slow_reader", components::identity::kObserver);
  std::atomic<int> slow{0};
  slow_node.reader<msg::ServoCorrection>([&](const msg::ServoCorrection&, const components::fdds::SampleInfo&) {
    ++slow;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  });
  Process comp(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg, "--wait-for-calibration-s", "0"});
  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  Process tracker(dir, "tracker", {"cellcal_tracker_adapter", "--config", cfg});
  Process joints(dir, "joints", {"cellcal_joint_state_adapter", "--config", cfg, "--wait-for-readers", "1"});
  auto setpoints = probe.node.writer<msg::ServoSetpoint>();
  const RobotModel& m = cell.robots[0].model;
  const Eigen::VectorXd q = Eigen::VectorXd::Constant(m.numJoints(), 0.3);
  msg::ServoSetpoint sp;
  sp.robot_id("tx60");
  sp.cartesian(false);
  sp.joint_position_rad(std::vector<double>(q.data(), q.data() + q.size()));
  // Stream until the campaign's last version has been blended in (the campaign ends after ~1.3 s; then nothing new
  // for 2 s), at most 30 s.
  const std::int64_t dt_ns = 2'000'000;
  std::uint64_t seq = 0, last_version = 0;
  auto next = std::chrono::steady_clock::now();
  auto last_new = next;
  const auto give_up = next + std::chrono::seconds(30);
  while (std::chrono::steady_clock::now() < give_up) {
    sp.sequence_number(++seq);
    sp.cycle_stamp_ns(1'000'000'000ULL + seq * dt_ns);
    sp.source_stamp_ns(static_cast<std::uint64_t>(wallNs()));
    setpoints.write(sp);
    const std::uint64_t v = probe.latestVersion("tx60");
    if (v != last_version) last_version = v, last_new = std::chrono::steady_clock::now();
    if (last_version >= 20 && std::chrono::steady_clock::now() - last_new > std::chrono::seconds(2)) break;
    std::this_thread::sleep_until(next += std::chrono::nanoseconds(dt_ns));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  std::lock_guard<std::mutex> l(mutex);
  ASSERT_GE(last_version, 20u) << engine.log();
  ASSERT_FALSE(answers.empty()) << comp.log();
  std::vector<Answer> applied;
  for (size_t k = 0; k < answers.size(); ++k) {
    if (k > 0) {
      EXPECT_GT(answers[k].sequence, answers[k - 1].sequence) << "out of order at " << k;
      EXPECT_GE(answers[k].version, answers[k - 1].version);
    }
    EXPECT_GE(answers[k].weight, 0.0);
    EXPECT_LE(answers[k].weight, 1.0);
    if (answers[k].applied) applied.push_back(answers[k]);
  }
  ASSERT_GT(applied.size(), 100u) << comp.log();
  double range = 0, worst = 0;
  for (const auto& a : applied) range = std::max(range, (a.q - applied.front().q).cwiseAbs().maxCoeff());
  for (size_t k = 1; k < applied.size(); ++k) {
    const double cycles = static_cast<double>(applied[k].cycle_ns - applied[k - 1].cycle_ns) / dt_ns;
    worst = std::max(worst, (applied[k].q - applied[k - 1].q).cwiseAbs().maxCoeff() / cycles);
  }
  const double allowed = 2 * range * dt_ns * 1e-9 / cell.compensation.blend_s;  // two blends' worth, per cycle
  std::printf("  %llu setpoints, %zu answered (%zu applied), versions up to %llu; joints moved over %.3g rad, at most "
              "%.3g rad a cycle (the blend allows %.3g); the slow reader took %d\n",
              static_cast<unsigned long long>(seq), answers.size(), applied.size(),
              static_cast<unsigned long long>(answers.back().version), range, worst, allowed, slow.load());
  EXPECT_GE(answers.size(), seq / 2) << "best effort on loopback: most setpoints answered";
  EXPECT_GT(range, 1e-5) << "the versions changed the correction";
  EXPECT_LE(worst, allowed);
  EXPECT_EQ(answers.back().version, answers.back().from) << "the last blend finished";
  // The slow reader takes at most one answer per 20 ms: a third of the stream at the most, while the fast one got
  // at least half of it (above): the writer did not wait for the slow one.
  EXPECT_LT(3 * static_cast<std::uint64_t>(slow.load()), seq) << "the slow reader was not slow";
}

// The tracker adapter is SIGKILLed at a random moment: the engine's diagnostics name the stale stream within
// stale_input_s (3 s) + one republish period, and the compensation publisher keeps applying the last good
// calibration, saying in each answer that the engine's input is stale.
TEST(CellProcesses, ADeadTrackerAdapterIsReportedAndCompensationKeepsTheLastGoodCalibration) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  const std::string cfg = writeCell(dir, domainForTest(), seed, {{"tx60", "tx60_target"}},
                                    "  initial_poses: 200\n  groups: 1\n");
  const CellConfig cell = loadCellConfig(cfg);
  Probe probe(cell);
  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  Process comp(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg});
  Process tracker(dir, "tracker", {"cellcal_tracker_adapter", "--config", cfg});
  Process joints(dir, "joints", {"cellcal_joint_state_adapter", "--config", cfg, "--wait-for-readers", "1"});
  std::mt19937_64 rng(seed);
  const int kill_after = std::uniform_int_distribution<int>(20, 60)(rng);
  ASSERT_TRUE(waitUntil([&] { return probe.latestVersion("tx60") >= static_cast<std::uint64_t>(kill_after); }, 30))
      << engine.log();
  ASSERT_EQ(tracker.stop(SIGKILL), 128 + SIGKILL);
  const auto killed = std::chrono::steady_clock::now();
  const auto killed_ns = static_cast<std::uint64_t>(wallNs());
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // readings already on the wire are in
  const std::uint64_t last = probe.latestVersion("tx60");
  std::string stale;
  ASSERT_TRUE(waitUntil([&] {
    std::lock_guard<std::mutex> l(probe.mutex);
    for (const auto& d : probe.diagnostics)
      if (d.source_stamp_ns() > killed_ns && d.stale_input() && d.stale_inputs().to_string().find("tracker_pose") != std::string::npos) stale = d.stale_inputs().to_string();
    return !stale.empty();
  }, 10)) << engine.log();
  const double noticed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - killed).count();
  std::printf("  tracker adapter killed at v%llu; engine reported '%s' after %.2f s\n",
              static_cast<unsigned long long>(last), stale.c_str(), noticed_s);
  EXPECT_LT(noticed_s, cell.engine.stale_input_s + 2 * cell.engine.republish_period_s + 0.5);
  EXPECT_EQ(stale.find("joint_state"), std::string::npos) << stale;  // the controller still streams
  EXPECT_EQ(probe.latestVersion("tx60"), last);                     // nothing to learn from
  // Compensation: applied with the last calibration, and says the input is stale.
  auto targets = probe.node.writer<msg::TargetPose>();
  msg::TargetPose t = reachableTarget(cell);
  std::uint64_t seq = 1000;
  ASSERT_TRUE(waitUntil([&] {
    t.sequence_number(++seq);
    targets.write(t);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    std::lock_guard<std::mutex> l(probe.mutex);
    for (const auto& c : probe.compensated)
      if (c.target_sequence() > 1000 && c.note().find("engine input stale") != std::string::npos) return true;
    return false;
  }, 10)) << comp.log();
  std::lock_guard<std::mutex> l(probe.mutex);
  for (const auto& c : probe.compensated) {
    if (c.target_sequence() <= 1000 || c.note().find("engine input stale") == std::string::npos) continue;
    EXPECT_TRUE(c.applied()) << c.reason();
    EXPECT_EQ(c.calibration_version(), last);
    EXPECT_NE(c.note().find("tracker_pose"), std::string::npos) << c.note();
  }
}

TEST(CellProcesses, EngineKilledMidRunResumesFromItsStateWithNoUpdateLost) {
  const std::string dir = testDir();
  const std::string cfg = writeCell(dir, domainForTest(), testSeed(), {{"tx60", "tx60_target"}},
                                    "  initial_poses: 80\n  groups: 1\n");
  const CellConfig cell = loadCellConfig(cfg);
  Probe probe(cell);
  auto engine = std::make_unique<Process>(dir, "engine", std::vector<std::string>{"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  Process tracker(dir, "tracker", {"cellcal_tracker_adapter", "--config", cfg});
  Process joints(dir, "joints", {"cellcal_joint_state_adapter", "--config", cfg, "--wait-for-readers", "1"});
  ASSERT_TRUE(waitUntil([&] { return probe.latestVersion("tx60") >= 20; }, 20)) << engine->log();
  ASSERT_EQ(engine->stop(SIGKILL), 128 + SIGKILL);
  const std::uint64_t published_before_kill = probe.latestVersion("tx60");
  const auto state = readEngineState(dir + "/state", "tx60");
  ASSERT_FALSE(state.is_null());
  // Persisted before published: the state holds at least every version anyone saw. The journal holds it: the
  // snapshot is rewritten only at start, every 8 MiB of journal and on a clean stop.
  EXPECT_GE(state["version"].get<std::uint64_t>(), published_before_kill);
  const auto snapshot_only = loadEngineState(stateFilePath(dir + "/state", "tx60"));
  EXPECT_LT(snapshot_only ? snapshot_only->version : 0, published_before_kill);
  const std::uint64_t persisted = state["version"];
  engine = std::make_unique<Process>(dir, "engine2", std::vector<std::string>{"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  ASSERT_TRUE(waitUntil([&] { return engine->log().find("resumed version " + std::to_string(persisted)) != std::string::npos; }, 10))
      << engine->log();
  // The campaign goes on; the restarted engine continues the count.
  ASSERT_TRUE(waitUntil([&] { return probe.latestVersion("tx60") > persisted + 5; }, 20)) << engine->log();
  joints.stop();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  engine->stop();
  const auto final_state = readEngineState(dir + "/state", "tx60");
  // No pose applied twice: one version per pose used, across the restart.
  EXPECT_EQ(final_state["version"], final_state["poses_used"]);
  EXPECT_GT(final_state["version"].get<std::uint64_t>(), persisted);
}

TEST(CellProcesses, StaleOutOfOrderAndMovingJointStatesAreNotPaired) {
  const std::string dir = testDir();
  const std::string cfg = writeCell(dir, domainForTest(), 1, {{"tx60", "tx60_target"}});
  const CellConfig cell = loadCellConfig(cfg);
  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  Probe probe(cell);
  auto joints = probe.node.writer<msg::JointState>();
  auto readings = probe.node.writer<msg::TrackerPose>();
  ASSERT_TRUE(waitUntil([&] {
    fdds::PublicationMatchedStatus a, b;
    joints.entity()->get_publication_matched_status(a);
    readings.entity()->get_publication_matched_status(b);
    return a.current_count > 0 && b.current_count > 0;
  }, 10));
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const RobotModel& m = cell.robots[0].model;
  const Eigen::VectorXd q = Eigen::VectorXd::Constant(6, 0.2);
  KinematicsData d(m);
  Observation o;
  o.q_rad = q;
  o.measured_in_tracker = forwardKinematics(m, d, m.nominal, q);
  std::uint64_t seq = 0;
  auto send_joint = [&](std::int64_t stamp, bool settled) {
    auto js = toJointState("tx60", stamp, ++seq, q, settled);
    joints.write(js);
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  };
  auto send_reading = [&](std::int64_t stamp) {
    auto tp = toTrackerPose("tx60_target", stamp, ++seq, o);
    readings.write(tp);
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  };
  const std::int64_t ms = 1'000'000;
  std::int64_t t = wallNs();
  // 1) the robot is moving around the reading
  send_joint(t, false);
  send_reading(t + 1 * ms);
  send_joint(t + 2 * ms, false);
  // 2) an out-of-order joint state (older than the last one) is dropped; the reading has no state within 50 ms
  send_joint(t - 500 * ms, true);
  send_reading(t + 100 * ms);
  send_joint(t + 200 * ms, true);
  // 3) a good one: settled on both sides
  t = t + 300 * ms;
  send_joint(t, true);
  send_reading(t + 1 * ms);
  send_joint(t + 2 * ms, true);
  ASSERT_TRUE(waitUntil([&] { return probe.latestVersion("tx60") == 1; }, 10)) << engine.log();
  std::map<std::string, std::uint64_t> rejected;
  ASSERT_TRUE(waitUntil([&] {
    std::lock_guard<std::mutex> l(probe.mutex);
    if (probe.diagnostics.empty()) return false;
    const auto& dg = probe.diagnostics.back();
    rejected.clear();
    for (size_t k = 0; k < dg.rejection_reasons().size(); ++k) rejected[dg.rejection_reasons()[k].to_string()] = dg.rejection_counts()[k];
    return dg.poses_paired() == 1 && rejected.size() >= 3;
  }, 10)) << engine.log();
  EXPECT_EQ(rejected["robot_moving"], 1u);
  EXPECT_EQ(rejected["out_of_order"], 1u);
  EXPECT_EQ(rejected["no_joint_state"], 1u);
  EXPECT_EQ(probe.latestVersion("tx60"), 1u);
}

TEST(CellProcesses, TwoRobotsOnOneDomainAreCalibratedIndependentlyByKey) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  const std::string cfg =
      writeCell(dir, domainForTest(), seed,
                {{"left", "left_target"},
                 {"right", "right_target", "ur10.yaml",
                  "{ x_mm: -1800, y_mm: 600, z_mm: -200, roll_deg: 0, pitch_deg: 0, yaw_deg: 20 }"}},
                "  initial_poses: 60\n  groups: 1\n");
  const auto s = runCell(dir, cfg, "5");
  ASSERT_FALSE(s.is_discarded());
  ASSERT_EQ(s["robots"].size(), 2u);
  for (const auto& r : s["robots"]) {
    EXPECT_GE(r["final_version"].get<int>(), 55) << r["robot_id"];
    // The robot keeps warming up after its campaign: judge against core's engine fed the same poses in-process.
    EXPECT_LT(r["verify_after_mm"].get<double>(), r["verify_before_mm"].get<double>() / 5) << r["robot_id"];
    EXPECT_LT(r["verify_after_mm"].get<double>(), 1.5 * r["in_process_verify_after_mm"].get<double>() + 0.005)
        << r["robot_id"];
    EXPECT_GT(r["targets_applied"].get<int>(), 0) << r["robot_id"];
  }
  // Each robot's state file holds its own model.
  const auto left = readEngineState(dir + "/run/state", "left"), right = readEngineState(dir + "/run/state", "right");
  EXPECT_EQ(left["robot_name"], "staubli_tx60");
  EXPECT_EQ(right["robot_name"], "ur10");
}

double holdoutErrorMm(const SimulatedCell& sim, const Eigen::VectorXd& params, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  KinematicsData d(sim.model());
  double sum = 0;
  const auto qs = sim.randomConfigurations(100, rng);
  for (const auto& q : qs) sum += (forwardKinematics(sim.model(), d, params, q).translation() - sim.truePose(q, 0).translation()).norm();
  return sum / qs.size() * 1e3;
}

Eigen::VectorXd paramsOf(const RobotModel& m, const msg::CalibrationState& s) {
  std::string err;
  auto c = fromCalibrationState(m, s, &err);
  EXPECT_TRUE(c.has_value()) << err;
  return c ? c->params : m.nominal;
}

TEST(CellProcesses, MeasurementFileReplaysThroughBothCsvSourcesAndCalibrates) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  const std::string cfg = writeCell(dir, domainForTest(), seed, {{"tx60", "tx60_target"}});
  const CellConfig cell = loadCellConfig(cfg);
  const SimulatedCell sim = makeSimulatedCell(cell.robots[0], cell.simulation, 0);
  std::mt19937_64 rng(seed);
  {
    std::ofstream csv(dir + "/m.csv");
    csv << "# simulated TX60, seed " << seed << "\nq1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,qw,qx,qy,qz,stamp_s\n";
    csv.precision(12);
    int k = 0;
    for (const auto& q : sim.randomConfigurations(40, rng)) {
      const Observation o = sim.measure(q, 0.0, rng);
      for (int j = 0; j < 6; ++j) csv << q[j] * 180 / kPi << ",";
      const Eigen::Quaterniond qn(o.measured_in_tracker.linear());
      const Eigen::Vector3d p = o.measured_in_tracker.translation() * 1e3;
      csv << p.x() << "," << p.y() << "," << p.z() << "," << qn.w() << "," << qn.x() << "," << qn.y() << "," << qn.z()
          << "," << 100 + 0.2 * k++ << "\n";
    }
  }
  Probe probe(cell);
  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  const std::string start = std::to_string((wallNs() / 1'000'000'000 + 3) * 1'000'000'000);
  Process joints(dir, "joints", {"cellcal_joint_state_adapter", "--config", cfg, "--source", "csv", "--csv", dir + "/m.csv",
                                 "--start-unix-ns", start});
  Process tracker(dir, "tracker", {"cellcal_tracker_adapter", "--config", cfg, "--source", "csv", "--csv", dir + "/m.csv",
                                   "--start-unix-ns", start});
  EXPECT_EQ(joints.wait(30), 0) << joints.log();
  EXPECT_EQ(tracker.wait(10), 0) << tracker.log();
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const std::uint64_t v = probe.latestVersion("tx60");
  EXPECT_GE(v, 36u) << engine.log();
  EXPECT_LE(v, 40u);
  std::lock_guard<std::mutex> l(probe.mutex);
  ASSERT_FALSE(probe.states.empty());
  const double after = holdoutErrorMm(sim, paramsOf(cell.robots[0].model, probe.states.back()), seed + 1);
  const double before = holdoutErrorMm(sim, cell.robots[0].model.nominal, seed + 1);
  EXPECT_LT(after, before / 10) << "before " << before << " mm";
}

TEST(CellProcesses, UdpSourcesBridgeAControllerAndATracker) {
  const std::string dir = testDir();
  const int domain = domainForTest();
  const std::uint64_t seed = testSeed();
  const std::string cfg = writeCell(dir, domain, seed, {{"tx60", "tx60_target"}});
  const CellConfig cell = loadCellConfig(cfg);
  const SimulatedCell sim = makeSimulatedCell(cell.robots[0], cell.simulation, 0);
  const int jport = 21000 + 2 * domain, tport = jport + 1;
  Probe probe(cell);
  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  Process joints(dir, "joints", {"cellcal_joint_state_adapter", "--config", cfg, "--source", "udp", "--udp-port",
                                 std::to_string(jport), "--stats-json", dir + "/joints.json"});
  Process tracker(dir, "tracker", {"cellcal_tracker_adapter", "--config", cfg, "--source", "udp", "--udp-port",
                                   std::to_string(tport), "--stats-json", dir + "/tracker.json"});
  ASSERT_TRUE(waitUntil([&] {
    std::lock_guard<std::mutex> l(probe.mutex);
    return !probe.states.empty();  // the engine is up and discovered
  }, 10));
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));  // adapters discovered
  const int fd = ::socket(AF_INET, SOCK_DGRAM, 0);
  auto send = [&](int port, const std::string& line) {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ::sendto(fd, line.data(), line.size(), 0, reinterpret_cast<sockaddr*>(&a), sizeof a);
  };
  std::mt19937_64 rng(seed);
  send(tport, "tx60_target 0 1 1.0 2.0\n");  // a bad line: counted, ignored
  int sent = 0;
  for (const auto& q : sim.randomConfigurations(30, rng)) {
    const Observation o = sim.measure(q, 0.0, rng);
    const std::int64_t t = wallNs();
    std::ostringstream js0, js1, tr;
    js0.precision(17);
    js1.precision(17);
    tr.precision(17);
    js0 << "tx60 " << t - 2'000'000 << " 1";
    js1 << "tx60 " << t + 2'000'000 << " 1";
    for (int j = 0; j < 6; ++j) {
      js0 << " " << q[j];
      js1 << " " << q[j];
    }
    const Eigen::Quaterniond qn(o.measured_in_tracker.linear());
    const Eigen::Vector3d p = o.measured_in_tracker.translation();
    tr << "tx60_target " << t << " 1 " << p.x() << " " << p.y() << " " << p.z() << " " << qn.x() << " " << qn.y() << " "
       << qn.z() << " " << qn.w() << " " << o.sigma_position_m << " " << o.sigma_orientation_rad;
    send(jport, js0.str());
    send(tport, tr.str());
    std::this_thread::sleep_for(std::chrono::milliseconds(3));
    send(jport, js1.str());
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    ++sent;
  }
  ::close(fd);
  EXPECT_TRUE(waitUntil([&] { return probe.latestVersion("tx60") >= 28; }, 10)) << engine.log();
  joints.stop();
  tracker.stop();
  EXPECT_EQ(readJson(dir + "/tracker.json")["extra"]["udp_bad_lines"], 1) << tracker.log();
  EXPECT_NE(tracker.log().find("expected 6, 8, 10 or 12 fields, got 5"), std::string::npos) << tracker.log();
  std::lock_guard<std::mutex> l(probe.mutex);
  const double after = holdoutErrorMm(sim, paramsOf(cell.robots[0].model, probe.states.back()), seed + 1);
  EXPECT_LT(after, holdoutErrorMm(sim, cell.robots[0].model.nominal, seed + 1) / 5);
}

}  // namespace
}  // namespace cellcal
