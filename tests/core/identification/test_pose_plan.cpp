// Planning a campaign (identification/pose_plan.hpp): on random robots (the TX60 and UR10 robot files, and an arm of
// ../shared/robots/ros-industrial from its URDF), random tracker placements and targets, points and 6D, K = 25 planned
// poses are measured by the simulated tracker and calibrated; the held-out error against the truth is compared with
// that of 25 (and, printed, of 100) random poses the tracker can also see (drawn here, plainly). Every planned configuration is
// within the limits, the tracker's range and its line of sight. The observability indices of the planned set are
// checked against a plain computation (the SVD written out here) and beat the random set's.
#include <gtest/gtest.h>

#include <Eigen/SVD>
#include <filesystem>
#include <random>

#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/pose_plan.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;

// The tracker head in the robot's base frame: the origin of the tracker frame.
Eigen::Vector3d trackerInBase(const Eigen::Matrix<double, 6, 1>& base_in_tracker) {
  const Pose B = poseFromXyzRpy(base_in_tracker[0], base_in_tracker[1], base_in_tracker[2], base_in_tracker[3],
                                base_in_tracker[4], base_in_tracker[5]);
  return B.inverse().translation();
}

// Random configurations within 90 % of the limits that the tracker sees (the same rules the planner applies, drawn
// here by the test itself).
std::vector<Eigen::VectorXd> visibleRandom(const RobotModel& m, const Eigen::VectorXd& params, const TrackerSetup& t,
                                           int count, std::mt19937_64& rng) {
  std::vector<Eigen::VectorXd> out;
  Eigen::VectorXd p0 = params;
  p0.segment<6>(m.baseParam(FrameParam::kX)).setZero();
  KinematicsData data(m);
  for (int tries = 0; static_cast<int>(out.size()) < count && tries < 200 * count; ++tries) {
    Eigen::VectorXd q(m.numJoints());
    for (int j = 0; j < m.numJoints(); ++j) {
      const double lo = std::max(m.limits[static_cast<size_t>(j)].lower_rad, -kPi) * 0.9;
      const double hi = std::min(m.limits[static_cast<size_t>(j)].upper_rad, kPi) * 0.9;
      q[j] = std::uniform_real_distribution<double>(lo, hi)(rng);
    }
    if (forwardKinematics(m, data, p0, q).translation().head<2>().norm() < 0.2) continue;
    if (visibility(m, params, q, t) == Visibility::kVisible) out.push_back(q);
  }
  return out;
}

// Calibrated from readings of `qs` (Gauss-Newton from the nominal model, the uncalibrated robot's prior), the mean
// position error against the truth on `verify`; averaged over `repeats` draws of the readings' noise (one draw's error
// scatters by a third about its expectation, which would hide a gain of a sixth).
double heldOutError(const SimulatedCell& cell, const std::vector<Eigen::VectorXd>& qs,
                    const std::vector<Eigen::VectorXd>& verify, MeasurementKind kind, std::mt19937_64& rng, int repeats) {
  const RobotModel& m = cell.model();
  KinematicsData data(m);
  double sum = 0;
  for (int r = 0; r < repeats; ++r) {
    CalibrationProblem problem;
    problem.model = &m;
    problem.initial_params = m.nominal;
    for (const auto& q : qs) problem.observations.push_back(cell.measure(q, 0.0, rng, kind));
    problem.prior = diagonalPrior(m, m.nominal, m.canonicalParams(), 1e-3, degToRad(0.1));
    const CalibrationResult c = solveGaussNewton(problem);
    for (const auto& q : verify)
      sum += (forwardKinematics(m, data, c.params, q).translation() - cell.truePose(q, 0.0).translation()).norm();
  }
  return sum / static_cast<double>(verify.size() * static_cast<size_t>(repeats));
}

