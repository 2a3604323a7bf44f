#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

bool contains(const std::vector<int>& v, int i) { return std::find(v.begin(), v.end(), i) != v.end(); }

class Identifiability : public ::testing::TestWithParam<std::string> {};

// Everett/Hollerbach: a serial arm of R revolute joints measured in 6D identifies 4R + 6 parameters
// (base and tool included); in position-only 4R + 3 (the tool orientation is invisible).
// A target off the flange axis (as a real SMR/T-Mac is).
RobotModel withToolOffset(RobotModel m) {
  m.nominal[m.toolParam(FrameParam::kX)] = 0.03;
  m.nominal[m.toolParam(FrameParam::kZ)] = 0.06;
  return m;
}

TEST_P(Identifiability, RankMatchesTheoryFor6DAndPositionOnly) {
  const RobotModel m = withToolOffset(test::robot(GetParam()));
  const auto r6 = structuralIdentifiability(m, m.nominal, MeasurementKind::kPose6D);
  EXPECT_EQ(r6.num_candidates, 4 * 6 + 12);
  EXPECT_EQ(r6.rank, 4 * 6 + 6) << r6.summary(m);
  const auto r3 = structuralIdentifiability(m, m.nominal, MeasurementKind::kPosition3D);
  EXPECT_EQ(r3.rank, 4 * 6 + 3) << r3.summary(m);
  for (FrameParam f : {FrameParam::kRoll, FrameParam::kPitch, FrameParam::kYaw})
    EXPECT_FALSE(contains(r3.identifiable, m.toolParam(f))) << r3.summary(m);
  EXPECT_TRUE(std::isfinite(r6.condition_number));
}

// A point target on the last joint's axis cannot reveal that joint's rotation: the analysis must say so.
TEST_P(Identifiability, PointTargetOnTheFlangeAxisLosesJoint6Rotation) {
  const RobotModel m = test::robot(GetParam());  // tool_in_flange = identity
  const auto r3 = structuralIdentifiability(m, m.nominal, MeasurementKind::kPosition3D);
  EXPECT_LT(r3.rank, 4 * 6 + 3) << r3.summary(m);
  EXPECT_FALSE(contains(r3.identifiable, m.jointParam(5, JointParam::kThetaOffset))) << r3.summary(m);
}

TEST_P(Identifiability, BaseZIsMergedIntoD1AndNeverEstimated) {
  const RobotModel m = withToolOffset(test::robot(GetParam()));
  const auto r = structuralIdentifiability(m, m.nominal, MeasurementKind::kPose6D);
  const int d1 = m.jointParam(0, JointParam::kD), bz = m.baseParam(FrameParam::kZ);
  EXPECT_TRUE(contains(r.identifiable, d1));
  EXPECT_FALSE(contains(r.identifiable, bz));
  auto it = std::find_if(r.dropped.begin(), r.dropped.end(), [&](const DroppedParameter& d) { return d.index == bz; });
  ASSERT_NE(it, r.dropped.end());
  ASSERT_FALSE(it->merged_into.empty());
  bool merged_into_d1 = false;
  for (const auto& [k, c] : it->merged_into) merged_into_d1 |= (k == d1);
  EXPECT_TRUE(merged_into_d1) << r.summary(m);
  EXPECT_NE(r.summary(m).find("base.z_m"), std::string::npos);
}

TEST_P(Identifiability, FewPosesLimitTheRank) {
  const RobotModel m = test::robot(GetParam());
  SimulationConfig sc;
  sc.seed = test::testSeed();
  SimulatedCell cell(m, sc);
  std::mt19937_64 rng(sc.seed);
  std::vector<Observation> obs;
  for (const auto& q : cell.randomConfigurations(3, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  const auto r = analyzeIdentifiability(cell.model(), cell.nominalParams(), obs);
  EXPECT_LE(r.rank, 18);  // 3 poses x 6 rows
  EXPECT_EQ(r.rank + static_cast<int>(r.dropped.size()), r.num_candidates);
}

// A registered tool frame is never exactly aligned with the flange: its roll, pitch and yaw come out a few hundredths
// of a degree off zero. Those small angles must not make a gauge pair (joint 6's alpha and the tool's roll: both turn
// the target about the flange x axis) look separable; if they did, the pair would be estimated together and drift
// along the gauge. The estimated set must be as well conditioned as with an exactly aligned tool.
TEST_P(Identifiability, SlightlyRotatedFramesDoNotSplitAGauge) {
  const RobotModel m = withToolOffset(test::robot(GetParam()));
  const auto aligned = structuralIdentifiability(m, m.nominal, MeasurementKind::kPose6D);
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> angle(-0.1 * kPi / 180, 0.1 * kPi / 180);
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::VectorXd p = m.nominal;
    for (FrameParam f : {FrameParam::kRoll, FrameParam::kPitch, FrameParam::kYaw}) {
      p[m.toolParam(f)] += angle(rng);
      p[m.baseParam(f)] += angle(rng);
    }
    const auto r = structuralIdentifiability(m, p, MeasurementKind::kPose6D);
    EXPECT_EQ(r.rank, aligned.rank) << r.summary(m);
    EXPECT_LT(r.condition_number, 3 * aligned.condition_number) << r.summary(m);
    EXPECT_FALSE(contains(r.identifiable, m.toolParam(FrameParam::kRoll)) &&
                 contains(r.identifiable, m.jointParam(5, JointParam::kAlpha)))
        << r.summary(m);
  }
}

TEST(IdentifiabilityOptions, RejectsBadTolerance) {
  IdentifiabilityOptions o;
  o.rank_tolerance = 0;
  std::string e;
  EXPECT_FALSE(o.IsValid(&e));
  EXPECT_FALSE(e.empty());
}

INSTANTIATE_TEST_SUITE_P(Robots, Identifiability, ::testing::Values("staubli_tx60", "ur10"));

}  // namespace
}  // namespace cellcal
