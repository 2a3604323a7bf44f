// Recordings of a running cell (cellcal record / replay / validate / export) through real processes on localhost:
// a recorded cell is reproduced exactly by `validate` and by replays through a fresh engine process, a changed
// calibration in the recording is found and named, and a recorder killed with SIGKILL leaves a readable file.
// The simulated robot's errors come from a fresh seed per run.
#include <gtest/gtest.h>

#include <fstream>
#include <random>

#include "cell_test_support.hpp"
#include "cellcal/recording/recording.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;
using namespace cellcal::components;
using namespace cellcal::recording;

const char* kProgram = "  initial_poses: 40\n  poses_per_group: 15\n  groups: 2\n  hours_between_groups: 1\n";

std::vector<double> stateParams(const std::string& state_dir) {
  const auto j = readEngineState(state_dir, "tx60");
  if (j.is_null() || !j.contains("params")) return {};
  return j["params"].get<std::vector<double>>();
}

// A copy of `in` where the CalibrationState of `version` has parameter `index` moved by `delta`.
void tamper(const std::string& in, const std::string& out, std::uint64_t version, size_t index, double delta) {
  const Recording r = readRecording(in, false);
  RecordingWriter w(out);
  for (const auto& m : r.in_log_order) {
    std::string data = m.message->data;
    if (*m.topic == TopicOf<msg::CalibrationState>::name) {
      msg::CalibrationState s;
      std::string error;
      ASSERT_TRUE(decodeCdr(data, &s, &error)) << error;
      if (s.version() == version) {
        s.parameter_values()[index] += delta;
        data = encodeCdr(s);
      }
    }
    w.writeEncoded(*m.topic, data, m.message->log_time_ns, m.message->publish_time_ns, m.message->sequence);
  }
  w.file().close();
}

TEST(CellRecording, ARecordedCellIsReproducedByValidateAndByReplays) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  // Stamps are not compared with the clock: the replays below run at twice the recorded speed.
  const std::string cfg = writeCell(dir, domainForTest(), seed, {{"tx60", "tx60_target"}}, kProgram, "  max_sample_age_s: 0\n");
  const std::string rec = dir + "/cell.mcap";
  ASSERT_FALSE(runCell(dir, cfg, "8", {"--record", rec}, 90).is_discarded());
  const std::vector<double> live = stateParams(dir + "/run/state");
  const auto live_version = readEngineState(dir + "/run/state", "tx60")["version"].get<std::uint64_t>();
  ASSERT_FALSE(live.empty());
  ASSERT_GE(live_version, 20u) << readTextFile(dir + "/cell.log");

  // validate: every recorded calibration reproduced, bit for bit within 1e-9 m / rad.
  Process v(dir, "validate", {"cellcal", "validate", rec, "--config", cfg, "--json", dir + "/v.json", "--require-match"});
  ASSERT_EQ(v.wait(60), 0) << v.log();
  const auto vj = readJson(dir + "/v.json")["robots"]["tx60"];
  EXPECT_EQ(vj["differ"], 0) << v.log();
  EXPECT_EQ(vj["recorded_not_reproduced"], 0) << v.log();
  EXPECT_GE(vj["compared"].get<std::uint64_t>(), live_version - 1) << v.log();  // the recorder may miss none but v0
  EXPECT_EQ(vj["final_version"].get<std::uint64_t>(), live_version);
  std::printf("  recorded %llu calibrations; validate: %s compared, real time x%.0f\n",
              static_cast<unsigned long long>(live_version), vj["compared"].dump().c_str(),
              readJson(dir + "/v.json")["real_time_factor"].get<double>());

  // A calibration changed in the file (random version, parameter and size above the tolerance) is found and named.
  const Recording r = readRecording(rec, false);
  std::vector<msg::CalibrationState> states;
  for (const auto& m : r.in_log_order)
    if (*m.topic == TopicOf<msg::CalibrationState>::name) {
      msg::CalibrationState s;
      ASSERT_TRUE(decodeCdr(m.message->data, &s, nullptr));
      if (s.version() > 0) states.push_back(s);
    }
  ASSERT_FALSE(states.empty());
  const auto& victim = states[rng() % states.size()];
  const size_t index = rng() % victim.parameter_names().size();
  const double delta = (rng() % 2 ? 1 : -1) * std::pow(10.0, std::uniform_real_distribution<double>(-8, -5)(rng));
  tamper(rec, dir + "/tampered.mcap", victim.version(), index, delta);
  Process t(dir, "validate_tampered", {"cellcal", "validate", dir + "/tampered.mcap", "--config", cfg, "--json",
                                       dir + "/t.json", "--require-match"});
  EXPECT_EQ(t.wait(60), 3) << t.log();
  const auto tj = readJson(dir + "/t.json")["robots"]["tx60"];
  EXPECT_EQ(tj["differ"], 1) << t.log();
  const std::string first = tj["first_difference"];
  const std::string name = victim.parameter_names()[index].to_string();
  EXPECT_NE(first.find("v" + std::to_string(victim.version()) + ": " + name), std::string::npos)
      << first << " (changed " << name << " of v" << victim.version() << " by " << delta << ")";

  // Replayed twice through a fresh engine process (inputs only, twice the recorded speed): the same final calibration
  // as the live engine's.
  for (int k = 0; k < 2; ++k) {
    const std::string state_dir = dir + "/replay" + std::to_string(k);
    Process engine(dir, "engine" + std::to_string(k), {"cellcal_calibration_engine", "--config", cfg, "--state-dir", state_dir, "--quiet"});
    Process replay(dir, "replay" + std::to_string(k), {"cellcal", "replay", rec, "--config", cfg, "--rate", "2", "--topics",
                                                       "cellcal/joint_state,cellcal/tracker_pose", "--json",
                                                       dir + "/replay" + std::to_string(k) + ".json"});
    ASSERT_EQ(replay.wait(60), 0) << replay.log();
    ASSERT_TRUE(waitUntil([&] { return stateParams(state_dir).size() == live.size() &&
                                       readEngineState(state_dir, "tx60")["version"] == live_version; }, 5))
        << engine.log() << replay.log();
    EXPECT_EQ(engine.stop(), 0);
    const auto p = stateParams(state_dir);
    double max_diff = 0;
    for (size_t i = 0; i < p.size(); ++i) max_diff = std::max(max_diff, std::abs(p[i] - live[i]));
    EXPECT_LT(max_diff, 1e-12) << "replay " << k;
    const auto rj = readJson(dir + "/replay" + std::to_string(k) + ".json");
    EXPECT_EQ(rj["refused"], 0);
    std::printf("  replay %d: final calibration v%llu, max |difference| to the live engine %.2e; timing error p99 %.0f us\n",
                k, static_cast<unsigned long long>(live_version), max_diff, rj["timing_error_p99_us"].get<double>());
  }
}

