// Registration: the robot's base in the tracker frame and the target on the flange, found from measurements alone.
#include <gtest/gtest.h>

#include <random>

#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/sim/simulation.hpp"
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

}  // namespace
}  // namespace cellcal
