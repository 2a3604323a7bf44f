// `cellcal plan iso9283` and `cellcal iso9283` as a user runs them: the test program planned for a random robot of a
// simulated cell, run by the simulated robot (hidden errors, the tracker's noise and the robot's repeatability), the
// figures against the nominal model and against a model calibrated on other poses of the same robot; rows named by
// the program instead of a pose column give the same figures; bad input named with exit 2.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "cell/cell_test_support.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/pose_plan.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "cellcal/lab/sim_program.hpp"
#include "core/identification/hidden_effect.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;
namespace fs = std::filesystem;

nlohmann::json readJsonFile(const std::string& path) { return nlohmann::json::parse(std::ifstream(path)); }

// A campaign of `n` random poses of `cell`'s robot read by its tracker, written to <dir>/campaign.csv and calibrated
// with `cellcal calibrate --robot <dir>/robot.yaml --save-robot saved` (the robot file written before).
void calibrateOnRandomPoses(const std::string& dir, const SimulatedCell& cell, int n, MeasurementKind kind,
                            std::mt19937_64& rng, const std::string& saved) {
  MeasurementFile c;
  for (const auto& q : cell.randomConfigurations(n, rng)) {
    const Observation o = cell.measure(q, 0.0, rng, kind);
    MeasurementRow row;
    row.q_rad = q;
    row.position_m = o.measured_in_tracker.translation();
    if (kind == MeasurementKind::kPose6D) row.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
    c.rows.push_back(row);
  }
  {
    std::ofstream out(dir + "/campaign.csv");
    writeMeasurementCsv(out, c, cell.model().numJoints(), "calibration campaign");
  }
  Process cal(dir, "calibrate", {"cellcal", "calibrate", "--robot", dir + "/robot.yaml", "--data", dir + "/campaign.csv",
                                 "--save-robot", saved});
  ASSERT_EQ(cal.wait(120), 0) << cal.log();
}