// A cell whose engine starts from a calibrated robot file publishes the file's model as a version of its own before
// any reading; validate reproduces that version too, so `validate --require-match` holds for such a cell as for one
// started from nominal. The file: the cell's own first run, exported and calibrated, as a user would.
TEST(CellRecording, ACellStartedFromACalibrationFileIsReproducedFromItsFirstVersion) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  const std::string cfg = writeCell(dir, domainForTest(), seed, {{"tx60", "tx60_target"}}, kProgram);
  ASSERT_FALSE(runCell(dir, cfg, "6", {"--record", dir + "/first.mcap"}, 90).is_discarded());
  Process exported(dir, "export", {"cellcal", "export", dir + "/first.mcap", "--config", cfg, "--out", dir + "/first.csv"});
  ASSERT_EQ(exported.wait(60), 0) << exported.log();
  Process calibrated(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml",
                                        "--data", dir + "/first.csv", "--save-robot", dir + "/calibrated.yaml"});
  ASSERT_EQ(calibrated.wait(60), 0) << calibrated.log();
  RobotEntry robot{"tx60", "tx60_target"};
  robot.calibration_file = dir + "/calibrated.yaml";
  std::filesystem::create_directories(dir + "/second");
  const std::string second = writeCell(dir + "/second", domainForTest(), seed, {robot}, kProgram);
  ASSERT_FALSE(runCell(dir + "/second", second, "6", {"--record", dir + "/second.mcap"}, 90).is_discarded());
  Process v(dir, "validate", {"cellcal", "validate", dir + "/second.mcap", "--config", second, "--json", dir + "/v.json",
                              "--require-match"});
  EXPECT_EQ(v.wait(60), 0) << v.log();
  const auto vj = readJson(dir + "/v.json")["robots"]["tx60"];
  EXPECT_EQ(vj["differ"], 0) << v.log();
  EXPECT_EQ(vj["recorded_not_reproduced"], 0) << v.log();
  // The file's version (v1, published at the engine's start) is among those compared.
  bool first_compared = false;
  for (const auto& row : vj["calibrations"])
    if (row["version"] == 1 && row.contains("max_difference_m")) first_compared = true;
  EXPECT_TRUE(first_compared) << vj.dump(1);
  std::printf("%s", v.log().c_str());
}

TEST(CellRecording, ARecorderKilledWithSigkillLeavesAReadableFile) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  const std::string cfg = writeCell(dir, domainForTest(), seed, {{"tx60", "tx60_target"}}, kProgram);
  const std::string file = dir + "/killed.mcap";
  Process recorder(dir, "recorder", {"cellcal", "record", "--config", cfg, "--out", file, "--flush-period-s", "0.2"});
  Process cell(dir, "cell", {"cellcal", "cell", "--config", cfg, "--duration-s", "6", "--work-dir", dir + "/run", "--quiet"});
  // Killed at a random moment while the cell runs.
  std::this_thread::sleep_for(std::chrono::milliseconds(3000 + rng() % 3000));
  ASSERT_EQ(recorder.stop(SIGKILL), 128 + SIGKILL);
  ASSERT_EQ(cell.wait(60), 0) << cell.log();
  mcap::ReadOptions o;
  o.tolerate_truncation = true;
  const auto cut = mcap::readFile(file, o);
  EXPECT_FALSE(cut.complete);
  EXPECT_GT(cut.messages.size(), 1000u) << cut.problem;
  // validate and replay read it as it is; --recover makes it whole with the same messages.
  Process v(dir, "validate", {"cellcal", "validate", file, "--config", cfg, "--json", dir + "/v.json"});
  ASSERT_EQ(v.wait(60), 0) << v.log();
  EXPECT_EQ(readJson(dir + "/v.json")["messages"].get<size_t>(), cut.messages.size());
  Process fix(dir, "recover", {"cellcal", "record", "--recover", file, "--out", dir + "/fixed.mcap"});
  ASSERT_EQ(fix.wait(60), 0) << fix.log();
  const auto whole = mcap::readFile(dir + "/fixed.mcap");
  EXPECT_TRUE(whole.complete);
  EXPECT_EQ(whole.messages.size(), cut.messages.size());
  std::printf("  killed recorder: %zu messages readable (%s)\n", cut.messages.size(), cut.problem.c_str());
}

}  // namespace
}  // namespace cellcal
