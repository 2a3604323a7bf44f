// CSV v1 measurement files: columns, units, optional orientation, and errors naming file:line:column.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <sstream>

#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "test_support.hpp"
#include "../identification/hidden_effect.hpp"

namespace cellcal {
namespace {

const std::string kHeader = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,qw,qx,qy,qz,stamp_s,group,operator\n";

std::string errorOf(const std::string& text, bool skip = false) {
  try {
    MeasurementCsvOptions o;
    o.skip_bad_rows = skip;
    parseMeasurementCsv(text, "m.csv", test::robot("staubli_tx60"), o);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(MeasurementCsv, ReadsRowsUnitsAndOptionalOrientation) {
  const RobotModel m = test::robot("staubli_tx60");
  const auto f = parseMeasurementCsv("# campaign 1\n# tracker AT960\n" + kHeader +
                                         "10,20,30,40,50,60,1000.5,-20,300,1,0,0,0,0.5,2,anna\n"
                                         "0,0,0,0,0,0,1,2,3,,,,,1.5,2,bob\n",
                                     "m.csv", m);
  ASSERT_EQ(f.rows.size(), 2u);
  EXPECT_EQ(f.rows[0].line, 4);
  EXPECT_NEAR(f.rows[0].q_rad[1], 20 * kPi / 180, 1e-15);
  EXPECT_NEAR(f.rows[0].position_m.x(), 1.0005, 1e-15);
  ASSERT_TRUE(f.rows[0].orientation.has_value());
  EXPECT_FALSE(f.rows[1].orientation.has_value());
  EXPECT_EQ(*f.rows[1].group, 2);
  EXPECT_EQ(*f.rows[1].stamp_s, 1.5);
  ASSERT_EQ(f.ignored_columns.size(), 1u);
  EXPECT_EQ(f.ignored_columns[0], "operator");
  EXPECT_EQ(toObservation(f.rows[1], MeasurementKind::kPose6D, 1e-5, 1e-4).kind, MeasurementKind::kPosition3D);
}

TEST(MeasurementCsv, BadRowsNameFileLineAndColumn) {
  EXPECT_EQ(errorOf(kHeader + "10,20,abc,40,50,60,1,2,3,,,,,0,1,x\n"), "m.csv:2:3: q3_deg: 'abc' is not a finite number");
  EXPECT_EQ(errorOf(kHeader + "10,20,30,40,50,60,1,,3,,,,,0,1,x\n"), "m.csv:2:8: y_mm: missing value");
  EXPECT_NE(errorOf(kHeader + "10,20,30,40,200,60,1,2,3,,,,,0,1,x\n").find("m.csv:2:5: q5_deg: joint outside its limits"),
            std::string::npos);
  EXPECT_NE(errorOf(kHeader + "10,20,30,40,50,60,1,2,3,1,1,0,0,0,1,x\n").find("m.csv:2:10: qw: quaternion norm"),
            std::string::npos);
  EXPECT_NE(errorOf(kHeader + "10,20,30,40,50,60,1,2,3,1,,0,0,0,1,x\n").find("m.csv:2:11: qx: missing value"),
            std::string::npos);
  EXPECT_NE(errorOf(kHeader + "10,20,30,40,50,60,1,2,nan,,,,,0,1,x\n").find("z_mm: 'nan' is not a finite number"),
            std::string::npos);
  EXPECT_NE(errorOf("q1_deg,x_mm,y_mm,z_mm\n1,2,3,4\n").find("missing column q2_deg"), std::string::npos);
  EXPECT_NE(errorOf("# only comments\n").find("no header row"), std::string::npos);
}

// A measured file (random robot, poses and count) is read as written; the same file with its positions written in
// metres is refused, naming the file, the header line and x_mm's column.
// The setup column: labels read, written and read back; an over-long label named with its line and column.
TEST(MeasurementCsv, SetupLabelsRoundTrip) {
  const std::string text = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,setup\n"
                           "10,20,30,40,50,60,1000,2000,300,north\n"
                           "11,21,31,41,51,61,1010,2010,310,after-move\n"
                           "12,22,32,42,52,62,1020,2020,320, north \n";
  const auto f = parseMeasurementCsv(text, "m.csv", test::robot("staubli_tx60"));
  ASSERT_EQ(f.rows.size(), 3u);
  EXPECT_EQ(f.rows[0].setup.value_or("?"), "north");
  EXPECT_EQ(f.rows[1].setup.value_or("?"), "after-move");
  EXPECT_EQ(f.rows[2].setup.value_or("?"), "north");
  std::ostringstream out;
  writeMeasurementCsv(out, f, 6, "");
  const auto back = parseMeasurementCsv(out.str(), "back.csv", test::robot("staubli_tx60"));
  for (size_t i = 0; i < 3; ++i) EXPECT_EQ(back.rows[i].setup, f.rows[i].setup);
  EXPECT_NE(errorOf("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,setup\n10,20,30,40,50,60,1,2,3," +
                    std::string(65, 'a') + "\n")
                .find("m.csv:2:10: setup: a set-up label has at most 64 characters"),
            std::string::npos);
}

// The ISO 9283 columns: each row's test pose and cycle, read, written and read back; a robot program is the joint
// columns with them and no readings (joints_only), refused as measurements; bad values named.
TEST(MeasurementCsv, PoseAndCycleRoundTripAndAProgramHasNoReadings) {
  const RobotModel m = test::robot("staubli_tx60");
  const std::string text = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,pose,cycle\n"
                           "10,20,30,40,50,60,1000,2000,300,P1,1\n"
                           "11,21,31,41,51,61,1010,2010,310,P5,1\n"
                           "12,22,32,42,52,62,1020,2020,320,P1,2\n";
  const auto f = parseMeasurementCsv(text, "m.csv", m);
  ASSERT_EQ(f.rows.size(), 3u);
  EXPECT_EQ(f.rows[1].pose.value_or("?"), "P5");
  EXPECT_EQ(f.rows[2].cycle.value_or(-1), 2);
  EXPECT_TRUE(f.ignored_columns.empty());
  std::ostringstream out;
  writeMeasurementCsv(out, f, 6, "");
  const auto back = parseMeasurementCsv(out.str(), "back.csv", m);
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(back.rows[i].pose, f.rows[i].pose);
    EXPECT_EQ(back.rows[i].cycle, f.rows[i].cycle);
  }
  const std::string program = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,pose,cycle\n10,20,30,40,50,60,P1,1\n"
                              "11,21,31,41,51,61,P5,1\n";
  MeasurementCsvOptions po;
  po.joints_only = true;
  const auto p = parseMeasurementCsv(program, "program.csv", m, po);
  ASSERT_EQ(p.rows.size(), 2u);
  EXPECT_NEAR(p.rows[1].q_rad[5], degToRad(61), 1e-15);
  EXPECT_EQ(p.rows[1].pose.value_or("?"), "P5");
  EXPECT_NE(errorOf(program).find("m.csv:1:1: header: missing column x_mm"), std::string::npos) << errorOf(program);
  EXPECT_NE(errorOf("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,pose,cycle\n10,20,30,40,50,60,1,2,3,P1,1.5\n")
                .find("m.csv:2:11: cycle: expected an integer"),
            std::string::npos);
  EXPECT_NE(errorOf("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,pose\n10,20,30,40,50,60,1,2,3,\"P1\"\n")
                .find("m.csv:2:10: pose: a pose name may not contain quotes"),
            std::string::npos);
}

TEST(MeasurementCsv, MetresInMillimetreColumnsAreCalledOut) {
  std::mt19937_64 rng(test::testSeed());
  for (int trial = 0; trial < 20; ++trial) {
    const RobotModel m = test::robot(rng() % 2 ? "staubli_tx60" : "ur10");
    SimulationConfig sc;
    sc.seed = rng();
    const SimulatedCell cell(m, sc);
    MeasurementFile f;
    for (const auto& q : cell.randomConfigurations(3 + static_cast<int>(rng() % 40), rng)) {
      MeasurementRow r;
      r.q_rad = q;
      r.position_m = cell.measure(q, 0.0, rng).measured_in_tracker.translation();
      f.rows.push_back(r);
    }
    std::ostringstream good, metres;
    writeMeasurementCsv(good, f, m.numJoints(), "");
    EXPECT_EQ(parseMeasurementCsv(good.str(), "m.csv", cell.model()).rows.size(), f.rows.size());
    for (auto& r : f.rows) r.position_m /= 1000.0;  // what a file with metres in x_mm reads as
    writeMeasurementCsv(metres, f, m.numJoints(), "");
    try {
      parseMeasurementCsv(metres.str(), "m.csv", cell.model());
      ADD_FAILURE() << "metres accepted, " << f.rows.size() << " rows";
    } catch (const ConfigError& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.rfind("m.csv:", 0), 0u) << what;
      EXPECT_NE(what.find(": x_mm, y_mm, z_mm: "), std::string::npos) << what;
      EXPECT_NE(what.find("metres written where millimetres are expected"), std::string::npos) << what;
    }
  }
}

// What a file of a tracker's export gets wrong: a measured file (robot, tracker, target, pose count drawn at random,
// 6D) is read as written; the same file with its joints in radians under the _deg header, its quaternions in x, y,
// z, w order under qw, qx, qy, qz, separated by ';', or with only its header is refused with the likely cause and the
// header line. Random 3D files and files of a robot that barely moves are not refused.
TEST(MeasurementCsv, WrongUnitsOrderOrSeparatorAreCalledOut) {
  std::mt19937_64 rng(test::testSeed());
  auto refusal = [](const std::string& text, const RobotModel& m) -> std::string {
    try {
      parseMeasurementCsv(text, "m.csv", m);
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "";
  };
  auto replaceFirst = [](std::string s, const std::string& from, const std::string& to) {
    const auto at = s.find(from);
    if (at != std::string::npos) s.replace(at, from.size(), to);
    return s;
  };
  for (int trial = 0; trial < 30; ++trial) {
    const test::RandomDraw d = test::randomDraw(rng);
    const RobotModel m = test::robot(d.name);
    const SimulatedCell cell(m, d.sc);
    MeasurementFile f;
    const bool oriented = trial % 3 != 2;
    for (const auto& q : cell.randomConfigurations(6 + static_cast<int>(rng() % 60), rng)) {
      MeasurementRow r;
      r.q_rad = q;
      const Observation o = cell.measure(q, 0.0, rng);
      r.position_m = o.measured_in_tracker.translation();
      if (oriented) r.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
      f.rows.push_back(r);
    }
    std::ostringstream out;
    writeMeasurementCsv(out, f, m.numJoints(), "");
    const std::string good = out.str();
    SCOPED_TRACE(d.name + ", " + std::to_string(f.rows.size()) + " rows" + (oriented ? ", 6D" : ", 3D"));
    EXPECT_EQ(refusal(good, m), "");
    // The header is the first line: q1_rad,...  Radians under _deg names.
    std::string header = good.substr(0, good.find('\n'));
    std::string as_deg = header;
    for (auto at = as_deg.find("_rad"); at != std::string::npos; at = as_deg.find("_rad")) as_deg.replace(at, 4, "_deg");
    const std::string rad_in_deg = refusal(replaceFirst(good, header, as_deg), m);
    EXPECT_EQ(rad_in_deg.rfind("m.csv:1:1: q1_deg..q" + std::to_string(m.numJoints()) + "_deg: ", 0), 0u) << rad_in_deg;
    EXPECT_NE(rad_in_deg.find("radians written where degrees are expected"), std::string::npos) << rad_in_deg;
    // ';' between the columns.
    std::string semi = good;
    std::replace(semi.begin(), semi.end(), ',', ';');
    const std::string semi_why = refusal(semi, m);
    EXPECT_EQ(semi_why.rfind("m.csv:1:1: header: one column", 0), 0u) << semi_why;
    EXPECT_NE(semi_why.find("separated by ';'"), std::string::npos) << semi_why;
    // Only the header.
    EXPECT_EQ(refusal(header + "\n", m), "m.csv:1: no data rows after the header");
    if (!oriented) continue;
    // x, y, z, w values under qw, qx, qy, qz: the reader takes the file's x as w, y as x, z as y and w as z, which is
    // what renaming the columns qw, qx, qy, qz as qz, qw, qx, qy does.
    const std::string xyzw = refusal(replaceFirst(good, "qw,qx,qy,qz", "qz,qw,qx,qy"), m);
    EXPECT_EQ(xyzw.rfind("m.csv:1:", 0), 0u) << xyzw;
    EXPECT_NE(xyzw.find("quaternions written in x, y, z, w order"), std::string::npos) << xyzw;
  }
  // A robot that barely moves (a few degrees about one configuration) is not taken for radians in _deg columns.
  const RobotModel m = test::robot("ur10");
  std::string text = "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n";
  KinematicsData kd(m);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int i = 0; i < 20; ++i) {
    Eigen::VectorXd q(6);
    for (int j = 0; j < 6; ++j) q[j] = u(rng);
    const Eigen::Vector3d p = forwardKinematics(m, kd, m.nominal, q * kPi / 180).translation() * 1e3;
    for (int j = 0; j < 6; ++j) text += std::to_string(q[j]) + ",";
    text += std::to_string(p.x()) + "," + std::to_string(p.y()) + "," + std::to_string(p.z()) + "\n";
  }
  EXPECT_EQ(refusal(text, m), "");
}

TEST(MeasurementCsv, SkipBadRowsKeepsTheGoodOnesAndCountsTheRest) {
  MeasurementCsvOptions o;
  o.skip_bad_rows = true;
  const auto f = parseMeasurementCsv(kHeader + "10,20,30,40,50,60,1,2,3,,,,,0,1,x\n"
                                               "10,20,zz,40,50,60,1,2,3,,,,,0,1,x\n"
                                               "11,20,30,40,50,60,1,2,3,,,,,1,1,x\n",
                                     "m.csv", test::robot("staubli_tx60"), o);
  EXPECT_EQ(f.rows.size(), 2u);
  EXPECT_EQ(f.skipped_rows, 1);
  ASSERT_EQ(f.warnings.size(), 1u);
  EXPECT_NE(f.warnings[0].find("m.csv:3:3: q3_deg"), std::string::npos);
}

// Per-reading sigmas (a tracker's own uncertainty of each reading): read, written back, refused when not > 0, and
// used as weights: on a file where half the readings are 30x noisier, a fit that knows which lands closer to the truth
// than one that weighs every reading alike (robot, frames and noise drawn at random).
TEST(MeasurementCsv, PerReadingSigmasAreReadWrittenAndWeighTheFit) {
  const RobotModel m = test::robot("staubli_tx60");
  const auto f = parseMeasurementCsv("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,sigma_position_mm,sigma_orientation_deg\n"
                                     "10,20,30,40,50,60,1000.5,-20,300,0.02,0.004\n0,0,0,0,0,0,1,2,3,,\n",
                                     "m.csv", m);
  ASSERT_EQ(f.rows.size(), 2u);
  EXPECT_NEAR(*f.rows[0].sigma_position_m, 2e-5, 1e-18);
  EXPECT_NEAR(*f.rows[0].sigma_orientation_rad, 0.004 * kPi / 180, 1e-18);
  EXPECT_FALSE(f.rows[1].sigma_position_m.has_value());
  const Observation o0 = toObservation(f.rows[0], MeasurementKind::kPose6D, 1e-3, 1e-3);
  const Observation o1 = toObservation(f.rows[1], MeasurementKind::kPose6D, 1e-3, 1e-3);
  EXPECT_EQ(o0.sigma_position_m, 2e-5);
  EXPECT_EQ(o1.sigma_position_m, 1e-3);
  std::ostringstream out;
  writeMeasurementCsv(out, f, 6, "");
  const auto back = parseMeasurementCsv(out.str(), "back.csv", m);
  EXPECT_NEAR(*back.rows[0].sigma_position_m, 2e-5, 1e-15);
  EXPECT_FALSE(back.rows[1].sigma_position_m.has_value());
  EXPECT_NE(errorOf("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,sigma_position_mm\n1,2,3,4,5,6,1,2,3,0\n")
                .find("m.csv:2:10: sigma_position_mm: a sigma must be > 0"),
            std::string::npos);

  std::mt19937_64 rng(test::testSeed());
  SimulationConfig sc;
  sc.seed = rng();
  const SimulatedCell cell(m, sc);
  std::vector<Observation> weighted, uniform;
  std::normal_distribution<double> g(0.0, 1.0);
  for (const auto& q : cell.randomConfigurations(120, rng)) {
    const bool noisy = weighted.size() % 2 == 1;
    const double sigma_m = noisy ? 0.3e-3 : 0.01e-3;
    MeasurementRow r;
    r.q_rad = q;
    r.position_m = cell.truePose(q, 0.0).translation() + sigma_m * Eigen::Vector3d(g(rng), g(rng), g(rng));
    r.sigma_position_m = sigma_m;
    weighted.push_back(toObservation(r, MeasurementKind::kPosition3D, 0.1e-3, 0.01));
    r.sigma_position_m.reset();
    uniform.push_back(toObservation(r, MeasurementKind::kPosition3D, 0.1e-3, 0.01));
  }
  auto heldOut = [&](const std::vector<Observation>& obs) {
    Eigen::VectorXd start = m.nominal;
    start.segment(m.baseParam(FrameParam::kX), 6) = sc.base_in_tracker;
    start.segment(m.toolParam(FrameParam::kX), 6) = sc.tool_in_flange;
    const CalibrationResult res = solveGaussNewton(CalibrationProblem{&m, start, obs, std::nullopt, {}, {}});
    KinematicsData d(m);
    double s = 0;
    std::mt19937_64 qr(5);
    const auto qs = cell.randomConfigurations(200, qr);
    for (const auto& q : qs) s += (forwardKinematics(m, d, res.params, q).translation() - cell.truePose(q, 0.0).translation()).norm();
    return s / qs.size() * 1e3;
  };
  const double w = heldOut(weighted), u = heldOut(uniform);
  std::printf("model error against the truth: weighted by the readings' sigmas %.4f mm, weighted alike %.4f mm\n", w, u);
  EXPECT_LT(w, 0.8 * u);
}

}  // namespace
}  // namespace cellcal