TEST(PosePlan, PlannedPosesCalibrateBetterThanAsManyRandomOnes) {
  std::mt19937_64 rng(test::testSeed());
  const fs::path arms = fs::path(CELLCAL_CONFIG_DIR) / "../../shared/robots/ros-industrial";
  std::vector<fs::path> urdfs;
  if (fs::is_directory(arms))
    for (const auto& e : fs::recursive_directory_iterator(arms))
      if (e.path().extension() == ".urdf") urdfs.push_back(e.path());
  std::sort(urdfs.begin(), urdfs.end());
  const int draws = 20;
  int no_worse_than_100 = 0, better_than_25 = 0, indices_better = 0;
  double sum_planned = 0, sum_25 = 0, sum_100 = 0;
  for (int draw = 0; draw < draws; ++draw) {
    test::RandomDraw d = test::randomDraw(rng);
    RobotModel nominal;
    if (!urdfs.empty() && draw % 3 == 2) {
      const fs::path f = urdfs[rng() % urdfs.size()];
      nominal = loadRobotModel(f.string());
      d.name = f.filename().string();
    } else {
      nominal = test::robot(d.name);
    }
    const SimulatedCell cell(nominal, d.sc);
    const RobotModel& m = cell.model();
    TrackerSetup tracker;
    tracker.position_in_base_m = trackerInBase(d.sc.base_in_tracker);
    tracker.min_range_m = 0.5;
    tracker.max_range_m = 6.0;
    PosePlanOptions o;
    o.count = 25;
    o.candidates = 1000;
    o.kind = d.kind;
    o.tracker = tracker;
    o.seed = rng();
    o.sigma_position_m = d.sc.tracker.sigmaPosition(2.5);
    o.sigma_orientation_rad = d.sc.tracker.sigmaOrientation();
    SCOPED_TRACE(d.name + (d.kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", draw " + std::to_string(draw));
    const PosePlan plan = planPoses(m, m.nominal, o);
    ASSERT_EQ(plan.chosen_q.size(), 25u);
    for (const auto& q : plan.chosen_q) {
      for (int j = 0; j < m.numJoints(); ++j) {
        EXPECT_GE(q[j], m.limits[static_cast<size_t>(j)].lower_rad);
        EXPECT_LE(q[j], m.limits[static_cast<size_t>(j)].upper_rad);
      }
      EXPECT_EQ(visibility(m, m.nominal, q, tracker), Visibility::kVisible);
    }
    // The indices of the planned set against a plain SVD of the same scaled Jacobian.
    {
      KinematicsData data(m);
      Eigen::MatrixXd J(6, m.numParams());
      const int rows = d.kind == MeasurementKind::kPose6D ? 6 : 3;
      Eigen::MatrixXd A(25 * rows, static_cast<Eigen::Index>(plan.estimated.size()));
      for (int i = 0; i < 25; ++i) {
        forwardKinematics(m, data, m.nominal, plan.chosen_q[static_cast<size_t>(i)]);
        computePoseJacobian(m, data, J);
        for (size_t k = 0; k < plan.estimated.size(); ++k) {
          const int c = plan.estimated[k];
          const double scale = m.isLength(c) ? o.prior_length_m : o.prior_angle_rad;
          for (int r = 0; r < rows; ++r)
            A(i * rows + r, static_cast<Eigen::Index>(k)) = J(r, c) * scale / (r < 3 ? o.sigma_position_m : o.sigma_orientation_rad);
        }
      }
      const Eigen::VectorXd s = Eigen::JacobiSVD<Eigen::MatrixXd>(A).singularValues();
      const double sn = s[s.size() - 1];
      EXPECT_NEAR(plan.chosen.O3, sn, 1e-9 * s[0]);
      EXPECT_NEAR(plan.chosen.O2, sn / s[0], 1e-9);
      EXPECT_NEAR(plan.chosen.O4, sn * sn / s[0], 1e-9 * s[0]);
      double product = 1;
      for (Eigen::Index k = 0; k < s.size(); ++k) product *= std::pow(s[k], 1.0 / static_cast<double>(s.size()));
      EXPECT_NEAR(plan.chosen.O1, product / std::sqrt(static_cast<double>(A.rows())), 1e-9 * product);
    }
    indices_better += plan.chosen.O1 > plan.random.O1 && plan.chosen_predicted_rms_m < plan.random_predicted_rms_m;
    const auto random100 = visibleRandom(m, m.nominal, tracker, 100, rng);
    const auto random25 = visibleRandom(m, m.nominal, tracker, 25, rng);
    const auto verify = visibleRandom(m, m.nominal, tracker, 300, rng);
    ASSERT_EQ(random100.size(), 100u);
    const double planned = heldOutError(cell, plan.chosen_q, verify, d.kind, rng, 5);
    const double r100 = heldOutError(cell, random100, verify, d.kind, rng, 5);
    const double r25 = heldOutError(cell, random25, verify, d.kind, rng, 5);
    sum_planned += planned;
    sum_25 += r25;
    sum_100 += r100;
    no_worse_than_100 += planned <= r100;
    better_than_25 += planned < r25;
    const double p100 = predictedPositionRms(m, m.nominal, plan.estimated, plan.prior_covariance, random100, plan.feasible_q, o);
    std::printf("  %-18s %-6s held-out planned 25 %.4f, random 25 %.4f, random 100 %.4f mm; predicted %.4f, %.4f, %.4f mm; "
                "O1 %.3g vs %.3g (%d visible, %d swaps)\n",
                d.name.c_str(), d.kind == MeasurementKind::kPose6D ? "6D" : "points", planned * 1e3, r25 * 1e3,
                r100 * 1e3, plan.chosen_predicted_rms_m * 1e3, plan.random_predicted_rms_m * 1e3, p100 * 1e3,
                plan.chosen.O1, plan.random.O1, plan.feasible, plan.exchanges);
  }
  std::printf("  %d draws: planned 25 no worse than random 100 in %d, better than random 25 in %d; indices and "
              "predicted error better in %d; mean held-out planned 25 %.4f, random 25 %.4f, random 100 %.4f mm\n", draws,
              no_worse_than_100, better_than_25, indices_better, sum_planned / draws * 1e3, sum_25 / draws * 1e3,
              sum_100 / draws * 1e3);
  // Measured over 220 draws (11 runs): planned 25 better than random 25 (each averaged over 5 noise draws) in 92 %;
  // at 92 %, 13 or fewer of 20 has a chance of 6e-4. The mean held-out error over the draws: planned 0.81-0.86 of
  // random 25's. Random 100 are better in every draw (0.009 against 0.017 mm): measuring 4x as many poses averages
  // the noise by 2x, which choosing among the poses the tracker sees does not reach (the predicted errors say the same:
  // planned 25 0.014-0.016, random 25 0.016-0.021, random 100 0.007-0.008 mm); printed, not asserted.
  EXPECT_GE(better_than_25, 14);
  EXPECT_LT(sum_planned, 0.95 * sum_25);
}

}  // namespace
}  // namespace cellcal
