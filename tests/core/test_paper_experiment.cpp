// The paper experiment on a fresh random robot: the published targets hold.
#include <gtest/gtest.h>

#include "cellcal/core/paper_experiment.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

TEST(PaperExperiment, ContinuousCalibrationStaysNearTheNoiseFloor) {
  PaperExperimentConfig cfg;
  cfg.sim.seed = test::testSeed();
  const auto r = runPaperExperiment(test::robot("staubli_tx60"), cfg);
  ASSERT_EQ(r.sweep.size(), cfg.sweep_poses.size());
  EXPECT_GT(r.sweep.front().verify_mean_m, 2 * r.sweep.back().verify_mean_m);  // 4 poses are not enough
  EXPECT_GT(r.true_error_nominal_m, 10 * r.noise_floor_m);
  int continuous_rls = 0;
  for (const auto& m : r.maintenance) {
    ASSERT_EQ(static_cast<int>(m.groups.size()), cfg.groups);
    // Where drift left something to correct (before > 2x floor), every update must reduce the error; at the floor an
    // update can only move it by noise.
    for (const auto& g : m.groups)
      if (g.verify_before_m > 2 * g.noise_floor_m)
        EXPECT_LT(g.verify_after_m, g.verify_before_m) << m.mode << " " << m.algorithm << " group " << g.group;
    if (m.mode == "continuous" && m.algorithm == "rls" && m.forgetting == 1.0) {
      ++continuous_rls;
      // Target: verification error within 1.5x the noise floor after each continuous update. It holds for every
      // update with 20 poses; with 15 poses it holds on average, and for every update in ~90% of random robots
      // (measured over 80 seeds, see docs/rls-vs-lm.md), so only the mean is asserted there.
      double mean_ratio = 0;
      for (size_t g = 1; g < m.groups.size(); ++g) mean_ratio += m.groups[g].verify_after_m / m.groups[g].noise_floor_m;
      mean_ratio /= static_cast<double>(m.groups.size() - 1);
      EXPECT_LT(mean_ratio, 1.5) << m.updated_poses << " poses";
      if (m.updated_poses >= 20) EXPECT_LT(m.worst_verify_to_floor, 1.5) << m.updated_poses << " poses";
    }
  }
  EXPECT_EQ(continuous_rls, static_cast<int>(cfg.continuous_poses.size()));
  EXPECT_GT(r.rls_time_per_pose_s, 0);
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
