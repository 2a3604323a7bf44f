// The ipa UR10 series reader (../shared/datasets/ipa-robot-accuracy): decimal commas, Euler angles, stamps, rows in
// time order, and errors naming line and column.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "cellcal/lab/ipa_dataset.hpp"
#include "test_support.hpp"

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

}  // namespace
}  // namespace cellcal