TEST(CliIso9283, PlannedRunMeasuredAndReportedBeforeAndAfterCalibration) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  RandomDraw d = randomDraw(rng);
  d.kind = MeasurementKind::kPose6D;
  const SimulatedCell cell(robot(d.name), d.sc);
  const RobotModel& m = cell.model();
  SCOPED_TRACE(d.name);
  // The robot file the user has: the nominal model with the cell's registration.
  saveRobotFile(dir + "/robot.yaml", m, nullptr, "the nominal " + m.name + " with this cell's registration");

  Process plan(dir, "plan", {"cellcal", "plan", "iso9283", "--robot", dir + "/robot.yaml", "--cycles", "10",
                             "--candidates", "15", "--seed", std::to_string(seed % 100000), "--out", dir + "/program.csv",
                             "--json", dir + "/plan.json"});
  ASSERT_EQ(plan.wait(120), 0) << plan.log();
  EXPECT_NE(plan.log().find("cube edge"), std::string::npos) << plan.log();
  MeasurementCsvOptions po;
  po.joints_only = true;
  const MeasurementFile program = readMeasurementCsv(dir + "/program.csv", m, po);
  ASSERT_EQ(program.rows.size(), 50u);
  const char* order[] = {"P1", "P5", "P4", "P3", "P2"};
  for (size_t i = 0; i < program.rows.size(); ++i) {
    EXPECT_EQ(*program.rows[i].pose, order[i % 5]);
    EXPECT_EQ(*program.rows[i].cycle, static_cast<long long>(i / 5 + 1));
  }
  // The planned joints reach the planned poses (forward kinematics of the file's model, base frame) to 1e-6 mm.
  const auto pj = readJsonFile(dir + "/plan.json");
  KinematicsData data(m);
  Eigen::VectorXd p0 = m.nominal;
  p0.segment<6>(m.baseParam(FrameParam::kX)).setZero();
  for (const auto& pose : pj["poses"]) {
    Eigen::VectorXd q(m.numJoints());
    for (int j = 0; j < m.numJoints(); ++j) q[j] = degToRad(pose["joints_deg"][static_cast<size_t>(j)].get<double>());
    const Eigen::Vector3d want(pose["base_mm"][0].get<double>(), pose["base_mm"][1].get<double>(), pose["base_mm"][2].get<double>());
    // joints_deg in the JSON are rounded by the printing of doubles only (17 digits): compare to 1e-6 mm.
    EXPECT_LT((forwardKinematics(m, data, p0, q).translation() * 1e3 - want).norm(), 1e-6) << pose.dump();
  }

  // The robot runs it; the tracker reads each visit.
  MeasurementFile f;
  for (const auto& r : program.rows) {
    const Observation o = cell.measure(r.q_rad, 0.0, rng, d.kind);
    MeasurementRow row;
    row.q_rad = r.q_rad;
    row.position_m = o.measured_in_tracker.translation();
    row.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
    row.pose = r.pose;
    row.cycle = r.cycle;
    f.rows.push_back(row);
  }
  {
    std::ofstream out(dir + "/test.csv");
    writeMeasurementCsv(out, f, m.numJoints(), "ISO 9283 test of a simulated " + m.name);
  }
  // A calibration of the same robot on 150 other poses (random), saved.
  ASSERT_NO_FATAL_FAILURE(calibrateOnRandomPoses(dir, cell, 150, d.kind, rng, dir + "/cal.yaml"));

  Process iso(dir, "iso9283", {"cellcal", "iso9283", "--robot", dir + "/robot.yaml", "--data", dir + "/test.csv",
                               "--model-robot", dir + "/cal.yaml", "--json", dir + "/iso.json", "--report", dir + "/report"});
  ASSERT_EQ(iso.wait(60), 0) << iso.log();
  const auto j = readJsonFile(dir + "/iso.json");
  ASSERT_EQ(j["poses"].size(), 5u) << j.dump();
  const Eigen::VectorXd truth = cell.trueParams(0.0);
  const int b = m.baseParam(FrameParam::kX);
  const Pose base = poseFromXyzRpy(m.nominal[b], m.nominal[b + 1], m.nominal[b + 2], m.nominal[b + 3], m.nominal[b + 4],
                                   m.nominal[b + 5]);
  double before = 0, after = 0;
  for (size_t k = 0; k < 5; ++k) {
    const auto& p = j["poses"][k];
    EXPECT_EQ(p["n"], 10);
    for (const char* key : {"AP_mm", "AP_a_deg", "AP_b_deg", "AP_c_deg", "RP_mm", "RP_a_deg", "RP_b_deg", "RP_c_deg"})
      EXPECT_TRUE(p[key].is_number()) << key << " " << p.dump();
    // Against the nominal model: the truth's error at the pose's joints (in the base frame), within what noise leaves
    // in a 10-visit barycentre (6 sigma of 30 um per axis over sqrt(10)).
    const int idx = std::stoi(p["name"].get<std::string>().substr(1)) - 1;
    const Eigen::VectorXd& q = program.rows[static_cast<size_t>(idx == 0 ? 0 : 5 - idx)].q_rad;
    const Eigen::Vector3d want = base.inverse() * forwardKinematics(m, data, truth, q).translation() -
                                 base.inverse() * forwardKinematics(m, data, m.nominal, q).translation();
    EXPECT_NEAR(p["AP_mm"].get<double>(), want.norm() * 1e3, 6 * 0.03 / std::sqrt(10.0)) << p.dump();
    before += p["AP_mm"].get<double>() / 5;
    after += j["after"]["poses"][k]["AP_mm"].get<double>() / 5;
    EXPECT_NEAR(j["after"]["poses"][k]["RP_mm"].get<double>(), p["RP_mm"].get<double>(), 1e-9) << "RP is the robot's";
  }
  EXPECT_TRUE(j["AD_mm"].is_number());
  EXPECT_TRUE(j["RD_mm"].is_number());
  EXPECT_EQ(j["distances"][0]["from"], "P2");
  EXPECT_LT(after, 0.3 * before) << "compensation with the calibrated model leaves less than a third";
  EXPECT_NE(iso.log().find("what compensation with it would leave"), std::string::npos) << iso.log();
  EXPECT_TRUE(fs::exists(dir + "/report/report.md"));
  EXPECT_TRUE(isGnuplotFigure(dir + "/report/clouds.png"));
  EXPECT_TRUE(isGnuplotFigure(dir + "/report/ap_rp.png"));
  // Against a specification: the measured figures decide (exit 5 when a pose is over the bound), the calibrated
  // model's are judged as a prediction. Bounds on either side of the worst pose's measured AP_p and RP_l.
  double worst_ap = 0, worst_rp = 0, worst_ap_after = 0;
  for (size_t k = 0; k < 5; ++k) {
    worst_ap = std::max(worst_ap, j["poses"][k]["AP_mm"].get<double>());
    worst_rp = std::max(worst_rp, j["poses"][k]["RP_mm"].get<double>());
    worst_ap_after = std::max(worst_ap_after, j["after"]["poses"][k]["AP_mm"].get<double>());
  }
  for (const double scale : {0.9, 1.1}) {
    Process spec(dir, "spec", {"cellcal", "iso9283", "--robot", dir + "/robot.yaml", "--data", dir + "/test.csv",
                               "--model-robot", dir + "/cal.yaml", "--json", dir + "/spec.json", "--spec-ap-mm",
                               std::to_string(scale * worst_ap), "--spec-rp-mm", std::to_string(1.1 * worst_rp)});
    EXPECT_EQ(spec.wait(60), scale < 1 ? 5 : 0) << spec.log();
    const auto s = readJsonFile(dir + "/spec.json");
    EXPECT_EQ(s["spec_ap"]["measured"]["pass"].get<bool>(), scale > 1) << s["spec_ap"].dump();
    EXPECT_NEAR(s["spec_ap"]["measured"]["worst_mm"].get<double>(), worst_ap, 1e-9);
    EXPECT_NEAR(s["spec_ap"]["predicted_after"]["worst_mm"].get<double>(), worst_ap_after, 1e-9);
    EXPECT_TRUE(s["spec_rp"]["measured"]["pass"].get<bool>()) << s["spec_rp"].dump();
    EXPECT_NEAR(s["spec_rp"]["measured"]["worst_mm"].get<double>(), worst_rp, 1e-9);
    EXPECT_NE(spec.log().find(scale < 1 ? "FAIL as measured" : "PASS as measured"), std::string::npos) << spec.log();
  }
  std::printf("  %s: cube %.0f mm; mean AP_p %.4f mm against the nominal model, %.4f mm against the calibrated one\n",
              d.name.c_str(), pj["cube"]["edge_mm"].get<double>(), before, after);

  // Rows named by the program (no pose column): the same figures.
  MeasurementFile unnamed = f;
  for (auto& r : unnamed.rows) {
    r.pose.reset();
    r.cycle.reset();
  }
  {
    std::ofstream out(dir + "/unnamed.csv");
    writeMeasurementCsv(out, unnamed, m.numJoints(), "the same test without pose names");
  }
  Process named(dir, "by_program", {"cellcal", "iso9283", "--robot", dir + "/robot.yaml", "--data", dir + "/unnamed.csv",
                                    "--program", dir + "/program.csv", "--json", dir + "/named.json"});
  ASSERT_EQ(named.wait(60), 0) << named.log();
  const auto n = readJsonFile(dir + "/named.json");
  for (size_t k = 0; k < 5; ++k) {
    EXPECT_EQ(n["poses"][k]["name"], j["poses"][k]["name"]);
    EXPECT_NEAR(n["poses"][k]["AP_mm"].get<double>(), j["poses"][k]["AP_mm"].get<double>(), 1e-9);
    EXPECT_NEAR(n["poses"][k]["RP_mm"].get<double>(), j["poses"][k]["RP_mm"].get<double>(), 1e-9);
  }

  // Bad input, exit 2 and named: a pose with one cycle; a row without a pose; --register on the five coplanar poses;
  // a cube out of reach.
  MeasurementFile one = f;
  one.rows.resize(6);  // P1 twice, P5 .. P2 once: P2 is named first (poses in the order of their names)
  {
    std::ofstream out(dir + "/one.csv");
    writeMeasurementCsv(out, one, m.numJoints(), "one cycle");
  }
  Process short_test(dir, "one_cycle", {"cellcal", "iso9283", "--robot", dir + "/robot.yaml", "--data", dir + "/one.csv"});
  EXPECT_EQ(short_test.wait(60), 2) << short_test.log();
  EXPECT_NE(short_test.log().find("test pose P2: 1 visit(s)"), std::string::npos) << short_test.log();
  Process no_pose(dir, "no_pose", {"cellcal", "iso9283", "--robot", dir + "/robot.yaml", "--data", dir + "/unnamed.csv"});
  EXPECT_EQ(no_pose.wait(60), 2) << no_pose.log();
  EXPECT_NE(no_pose.log().find("unnamed.csv:"), std::string::npos) << no_pose.log();
  EXPECT_NE(no_pose.log().find("pose: a row without a test pose name"), std::string::npos) << no_pose.log();
  Process reg(dir, "register", {"cellcal", "iso9283", "--robot", dir + "/robot.yaml", "--data", dir + "/test.csv", "--register"});
  EXPECT_EQ(reg.wait(60), 2) << reg.log();
  EXPECT_NE(reg.log().find("--register"), std::string::npos) << reg.log();
  Process far(dir, "far", {"cellcal", "plan", "iso9283", "--robot", dir + "/robot.yaml", "--cube-centre-mm", "5000,0,500",
                           "--candidates", "3", "--out", dir + "/far.csv"});
  EXPECT_EQ(far.wait(60), 2) << far.log();
  EXPECT_NE(far.log().find("P1 (the centre)"), std::string::npos) << far.log();
  EXPECT_NE(far.log().find("closest pose found is"), std::string::npos) << far.log();
  EXPECT_FALSE(fs::exists(dir + "/far.csv"));
}

