// Several set-ups in one calibration (setups.hpp): the same robot measured from two or three tracker placements.
// Random robots, hidden kinematic errors, placements, measurement types and row counts; the fit sees only the nominal
// model, each set-up's rows and its registration.
#include <gtest/gtest.h>

#include <random>

#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/identification/setups.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/placements.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

constexpr double kPerSetupBound = 1.3;

double meanError(const RobotModel& m, const Eigen::VectorXd& params, const std::vector<Observation>& obs) {
  return mean(positionErrors(m, params, obs));
}

// One set-up: the plain reference is the single-set-up calibration (fitExtended, geometric) on the same rows; the
// two agree to a micrometre at fresh configurations. Two or three: judged against the true poses at fresh
// configurations, the joint fit is better than the set-ups' own calibrations on average over the run (more rows for
// the same kinematics), and no set-up's error is above kPerSetupBound times its own calibration's (a set-up's frames
// come from its own rows in both, so one set-up can come out a little worse by chance). Measured over 200 seeds
// (3,000 set-ups): largest ratio 1.19, median 0.74; the run's mean at most 0.83 of the own calibrations'. Until
// 2026-11-29 each set-up was held to 1.05x its own calibration on noisy fresh readings, which a CI seed failed at
// 1.08x (CELLCAL_TEST_SEED=14411837373366597251).
TEST(Setups, OneModelWithAFramePairPerSetUp) {
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  double joint_sum = 0, separate_sum = 0;
  int judged = 0;
  for (int draw = 0; draw < 8; ++draw) {
    const SimulationConfig sc = test::randomPlacement(rng);
    const RobotModel robot = test::robot(draw % 2 ? "ur10" : "staubli_tx60");
    const MeasurementKind kind = draw % 4 < 2 ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
    const int setups = draw < 2 ? 1 : 2 + draw % 2;
    const std::string what = robot.name + (kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", " +
                             std::to_string(setups) + " set-ups, seed " + std::to_string(sc.seed);
    std::vector<SimulatedCell> cells;
    for (int s = 0; s < setups; ++s) cells.emplace_back(robot, s == 0 ? sc : test::trackerMoved(sc, rng));
    SetupsProblem problem;
    problem.model = &robot;
    std::vector<std::vector<Observation>> fresh;
    for (const auto& cell : cells) {
      std::vector<Observation> obs, check;
      const int n = 25 + static_cast<int>(20 * std::abs(u(rng)));
      for (const auto& q : cell.randomConfigurations(n, rng)) obs.push_back(cell.measure(q, 0.0, rng, kind));
      // Fresh configurations judged against the truth (no tracker noise in the judgement).
      for (const auto& q : cell.randomConfigurations(100, rng)) {
        Observation o;
        o.q_rad = q;
        o.kind = kind;
        o.measured_in_tracker = cell.truePose(q, 0.0);
        check.push_back(o);
      }
      Eigen::VectorXd start = robot.nominal;
      start.tail<12>().setZero();
      problem.starts.push_back(registerFrames(robot, start, obs).params);
      problem.observations.push_back(obs);
      fresh.push_back(check);
    }
    const SetupsFit joint = fitSetups(problem);
    ASSERT_TRUE(joint.converged) << what << ": " << joint.message;
    ASSERT_EQ(joint.params.size(), static_cast<size_t>(setups));
    for (int s = 0; s < setups; ++s) {
      const std::vector<Drivers> drivers(problem.observations[s].size());
      const ExtendedFit own = fitExtended(robot, problem.starts[s], problem.observations[s], drivers, std::vector<Extension>{});
      ASSERT_TRUE(own.converged) << what;
      const double e_joint = meanError(robot, joint.params[s], fresh[s]);
      const double e_own = meanError(robot, own.params, fresh[s]);
      std::printf("  %-40s set-up %d: joint %.4f mm, its own calibration %.4f mm (nominal %.4f)\n", what.c_str(), s + 1,
                  e_joint * 1e3, e_own * 1e3, meanError(robot, problem.starts[s], fresh[s]) * 1e3);
      if (setups == 1) {
        KinematicsData d(robot);
        double worst = 0;
        for (const auto& o : fresh[s])
          worst = std::max(worst, (forwardKinematics(robot, d, joint.params[s], o.q_rad).translation() -
                                   forwardKinematics(robot, d, own.params, o.q_rad).translation()).norm());
        EXPECT_LT(worst, 1e-6) << what;
        EXPECT_EQ(joint.estimated, own.estimated) << what;
      } else {
        joint_sum += e_joint;
        separate_sum += e_own;
        ++judged;
        EXPECT_LT(e_joint, kPerSetupBound * e_own) << what << ", set-up " << s + 1;
      }
    }
  }
  std::printf("  mean over the set-ups of several: joint %.4f mm, each its own %.4f mm\n", joint_sum / judged * 1e3,
              separate_sum / judged * 1e3);
  EXPECT_LT(joint_sum, separate_sum) << "the joint fit, with more rows for the same kinematics, is not better on average";
}

}  // namespace
}  // namespace cellcal
