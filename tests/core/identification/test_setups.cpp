// Several set-ups in one calibration (setups.hpp): the same robot measured from two or three tracker placements.
// Random robots, hidden kinematic errors, placements, measurement types and row counts; the fit sees only the nominal
// model, each set-up's rows and its registration.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
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
constexpr double kPerSetupAllowance_m = 2e-6;  // chance, at a micrometre level (the distribution below)

double meanError(const RobotModel& m, const Eigen::VectorXd& params, const std::vector<Observation>& obs) {
  return mean(positionErrors(m, params, obs));
}

// One set-up drawn on `cell`: n noisy readings (its identification rows, with the frames registered on them into
// `problem`) and 100 fresh configurations with their true poses (the judgement, free of tracker noise).
std::vector<Observation> addSetUp(const RobotModel& robot, const SimulatedCell& cell, MeasurementKind kind, int n,
                                  std::mt19937_64& rng, SetupsProblem& problem) {
  std::vector<Observation> obs, check;
  for (const auto& q : cell.randomConfigurations(n, rng)) obs.push_back(cell.measure(q, 0.0, rng, kind));
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
  problem.drivers.emplace_back(obs.size());
  return check;
}

// Both solvers run to a tight step tolerance: a one-set-up comparison is of their optima, not of where each stopped
// (at the default 1e-9 they differed by up to 1.2 um: CELLCAL_TEST_SEED=9585788424224239527).
SolverOptions tightSolver() {
  SolverOptions tight;
  tight.step_tolerance = 1e-12;
  tight.max_iterations = 200;
  return tight;
}

// The mean position error of set-up s's model under `fit` at fresh configurations (their true poses).
double meanExtendedError(const RobotModel& robot, const SetupsProblem& pr, const SetupsFit& fit, size_t s,
                         const std::vector<Observation>& fresh, const std::vector<Drivers>& drivers) {
  double sum = 0;
  for (const auto& r : positionResiduals(robot, setupFit(pr, fit, s), fresh, drivers)) sum += r.norm();
  return sum / static_cast<double>(fresh.size());
}

// One set-up against its plain reference, fitExtended on the same rows and drivers: the same estimated columns and
// rows left out, predictions within a micrometre at the fresh configurations.
void expectAsFitExtended(const RobotModel& robot, const SetupsProblem& extended, const SetupsFit& x,
                         const std::vector<Observation>& fresh, const std::vector<Drivers>& drivers,
                         const std::string& what) {
  const ExtendedFit own = fitExtended(robot, extended.starts[0], extended.observations[0], extended.drivers[0],
                                      extended.extensions, tightSolver());
  ASSERT_TRUE(own.converged) << what;
  EXPECT_EQ(x.rows_left_out.empty() ? 0 : x.rows_left_out[0], own.rows_left_out) << what;
  const auto a = positionResiduals(robot, setupFit(extended, x, 0), fresh, drivers);
  const auto b = positionResiduals(robot, own, fresh, drivers);
  double worst = 0;
  for (size_t i = 0; i < a.size(); ++i) worst = std::max(worst, (a[i] - b[i]).norm());
  EXPECT_LT(worst, 1e-6) << what;
  std::vector<int> kinematic_and_frames;  // the state's columns below the extension parameters
  for (int c : x.estimated)
    if (c < robot.numParams()) kinematic_and_frames.push_back(c);
  std::sort(kinematic_and_frames.begin(), kinematic_and_frames.end());
  EXPECT_EQ(kinematic_and_frames, own.estimated) << what;
  EXPECT_EQ(x.estimated_extension, own.estimated_extension) << what;
}

// One set-up: the plain reference is the single-set-up calibration (fitExtended, geometric) on the same rows; the
// two agree to a micrometre at fresh configurations. Two or three: judged against the true poses at fresh
// configurations, the joint fit is better than the set-ups' own calibrations on average over the run (more rows for
// the same kinematics), and no set-up's error is above kPerSetupBound times its own calibration's (a set-up's frames
// come from its own rows in both, so one set-up can come out a little worse by chance) plus 2 um. Measured over 200
// seeds (3,000 set-ups): largest ratio 1.19, median 0.74; the run's mean at most 0.83 of the own calibrations'. Over
// 1,500 seeds (22,500 set-ups, 2026-11-29): median 0.745, 99.9th percentile 1.155, largest 1.35; the two above 1.3
// were above it by 0.4 and 0.5 um (CELLCAL_TEST_SEED=14054155998754238561: 0.0152 against 0.0110 mm), hence the
// allowance; a set-up the joint fit gets wrong is off by far more. Until 2026-11-29 each set-up was held to 1.05x its
// own calibration on noisy fresh readings, which a CI seed failed at 1.08x (CELLCAL_TEST_SEED=14411837373366597251).
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
    for (const auto& cell : cells)
      fresh.push_back(addSetUp(robot, cell, kind, 25 + static_cast<int>(20 * std::abs(u(rng))), rng, problem));
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
        EXPECT_LT(e_joint, kPerSetupBound * e_own + kPerSetupAllowance_m) << what << ", set-up " << s + 1;
      }
    }
  }
  std::printf("  mean over the set-ups of several: joint %.4f mm, each its own %.4f mm\n", joint_sum / judged * 1e3,
              separate_sum / judged * 1e3);
  EXPECT_LT(joint_sum, separate_sum) << "the joint fit, with more rows for the same kinematics, is not better on average";
}

