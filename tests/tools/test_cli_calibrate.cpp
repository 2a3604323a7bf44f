// `cellcal calibrate` and `cellcal import` as a user runs them: a measurement file of a simulated robot whose
// placement in the tracker frame is unknown to the robot file (hidden errors and placement from a fresh seed).
#include <gtest/gtest.h>

#include "cell/cell_test_support.hpp"
#include "cellcal/core/ipa_dataset.hpp"
#include "cellcal/core/kinematics.hpp"
#include "cellcal/core/simulation.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

TEST(CliCalibrate, RegistersAndCalibratesAFileToTheNoiseFloor) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  SimulationConfig sc;
  sc.seed = seed;
  const SimulatedCell cell(robot("staubli_tx60"), sc);  // base at (2.2, 0.4, -0.3) m, yaw 160 deg: not in the file
  std::mt19937_64 rng(seed);
  MeasurementFile f;
  double floor_mm = 0;
  int n = 0;
  for (const auto& q : cell.randomConfigurations(200, rng)) {
    const Observation o = cell.measure(q, 0.0, rng);
    MeasurementRow r;
    r.q_rad = q;
    r.position_m = o.measured_in_tracker.translation();
    r.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
    f.rows.push_back(r);
    if (n++ % 2 == 1) floor_mm += (o.measured_in_tracker.translation() - cell.truePose(q, 0).translation()).norm() * 1e3;
  }
  floor_mm /= 100;
  {
    std::ofstream out(dir + "/m.csv");
    writeMeasurementCsv(out, f, 6, "simulated TX60");
  }
  Process p(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml",
                               "--data", dir + "/m.csv", "--json", dir + "/r.json", "--sigma-position-mm", "0.012"});
  ASSERT_EQ(p.wait(60), 0) << p.log();
  const auto j = readJson(dir + "/r.json");
  EXPECT_TRUE(j["converged"].get<bool>());
  EXPECT_EQ(j["identification_rows"], 100);
  EXPECT_EQ(j["verification_rows"], 100);
  const double before = j["verification"]["before"]["mean_mm"], after = j["verification"]["after"]["mean_mm"];
  EXPECT_GT(before, 0.2) << p.log();
  EXPECT_LT(after, 1.3 * floor_mm) << "floor " << floor_mm << " mm\n" << p.log();
  EXPECT_LT(j["solve_time_s"].get<double>(), 5.0);
}

TEST(CliCalibrate, BadFilesAreNamedWithLineAndColumn) {
  const std::string dir = testDir();
  std::ofstream(dir + "/bad.csv") << "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n1,2,3,4,5,6,1,2,3\n1,2,3,4,5,six,1,2,3\n";
  Process p(dir, "calibrate", {"cellcal", "calibrate", "--robot", std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml",
                               "--data", dir + "/bad.csv"});
  EXPECT_NE(p.wait(30), 0);
  EXPECT_NE(p.log().find("bad.csv:3:6: q6_deg: 'six' is not a finite number"), std::string::npos) << p.log();
}

}  // namespace
}  // namespace cellcal
