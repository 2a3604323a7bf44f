// Batch identification recovers geometric errors hidden at random (errors, poses and noise drawn from a fresh seed;
// the solvers see only the nominal model and the noisy measurements).
#include <gtest/gtest.h>

#include <filesystem>

#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/placements.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

enum class Solver { kGaussNewton, kLevenbergMarquardt };

struct Setup {
  std::string robot;
  MeasurementKind kind;
  Solver solver;
};

class Identification : public ::testing::TestWithParam<Setup> {};

CalibrationResult solve(Solver s, const CalibrationProblem& p) {
  return s == Solver::kGaussNewton ? solveGaussNewton(p) : solveLevenbergMarquardt(p);
}

TEST_P(Identification, RecoversInjectedErrorsToTheNoiseFloor) {
  const auto [robot, kind, solver] = GetParam();
  SimulationConfig sc;
  sc.seed = test::testSeed();
  SimulatedCell cell(test::robot(robot), sc);
  std::mt19937_64 rng(sc.seed + 1);
  std::vector<Observation> ident, verify;
  for (const auto& q : cell.randomConfigurations(60, rng)) ident.push_back(cell.measure(q, 0.0, rng, kind));
  for (const auto& q : cell.randomConfigurations(60, rng)) verify.push_back(cell.measure(q, 0.0, rng, kind));
  const Eigen::VectorXd truth = cell.trueParams(0.0);
  const double floor = mean(positionErrors(cell.model(), truth, verify));
  const double before = mean(positionErrors(cell.model(), cell.nominalParams(), verify));
  ASSERT_GT(before, 10 * floor);  // the hidden errors are far above the noise

  CalibrationProblem p{&cell.model(), cell.nominalParams(), ident, std::nullopt, {}, {}};
  const CalibrationResult r = solve(solver, p);
  EXPECT_TRUE(r.converged) << r.message;
  EXPECT_LT(r.final_cost_per_observation, r.initial_cost_per_observation / 100);
  const double after = mean(positionErrors(cell.model(), r.params, verify));
  EXPECT_LT(after, 1.3 * floor) << "before " << before * 1e3 << " mm, floor " << floor * 1e3 << " mm";
  // Whitened cost per observation ~ rows/2 for a consistent noise model (chi-square): within a factor of 2.
  const double rows = kind == MeasurementKind::kPose6D ? 6 : 3;
  EXPECT_LT(r.final_cost_per_observation, rows);
  EXPECT_GT(r.final_cost_per_observation, rows / 8);

  // Intrinsic geometry (distances and angles between consecutive axes) matches the truth within 5 sigma.
  const RobotModel& m = cell.model();
  const auto named = r.parameters(m, cell.nominalParams());
  for (int idx : {m.jointParam(1, JointParam::kA), m.jointParam(3, JointParam::kAlpha),
                  m.jointParam(4, JointParam::kAlpha)}) {
    ASSERT_TRUE(named[idx].estimated) << named[idx].name;
    const double err = named[idx].value - m.toHuman(idx, truth[idx]);
    EXPECT_LT(std::abs(err), 5 * named[idx].stddev + 1e-9)
        << named[idx].name << ": error " << err << ", sigma " << named[idx].stddev;
    // Where the data resolve the hidden error (it exceeds 5 sigma), the estimate must also have moved toward it;
    // an error below the resolution (3D data resolve alpha angles to ~0.01 deg) may legitimately stay put.
    const double initial_err = named[idx].initial - m.toHuman(idx, truth[idx]);
    if (std::abs(initial_err) > 5 * named[idx].stddev) {
      EXPECT_LT(std::abs(err), std::abs(initial_err)) << named[idx].name << " did not move toward the truth";
    }
  }
  // Dropped (merged) parameters stay exactly where they started.
  for (const auto& d : r.identifiability.dropped) EXPECT_EQ(r.params[d.index], cell.nominalParams()[d.index]);
}

INSTANTIATE_TEST_SUITE_P(
    All, Identification,
    ::testing::Values(Setup{"staubli_tx60", MeasurementKind::kPose6D, Solver::kGaussNewton},
                      Setup{"staubli_tx60", MeasurementKind::kPose6D, Solver::kLevenbergMarquardt},
                      Setup{"staubli_tx60", MeasurementKind::kPosition3D, Solver::kGaussNewton},
                      Setup{"staubli_tx60", MeasurementKind::kPosition3D, Solver::kLevenbergMarquardt},
                      Setup{"ur10", MeasurementKind::kPose6D, Solver::kGaussNewton},
                      Setup{"ur10", MeasurementKind::kPosition3D, Solver::kLevenbergMarquardt}),
    [](const ::testing::TestParamInfo<Setup>& i) {
      return i.param.robot + (i.param.kind == MeasurementKind::kPose6D ? "_6D_" : "_3D_") +
             (i.param.solver == Solver::kGaussNewton ? "GaussNewton" : "LevenbergMarquardt");
    });