// A model extension is the robot's: one set of its parameters for every set-up. A hidden effect drawn at random
// (joint compliance on joint 2 or 3, a joint scale or a cyclic transmission error on joints 1-5; 0.1-0.4 mrad RMS) on a
// random robot, placement and measurement type. One set-up: the plain reference is fitExtended on the same rows and
// drivers (the same estimated columns, predictions within a micrometre at fresh configurations). Two or three set-ups:
// at fresh configurations against the truth, the extended joint fit beats the geometric joint fit in every draw.
void expectAnExtensionCommonToEverySetUp(std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int draw = 0; draw < 6; ++draw) {
    SimulationConfig sc = test::randomPlacement(rng);
    const RobotModel robot = test::robot(draw % 2 ? "ur10" : "staubli_tx60");
    const MeasurementKind kind = draw % 4 < 2 ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
    const Cause cause = std::array<Cause, 3>{Cause::kJointCompliance, Cause::kJointScale, Cause::kCyclicTransmission}[rng() % 3];
    // Joints 1-5: an error of joint 6 moves the target by the angle times its offset from the flange (5-60 um here),
    // too near the readings' noise for four more parameters to show against the geometric fit (seed
    // 2593690044422453576: 0.0106 against 0.0105 mm).
    const int joint = cause == Cause::kJointCompliance ? 1 + static_cast<int>(rng() % 2) : static_cast<int>(rng() % 5);
    const double size_rad = (0.1 + 0.3 * std::abs(u(rng))) * 1e-3 * (u(rng) < 0 ? -1 : 1);
    {
      const SimulatedCell plain(robot, sc);
      const auto qs = plain.randomConfigurations(200, rng);
      const auto links = robot.links.empty() ? plausibleLinks(robot, plain.trueParams(0), rng) : robot.links;
      sc.hidden = scaledHiddenEffect(robot, plain.trueParams(0), cause, joint, size_rad, links, qs, rng);
    }
    const int setups = draw < 2 ? 1 : 2 + draw % 2;
    const Extension ext{cause, joint};
    const std::string what = robot.name + (kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", " +
                             extensionSpec(ext) + " " + std::to_string(size_rad * 1e3) + " mrad, " +
                             std::to_string(setups) + " set-ups, seed " + std::to_string(seed) + " draw " +
                             std::to_string(draw);
    SetupsProblem geometric;
    geometric.model = &robot;
    std::vector<std::vector<Observation>> fresh;
    for (int s = 0; s < setups; ++s) {
      const SimulatedCell cell(robot, s == 0 ? sc : test::trackerMoved(sc, rng));
      fresh.push_back(addSetUp(robot, cell, kind, 40 + static_cast<int>(30 * std::abs(u(rng))), rng, geometric));
    }
    SetupsProblem extended = geometric;
    extended.extensions = {ext};
    const SetupsFit g = fitSetups(geometric, tightSolver()), x = fitSetups(extended, tightSolver());
    ASSERT_TRUE(g.converged && x.converged) << what;
    ASSERT_EQ(x.extension_params.size(), numExtensionParams(robot, extended.extensions)) << what;
    EXPECT_FALSE(x.estimated_extension.empty()) << what;
    double e_g = 0, e_x = 0;
    for (int s = 0; s < setups; ++s) {
      const std::vector<Drivers> none(fresh[s].size());
      e_x += meanExtendedError(robot, extended, x, s, fresh[s], none) / setups;
      e_g += meanError(robot, g.params[s], fresh[s]) / setups;
      if (setups == 1) expectAsFitExtended(robot, extended, x, fresh[0], none, what);
    }
    std::printf("  %-62s fresh mean: extended %.4f mm, geometric %.4f mm\n", what.c_str(), e_x * 1e3, e_g * 1e3);
    if (setups > 1) {
      EXPECT_LT(e_x, e_g) << what;
    }
  }
}

TEST(Setups, AnExtensionIsCommonToEverySetUp) { expectAnExtensionCommonToEverySetUp(test::testSeed()); }

// Seeds that once failed. 829672055: UR10, points, a target 2.4 mm off the flange axis, three set-ups; set-up 3's
// tool was held at its registration while joint 6's flange-side parameters were estimated, and Levenberg-Marquardt
// crawled along a rotation about the flange (joint 6's offset at -1.1 rad after 200 iterations, not converged).
TEST(Setups, SeedsThatOnceFailed) {
  for (std::uint64_t seed : {829672055ull}) {
    SCOPED_TRACE(seed);
    expectAnExtensionCommonToEverySetUp(seed);
  }
}

