// `cellcal import csv`, `validate` and `export` as a user runs them, on a measurement file of a simulated robot
// (hidden errors from a fresh seed): every row survives the trip CSV -> recording -> CSV, validate calibrates from
// the recording and is deterministic.
#include <gtest/gtest.h>

#include <numeric>

#include "cell/cell_test_support.hpp"
#include "cellcal/lab/ipa_dataset.hpp"
#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

TEST(CliRecording, ImportValidateAndExportKeepEveryRow) {
  const std::string dir = testDir();
  const std::uint64_t seed = testSeed();
  SimulationConfig sc;
  sc.seed = seed;
  const SimulatedCell sim(robot("staubli_tx60"), sc);
  std::mt19937_64 rng(seed);
  MeasurementFile f;
  double t_s = 0;
  const int rows = 60 + static_cast<int>(rng() % 60);
  for (const auto& q : sim.randomConfigurations(rows, rng)) {
    const Observation o = sim.measure(q, 0.0, rng);
    MeasurementRow r;
    r.q_rad = q;
    r.position_m = o.measured_in_tracker.translation();
    if (rng() % 4) r.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());  // some rows position-only
    t_s += std::uniform_real_distribution<double>(5, 60)(rng);
    r.stamp_s = std::round(t_s * 1000) / 1000;
    f.rows.push_back(r);
  }
  {
    std::ofstream out(dir + "/m.csv");
    writeMeasurementCsv(out, f, 6, "simulated TX60");
  }
  const std::string cell = dir + "/cell.yaml";
  std::ofstream(cell) << "dds: { profiles_file: " << CELLCAL_CONFIG_DIR << "/dds/cellcal_qos.xml }\n"
                      << "time_compression: 1\nrobots:\n  - { robot_id: tx60, target_id: tx60_target, robot_file: "
                      << CELLCAL_CONFIG_DIR << "/robots/staubli_tx60.yaml,\n      base_in_tracker: { x_mm: 2200, y_mm: 400, "
                      << "z_mm: -300, roll_deg: 0, pitch_deg: 0, yaw_deg: 160.43 },\n      tool_in_flange: { x_mm: 30, y_mm: 0, "
                      << "z_mm: 60, roll_deg: 0, pitch_deg: 0, yaw_deg: 0 } }\nengine: { state_dir: " << dir << "/state }\n";
  Process imp(dir, "import", {"cellcal", "import", "csv", dir + "/m.csv", "--robot",
                              std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml", "--robot-id", "tx60",
                              "--out", dir + "/m.mcap"});
  ASSERT_EQ(imp.wait(60), 0) << imp.log();

  nlohmann::json runs[2];
  for (int k = 0; k < 2; ++k) {
    Process v(dir, "validate" + std::to_string(k), {"cellcal", "validate", dir + "/m.mcap", "--config", cell, "--json",
                                                    dir + "/v" + std::to_string(k) + ".json", "--figures", dir + "/figures"});
    ASSERT_EQ(v.wait(60), 0) << v.log();
    for (const char* f : {"/figures/tx60_accuracy.png", "/figures/tx60_joint_drift.png"}) EXPECT_TRUE(isGnuplotFigure(dir + f));
    runs[k] = readJson(dir + "/v" + std::to_string(k) + ".json")["robots"]["tx60"];
  }
  EXPECT_EQ(runs[0]["reproduced"].get<int>(), rows) << runs[0]["rejected"];
  EXPECT_EQ(runs[0]["calibrations"], runs[1]["calibrations"]) << "validate is not deterministic";
  EXPECT_EQ(runs[0]["final_parameters"], runs[1]["final_parameters"]);
  EXPECT_EQ(runs[0]["recorded"], 0);  // nothing to compare with: reported, not an error
  // The a-priori error (each pose predicted before it is used) falls as the engine learns the robot.
  const auto& c = runs[0]["calibrations"];
  double early = 0, late = 0;
  for (int i = 0; i < 10; ++i) early += c[i + 1].value("verification_mm", 0.0) / 10;
  late = c[c.size() - 1]["verification_mm"].get<double>();
  EXPECT_LT(late, 0.5 * early) << "first poses " << early << " mm, last " << late << " mm";
  // The run's held-out figures are its updates' a-priori errors, one per update: their mean, 99.7th percentile and
  // max; the engine's own running figure (the mean of the last kRecentPoses) is the same errors' window mean.
  std::vector<double> held;
  for (size_t k = 0; k < c.size(); ++k) {
    if (c[k]["held_out_mm"].is_null()) continue;
    held.push_back(c[k]["held_out_mm"].get<double>());
    if (held.size() < CalibrationEngine::kRecentPoses) continue;
    const double window = std::accumulate(held.end() - CalibrationEngine::kRecentPoses, held.end(), 0.0) /
                          CalibrationEngine::kRecentPoses;
    EXPECT_NEAR(c[k]["verification_mm"].get<double>(), window, 1e-9) << "version " << c[k]["version"];
  }
  const auto& h = runs[0]["held_out_mm"];
  ASSERT_EQ(h["updates"].get<size_t>(), held.size());
  EXPECT_EQ(held.size(), static_cast<size_t>(rows));  // every row made a version
  EXPECT_NEAR(h["mean_mm"].get<double>(), std::accumulate(held.begin(), held.end(), 0.0) / held.size(), 1e-9);
  EXPECT_NEAR(h["p997_mm"].get<double>(), percentile(held, 0.997), 1e-12);
  EXPECT_NEAR(h["max_mm"].get<double>(), *std::max_element(held.begin(), held.end()), 1e-12);

  Process exp(dir, "export", {"cellcal", "export", dir + "/m.mcap", "--config", cell, "--out", dir + "/back.csv"});
  ASSERT_EQ(exp.wait(60), 0) << exp.log();
  const RobotModel model = robot("staubli_tx60");
  const MeasurementFile back = readMeasurementCsv(dir + "/back.csv", model);
  ASSERT_EQ(back.rows.size(), f.rows.size());
  for (size_t i = 0; i < f.rows.size(); ++i) {
    EXPECT_LT((back.rows[i].q_rad - f.rows[i].q_rad).cwiseAbs().maxCoeff(), 1e-9) << i;
    EXPECT_LT((back.rows[i].position_m - f.rows[i].position_m).norm(), 1e-9) << i;
    ASSERT_EQ(back.rows[i].orientation.has_value(), f.rows[i].orientation.has_value()) << i;
    if (f.rows[i].orientation) {
      EXPECT_LT(back.rows[i].orientation->angularDistance(*f.rows[i].orientation), 1e-9) << i;
    }
    EXPECT_NEAR(*back.rows[i].stamp_s, *f.rows[i].stamp_s - *f.rows[0].stamp_s, 1e-6) << i;
  }
}

TEST(CliRecording, RowsTooCloseInTimeAreRefusedWithTheirLine) {
  const std::string dir = testDir();
  std::ofstream(dir + "/m.csv") << "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,stamp_s\n"
                                << "0,10,20,0,30,0,1000,0,0,0\n0,11,20,0,30,0,1000,0,0,0.005\n";
  Process imp(dir, "import", {"cellcal", "import", "csv", dir + "/m.csv", "--robot",
                              std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml", "--out", dir + "/m.mcap"});
  EXPECT_NE(imp.wait(60), 0);
  EXPECT_NE(imp.log().find("m.csv:3:"), std::string::npos) << imp.log();
}

}  // namespace
}  // namespace cellcal
