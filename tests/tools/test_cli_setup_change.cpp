// A tracker moved in the middle of a measurement file, as a user meets it: `cellcal calibrate` names the row where the
// set-up changed, registers the two set-ups apart and gives their figures (the same as the rows with a setup column
// saying so, the plain reference); `--one-setup` takes them as one; `diagnose`, which takes one set-up, says so and
// diagnoses the larger block; a file without a change stays one set-up. Robot, effect, measurement type, the row and
// size of the move drawn at random.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "cell/cell_test_support.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "core/identification/hidden_effect.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

// The robot file of a draw: the TX60's or the UR10's, or the URDF it was drawn from.
std::string robotFileOf(const HiddenEffectData& h) {
  return h.draw.robot.find(".urdf") != std::string::npos
             ? h.draw.robot
             : std::string(CELLCAL_CONFIG_DIR) + "/robots/" + h.draw.robot + ".yaml";
}

void write(const std::string& path, const MeasurementFile& f, const char* comment) {
  std::ofstream out(path);
  writeMeasurementCsv(out, f, 6, comment);
}

TEST(CliSetupChange, AMovedTrackerIsFoundAndTheSetUpsAreCalibratedApart) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  DrawOptions o;
  o.category = rng() % 2 ? DrawCategory::kSingle : DrawCategory::kNoiseOnly;
  o.poses = 160 + static_cast<int>(rng() % 80);
  const std::vector<std::string> urdfs = {"abb/irb2600_12_165.urdf", "kuka/kr10r1420.urdf", "fanuc/m10ia.urdf"};
  const std::string shared = std::string(CELLCAL_CONFIG_DIR) + "/../../shared/robots/ros-industrial/";
  const std::string urdf = shared + urdfs[rng() % urdfs.size()];
  o.robot = rng() % 2 && std::filesystem::exists(urdf) ? urdf : "";
  const HiddenEffectData h = makeHiddenEffectData(o, rng());
  const int n = static_cast<int>(h.file.rows.size());
  const std::string robot = robotFileOf(h);
  write(dir + "/one.csv", h.file, "simulated robot, one set-up");
  // The tracker moved before row `at`: every later reading seen from a tracker displaced by 0.5-20 mm and turned
  // by as many mrad, about and along random directions.
  const int at = 20 + static_cast<int>(rng() % static_cast<std::uint64_t>(n - 39));
  const double size_mm = std::exp(std::uniform_real_distribution<double>(std::log(0.5), std::log(20.0))(rng));
  std::normal_distribution<double> g;
  Pose delta = Pose::Identity();
  delta.translation() = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized() * size_mm * 1e-3;
  delta.linear() = Eigen::AngleAxisd(size_mm * 1e-3, Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized()).matrix();
  MeasurementFile moved = h.file;
  for (int i = at; i < n; ++i) {
    MeasurementRow& r = moved.rows[static_cast<size_t>(i)];
    r.position_m = delta * r.position_m;
    if (r.orientation) r.orientation = Eigen::Quaterniond(delta.linear() * r.orientation->toRotationMatrix());
  }
  write(dir + "/moved.csv", moved, "simulated robot, the tracker moved");
  const MeasurementFile read_back = readMeasurementCsv(dir + "/moved.csv", loadRobotFile(robot).model);
  const int true_line = read_back.rows[static_cast<size_t>(at)].line;
  std::printf("%s; tracker moved %.2f mm before row %d (line %d)\n", h.draw.describe().c_str(), size_mm, at, true_line);

  Process c(dir, "calibrate", {"cellcal", "calibrate", "--robot", robot, "--data", dir + "/moved.csv", "--json",
                               dir + "/moved.json"});
  ASSERT_EQ(c.wait(120), 0) << c.log();
  const auto j = readJson(dir + "/moved.json");
  ASSERT_EQ(j["setups"].size(), 2u) << c.log();
  const auto& change = j["setups"][1]["found_setup_change"];
  ASSERT_FALSE(change.is_null()) << c.log();
  const int line = change["line"];
  EXPECT_LE(std::abs(line - true_line), 2) << c.log();
  EXPECT_TRUE(j["setups"][0]["found_setup_change"].is_null());
  // How it was found: one registration cannot fit both sides (above 5 mm RMS, each side far below), or the scan.
  if (change["found_by"] == "registration") {
    const auto& rms = change["registration_rms_mm"];
    EXPECT_GT(rms["one"].get<double>(), 5.0) << change.dump();
    EXPECT_LT(std::max(rms["before"].get<double>(), rms["after"].get<double>()), rms["one"].get<double>()) << change.dump();
    EXPECT_TRUE(change["probability"].is_null() && change["move_mm"].is_null()) << change.dump();
  } else {
    EXPECT_EQ(change["found_by"], "scan") << change.dump();
    EXPECT_LT(change["probability"].get<double>(), 1e-6) << change.dump();
    EXPECT_GE(change["move_mm"].get<double>(), 0.25) << change.dump();
  }
  EXPECT_NE(c.log().find("are 2 set-ups (the tracker or the target moved; no setup column says so): a change before "
                         "line " + std::to_string(line)),
            std::string::npos)
      << c.log();
  const std::string first = dir + "/moved.csv [lines " + std::to_string(read_back.rows.front().line) + "-" +
                            std::to_string(line - 1) + "]";
  EXPECT_EQ(j["setups"][0]["data"], first) << c.log();

  // The plain reference: the same rows with a setup column that splits them there.
  MeasurementFile labelled = read_back;  // the lines of moved.csv
  for (auto& r : labelled.rows) r.setup = r.line < line ? "before" : "after";
  write(dir + "/labelled.csv", labelled, "simulated robot, the set-ups named");
  Process ref(dir, "labelled", {"cellcal", "calibrate", "--robot", robot, "--data", dir + "/labelled.csv", "--json",
                                dir + "/labelled.json"});
  ASSERT_EQ(ref.wait(120), 0) << ref.log();
  const auto r = readJson(dir + "/labelled.json");
  ASSERT_EQ(r["setups"].size(), 2u) << ref.log();
  ASSERT_EQ(r["parameters"].size(), j["parameters"].size());
  for (size_t k = 0; k < j["parameters"].size(); ++k)
    EXPECT_NEAR(r["parameters"][k]["value"].get<double>(), j["parameters"][k]["value"].get<double>(),
                1e-6 * (1 + std::abs(j["parameters"][k]["value"].get<double>())))  // to the solver's tolerance
        << j["parameters"][k]["name"];
  for (int s = 0; s < 2; ++s)
    for (const char* figure : {"mean_mm", "p997_mm", "max_mm"})
      EXPECT_NEAR(r["setups"][s]["verification"]["after"][figure].get<double>(),
                  j["setups"][s]["verification"]["after"][figure].get<double>(), 1e-6)
          << figure;

  // --one-setup: one registration of every row, as before the search (a fit worse than the nominal model on the
  // held-out rows exits 4); nothing found is said.
  Process one(dir, "one-setup", {"cellcal", "calibrate", "--robot", robot, "--data", dir + "/moved.csv", "--json",
                                 dir + "/one_setup.json", "--one-setup"});
  const int one_exit = one.wait(120);
  EXPECT_TRUE(one_exit == 0 || one_exit == 4) << one.log();
  EXPECT_TRUE(readJson(dir + "/one_setup.json")["setups"].is_null());
  EXPECT_EQ(one.log().find("no setup column says so"), std::string::npos) << one.log();

  // diagnose takes one set-up: it says what it found and diagnoses the larger block.
  Process d(dir, "diagnose", {"cellcal", "diagnose", "--robot", robot, "--data", dir + "/moved.csv", "--json",
                              dir + "/d.json", "--no-progress"});
  ASSERT_EQ(d.wait(300), 0) << d.log();
  const auto dj = readJson(dir + "/d.json");
  ASSERT_EQ(dj["setup_changes_found"].size(), 1u) << d.log();
  EXPECT_EQ(dj["setup_changes_found"][0]["line"], line);
  const bool first_larger = line - read_back.rows.front().line >= read_back.rows.back().line - line + 1;
  const std::string larger = first_larger ? first
                                          : dir + "/moved.csv [lines " + std::to_string(line) + "-" +
                                                std::to_string(read_back.rows.back().line) + "]";
  EXPECT_EQ(dj["rows_diagnosed"], larger) << d.log();
  EXPECT_NE(d.log().find("diagnose takes one: it diagnoses " + larger + ", the largest"), std::string::npos)
      << d.log();

  // A command that takes one set-up refuses the rows it found to be two, and says why.
  Process fo(dir, "frames-only", {"cellcal", "calibrate", "--robot", robot, "--data", dir + "/moved.csv",
                                  "--frames-only"});
  EXPECT_EQ(fo.wait(60), 2) << fo.log();
  EXPECT_NE(fo.log().find("--frames-only takes one set-up: the rows of " + dir + "/moved.csv are 2 set-ups"),
            std::string::npos)
      << fo.log();

  // The same file without the move: one set-up.
  Process still(dir, "unmoved", {"cellcal", "calibrate", "--robot", robot, "--data", dir + "/one.csv", "--json",
                                 dir + "/one.json"});
  ASSERT_EQ(still.wait(120), 0) << still.log();
  EXPECT_TRUE(readJson(dir + "/one.json")["setups"].is_null()) << still.log();
}

}  // namespace
}  // namespace cellcal
