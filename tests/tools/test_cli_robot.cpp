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
#include "cellcal/core/files/export.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
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

// The real UR10 series A calibrated through ROS-Industrial's ur10.urdf and exported as a URDF: the data cannot tell
// joint 1's offset along and about its axis from the base's z and yaw, so the exported base_link -> tool0 moves from
// the nominal description only by what the data see relative to the base: over configurations within the limits,
// the mean z change within 0.1 mm and the best turn about joint 1's axis within 0.005 deg, computed here from both
// files read back on the export's configurations (its own figures agree), and the registered base carries the rest: the exported description
// with the calibrated frames predicts the held-out readings as the calibration does.
TEST(CliRobot, RealSeriesAExportMovesTool0OnlyByWhatTheDataSee) {
  const fs::path ipa = fs::path(CELLCAL_CONFIG_DIR) / "../../shared/datasets/ipa-robot-accuracy";
  const fs::path urdf = kArms / "universal_robots" / "ur10.urdf";
  if (!fs::is_directory(ipa) || !fs::exists(urdf)) GTEST_SKIP() << ipa << " or " << urdf << " missing";
  const std::string dir = testDir(), csv = dir + "/a.csv";
  Process imp(dir, "import", {"cellcal", "import", "ipa", (ipa / "Series_A/measurements_grid.csv").string(), "--out", csv});
  ASSERT_EQ(imp.wait(60), 0) << imp.log();
  Process cal(dir, "calibrate", {"cellcal", "calibrate", "--robot", urdf.string(), "--data", csv, "--save-robot",
                                 dir + "/cal.yaml", "--json", dir + "/cal.json"});
  ASSERT_EQ(cal.wait(120), 0) << cal.log();
  EXPECT_NE(cal.log().find("carried by the base and tool frames (no data tell them from the frames): "
                           "joint1.theta_offset_deg joint1.d_mm"), std::string::npos) << cal.log();
  Process e(dir, "export", {"cellcal", "robot", "export", "--robot", dir + "/cal.yaml", "--format", "urdf", "--urdf",
                            urdf.string(), "--out", dir + "/exported.urdf", "--json", dir + "/export.json"});
  ASSERT_EQ(e.wait(60), 0) << e.log();
  const UrdfImport nominal = importUrdf(readTextFile(urdf.string()), urdf.string());
  const UrdfImport exported = importUrdf(readTextFile(dir + "/exported.urdf"), dir + "/exported.urdf");
  KinematicsData dn(nominal.model), de(exported.model);
  double z_sum = 0, s = 0, c = 0;
  const std::vector<Eigen::VectorXd> qs = spreadConfigurations(nominal.model, 300);  // the export's own
  const int n = static_cast<int>(qs.size());
  for (const auto& q : qs) {
    const Eigen::Vector3d a = forwardKinematics(nominal.model, dn, nominal.model.nominal, q).translation();
    const Eigen::Vector3d b = forwardKinematics(exported.model, de, exported.model.nominal, q).translation();
    z_sum += (b - a).z();
    s += a.x() * b.y() - a.y() * b.x();  // the shoulder pan axis is base_link's z through its origin
    c += a.x() * b.x() + a.y() * b.y();
  }
  const double z_mm = z_sum / n * 1e3, yaw_deg = radToDeg(std::atan2(s, c));
  const auto j = nlohmann::json::parse(std::ifstream(dir + "/export.json"));
  std::printf("  series A exported through ur10.urdf: base_link -> tool0 z change %.4f mm mean, turn about joint 1 "
              "%.4f deg (the export says %.4f mm, %.4f deg)\n",
              z_mm, yaw_deg, j["tool0_change"]["mean_offset_mm"][2].get<double>(),
              j["tool0_change"]["yaw_about_joint1_deg"].get<double>());
  EXPECT_LT(std::abs(z_mm), 0.1);
  EXPECT_LT(std::abs(yaw_deg), 0.005);
  EXPECT_NEAR(j["tool0_change"]["mean_offset_mm"][2].get<double>(), z_mm, 1e-6);
  EXPECT_NEAR(j["tool0_change"]["yaw_about_joint1_deg"].get<double>(), yaw_deg, 1e-6);
  // The exported description and the calibrated frames predict the verification rows as the calibration did.
  const RobotFile rf = loadRobotFile(dir + "/cal.yaml");
  const MeasurementFile f = readMeasurementCsv(csv, rf.model);
  Eigen::VectorXd p = exported.model.nominal;
  p.segment<12>(p.size() - 12) = rf.model.nominal.segment<12>(rf.model.nominal.size() - 12);
  double sum = 0;
  int rows = 0;
  for (size_t i = 1; i < f.rows.size(); i += 2, ++rows)
    sum += (forwardKinematics(exported.model, de, p, f.rows[i].q_rad).translation() - f.rows[i].position_m).norm();
  const double cal_mean = nlohmann::json::parse(std::ifstream(dir + "/cal.json"))["verification"]["after"]["mean_mm"];
  EXPECT_NEAR(sum / rows * 1e3, cal_mean, 1e-4 * cal_mean);

  // From an extended calibration a geometric-only format gets the geometric calibration of the same data: its
  // held-out mean is the plain calibration's (within 1 %), and both figures are printed.
  Process ext(dir, "calibrate_compliance", {"cellcal", "calibrate", "--robot", urdf.string(), "--data", csv,
                                            "--model", "joint_compliance:2", "--save-robot", dir + "/compliance.yaml"});
  ASSERT_EQ(ext.wait(120), 0) << ext.log();
  Process ur(dir, "export_compliance", {"cellcal", "robot", "export", "--robot", dir + "/compliance.yaml", "--format",
                                        "ur-kinematics", "--urdf", urdf.string(), "--out", dir + "/kinematics.yaml",
                                        "--json", dir + "/compliance_export.json"});
  ASSERT_EQ(ur.wait(60), 0) << ur.log();
  EXPECT_NE(ur.log().find("the geometric calibration of the same data"), std::string::npos) << ur.log();
  const auto je = nlohmann::json::parse(std::ifstream(dir + "/compliance_export.json"));
  const double exported_mean = je["verification_exported"]["mean_mm"], full_mean = je["verification_full_model"]["mean_mm"];
  std::printf("  the joint_compliance:2 calibration exported as UR kinematics: held-out %.4f mm (full model %.4f, plain "
              "geometric calibration %.4f)\n", exported_mean, full_mean, cal_mean);
  EXPECT_LT(exported_mean, 1.01 * cal_mean);
  // What each written file leaves out at its tool0 over the calibration rows: nothing for the plain calibration's
  // URDF (the file is the calibration), the compliance's sag and the two fits' difference for the UR file.
  EXPECT_EQ(j["left_out_at_tool0"]["rows"].get<int>(), static_cast<int>(f.rows.size()));
  EXPECT_LT(j["left_out_at_tool0"]["max_mm"].get<double>(), 1e-9) << j.dump(2);
  EXPECT_GT(je["left_out_at_tool0"]["mean_mm"].get<double>(), 0.01) << je.dump(2);
}