// A backlash is the robot's too, and its basis (the play state) depends on its width: a hidden backlash of random
// width (0.2-1.2 mrad) on a random joint 1-5, random robot, placement and measurement type; each set-up a path of
// stand-stills (the play state carried along it) whose first rows identify and the rest are fresh configurations,
// judged against their true poses. One set-up: the plain reference is fitExtended on the same rows and drivers (the
// same estimated columns and rows left out, predictions within a micrometre). Two or three: the width within a
// quarter of the truth (joints 1-3, the arm), and the extended fit beats the geometric one at the fresh
// configurations in every draw. Every set-up leaves out its rows before its backlash joint first moved.
TEST(Setups, ABacklashIsCommonToEverySetUp) {
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  for (int draw = 0; draw < 6; ++draw) {
    SimulationConfig sc = test::randomPlacement(rng);
    const RobotModel robot = test::robot(draw % 2 ? "ur10" : "staubli_tx60");
    const MeasurementKind kind = draw % 4 < 2 ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
    sc.hidden.cause = Cause::kBacklash;
    sc.hidden.joint = static_cast<int>(rng() % 5);
    sc.hidden.backlash_width_rad = 2e-4 + 1e-3 * u(rng);
    const int setups = draw < 2 ? 1 : 2 + draw % 2;
    const Extension ext{Cause::kBacklash, sc.hidden.joint};
    const std::string what = robot.name + (kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", backlash:" +
                             std::to_string(sc.hidden.joint + 1) + " " + std::to_string(sc.hidden.backlash_width_rad * 1e3) +
                             " mrad, " + std::to_string(setups) + " set-ups, seed " + std::to_string(seed) + " draw " +
                             std::to_string(draw);
    SetupsProblem geometric;
    geometric.model = &robot;
    std::vector<std::vector<Observation>> fresh;
    std::vector<std::vector<Drivers>> fresh_drivers;
    for (int s = 0; s < setups; ++s) {
      const SimulatedCell cell(robot, s == 0 ? sc : test::trackerMoved(sc, rng));
      const int n = 40 + static_cast<int>(30 * u(rng));
      const auto qs = cell.randomConfigurations(n + 60, rng);
      const DriverTable d = driversFromSequence(qs, {}, {});
      std::vector<Observation> ident, check;
      HiddenJointState state;
      for (size_t i = 0; i < qs.size(); ++i) {
        if (i) state = cell.advanceHiddenState(state, qs[i - 1], qs[i]);
        if (static_cast<int>(i) < n) {
          ident.push_back(cell.measure(qs[i], &state, 0.0, rng, kind));
        } else {
          Observation o;
          o.q_rad = qs[i];
          o.kind = kind;
          o.measured_in_tracker = cell.truePose(qs[i], 0.0, &state);
          check.push_back(o);
        }
      }
      Eigen::VectorXd start = robot.nominal;
      start.tail<12>().setZero();
      geometric.starts.push_back(registerFrames(robot, start, ident).params);
      geometric.observations.push_back(ident);
      geometric.drivers.emplace_back(d.rows.begin(), d.rows.begin() + n);
      fresh.push_back(check);
      fresh_drivers.emplace_back(d.rows.begin() + n, d.rows.end());
    }
    SetupsProblem extended = geometric;
    extended.extensions = {ext};
    const SetupsFit g = fitSetups(geometric, tightSolver()), x = fitSetups(extended, tightSolver());
    ASSERT_TRUE(g.converged && x.converged) << what;
    ASSERT_EQ(x.rows_left_out.size(), static_cast<size_t>(setups)) << what;
    ASSERT_EQ(x.estimated_extension, std::vector<int>{0}) << what;
    double e_g = 0, e_x = 0;
    for (int s = 0; s < setups; ++s) {
      EXPECT_GE(x.rows_left_out[s], 1) << what << ": the first row's play state is unknown";
      e_x += meanExtendedError(robot, extended, x, s, fresh[s], fresh_drivers[s]) / setups;
      e_g += meanError(robot, g.params[s], fresh[s]) / setups;
      if (setups == 1) expectAsFitExtended(robot, extended, x, fresh[0], fresh_drivers[0], what);
    }
    std::printf("  %-62s width %.4f mrad (true %.4f), fresh mean: extended %.4f mm, geometric %.4f mm\n", what.c_str(),
                -x.extension_params[0] * 1e3, sc.hidden.backlash_width_rad * 1e3, e_x * 1e3, e_g * 1e3);
    if (setups > 1) {
      // Joints 1-3 move the target through the arm (>= 0.3 m): the width to a quarter. A wrist joint moves it through
      // the wrist-to-target offset only, where 0.2 mrad is 10-20 um, below the readings' noise (seed 959142572:
      // joint 5, 0.141 mrad for 0.201; seed 307381180: TX60 joint 4, 0.275 for 0.213); there the fresh error alone
      // is judged.
      if (sc.hidden.joint < 3) {
        EXPECT_NEAR(-x.extension_params[0], sc.hidden.backlash_width_rad, 0.25 * sc.hidden.backlash_width_rad) << what;
      }
      EXPECT_LT(e_x, e_g) << what;
    }
  }
}

}  // namespace
}  // namespace cellcal