TEST(IdentificationProblem, InvalidProblemsAreReportedNotCrashed) {
  const RobotModel m = test::robot("staubli_tx60");
  CalibrationProblem p{&m, m.nominal, {}, std::nullopt, {}, {}};
  std::string e;
  EXPECT_FALSE(p.IsValid(&e));
  EXPECT_NE(e.find("no observations"), std::string::npos);
  Observation o;
  o.q_rad = Eigen::VectorXd::Zero(5);
  p.observations.push_back(o);
  EXPECT_FALSE(p.IsValid(&e));
  EXPECT_NE(e.find("observation 0"), std::string::npos) << e;
  EXPECT_THROW(solveGaussNewton(p), std::invalid_argument);
  EXPECT_THROW(solveLevenbergMarquardt(p), std::invalid_argument);
}

TEST(IdentificationSolvers, GaussNewtonAndLevenbergMarquardtAgree) {
  SimulationConfig sc;
  sc.seed = test::testSeed();
  SimulatedCell cell(test::robot("staubli_tx60"), sc);
  std::mt19937_64 rng(sc.seed);
  std::vector<Observation> obs;
  for (const auto& q : cell.randomConfigurations(50, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  CalibrationProblem p{&cell.model(), cell.nominalParams(), obs, std::nullopt, {}, {}};
  const auto gn = solveGaussNewton(p), lm = solveLevenbergMarquardt(p);
  ASSERT_EQ(gn.estimated, lm.estimated);
  for (size_t k = 0; k < gn.estimated.size(); ++k) {
    const int i = gn.estimated[k];
    EXPECT_NEAR(gn.params[i], lm.params[i], 0.01 * std::sqrt(gn.covariance(k, k))) << cell.model().paramName(i);
  }
}

// A measurement campaign as trackers are often run: a Cartesian grid at one tool orientation, points only, the target
// 0.1-0.2 mm off the flange axis (an SMR in a nest on the flange), and an effect the geometric model does not hold
// (joint compliance or a cyclic transmission error of a random joint among 1-3, random size), on the TX60, the UR10 and,
// where ../shared has it, the UR5 from its URDF; random errors, placement, grid, seed. Rank alone keeps parameters the
// grid barely separates (joint 4 and 5's, tens of mm and degrees of 1 sigma), and their values wander; with the
// plausible ranges (identifiability.hpp) the fit converges, every parameter it estimates stays within a few
// plausible deviations of the file's value with a 1 sigma below that range, the noise scale is the one the fit
// leaves, and the held-out rows of the grid are predicted about as well as by the rank-only fit where that converged
// (and far better where it did not). Away from the grid (other orientations) neither fit can be trusted: printed.
TEST(IdentificationPlausibleRanges, AGridAtOneToolOrientationConvergesOnWhatTheRowsPin) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0, 1);
  const std::vector<RobotModel> robots = test::robotsWithUr5();
  int draws = 0, wandering = 0, compared = 0;
  double ratio_sum = 0;
  for (int trial = 0; trial < 40 && draws < 6; ++trial) {
    const RobotModel& file = robots[static_cast<size_t>(draws) % robots.size()];
    SimulationConfig sc = test::randomPlacement(rng);
    test::nearAxisTarget(sc, rng);
    const SimulatedCell plain(file, sc);
    const RobotModel& m = plain.model();
    KinematicsData data(m);
    double edge = 0;
    const std::vector<Eigen::VectorXd> qs = test::gridAtOneOrientation(plain, 6, rng, &edge);
    if (qs.size() < 100) continue;  // a cube the robot does not reach from there: another draw
    const Cause cause = u(rng) < 0.5 ? Cause::kJointCompliance : Cause::kCyclicTransmission;
    const int joint = static_cast<int>(3 * u(rng)) % 3;
    const double size_rad = (0.01 + 0.04 * u(rng)) * kPi / 180 * (u(rng) < 0.5 ? -1 : 1);
    sc.hidden = scaledHiddenEffect(m, plain.trueParams(0), cause, joint, size_rad,
                                   file.links.empty() ? plausibleLinks(m, plain.trueParams(0), rng) : file.links, qs, rng);
    const SimulatedCell cell(file, sc);
    std::vector<Observation> ident, verify, elsewhere;
    for (size_t i = 0; i < qs.size(); ++i)
      (i % 2 ? verify : ident).push_back(cell.measure(qs[i], 0.0, rng, MeasurementKind::kPosition3D));
    for (const auto& q : cell.randomConfigurations(200, rng))
      elsewhere.push_back(cell.measure(q, 0.0, rng, MeasurementKind::kPosition3D));
    const Eigen::VectorXd start = registerFrames(m, m.nominal, ident).params;
    CalibrationProblem p{&m, start, ident, std::nullopt, {}, {}};
    const CalibrationResult rank_only = solveGaussNewton(p);
    p.identifiability.prior_sigma = plausibleDeviation(m);
    const CalibrationResult r = solveGaussNewton(p);
    ++draws;
    auto meanError = [&](const Eigen::VectorXd& params, const std::vector<Observation>& rows) {
      double sum = 0;
      for (const auto& o : rows)
        sum += (forwardKinematics(m, data, params, o.q_rad).translation() - o.measured_in_tracker.translation()).norm();
      return sum / static_cast<double>(rows.size());
    };
    auto verifyMean = [&](const Eigen::VectorXd& params) { return meanError(params, verify); };
    const std::string what = m.name + " grid " + std::to_string(qs.size()) + " points, edge " + std::to_string(edge) +
                             " m, " + causeName(cause) + " joint " + std::to_string(joint + 1) + ", " +
                             std::to_string(size_rad * 180 / kPi) + " deg\n" + r.identifiability.summary(m);
    double worst_rank_only = 0;  // the largest 1 sigma over its plausible range among the rank-only fit's kinematics
    for (size_t k = 0; k < rank_only.estimated.size(); ++k) {
      const int c = rank_only.estimated[k];
      if (c < 5 * m.numJoints())
        worst_rank_only = std::max(worst_rank_only, std::sqrt(rank_only.covariance(k, k)) / p.identifiability.prior_sigma[c]);
    }
    wandering += worst_rank_only > 1;
    EXPECT_TRUE(r.converged) << r.message << "\n" << what;
    // The noise scale is the first fit's: at least 1, at most what the final fit (as many parameters or fewer) leaves.
    Eigen::VectorXd res;
    stackResiduals(m, r.params, ident, res, nullptr);
    const double final_scale = std::sqrt(res.squaredNorm() / static_cast<double>(res.size() - static_cast<Eigen::Index>(r.estimated.size())));
    EXPECT_GE(r.identifiability.noise_scale, 1.0) << what;
    EXPECT_LE(r.identifiability.noise_scale, std::max(1.0, final_scale) * 1.01) << what;
    for (size_t k = 0; k < r.estimated.size(); ++k) {
      const int c = r.estimated[k];
      if (c >= 5 * m.numJoints()) continue;
      const double range = p.identifiability.prior_sigma[c];
      EXPECT_LT(std::abs(r.params[c] - start[c]), 5 * range) << m.paramName(c) << "\n" << what;
      EXPECT_LT(std::sqrt(r.covariance(k, k)), range) << m.paramName(c) << "\n" << what;
    }
    const double mean = verifyMean(r.params), mean_rank = verifyMean(rank_only.params), before = verifyMean(start);
    EXPECT_LT(mean, before) << what;
    // Within the grid the wandering parameters of the rank-only fit take up some of the unmodelled effect: holding
    // them costs a little there. Measured over 76 draws (15 runs): the rank-only fit did not converge in 13; where it
    // did, the held-out ratio was 1.00 at the median, 0.98 on average, 1.25 at the most.
    if (rank_only.converged) {
      EXPECT_LT(mean, 1.4 * mean_rank) << what;
      ratio_sum += mean / mean_rank;
      ++compared;
    }
    std::printf("%s: held-out %.4f mm (rank only %.4f%s, before %.4f), elsewhere %.3f (rank only %.3f, before %.3f), %zu estimated (rank only %zu), noise x%.1f, rank "
                "only's widest kinematic sigma %.1fx its range\n",
                m.name.c_str(), mean * 1e3, mean_rank * 1e3, rank_only.converged ? "" : " NOT converged", before * 1e3,
                meanError(r.params, elsewhere) * 1e3, meanError(rank_only.params, elsewhere) * 1e3, meanError(start, elsewhere) * 1e3,
                r.estimated.size(), rank_only.estimated.size(), r.identifiability.noise_scale, worst_rank_only);
  }
  EXPECT_EQ(draws, 6);
  if (compared > 0) {
    EXPECT_LT(ratio_sum / compared, 1.1);
  }
  EXPECT_GE(2 * wandering, draws) << "the rank-only fit pinned every parameter in most draws: these grids were easy";
}

}  // namespace
}  // namespace cellcal
