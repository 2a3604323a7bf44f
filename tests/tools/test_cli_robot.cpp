// `cellcal robot import` and `robot export` as a user runs them, around `calibrate --robot FILE.urdf`: a robot file
// from a random arm of ../shared/robots/ros-industrial naming its source; a measurement file of that arm (hidden
// errors, unknown placement) calibrated from the URDF directly; the calibration exported as a URDF, a UR kinematics
// file and a DH table, each run saying what it does not carry; bad input refused with nothing written. The real UR10
// series through the ROS-Industrial UR10 URDF give the figures of the hand-written config/robots/ur10.yaml.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "cell/cell_test_support.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/urdf.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/hidden_effect.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;
namespace fs = std::filesystem;

const fs::path kArms = fs::path(CELLCAL_CONFIG_DIR) / "../../shared/robots/ros-industrial";

TEST(CliRobot, AUrdfImportedCalibratedAndExported) {
  if (!fs::is_directory(kArms)) GTEST_SKIP() << kArms << " missing";
  std::vector<fs::path> files;
  for (const auto& e : fs::recursive_directory_iterator(kArms))
    if (e.path().extension() == ".urdf") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  const fs::path urdf = files[rng() % files.size()];
  SCOPED_TRACE(urdf.string());
  const std::string dir = testDir();
  Process imp(dir, "import", {"cellcal", "robot", "import", urdf.string(), "--out", dir + "/arm.yaml"});
  ASSERT_EQ(imp.wait(30), 0) << imp.log();
  EXPECT_NE(imp.log().find("revolute"), std::string::npos) << imp.log();
  const RobotFile rf = loadRobotFile(dir + "/arm.yaml");
  std::map<std::string, std::string> source(rf.source.begin(), rf.source.end());
  EXPECT_EQ(source["urdf"], urdf.string());
  EXPECT_EQ(source["base_link"], "base_link");
  EXPECT_EQ(source["tip_link"], "tool0");
  EXPECT_EQ(source["sha256"].size(), 64u);
  // The same model as --robot FILE.urdf reads it.
  const RobotModel direct = loadRobotModel(urdf.string());
  EXPECT_LT((rf.model.nominal - direct.nominal).cwiseAbs().maxCoeff(), 1e-12);

  // A measurement file of the arm with hidden errors at a random placement, calibrated from the URDF.
  RandomDraw d = randomDraw(rng);
  d.sc.seed = seed;
  const SimulatedCell cell(direct, d.sc);
  MeasurementFile f;
  for (const auto& q : cell.randomConfigurations(160, rng))
    f.rows.push_back(measuredRow(q, cell.measure(q, 0.0, rng, d.kind)));
  {
    std::ofstream out(dir + "/m.csv");
    writeMeasurementCsv(out, f, direct.numJoints(), "simulated " + direct.name);
  }
  Process cal(dir, "calibrate", {"cellcal", "calibrate", "--robot", urdf.string(), "--data", dir + "/m.csv",
                                 "--save-robot", dir + "/cal.yaml", "--json", dir + "/cal.json"});
  ASSERT_EQ(cal.wait(120), 0) << cal.log();
  const RobotFile calibrated = loadRobotFile(dir + "/cal.yaml");
  EXPECT_EQ(calibrated.model.joint_names, direct.joint_names);
  EXPECT_FALSE(calibrated.source.empty()) << "the calibrated file names the URDF it came from";
  // The three formats.
  for (const std::string format : {"urdf", "ur-kinematics", "dh-table"}) {
    const bool ur = urdf.string().find("universal_robots") != std::string::npos;
    if (format == "ur-kinematics" && !ur) continue;
    const std::string out = dir + "/exported." + format;
    Process e(dir, "export_" + format, {"cellcal", "robot", "export", "--robot", dir + "/cal.yaml", "--format", format,
                                        "--urdf", urdf.string(), "--out", out, "--json", out + ".json"});
    ASSERT_EQ(e.wait(60), 0) << e.log();
    EXPECT_TRUE(fs::exists(out));
    EXPECT_NE(e.log().find("held-out on its calibration rows"), std::string::npos) << e.log();
    EXPECT_NE(e.log().find("not carried: what the target's frame absorbed"), std::string::npos) << e.log();
    const auto j = nlohmann::json::parse(std::ifstream(out + ".json"));
    EXPECT_TRUE(j["verification_exported"].is_object()) << j.dump();
    if (format == "urdf") {
      // It reads back as the arm, calibrated: the export's FK at random joints is the calibrated model's.
      const UrdfImport back = importUrdf(readTextFile(out), out);
      KinematicsData da(back.model), db(calibrated.model);
      Eigen::VectorXd p = calibrated.model.nominal;
      p.segment<6>(p.size() - 12).setZero();
      p.segment<6>(p.size() - 6).setZero();
      for (const auto& q : cell.randomConfigurations(20, rng))
        EXPECT_LT((forwardKinematics(back.model, da, back.model.nominal, q).translation() -
                   forwardKinematics(calibrated.model, db, p, q).translation()).norm(), 1e-9);
    }
  }

  // Bad input: nothing written, exit 2, the element named.
  std::string text = readTextFile(urdf.string());
  const auto at = text.find("type=\"revolute\"");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 15, "type=\"prismatic\"");
  std::ofstream(dir + "/bad.urdf") << text;
  Process bad(dir, "bad_import", {"cellcal", "robot", "import", dir + "/bad.urdf", "--out", dir + "/bad.yaml"});
  EXPECT_EQ(bad.wait(30), 2) << bad.log();
  EXPECT_NE(bad.log().find("bad.urdf:"), std::string::npos) << bad.log();
  EXPECT_NE(bad.log().find("<joint name="), std::string::npos) << bad.log();
  EXPECT_FALSE(fs::exists(dir + "/bad.yaml"));
  // Exported against another arm's URDF.
  const fs::path other = files[(std::find(files.begin(), files.end(), urdf) - files.begin() + 1) % files.size()];
  Process wrong(dir, "wrong_export", {"cellcal", "robot", "export", "--robot", dir + "/cal.yaml", "--format", "urdf",
                                      "--urdf", other.string(), "--out", dir + "/wrong.urdf"});
  EXPECT_EQ(wrong.wait(30), 2) << wrong.log();
  EXPECT_NE(wrong.log().find("not the description"), std::string::npos) << wrong.log();
  EXPECT_FALSE(fs::exists(dir + "/wrong.urdf"));
  // Without --urdf: the robot file's source URDF, the same export; a robot file that names none (written by hand,
  // or its source gone) is refused, nothing written.
  Process by_source(dir, "by_source", {"cellcal", "robot", "export", "--robot", dir + "/cal.yaml", "--format", "urdf",
                                       "--out", dir + "/by_source.urdf"});
  EXPECT_EQ(by_source.wait(30), 0) << by_source.log();
  EXPECT_NE(by_source.log().find("(the robot file's source)"), std::string::npos) << by_source.log();
  EXPECT_EQ(readTextFile(dir + "/by_source.urdf"), readTextFile(dir + "/exported.urdf"));
  std::string orphan = readTextFile(dir + "/cal.yaml");
  ASSERT_NE(orphan.find(urdf.string()), std::string::npos);
  for (size_t at = orphan.find(urdf.string()); at != std::string::npos; at = orphan.find(urdf.string(), at))
    orphan.replace(at, urdf.string().size(), dir + "/gone.urdf");
  std::ofstream(dir + "/orphan.yaml") << orphan;
  Process missing(dir, "no_urdf", {"cellcal", "robot", "export", "--robot", dir + "/orphan.yaml", "--format", "urdf",
                                   "--out", dir + "/x.urdf"});
  EXPECT_EQ(missing.wait(30), 2) << missing.log();
  EXPECT_NE(missing.log().find("gone.urdf is not there"), std::string::npos) << missing.log();
  EXPECT_FALSE(fs::exists(dir + "/x.urdf"));
}

