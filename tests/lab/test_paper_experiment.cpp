// The paper experiment on fresh random robots: the published targets hold.
// Measured rates over 5,300 robots (cellcal experiment paper --seeds N --seed S, 2026-12-02: S = 1000 (300 robots),
// 7000000 (2,000), 13286945441070000000 (2,000), 13286945441074123000 (1,000)): every continuous RLS update within
// 1.5x the noise floor for 99.2-99.7 % of robots with 20 poses and 91.7-93.3 % with 15 random poses; when RLS chooses
// its poses, 99.5-100 % and 98.8-99.3 %. The test draws 30 robots per run and asserts counts whose chance of failing by
// bad luck is below 1e-4 each at slightly worse rates than measured (0.75 %, 8 %, 0.2 %, 1.2 % of robots outside;
// binomial) while a real regression fails them. (10 robots with at most one outside failed a CI run by chance:
// CELLCAL_TEST_SEED=13286945441074123106 has two robots of 10 at 1.52x with 20 chosen poses; the robots around it
// have 0.5 % outside.) (From d78b375 to 9d8d77e the rates were 97.7 / 88.3 / 100 / 97.3 %: the drift of the
// parameters dropped for the tool frame was lost, see RlsDrift in test_rls.cpp; the 5-robot counts of that time failed
// a CI run, CELLCAL_TEST_SEED=18191186204246796854.)
#include <gtest/gtest.h>

#include "cellcal/lab/paper_experiment.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

TEST(PaperExperiment, ContinuousCalibrationStaysNearTheNoiseFloor) {
  const std::uint64_t seed = test::testSeed();
  const RobotModel robot = test::robot("staubli_tx60");
  const int robots = 30;
  int within15 = 0, within20 = 0, selected15 = 0, selected20 = 0;
  for (int k = 0; k < robots; ++k) {
    PaperExperimentConfig cfg;
    cfg.sim.seed = seed + static_cast<std::uint64_t>(k);
    SCOPED_TRACE("robot seed " + std::to_string(cfg.sim.seed));
    const auto r = runPaperExperiment(robot, cfg);
    ASSERT_EQ(r.sweep.size(), cfg.sweep_poses.size());
    EXPECT_GT(r.sweep.front().verify_mean_m, 2 * r.sweep.back().verify_mean_m);  // 4 poses are not enough
    EXPECT_GT(r.true_error_nominal_m, 10 * r.noise_floor_m);
    int continuous_rls = 0;
    for (const auto& m : r.maintenance) {
      ASSERT_EQ(static_cast<int>(m.groups.size()), cfg.groups);
      // Where drift left something to correct (before > 2x floor), every update must reduce the error; at the
      // floor an update can only move it by noise.
      for (const auto& g : m.groups) {
        if (g.verify_before_m > 2 * g.noise_floor_m) {
          EXPECT_LT(g.verify_after_m, g.verify_before_m) << m.mode << " " << m.algorithm << " group " << g.group;
        }
      }
      if (m.mode == "continuous" && m.algorithm == "rls" && m.forgetting == 1.0) {
        ++continuous_rls;
        double mean_ratio = 0;
        for (size_t g = 1; g < m.groups.size(); ++g)
          mean_ratio += m.groups[g].verify_after_m / m.groups[g].noise_floor_m;
        mean_ratio /= static_cast<double>(m.groups.size() - 1);
        // Mean over the updates of verify/floor, 120 robots (cellcal experiment paper --seed 5000..5119): largest
        // 1.481 with 15 random poses (median 1.248), 1.33 with 15 chosen, 1.30 / 1.27 with 20. One robot of a CI run
        // reached 1.506 with 15 random poses: that case's bound is 1.75; the count below judges how often it holds.
        const double bound = m.updated_poses == 15 && m.pose_selection == "first" ? 1.75 : 1.5;
        EXPECT_LT(mean_ratio, bound) << m.updated_poses << " poses, " << m.pose_selection;
        const bool within = m.worst_verify_to_floor <= 1.5;
        const bool selected = m.pose_selection != "first";
        if (m.updated_poses == 15) (selected ? selected15 : within15) += within;
        if (m.updated_poses == 20) (selected ? selected20 : within20) += within;
      }
      if (m.mode == "periodic") {
        EXPECT_LT(m.worst_verify_to_floor, 1.5) << m.algorithm;
      }
    }
    EXPECT_EQ(continuous_rls, 2 * static_cast<int>(cfg.continuous_poses.size()));  // random and chosen poses
    EXPECT_GT(r.rls_time_per_pose_s, 0);
  }
  // P(fail by chance), binomial over 30 robots at the rates above: at most 3 outside at 0.75 %: 7e-5; at most 9 at
  // 8 %: 7e-5; at most 2 at 0.2 %: 3e-5; at most 4 at 1.2 %: 3e-5.
  EXPECT_GE(within20, robots - 3) << "robots whose every 20-pose update stayed within 1.5x the floor";
  EXPECT_GE(within15, robots - 9) << "robots whose every 15-pose update stayed within 1.5x the floor";
  EXPECT_GE(selected20, robots - 2) << "same with 20 chosen poses";
  EXPECT_GE(selected15, robots - 4) << "same with 15 chosen poses";
  std::printf("  %d robots: every update within 1.5x the floor for %d (20 poses), %d (15), %d (20 chosen), %d (15 chosen)\n",
              robots, within20, within15, selected20, selected15);
}

TEST(PaperExperiment, InvalidConfigIsReported) {
  PaperExperimentConfig cfg;
  cfg.identification_poses = 200;
  std::string e;
  EXPECT_FALSE(cfg.IsValid(&e));
  EXPECT_THROW(runPaperExperiment(test::robot("staubli_tx60"), cfg), std::invalid_argument);
}

}  // namespace
}  // namespace cellcal