// The ISO program run through compensation and measured: a simulated cell whose engine starts from a calibration of
// its own robot (in-process, 60 random 6D readings) sends the planned program's poses as targets (`cell
// --targets-program`); the compensation publisher corrects them, the simulated tracker reads where the robot lands
// (`--landed-csv`), and `iso9283 --compensated` gives the figures. Each landed row keeps the program row's joints,
// pose and cycle; iso9283's AP is the plain one of those rows; AP after compensation is under a third of the robot's
// own error at each pose (the truth against the nominal model, at the rows' cell time), and within the cell's
// hold-out error of the calibration (plus the noise of a barycentre).
TEST(CliIso9283, AProgramRunThroughCompensationIsMeasuredWhereItLands) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  const int domain = domainForTest();
  const std::string plain_cfg = writeCell(dir, domain, seed, {{"tx60", "tx60_target"}}, "", "", "", "plain");
  const CellConfig plain = loadCellConfig(plain_cfg);
  const CellRobot& cr = plain.robots[0];
  const SimulatedCell sim = makeSimulatedCell(cr, plain.simulation, 0);
  const RobotModel& m = cr.model;
  saveRobotFile(dir + "/robot.yaml", m, nullptr, "the nominal " + m.name + " with this cell's registration");
  ASSERT_NO_FATAL_FAILURE(calibrateOnRandomPoses(dir, sim, 60, MeasurementKind::kPose6D, rng, dir + "/calibrated.yaml"));
  RobotEntry robot{"tx60", "tx60_target"};
  robot.calibration_file = dir + "/calibrated.yaml";
  const std::string cfg = writeCell(dir, domain, seed, {robot});
  Process plan(dir, "plan", {"cellcal", "plan", "iso9283", "--config", cfg, "--cycles", "6", "--candidates", "15",
                             "--seed", std::to_string(seed % 100000), "--out", dir + "/program.csv"});
  ASSERT_EQ(plan.wait(120), 0) << plan.log();
  const auto summary = runCell(dir, cfg, "4", {"--targets-program", dir + "/program.csv", "--landed-csv", dir + "/landed.csv"}, 90);
  ASSERT_FALSE(summary.is_discarded());
  const auto& r = summary["robots"][0];
  MeasurementCsvOptions po;
  po.joints_only = true;
  const MeasurementFile program = readMeasurementCsv(dir + "/program.csv", m, po);
  const MeasurementFile landed = readMeasurementCsv(dir + "/landed.csv", m);
  ASSERT_EQ(r["landed_rows"].get<std::size_t>(), landed.rows.size()) << r.dump(1);
  // Each landed row: the program row of its pose and cycle, its joints as they were.
  std::map<std::string, std::vector<const MeasurementRow*>> visits;
  for (const auto& row : landed.rows) {
    ASSERT_TRUE(row.pose && row.cycle);
    const MeasurementRow* asked = nullptr;
    for (const auto& p : program.rows)
      if (p.pose == row.pose && p.cycle == row.cycle) asked = &p;
    ASSERT_NE(asked, nullptr) << *row.pose << " cycle " << *row.cycle;
    EXPECT_LT((asked->q_rad - row.q_rad).cwiseAbs().maxCoeff(), 1e-9);
    visits[*row.pose].push_back(&row);
  }
  ASSERT_EQ(visits.size(), 5u) << "every test pose landed";
  for (const auto& [pose, v] : visits) ASSERT_GE(v.size(), 2u) << pose << ": fewer than 2 cycles answered";

  Process iso(dir, "iso9283", {"cellcal", "iso9283", "--config", cfg, "--data", dir + "/landed.csv", "--compensated",
                               "--json", dir + "/iso.json", "--spec-ap-mm", "1", "--spec-rp-mm", "1"});
  ASSERT_EQ(iso.wait(60), 0) << iso.log();
  EXPECT_NE(iso.log().find("through compensation (measured where the robot landed)"), std::string::npos) << iso.log();
  const auto j = readJsonFile(dir + "/iso.json");
  EXPECT_EQ(j["commanded_by"], "nominal, through compensation");
  const double holdout_mm = r["verify_after_mm"].get<double>();
  KinematicsData data(m);
  double after = 0, before = 0;
  for (const auto& p : j["poses"]) {
    const auto& v = visits.at(p["name"].get<std::string>());
    // Plain AP: the barycentre of the landed positions against the commanded (nominal model at the program's joints).
    Eigen::Vector3d bary = Eigen::Vector3d::Zero(), truth_error = Eigen::Vector3d::Zero();
    for (const MeasurementRow* row : v) {
      bary += row->position_m / static_cast<double>(v.size());
      truth_error += (sim.truePose(row->q_rad, *row->stamp_s / 3600).translation() -
                      forwardKinematics(m, data, m.nominal, row->q_rad).translation()) / static_cast<double>(v.size());
    }
    const Eigen::Vector3d commanded = forwardKinematics(m, data, m.nominal, v.front()->q_rad).translation();
    EXPECT_NEAR(p["AP_mm"].get<double>(), (bary - commanded).norm() * 1e3, 1e-6) << p.dump();
    EXPECT_EQ(p["n"].get<std::size_t>(), v.size());
    // Within the calibration's hold-out error of the cell, and the noise of a barycentre of n visits (tracker and
    // repeatability, 6 sigma of 30 um per axis over sqrt(n)).
    EXPECT_LT(p["AP_mm"].get<double>(), 3 * holdout_mm + 6 * 0.03 / std::sqrt(static_cast<double>(v.size()))) << p.dump();
    after += p["AP_mm"].get<double>() / 5;
    before += truth_error.norm() * 1e3 / 5;
  }
  std::printf("  AP after compensation %.4f mm (measured), the robot's own error at the test poses %.4f mm, the "
              "cell's hold-out error %.4f mm; %zu of %zu targets landed\n",
              after, before, holdout_mm, landed.rows.size(), program.rows.size());
  EXPECT_LT(after, before / 3);
  EXPECT_TRUE(j["spec_ap"]["measured"]["pass"].get<bool>()) << j["spec_ap"].dump();
  // Without the program, no landing to read; with a prediction model, refused (the data were compensated already).
  Process no_program(dir, "no_program", {"cellcal", "cell", "--config", cfg, "--landed-csv", dir + "/x.csv"});
  EXPECT_EQ(no_program.wait(30), 2) << no_program.log();
  EXPECT_NE(no_program.log().find("--landed-csv: needs --targets-program"), std::string::npos) << no_program.log();
  Process both(dir, "both", {"cellcal", "iso9283", "--config", cfg, "--data", dir + "/landed.csv", "--compensated",
                             "--model-robot", dir + "/calibrated.yaml"});
  EXPECT_EQ(both.wait(60), 2) << both.log();
}

}  // namespace
}  // namespace cellcal

