// CSV v1 measurement files: columns, units, optional orientation, and errors naming file:line:column.
#include <gtest/gtest.h>

#include <random>
#include <sstream>

#include "cellcal/core/ipa_dataset.hpp"
#include "cellcal/core/measurement_csv.hpp"
#include "cellcal/core/simulation.hpp"
#include "test_support.hpp"

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

}  // namespace
}  // namespace cellcal

// ---- the ipa series reader and registration (appended suite) ----
#include <filesystem>
#include <fstream>

#include "cellcal/core/ipa_dataset.hpp"
#include "cellcal/core/kinematics.hpp"
#include "cellcal/core/registration.hpp"
#include "cellcal/core/simulation.hpp"

namespace cellcal {
namespace {

std::string writeTemp(const std::string& name, const std::string& text) {
  const auto p = std::filesystem::temp_directory_path() / (name + std::to_string(::getpid()));
  std::ofstream(p) << text;
  return p.string();
}

const std::string kIpaHeader =
    "Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;shoulder_lift_joint;elbow_joint;"
    "wrist_1_joint;wrist_2_joint;wrist_3_joint;measurement_temperature;measurement_x;measurement_y;measurement_z;"
    "measurement_rx;measurement_ry;measurement_rz\n";

TEST(IpaSeries, DecimalCommasEulerXYZAndStamps) {
  const std::string p = writeTemp("ipa_a", kIpaHeader +
                                               "20200714163904;0,3;0;1,4;0;0;0;-1,5708;-1,5708;0,0;-1,5708;0,0;0,0;23,68;2361,9831;-1368,5474;119,39713;90;0;0\n"
                                               "20200714163924;0,8;0,6;0,9;0;0;0;-2,1;-2,0;-0,8;-0,2;0,39;0,0;23,70;1685,2797;-1665,3456;-415,81103;10;20;30\n");
  std::string notes;
  const MeasurementFile f = readIpaSeries(p, test::robot("ur10"), &notes);
  ASSERT_EQ(f.rows.size(), 2u);
  EXPECT_NEAR(f.rows[0].q_rad[0], -1.5708, 1e-12);
  EXPECT_NEAR(f.rows[0].position_m.x(), 2.3619831, 1e-12);
  EXPECT_NEAR(*f.rows[0].temperature_c, 23.68, 1e-12);
  EXPECT_EQ(*f.rows[1].stamp_s, 20.0);
  // Intrinsic X-Y-Z: R = Rx(a) Ry(b) Rz(c).
  EXPECT_TRUE(f.rows[0].orientation->toRotationMatrix().isApprox(
      Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitX()).toRotationMatrix(), 1e-12));
  const Eigen::Matrix3d R = (Eigen::AngleAxisd(degToRad(10), Eigen::Vector3d::UnitX()) *
                             Eigen::AngleAxisd(degToRad(20), Eigen::Vector3d::UnitY()) *
                             Eigen::AngleAxisd(degToRad(30), Eigen::Vector3d::UnitZ())).toRotationMatrix();
  EXPECT_TRUE(f.rows[1].orientation->toRotationMatrix().isApprox(R, 1e-12));
  EXPECT_NE(notes.find("0.01 h"), std::string::npos) << notes;
  // Round trip through CSV v1.
  std::ostringstream csv;
  writeMeasurementCsv(csv, f, 6, "test");
  const MeasurementFile back = parseMeasurementCsv(csv.str(), "back.csv", test::robot("ur10"));
  ASSERT_EQ(back.rows.size(), 2u);
  EXPECT_NEAR((back.rows[1].position_m - f.rows[1].position_m).norm(), 0, 1e-12);
  EXPECT_NEAR(back.rows[1].orientation->angularDistance(*f.rows[1].orientation), 0, 1e-9);
  EXPECT_EQ(*back.rows[1].stamp_s, 20.0);
  std::filesystem::remove(p);
}

// Series A's rows are not all in time order and its stamps span days with long pauses: rows are written in time
// order and the notes say so.
TEST(IpaSeries, RowsOutOfTimeOrderAreWrittenInTimeOrderAndSessionsCounted) {
  const std::string row = ";0;0;0;0;0;0;-1,5708;-1,5708;0,0;-1,5708;0,0;0,0;23;1;2;3;0;0;0\n";
  const std::string p = writeTemp("ipa_order", kIpaHeader + "20200714163904" + row + "20200714170904" + row +
                                                   "20200715000000" + row + "20200714164904" + row);
  std::string notes;
  const MeasurementFile f = readIpaSeries(p, test::robot("ur10"), &notes);
  ASSERT_EQ(f.rows.size(), 4u);
  std::vector<double> t;
  for (const auto& r : f.rows) t.push_back(*r.stamp_s);
  EXPECT_EQ(t, (std::vector<double>{0.0, 600.0, 1800.0, 26456.0}));
  EXPECT_EQ(f.rows[1].line, 5);  // the row keeps its source line
  EXPECT_NE(notes.find("2 session(s)"), std::string::npos) << notes;
  EXPECT_NE(notes.find("1 rows out of time order"), std::string::npos) << notes;
  std::filesystem::remove(p);
}

TEST(IpaSeries, DamagedStampsKeepRowOrderAndBadCellsNameLineAndColumn) {
  const std::string ok = writeTemp("ipa_b", kIpaHeader +
                                                "2,02011E+13;0;0;0;0;0;0;0;0;0;0;0;0;22;1;2;3;0;0;0\n");
  std::string notes;
  const MeasurementFile f = readIpaSeries(ok, test::robot("ur10"), &notes);
  EXPECT_FALSE(f.rows[0].stamp_s.has_value());
  EXPECT_NE(notes.find("row order only"), std::string::npos);
  const std::string bad = writeTemp("ipa_c", kIpaHeader + "20200714163904;0;0;0;0;0;0;0;0;x;0;0;0;22;1;2;3;0;0;0\n");
  try {
    readIpaSeries(bad, test::robot("ur10"));
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(":2:10: elbow_joint: 'x' is not a number"), std::string::npos) << e.what();
  }
  std::filesystem::remove(ok);
  std::filesystem::remove(bad);
}

TEST(Registration, FindsAnUnknownBaseAndToolFromMeasurements) {
  // The robot stands somewhere in the tracker frame (random position and yaw); the registration only sees nominal
  // kinematics and measurements.
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  SimulationConfig sc;
  sc.seed = seed;
  sc.base_in_tracker << 3 * u(rng), 3 * u(rng), u(rng), 0.02 * u(rng), 0.02 * u(rng), kPi * u(rng);
  sc.tool_in_flange << 0.1 * u(rng), 0.1 * u(rng), 0.05 + 0.1 * std::abs(u(rng)), 0, 0, 0;
  const SimulatedCell cell(test::robot("ur10"), sc);
  std::vector<Observation> obs;
  for (const auto& q : cell.randomConfigurations(60, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  Eigen::VectorXd start = cell.model().nominal;
  start.tail<12>().setZero();  // unknown frames
  const RegistrationResult r = registerFrames(cell.model(), start, obs);
  const int b = cell.model().baseParam(FrameParam::kX);
  // Within the size of the hidden kinematic errors (0.1-0.5 mm, 0.01-0.05 deg over a 1.3 m arm).
  EXPECT_LT(r.rms_position_m, 3e-3);
  EXPECT_LT((r.params.segment<3>(b) - sc.base_in_tracker.head<3>()).norm(), 0.01);
  EXPECT_NEAR(std::remainder(r.params[b + 5] - sc.base_in_tracker[5], 2 * kPi), 0, 0.01);
}

}  // namespace
}  // namespace cellcal
