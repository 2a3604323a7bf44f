// Pairing tracker readings with the joint state valid at their stamp: only when the robot stood still across the
// reading; waiting, timeouts, and rejections with reasons.
#include <gtest/gtest.h>

#include <random>

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

// Two hosts whose clocks disagree: every tracker reading is taken while the robot stands still, but its stamp is
// `lead` later (or earlier) than the robot's clock says. Random program (stand-stills of 20-40 ms, moves of
// 30-100 ms, joint states at 500 Hz, a reading at a random instant of each stand-still) and random lead of 25-60 ms
// either way. The hint must appear, and its range of leads must hold the true one; with synchronized clocks (lead 0)
// it must never appear.
TEST_F(PairingFixture, AClockOffsetShowsAsReadingsBesideTheStandStills) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0, 1);
  int firsts = 0;
  for (int trial = 0; trial < 40; ++trial) {
    const bool synchronized = trial % 4 == 0;
    const double lead_ms = synchronized ? 0.0 : (u(rng) < 0.5 ? -1 : 1) * (25 + 35 * u(rng));
    PairingBuffer b(m, opt);
    Eigen::VectorXd at = Eigen::VectorXd::Constant(6, 0.3);
    std::int64_t t = t0;
    std::vector<std::int64_t> readings;  // true instants
    int paired = 0;
    auto joints_until = [&](std::int64_t end, bool settled, const Eigen::VectorXd& q1, const Eigen::VectorXd& q0) {
      const std::int64_t start = t;
      for (; t < end; t += 2 * kMs) {
        const double f = static_cast<double>(t - start) / static_cast<double>(end - start);
        ASSERT_FALSE(b.addJointState(joint(t, settled, settled ? q1 : Eigen::VectorXd(q0 + f * (q1 - q0))), t));
        // Readings due by now (the tracker sends at once; its stamp carries the lead).
        while (!readings.empty() && readings.front() <= t) {
          const auto stamp = readings.front() + static_cast<std::int64_t>(lead_ms * kMs);
          ASSERT_FALSE(b.addTrackerSample(reading(stamp), readings.front()));
          readings.erase(readings.begin());
        }
        paired += static_cast<int>(b.poll(t).paired.size());
      }
    };
    for (int pose = 0; pose < 30; ++pose) {
      const Eigen::VectorXd from = at;
      at += 0.05 * Eigen::VectorXd::Random(6);
      joints_until(t + static_cast<std::int64_t>((30 + 70 * u(rng)) * kMs), false, at, from);
      const std::int64_t still = t, len = static_cast<std::int64_t>((20 + 20 * u(rng)) * kMs);
      readings.push_back(still + 2 * kMs + static_cast<std::int64_t>(u(rng) * static_cast<double>(len - 4 * kMs)));
      joints_until(still + len, true, at, at);
    }
    joints_until(t + 600 * kMs, true, at, at);  // let the last readings be judged
    const auto h = b.clockOffsetHint();
    if (synchronized) {
      EXPECT_FALSE(h) << "trial " << trial << ": a hint with synchronized clocks: lead " << h->tracker_ahead_s;
      EXPECT_GE(paired, 28) << "trial " << trial;
      continue;
    }
    ASSERT_TRUE(h) << "trial " << trial << ": lead " << lead_ms << " ms not seen; paired " << paired;
    // The true lead lies in the range named first (random stand-stills and moves: no second lead fits as many, or,
    // when one does by chance, the true one is among the two).
    const bool first = h->tracker_ahead_min_s * 1e3 <= lead_ms && lead_ms <= h->tracker_ahead_max_s * 1e3;
    const bool second = h->other_ahead_s && h->other_ahead_min_s * 1e3 <= lead_ms && lead_ms <= h->other_ahead_max_s * 1e3;
    EXPECT_TRUE(first || second) << "trial " << trial << ": lead " << lead_ms << " ms, named "
                                 << h->tracker_ahead_min_s * 1e3 << ".." << h->tracker_ahead_max_s * 1e3;
    firsts += first;
    EXPECT_GE(h->fit_with_shift, 9);
    EXPECT_GE(h->fit_with_shift - h->fit_without_shift, 4);
  }
  EXPECT_GE(firsts, 27) << "of 30 offsets, the true lead named first";
}

}  // namespace
}  // namespace cellcal