namespace cellcal {
namespace {

// `cellcal plan poses` beside a cell file: the tracker at the registration's tracker frame origin; every chosen
// configuration within the limits and seen by the tracker; the chosen set's indices and predicted error beside random
// ones; a range no configuration falls in is refused with what was refused, nothing written.
// `plan iso9283 --directions 3`: the cycles in three orders in turn, each pose approached from three other test
// poses; `iso9283` then gives vAP at every pose, equal to the plain computation: the largest distance between the
// barycentres of the position deviations (attained - commanded by the nominal model) of the visits from each pose
// before them.
TEST(CliIso9283, ThreeApproachesGiveTheMultiDirectionalAccuracy) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  std::mt19937_64 rng(seed);
  RandomDraw d = randomDraw(rng);
  const SimulatedCell cell(robot(d.name), d.sc);
  const RobotModel& m = cell.model();
  SCOPED_TRACE(d.name);
  saveRobotFile(dir + "/robot.yaml", m, nullptr, "the nominal " + m.name + " with this cell's registration");
  Process plan(dir, "plan", {"cellcal", "plan", "iso9283", "--robot", dir + "/robot.yaml", "--cycles", "9",
                             "--directions", "3", "--candidates", "15", "--seed", std::to_string(seed % 100000), "--out",
                             dir + "/program.csv"});
  ASSERT_EQ(plan.wait(120), 0) << plan.log();
  MeasurementCsvOptions po;
  po.joints_only = true;
  const MeasurementFile program = readMeasurementCsv(dir + "/program.csv", m, po);
  ASSERT_EQ(program.rows.size(), 45u);
  MeasurementFile f;
  KinematicsData data(m);
  std::map<std::string, std::map<std::string, std::vector<Eigen::Vector3d>>> from;  // pose -> predecessor -> deviations
  for (size_t i = 0; i < program.rows.size(); ++i) {
    const auto& r = program.rows[i];
    const Observation o = cell.measure(r.q_rad, 0.0, rng, d.kind);
    MeasurementRow row;
    row.q_rad = r.q_rad;
    row.position_m = o.measured_in_tracker.translation();
    if (d.kind == MeasurementKind::kPose6D) row.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
    row.pose = r.pose;
    row.cycle = r.cycle;
    f.rows.push_back(row);
    if (i > 0)
      from[*r.pose][*program.rows[i - 1].pose].push_back(row.position_m -
                                                          forwardKinematics(m, data, m.nominal, r.q_rad).translation());
  }
  {
    std::ofstream out(dir + "/test.csv");
    writeMeasurementCsv(out, f, m.numJoints(), "ISO 9283 test, three approaches");
  }
  Process iso(dir, "iso9283", {"cellcal", "iso9283", "--robot", dir + "/robot.yaml", "--data", dir + "/test.csv",
                               "--json", dir + "/iso.json"});
  ASSERT_EQ(iso.wait(60), 0) << iso.log();
  const auto j = readJsonFile(dir + "/iso.json");
  ASSERT_EQ(j["poses"].size(), 5u);
  for (const auto& p : j["poses"]) {
    const std::string name = p["name"];
    ASSERT_EQ(from[name].size(), 3u) << name << " approached from " << from[name].size() << " poses";
    std::vector<Eigen::Vector3d> centres;
    for (const auto& [before, deviations] : from[name]) {
      Eigen::Vector3d c = Eigen::Vector3d::Zero();
      for (const auto& e : deviations) c += e / static_cast<double>(deviations.size());
      centres.push_back(c);
    }
    double plain = 0;
    for (size_t a = 0; a < centres.size(); ++a)
      for (size_t b = a + 1; b < centres.size(); ++b) plain = std::max(plain, (centres[a] - centres[b]).norm());
    ASSERT_TRUE(p["vAP_mm"].is_number()) << p.dump();
    EXPECT_NEAR(p["vAP_mm"].get<double>(), plain * 1e3, 1e-6) << name;
  }
}

TEST(CliPlanPoses, ChosenConfigurationsTheTrackerSeesWithTheirIndices) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  const std::string cell = std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml";
  Process plan(dir, "plan_poses", {"cellcal", "plan", "poses", "--config", cell, "--count", "20", "--candidates", "600",
                                   "--seed", std::to_string(seed % 1000000), "--range-mm", "1000,6000", "--out",
                                   dir + "/poses.csv", "--json", dir + "/poses.json"});
  ASSERT_EQ(plan.wait(120), 0) << plan.log();
  for (const char* line : {"O1 (Borm and Menq)", "O2 (inverse condition number)", "O3 (smallest singular value)",
                           "O4 (noise amplification)", "the registration's tracker frame origin"})
    EXPECT_NE(plan.log().find(line), std::string::npos) << line << "\n" << plan.log();
  const auto j = nlohmann::json::parse(std::ifstream(dir + "/poses.json"));
  EXPECT_EQ(j["chosen"]["joints_deg"].size(), 20u);
  EXPECT_LT(j["chosen"]["predicted_rms_mm"].get<double>(), j["random"]["predicted_rms_mm"].get<double>()) << j.dump();
  EXPECT_GT(j["chosen"]["indices"]["O1"].get<double>(), j["random"]["indices"]["O1"].get<double>()) << j.dump();
  const CellConfig c = loadCellConfig(cell);
  const RobotModel& m = c.robots[0].model;
  MeasurementCsvOptions po;
  po.joints_only = true;
  const MeasurementFile program = readMeasurementCsv(dir + "/poses.csv", m, po);
  ASSERT_EQ(program.rows.size(), 20u);
  TrackerSetup t;
  const int b = m.baseParam(FrameParam::kX);
  t.position_in_base_m = poseFromXyzRpy(m.nominal[b], m.nominal[b + 1], m.nominal[b + 2], m.nominal[b + 3], m.nominal[b + 4],
                                        m.nominal[b + 5])
                             .inverse()
                             .translation();
  t.min_range_m = 1.0;
  t.max_range_m = 6.0;
  for (const auto& r : program.rows) EXPECT_EQ(visibility(m, m.nominal, r.q_rad, t), Visibility::kVisible);
  Process none(dir, "no_pose", {"cellcal", "plan", "poses", "--config", cell, "--count", "5", "--candidates", "100",
                                "--range-mm", "10000,12000", "--out", dir + "/none.csv"});
  EXPECT_EQ(none.wait(60), 2) << none.log();
  EXPECT_NE(none.log().find("out of the tracker's range"), std::string::npos) << none.log();
  EXPECT_FALSE(fs::exists(dir + "/none.csv"));
}

}  // namespace
}  // namespace cellcal