// Real data through a URDF: the ipa UR10 series A and B calibrated with `--robot ur10.urdf` (ROS-Industrial's
// description, converted on the fly) give the held-out figures of config/robots/ur10.yaml (written by hand from UR's
// DH table) within 1 %: the conversion is the same robot, Hayati's parallel joints included.
TEST(CliRobot, RealSeriesThroughTheUrdfGiveTheRobotFilesFigures) {
  const fs::path ipa = fs::path(CELLCAL_CONFIG_DIR) / "../../shared/datasets/ipa-robot-accuracy";
  const fs::path urdf = kArms / "universal_robots" / "ur10.urdf";
  if (!fs::is_directory(ipa) || !fs::exists(urdf)) GTEST_SKIP() << ipa << " or " << urdf << " missing";
  const std::string dir = testDir();
  const std::vector<std::pair<std::string, std::string>> series = {
      {"A", "Series_A/measurements_grid.csv"}, {"B", "Series_B/measurements_joint_configurations.csv"}};
  for (const auto& [name, file] : series) {
    SCOPED_TRACE("series " + name);
    const std::string csv = dir + "/" + name + ".csv";
    Process imp(dir, "import_" + name, {"cellcal", "import", "ipa", (ipa / file).string(), "--out", csv});
    ASSERT_EQ(imp.wait(60), 0) << imp.log();
    double mean[2][2];  // [robot file, URDF][before, after]
    for (int k = 0; k < 2; ++k) {
      const std::string robot = k == 0 ? std::string(CELLCAL_CONFIG_DIR) + "/robots/ur10.yaml" : urdf.string();
      const std::string json = dir + "/" + name + std::to_string(k) + ".json";
      Process cal(dir, "calibrate_" + name + std::to_string(k),
                  {"cellcal", "calibrate", "--robot", robot, "--data", csv, "--json", json});
      ASSERT_EQ(cal.wait(120), 0) << cal.log();
      const auto j = nlohmann::json::parse(std::ifstream(json));
      mean[k][0] = j["verification"]["before"]["mean_mm"];
      mean[k][1] = j["verification"]["after"]["mean_mm"];
    }
    std::printf("  series %s: held-out mean before/after %.4f/%.4f mm from ur10.yaml, %.4f/%.4f mm from ur10.urdf\n",
                name.c_str(), mean[0][0], mean[0][1], mean[1][0], mean[1][1]);
    for (int b = 0; b < 2; ++b) EXPECT_NEAR(mean[1][b], mean[0][b], 0.01 * mean[0][b]) << (b ? "after" : "before");
  }
}

}  // namespace
}  // namespace cellcal
