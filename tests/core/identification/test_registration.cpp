// Registration: the robot's base in the tracker frame and the target on the flange, found from measurements alone.
#include <gtest/gtest.h>

#include <random>

#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/placements.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

TEST(Registration, FindsAnUnknownBaseAndToolFromMeasurements) {
  // The robot stands somewhere in the tracker frame (random position and yaw); the registration only sees nominal
  // kinematics and measurements.
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  SimulationConfig sc;
  sc.seed = seed;
  sc.base_in_tracker << 3 * u(rng), 3 * u(rng), u(rng), 0.02 * u(rng), 0.02 * u(rng), kPi * u(rng);
  sc.tool_in_flange << 0.1 * u(rng), 0.1 * u(rng), 0.05 + 0.1 * std::abs(u(rng)), 0, 0, 0;
  const SimulatedCell cell(test::robot("ur10"), sc);
  std::vector<Observation> obs;
  for (const auto& q : cell.randomConfigurations(60, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  Eigen::VectorXd start = cell.model().nominal;
  start.tail<12>().setZero();  // unknown frames
  const RegistrationResult r = registerFrames(cell.model(), start, obs);
  const int b = cell.model().baseParam(FrameParam::kX);
  // Within the size of the hidden kinematic errors (0.1-0.5 mm, 0.01-0.05 deg over a 1.3 m arm).
  EXPECT_LT(r.rms_position_m, 3e-3);
  EXPECT_LT((r.params.segment<3>(b) - sc.base_in_tracker.head<3>()).norm(), 0.01);
  EXPECT_NEAR(std::remainder(r.params[b + 5] - sc.base_in_tracker[5], 2 * kPi), 0, 0.01);
}

// Rows of two tracker placements joined in one file: the change is found at its row, with each side's residual at the
// robot's own error; a file of one placement, with points or 6D, is never split. Random robots, placements (the
// tracker moved 0.3-2 m and turned up to 90 deg), split rows and measurement types.
TEST(Registration, RowsOfTwoSetUpsAreFoundWhereTheyChange) {
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int draw = 0; draw < 12; ++draw) {
    const SimulationConfig sc = test::randomPlacement(rng);
    const RobotModel robot = test::robot(draw % 2 ? "ur10" : "staubli_tx60");
    const MeasurementKind kind = u(rng) < 0 ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
    const SimulatedCell first(robot, sc);
    const SimulatedCell second(robot, test::trackerMoved(sc, rng));  // same robot and hidden errors, tracker elsewhere
    const int n = 60 + static_cast<int>(100 * std::abs(u(rng)));
    const int change = 10 + static_cast<int>((n - 20) * std::abs(u(rng)));
    std::vector<Observation> obs;
    for (const auto& q : first.randomConfigurations(n, rng)) {
      obs.push_back((static_cast<int>(obs.size()) < change ? first : second).measure(q, 0.0, rng, kind));
    }
    Eigen::VectorXd start = robot.nominal;
    start.tail<12>().setZero();
    const std::string what = robot.name + (kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", " +
                             std::to_string(n) + " rows, change at " + std::to_string(change) + ", seed " + std::to_string(sc.seed);
    const auto c = findSetupChange(robot, start, obs);
    ASSERT_TRUE(c) << what;
    EXPECT_EQ(c->first_row, change) << what;
    EXPECT_GT(c->rms_single_m, 20e-3) << what;
    EXPECT_LT(std::max(c->rms_first_m, c->rms_second_m), 2e-3) << what;
    // One placement: never split.
    const std::vector<Observation> one(obs.begin(), obs.begin() + change);
    if (change >= 16) {
      EXPECT_FALSE(findSetupChange(robot, start, one)) << what;
    }
  }
}

}  // namespace
}  // namespace cellcal