namespace cellcal {
namespace {

// `cellcal plan cover`: a calibrated robot file whose extension of a joint was judged over a window of that joint's
// angles (drawn at random from the program's, each end its own share of the way out), a program of random
// configurations. The targets passed through as never judged are exactly those a plain check of the window finds,
// each named with its joint; they, and only they, are written to measure (no registration: the tracker's place is not
// known, nothing refused for sight); the others are corrected. A robot file without a calibration is refused.
TEST(CliPlanCover, TargetsWhereTheExtensionsWereNeverJudgedAreTheOnesToMeasure) {
  const std::string dir = testDir();
  std::mt19937_64 rng(testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const std::string nominal = std::string(CELLCAL_CONFIG_DIR) + "/robots/ur10.yaml";
  const RobotFile rf = loadRobotFile(nominal);
  const RobotModel& m = rf.model;
  const int joint = 1 + static_cast<int>(3 * u(rng)) % 3;  // joint 2, 3 or 4
  // The program: random configurations within 90 % of the limits.
  std::vector<Eigen::VectorXd> qs;
  for (int k = 0; k < 30; ++k) {
    Eigen::VectorXd q(m.numJoints());
    for (int j = 0; j < q.size(); ++j) {
      const double lo = std::max(m.limits[static_cast<size_t>(j)].lower_rad, -kPi),
                   hi = std::min(m.limits[static_cast<size_t>(j)].upper_rad, kPi);
      q[j] = 0.9 * (lo + (hi - lo) * u(rng)) + 0.05 * (lo + hi);
    }
    qs.push_back(q);
  }
  std::vector<double> angles;
  for (const auto& q : qs) angles.push_back(q[joint]);
  std::sort(angles.begin(), angles.end());
  RobotCalibration cal;
  cal.extensions = {Extension{Cause::kCyclicTransmission, joint}};
  cal.extension_params = Eigen::VectorXd::Zero(numExtensionParams(m, cal.extensions));
  BeyondRange b;
  b.joint = joint;
  // The window's ends halfway between the program's angles (the robot file keeps them to its own precision).
  const auto lo = static_cast<size_t>(6 + 4 * u(rng)), hi = static_cast<size_t>(19 + 4 * u(rng));
  b.lower_rad = 0.5 * (angles[lo] + angles[lo + 1]);
  b.upper_rad = 0.5 * (angles[hi] + angles[hi + 1]);
  b.checked_rad = (0.2 + 0.5 * u(rng)) * std::min(b.lower_rad - angles.front(), angles.back() - b.upper_rad);
  cal.beyond_data = {b};
  std::ofstream(dir + "/calibrated.yaml") << robotFileText(m, &cal, "plan cover test");
  std::ostringstream csv;
  csv.precision(17);
  for (int j = 1; j <= m.numJoints(); ++j) csv << "q" << j << "_rad" << (j < m.numJoints() ? "," : "\n");
  for (const auto& q : qs)
    for (int j = 0; j < q.size(); ++j) csv << q[j] << (j + 1 < q.size() ? "," : "\n");
  std::ofstream(dir + "/program.csv") << csv.str();
  Process cover(dir, "plan_cover", {"cellcal", "plan", "cover", "--robot", nominal, "--calibration", dir + "/calibrated.yaml",
                                    "--program", dir + "/program.csv", "--around", "2", "--around-deg", "3",
                                    "--out", dir + "/measure.csv"});
  ASSERT_EQ(cover.wait(120), 0) << cover.log();
  // Plain reference: the joint's angle farther beyond the window than judged.
  std::vector<int> expected;
  for (size_t i = 0; i < qs.size(); ++i)
    if (qs[i][joint] < b.lower_rad - b.checked_rad || qs[i][joint] > b.upper_rad + b.checked_rad)
      expected.push_back(static_cast<int>(i));
  std::printf("  joint %d window [%.1f, %.1f] deg judged %.1f deg beyond: %zu of 30 targets farther\n", joint + 1,
              b.lower_rad * 180 / kPi, b.upper_rad * 180 / kPi, b.checked_rad * 180 / kPi, expected.size());
  EXPECT_NE(cover.log().find("passed through where the model's extensions were never judged: " + std::to_string(expected.size())),
            std::string::npos) << cover.log();
  EXPECT_NE(cover.log().find("corrected: " + std::to_string(30 - expected.size())), std::string::npos) << cover.log();
  for (int i : expected)
    EXPECT_NE(cover.log().find("row " + std::to_string(i + 1) + ": joint " + std::to_string(joint + 1) + " at "),
              std::string::npos) << i << "\n" << cover.log();
  MeasurementCsvOptions po;
  po.joints_only = true;
  const MeasurementFile measure = readMeasurementCsv(dir + "/measure.csv", m, po);
  // Each target, then 2 configurations around it: every joint within 3 deg of the target's, within the limits.
  ASSERT_EQ(measure.rows.size(), 3 * expected.size()) << cover.log();
  for (size_t k = 0; k < expected.size(); ++k) {
    const Eigen::VectorXd& target = qs[static_cast<size_t>(expected[k])];
    const std::string name = "row " + std::to_string(expected[k] + 1);
    EXPECT_TRUE(measure.rows[3 * k].q_rad.isApprox(target, 1e-15)) << k;
    EXPECT_EQ(measure.rows[3 * k].pose.value_or(""), name);
    for (size_t n = 1; n <= 2; ++n) {
      const MeasurementRow& near = measure.rows[3 * k + n];
      EXPECT_EQ(near.pose.value_or(""), name + " around " + std::to_string(n));
      EXPECT_LE((near.q_rad - target).cwiseAbs().maxCoeff(), 3 * kPi / 180 + 1e-12) << name;
      EXPECT_GT((near.q_rad - target).cwiseAbs().maxCoeff(), 0) << name;
      EXPECT_TRUE(m.withinLimits(near.q_rad)) << name;
    }
  }
  // The guard off: the same targets corrected with their error not known, said and written to measure all the same.
  Process blind(dir, "plan_cover_blind", {"cellcal", "plan", "cover", "--robot", nominal, "--calibration",
                                          dir + "/calibrated.yaml", "--program", dir + "/program.csv",
                                          "--max-predicted-sigma-mm", "0", "--around", "0", "--out", dir + "/blind.csv"});
  ASSERT_EQ(blind.wait(120), 0) << blind.log();
  EXPECT_NE(blind.log().find("never judged (the guard off): " + std::to_string(expected.size())), std::string::npos)
      << blind.log();
  EXPECT_EQ(readMeasurementCsv(dir + "/blind.csv", m, po).rows.size(), expected.size()) << blind.log();
  // Corrected beyond the window within the judged distance: said in the run above; with --beyond-data written to
  // measure too, after the never-judged ones' in the program's order.
  std::vector<int> beyond, both;
  for (size_t i = 0; i < qs.size(); ++i) {
    const double q = qs[i][joint];
    const bool near = (q < b.lower_rad && q >= b.lower_rad - b.checked_rad) || (q > b.upper_rad && q <= b.upper_rad + b.checked_rad);
    if (near) beyond.push_back(static_cast<int>(i));
    if (near || std::count(expected.begin(), expected.end(), static_cast<int>(i))) both.push_back(static_cast<int>(i));
  }
  EXPECT_NE(cover.log().find("(within the distance they were judged): " + std::to_string(beyond.size())), std::string::npos)
      << cover.log();
  for (int i : beyond)
    EXPECT_NE(cover.log().find("row " + std::to_string(i + 1) + ": joint " + std::to_string(joint + 1) + " at "),
              std::string::npos) << i << "\n" << cover.log();
  Process wide(dir, "plan_cover_beyond", {"cellcal", "plan", "cover", "--robot", nominal, "--calibration",
                                          dir + "/calibrated.yaml", "--program", dir + "/program.csv", "--beyond-data",
                                          "--around", "0", "--out", dir + "/beyond.csv"});
  ASSERT_EQ(wide.wait(120), 0) << wide.log();
  const MeasurementFile beyond_rows = readMeasurementCsv(dir + "/beyond.csv", m, po);
  ASSERT_EQ(beyond_rows.rows.size(), both.size()) << wide.log();
  for (size_t k = 0; k < both.size(); ++k)
    EXPECT_EQ(beyond_rows.rows[k].pose.value_or(""), "row " + std::to_string(both[k] + 1)) << wide.log();
  // A robot file without a calibration section.
  Process bare(dir, "plan_cover_bare", {"cellcal", "plan", "cover", "--robot", nominal, "--calibration", nominal,
                                        "--program", dir + "/program.csv", "--out", dir + "/bare.csv"});
  EXPECT_EQ(bare.wait(60), 2) << bare.log();
  EXPECT_NE(bare.log().find("not a calibrated robot file"), std::string::npos) << bare.log();
  EXPECT_FALSE(fs::exists(dir + "/bare.csv"));
}

}  // namespace
}  // namespace cellcal
