// The engine's health rule (core/engine/health.hpp) as its header states it, on facts drawn at random around each
// threshold: which health and cause, whether the last good version is held, the words' opening, the drift alarm.
#include <gtest/gtest.h>

#include <random>

#include "cellcal/core/engine/health.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

bool startsWith(const std::string& s, const std::string& p) { return s.rfind(p, 0) == 0; }

TEST(Health, TheRuleIsWhatItsHeaderStates) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  EngineSettings s;
  s.outlier_hold_after = 3 + static_cast<int>(5 * u(rng));
  s.hold_prediction_sigma_m = 1e-4 + 1e-3 * u(rng);
  int seen[4] = {0, 0, 0, 0};
  for (int k = 0; k < 2000; ++k) {
    HealthFacts f;
    f.poses_needed = static_cast<std::size_t>(20 * u(rng));
    f.poses_used = static_cast<std::size_t>(f.poses_needed + 4 * u(rng)) - (u(rng) < 0.3 ? 3 : 0);
    if (f.poses_used > 1000) f.poses_used = 0;  // wrapped below zero
    f.consecutive_outliers = s.outlier_hold_after + static_cast<int>(4 * u(rng)) - 2;
    f.prediction_sigma_m = s.hold_prediction_sigma_m * (0.5 + u(rng));
    f.drift_alarm = u(rng) < 0.3;
    f.recent_nis_per_row = 10 * u(rng);
    if (u(rng) < 0.6) f.good_version = 1 + static_cast<std::uint64_t>(100 * u(rng));
    f.refused_file = u(rng) < 0.3;
    const HealthVerdict v = judgeHealth(f, s);
    const std::string reason = describe(v);
    const bool outliers = f.consecutive_outliers >= s.outlier_hold_after;
    const bool wide = f.prediction_sigma_m > s.hold_prediction_sigma_m;
    EXPECT_EQ(v.drift_alarm, f.drift_alarm || outliers);
    EXPECT_EQ(v.hold, v.health == Health::kHoldLastGood);
    ++seen[static_cast<int>(v.health)];
    if (f.poses_used < f.poses_needed) {
      EXPECT_EQ(v.health, Health::kUncalibrated);
      EXPECT_EQ(v.cause, HealthCause::kTooFewPoses);
      EXPECT_TRUE(startsWith(reason, std::to_string(f.poses_used) + " of the " + std::to_string(f.poses_needed)))
          << reason;
      EXPECT_EQ(reason.find("calibration file does not fit") != std::string::npos, f.refused_file) << reason;
    } else if (outliers || wide) {
      const std::string cause = outliers ? std::to_string(f.consecutive_outliers) + " poses in a row beyond the outlier gate"
                                         : "predicted position error";
      EXPECT_EQ(v.cause, outliers ? HealthCause::kOutliersInARow : HealthCause::kPredictionAboveBound);
      if (f.good_version) {
        EXPECT_EQ(v.health, Health::kHoldLastGood);
        EXPECT_TRUE(startsWith(reason, "holding v" + std::to_string(*f.good_version) + ": " + cause)) << reason;
      } else {
        EXPECT_EQ(v.health, Health::kUncalibrated);
        EXPECT_TRUE(startsWith(reason, "nothing good to hold yet: " + cause)) << reason;
      }
    } else if (f.drift_alarm) {
      EXPECT_EQ(v.health, Health::kDegraded);
      EXPECT_EQ(v.cause, HealthCause::kDriftAlarm);
      EXPECT_TRUE(startsWith(reason, "drift alarm: recent normalized innovation")) << reason;
    } else {
      EXPECT_EQ(v.health, Health::kOk);
      EXPECT_EQ(v.cause, HealthCause::kNone);
      EXPECT_TRUE(reason.empty()) << reason;
    }
  }
  for (int h = 0; h < 4; ++h) EXPECT_GT(seen[h], 50) << healthName(static_cast<Health>(h));
  EXPECT_EQ(posesNeeded(13, MeasurementKind::kPose6D, false), 6u);  // 2 x ceil(13 / 6)
  EXPECT_EQ(posesNeeded(13, MeasurementKind::kPosition3D, false), 10u);  // 2 x ceil(13 / 3)
  EXPECT_EQ(posesNeeded(13, MeasurementKind::kPose6D, true), 0u);
}

}  // namespace
}  // namespace cellcal
