// Pairing tracker readings with the joint state valid at their stamp: only when the robot stood still across the
// reading; waiting, timeouts, and rejections with reasons.
#include <gtest/gtest.h>

#include "cellcal/core/engine/pairing.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

struct PairingFixture : ::testing::Test {
  RobotModel m = test::robot("staubli_tx60");
  PairingOptions opt;
  static constexpr std::int64_t kMs = 1000000;
  std::int64_t t0 = 1'700'000'000'000'000'000;
  Eigen::VectorXd q = Eigen::VectorXd::Constant(6, 0.3);
  std::uint64_t seq = 0;

  JointSample joint(std::int64_t t, bool settled, const Eigen::VectorXd& at) { return {t, ++seq, at, settled}; }
  TrackerSample reading(std::int64_t t) {
    TrackerSample s;
    s.stamp_ns = t;
    s.sequence = ++seq;
    s.position_m = Eigen::Vector3d(1, 2, 3);
    return s;
  }
};

TEST_F(PairingFixture, PairsOnlyWhenTheRobotStoodStillAcrossTheReading) {
  PairingBuffer b(m, opt);
  for (int k = 0; k <= 10; ++k) ASSERT_FALSE(b.addJointState(joint(t0 + k * 2 * kMs, true, q), t0 + k * 2 * kMs));
  ASSERT_FALSE(b.addTrackerSample(reading(t0 + 9 * kMs), t0 + 9 * kMs));
  const auto out = b.poll(t0 + 21 * kMs);
  ASSERT_EQ(out.paired.size(), 1u);
  EXPECT_EQ(out.paired[0].joint_stamp_ns, t0 + 8 * kMs);
  EXPECT_EQ(out.paired[0].observation.q_rad, q);
  EXPECT_NEAR(out.paired[0].observation.measured_in_tracker.translation().y(), 2.0, 0);
}

TEST_F(PairingFixture, ReadingWaitsForTheNextJointStateThenDecides) {
  PairingBuffer b(m, opt);
  ASSERT_FALSE(b.addJointState(joint(t0, true, q), t0));
  ASSERT_FALSE(b.addTrackerSample(reading(t0 + kMs), t0 + kMs));
  EXPECT_TRUE(b.poll(t0 + 2 * kMs).paired.empty());
  EXPECT_EQ(b.pending(), 1u);
  Eigen::VectorXd moved = q;
  moved[2] += 0.01;
  ASSERT_FALSE(b.addJointState(joint(t0 + 2 * kMs, true, moved), t0 + 2 * kMs));
  const auto out = b.poll(t0 + 3 * kMs);
  ASSERT_EQ(out.rejected.size(), 1u);
  EXPECT_EQ(out.rejected[0].first, Rejection::kRobotMoved) << out.rejected[0].second;
}

TEST_F(PairingFixture, MovingStaleAndMissingJointStatesAreNotPaired) {
  {
    PairingBuffer b(m, opt);
    b.addJointState(joint(t0, true, q), t0);
    b.addJointState(joint(t0 + 2 * kMs, false, q), t0 + 2 * kMs);
    b.addTrackerSample(reading(t0 + kMs), t0 + kMs);
    const auto out = b.poll(t0 + 3 * kMs);
    ASSERT_EQ(out.rejected.size(), 1u);
    EXPECT_EQ(out.rejected[0].first, Rejection::kRobotMoving);
  }
  {  // the last joint state before the reading is older than the skew: stale
    PairingBuffer b(m, opt);
    b.addJointState(joint(t0, true, q), t0);
    b.addJointState(joint(t0 + 200 * kMs, true, q), t0 + 200 * kMs);
    b.addTrackerSample(reading(t0 + 100 * kMs), t0 + 200 * kMs);
    const auto out = b.poll(t0 + 201 * kMs);
    ASSERT_EQ(out.rejected.size(), 1u);
    EXPECT_EQ(out.rejected[0].first, Rejection::kNoJointState) << out.rejected[0].second;
  }
  {  // no joint state after the reading arrives within the skew: decided by timeout
    PairingBuffer b(m, opt);
    b.addJointState(joint(t0, true, q), t0);
    b.addTrackerSample(reading(t0 + kMs), t0 + kMs);
    EXPECT_TRUE(b.poll(t0 + 10 * kMs).rejected.empty());
    const auto out = b.poll(t0 + 60 * kMs);
    ASSERT_EQ(out.rejected.size(), 1u);
    EXPECT_EQ(out.rejected[0].first, Rejection::kNoJointState);
  }
}

TEST_F(PairingFixture, OutOfOrderDuplicateAndBadSamplesAreRejectedWithReasons) {
  PairingBuffer b(m, opt);
  std::string d;
  ASSERT_FALSE(b.addJointState(joint(t0 + 10 * kMs, true, q), t0 + 10 * kMs));
  EXPECT_EQ(b.addJointState(joint(t0 + 5 * kMs, true, q), t0 + 11 * kMs, &d), Rejection::kOutOfOrder);
  EXPECT_NE(d.find("older"), std::string::npos);
  EXPECT_EQ(b.addJointState(joint(t0 + 10 * kMs, true, q), t0 + 11 * kMs), Rejection::kDuplicate);
  Eigen::VectorXd bad = q;
  bad[4] = std::nan("");
  EXPECT_EQ(b.addJointState(joint(t0 + 12 * kMs, true, bad), t0 + 12 * kMs), Rejection::kNonFinite);
  bad = q;
  bad[4] = 3.0;  // beyond the TX60 joint 5 limit
  EXPECT_EQ(b.addJointState(joint(t0 + 12 * kMs, true, bad), t0 + 12 * kMs), Rejection::kJointsOutsideLimits);
  EXPECT_EQ(b.addJointState(joint(t0 + 12 * kMs, true, Eigen::VectorXd::Zero(5)), t0 + 12 * kMs),
            Rejection::kWrongJointCount);
  EXPECT_EQ(b.addJointState(joint(t0 + 20'000 * kMs, true, q), t0 + 12 * kMs, &d), Rejection::kStampInFuture);
  EXPECT_NE(d.find("clocks"), std::string::npos);
  TrackerSample r = reading(t0 + 13 * kMs);
  r.orientation_xyzw = {0, 0, 0, 1.1};
  EXPECT_EQ(b.addTrackerSample(r, t0 + 13 * kMs), Rejection::kNonUnitQuaternion);
  r = reading(t0 + 13 * kMs);
  r.valid = false;
  EXPECT_EQ(b.addTrackerSample(r, t0 + 13 * kMs), Rejection::kTrackerInvalid);
  r = reading(t0 - 10'000 * kMs);
  EXPECT_EQ(b.addTrackerSample(r, t0 + 13 * kMs), Rejection::kStampTooOld);
  b.setAppliedUntil(t0 + 14 * kMs);
  EXPECT_EQ(b.addTrackerSample(reading(t0 + 14 * kMs), t0 + 15 * kMs), Rejection::kAlreadyApplied);
}

}  // namespace
}  // namespace cellcal
