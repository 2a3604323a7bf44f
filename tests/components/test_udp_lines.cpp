// The `udp` sources' line formats (docs/udp-sources.md): random valid lines read back exactly; every kind of bad line
// refused with the field named.
#include <gtest/gtest.h>

#include <iomanip>
#include <random>
#include <sstream>

#include "cellcal/components/udp_lines.hpp"
#include "test_support.hpp"

namespace cellcal::components {
namespace {

const CellConfig& cell() {
  static const CellConfig c = loadCellConfig(std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml");
  return c;
}

TEST(UdpLines, RandomJointLinesReadBack) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-3, 3);
  const CellRobot& r = cell().robots.front();
  for (int k = 0; k < 200; ++k) {
    const std::int64_t stamp = k % 5 == 0 ? 0 : static_cast<std::int64_t>(rng() >> 2);
    const bool settled = rng() % 2;
    std::ostringstream line;
    line << std::setprecision(17) << r.robot_id << (k % 3 ? " " : "\t ") << stamp << " " << settled;
    Eigen::VectorXd q(r.model.numJoints());
    for (int j = 0; j < q.size(); ++j) line << " " << (q[j] = u(rng));
    std::string why;
    const auto got = parseJointLine(line.str(), cell(), &why);
    ASSERT_TRUE(got) << why << ": " << line.str();
    EXPECT_EQ(got->robot, &r);
    EXPECT_EQ(got->stamp_ns, stamp);
    EXPECT_EQ(got->settled, settled);
    EXPECT_EQ(got->q_rad, q);
  }
}

TEST(UdpLines, RandomTrackerLinesReadBackInEveryLength) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-3, 3);
  const CellRobot& r = cell().robots.front();
  for (int fields : {6, 8, 10, 12})
    for (int k = 0; k < 50; ++k) {
      std::vector<double> v;
      for (int i = 0; i < fields - 3; ++i) v.push_back(u(rng));
      std::ostringstream line;
      line << std::setprecision(17) << r.target_id << " " << k << " " << (k % 2);
      for (double x : v) line << " " << x;
      std::string why;
      const auto got = parseTrackerLine(line.str(), cell(), &why);
      ASSERT_TRUE(got) << why << ": " << line.str();
      EXPECT_EQ(got->robot, &r);
      EXPECT_EQ(got->stamp_ns, k);
      EXPECT_EQ(got->valid, k % 2 == 1);
      EXPECT_EQ(got->position_m, Eigen::Vector3d(v[0], v[1], v[2]));
      EXPECT_EQ(got->orientation_xyzw.has_value(), fields >= 10);
      if (fields >= 10) {
        EXPECT_EQ(*got->orientation_xyzw, (std::array<double, 4>{v[3], v[4], v[5], v[6]}));
      }
      EXPECT_EQ(got->sigma_position_m, fields == 8 ? v[3] : fields == 12 ? v[7] : 0.0);
      EXPECT_EQ(got->sigma_orientation_rad, fields == 8 ? v[4] : fields == 12 ? v[8] : 0.0);
    }
}

TEST(UdpLines, BadLinesNameTheField) {
  const CellRobot& r = cell().robots.front();
  const std::string id = r.robot_id, target = r.target_id;
  auto jointError = [&](const std::string& line) {
    std::string why;
    EXPECT_FALSE(parseJointLine(line, cell(), &why)) << line;
    return why;
  };
  auto trackerError = [&](const std::string& line) {
    std::string why;
    EXPECT_FALSE(parseTrackerLine(line, cell(), &why)) << line;
    return why;
  };
  EXPECT_EQ(jointError(""), "empty line");
  EXPECT_EQ(jointError("nobody 0 1 0 0 0 0 0 0"), "unknown robot_id 'nobody'");
  EXPECT_EQ(jointError(id + " 0 1 0 0 0"), "expected 3 + 6 fields, got 6");
  EXPECT_EQ(jointError(id + " -5 1 0 0 0 0 0 0"), "field 2 (stamp_ns): '-5' is not a non-negative integer");
  EXPECT_EQ(jointError(id + " 0 2 0 0 0 0 0 0"), "field 3 (settled): expected 0 or 1, got '2'");
  EXPECT_EQ(jointError(id + " 0 1 0 0 nan 0 0 0"), "field 6 (q3_rad): 'nan' is not a finite number");
  EXPECT_EQ(jointError(id + " 0 1 0 0 0 0 0 1e999"), "field 9 (q6_rad): '1e999' is not a finite number");
  EXPECT_EQ(trackerError(target), "expected 6, 8, 10 or 12 fields, got 1");
  EXPECT_EQ(trackerError("elsewhere 0 1 1 2 3"), "unknown target_id 'elsewhere'");
  EXPECT_EQ(trackerError(target + " 0 1 1 2 3 4"), "expected 6, 8, 10 or 12 fields, got 7");
  EXPECT_EQ(trackerError(target + " x 1 1 2 3"), "field 2 (stamp_ns): 'x' is not a non-negative integer");
  EXPECT_EQ(trackerError(target + " 0 yes 1 2 3"), "field 3 (valid): expected 0 or 1, got 'yes'");
  EXPECT_EQ(trackerError(target + " 0 1 1 2 3m"), "field 6: '3m' is not a finite number");
}

}  // namespace
}  // namespace cellcal::components