// `robot check`: a simulated UR controller (its `base` frame half a turn from base_link, poses rounded to a micrometre
// and 1e-9 of a quaternion) running a calibrated robot file (every joint angle and non-zero length of the UR10 URDF
// moved 0.01-0.05 deg or 0.1-0.5 mm at random) is found to run it; one running the nominal URDF is found not to (exit 3), and the
// parameters named, largest first, are the calibration's moves, each within 2 % of its size; the nominal controller
// against the nominal URDF passes; a bad row is refused naming its line.
TEST(CliRobot, CheckTellsWhichModelAControllerRuns) {
  const fs::path urdf = kArms / "universal_robots" / "ur10.urdf";
  if (!fs::exists(urdf)) GTEST_SKIP() << urdf << " missing";
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto signedIn = [&](double lo, double hi) { return (u01(rng) < 0.5 ? -1 : 1) * (lo + (hi - lo) * u01(rng)); };
  const RobotModel nominal = loadRobotModel(urdf.string());
  RobotModel calibrated = nominal;
  // (A robot file without a calibration section keeps its zero lengths zero: one written by hand.)
  for (int i : nominal.canonicalParams())
    if (i < 5 * nominal.numJoints() && (!nominal.isLength(i) || nominal.nominal[i] != 0))
      calibrated.nominal[i] += nominal.isLength(i) ? signedIn(1e-4, 5e-4) : degToRad(signedIn(0.01, 0.05));
  saveRobotFile(dir + "/cal.yaml", calibrated, nullptr, "a calibration written by hand");
  auto controller = [&](const RobotModel& runs, const std::string& path) {
    Eigen::VectorXd p = runs.nominal;
    p.segment<6>(runs.baseParam(FrameParam::kX)) << 0, 0, 0, 0, 0, kPi;
    p.segment<6>(runs.toolParam(FrameParam::kX)).setZero();
    KinematicsData data(runs);
    std::mt19937_64 q_rng(7);
    MeasurementFile f;
    for (int k = 0; k < 60; ++k) {
      MeasurementRow row;
      row.q_rad.resize(6);
      for (int j = 0; j < 6; ++j) row.q_rad[j] = std::uniform_real_distribution<double>(-kPi, kPi)(q_rng);
      const Pose T = forwardKinematics(runs, data, p, row.q_rad);
      row.position_m = (T.translation() * 1e6).array().round() / 1e6;
      Eigen::Quaterniond q(T.linear());
      q.coeffs() = (q.coeffs() * 1e9).array().round() / 1e9;
      row.orientation = q.normalized();
      f.rows.push_back(row);
    }
    std::ofstream out(path);
    writeMeasurementCsv(out, f, 6, "a controller's tool0_controller");
  };
  controller(calibrated, dir + "/runs_cal.csv");
  controller(nominal, dir + "/runs_nominal.csv");
  const std::vector<std::string> ur_base = {"--base-in-controller", "0,0,0,0,0,180"};
  auto check = [&](const std::string& name, const std::string& robot, const std::string& data) {
    std::vector<std::string> args = {"cellcal", "robot", "check", "--robot", robot, "--data", data, "--json",
                                     dir + "/" + name + ".json"};
    args.insert(args.end(), ur_base.begin(), ur_base.end());
    return Process(dir, name, args);
  };
  Process runs_it = check("runs_it", dir + "/cal.yaml", dir + "/runs_cal.csv");
  EXPECT_EQ(runs_it.wait(60), 0) << runs_it.log();
  EXPECT_NE(runs_it.log().find("the controller computes with this model"), std::string::npos) << runs_it.log();
  Process nominal_ok = check("nominal_ok", urdf.string(), dir + "/runs_nominal.csv");
  EXPECT_EQ(nominal_ok.wait(60), 0) << nominal_ok.log();
  Process other = check("other", dir + "/cal.yaml", dir + "/runs_nominal.csv");
  EXPECT_EQ(other.wait(60), 3) << other.log();
  EXPECT_NE(other.log().find("does NOT compute with this model"), std::string::npos) << other.log();
  const auto j = nlohmann::json::parse(std::ifstream(dir + "/other.json"));
  EXPECT_FALSE(j["matches"].get<bool>());
  EXPECT_GT(j["max_mm"].get<double>(), 0.1);
  EXPECT_LT(j["left_mean_mm"].get<double>(), 0.001) << j.dump(2);
  ASSERT_GE(j["explained_by"].size(), 5u) << j.dump(2);
  for (const auto& e : j["explained_by"]) {  // each named change undoes the calibration's move of that parameter
    int index = -1;
    for (int i = 0; i < nominal.numParams(); ++i)
      if (nominal.paramNameHuman(i) == e["name"].get<std::string>()) index = i;
    ASSERT_GE(index, 0) << e.dump();
    const double moved = nominal.toHuman(index, calibrated.nominal[index] - nominal.nominal[index]);
    if (std::abs(moved) < 1e-12) continue;  // a parameter the move did not touch, explaining a little
    EXPECT_NEAR(e["change"].get<double>(), -moved, 0.02 * std::abs(moved)) << e.dump();
  }
  // `robot fk` of the calibrated file with the controller's frame gives that controller's poses (to their rounding).
  Process fk(dir, "fk", {"cellcal", "robot", "fk", "--robot", dir + "/cal.yaml", "--data", dir + "/runs_cal.csv",
                         "--base-in-controller", "0,0,0,0,0,180", "--out", dir + "/fk.csv"});
  ASSERT_EQ(fk.wait(60), 0) << fk.log();
  const MeasurementFile made = readMeasurementCsv(dir + "/fk.csv", nominal),
                        logged = readMeasurementCsv(dir + "/runs_cal.csv", nominal);
  ASSERT_EQ(made.rows.size(), logged.rows.size());
  double fk_worst_m = 0, fk_worst_rad = 0;
  for (size_t i = 0; i < made.rows.size(); ++i) {
    EXPECT_LT((made.rows[i].q_rad - logged.rows[i].q_rad).norm(), 1e-12);
    fk_worst_m = std::max(fk_worst_m, (made.rows[i].position_m - logged.rows[i].position_m).norm());
    fk_worst_rad = std::max(fk_worst_rad, made.rows[i].orientation->angularDistance(*logged.rows[i].orientation));
  }
  EXPECT_LT(fk_worst_m, 1e-6);
  EXPECT_LT(fk_worst_rad, 1e-8);
  // A bad row: refused naming its line, exit 2.
  std::string text = readTextFile(dir + "/runs_cal.csv");
  const auto last = text.rfind('\n', text.size() - 2);
  text = text.substr(0, last + 1) + "1,2,3\n";
  std::ofstream(dir + "/bad.csv") << text;
  Process bad = check("bad", dir + "/cal.yaml", dir + "/bad.csv");
  EXPECT_EQ(bad.wait(60), 2) << bad.log();
  EXPECT_NE(bad.log().find("bad.csv:"), std::string::npos) << bad.log();
}

}  // namespace
}  // namespace cellcal
