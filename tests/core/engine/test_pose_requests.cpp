// The engine's pose requests (core/engine/pose_requests.hpp) on random robots, registrations, targets and measurement
// types (points or 6D):
//  - what is proposed: candidates the tracker can measure, within the limits, distinct; the first one is the plain
//    argmax of the predicted variance's reduction written out here in the information form (a different formula from
//    the selection's covariance update); the predicted figures against a plain computation;
//  - what following them gains: an engine that measures, pose after pose, the first configuration of its newest
//    proposal it has not measured yet, against an engine that measures as many configurations drawn at random from
//    the same measurable candidates; both judged on the truth's error over configurations of the whole workspace.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <random>

#include "cellcal/core/engine/pose_requests.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/engine/engine_feed.hpp"
#include "core/identification/hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

// A robot of the draw in a cell registered as drawn (the engine's nominal frames), and its simulated truth.
struct Draw {
  test::RandomDraw d;
  CellRobot robot;
  std::unique_ptr<SimulatedCell> cell;
};
Draw makeDraw(std::mt19937_64& rng) {
  Draw w;
  w.d = test::randomDraw(rng);
  w.robot.robot_id = "r";
  w.robot.target_id = "t";
  w.robot.measurement = w.d.kind;
  w.robot.model = test::robot(w.d.name);
  RobotModel& m = w.robot.model;
  m.nominal.segment<6>(m.baseParam(FrameParam::kX)) = w.d.sc.base_in_tracker;
  m.nominal.segment<6>(m.toolParam(FrameParam::kX)) = w.d.sc.tool_in_flange;
  w.cell = std::make_unique<SimulatedCell>(m, w.d.sc);
  return w;
}

// One reading of configuration q fed to the engine at cell time t_s (a stand-still around it), as a cell would.
struct PoseFeed {
  const SimulatedCell& cell;
  MeasurementKind kind;
  std::mt19937_64 rng;
  std::uint64_t seq = 0;
  void measure(CalibrationEngine& engine, const Eigen::VectorXd& q, double t_s) {
    const std::int64_t t = 1'700'000'000'000'000'000 + static_cast<std::int64_t>(t_s * 1e9);
    const Observation o = cell.measure(q, t_s / 3600.0, rng, kind);
    TrackerSample s = test::trackerSample(o, t, ++seq);
    s.has_orientation = kind == MeasurementKind::kPose6D;
    for (int i = 0; i < 3; ++i) {
      s.covariance[i * 7] = o.sigma_position_m * o.sigma_position_m;
      s.covariance[(i + 3) * 7] = o.sigma_orientation_rad * o.sigma_orientation_rad;
    }
    engine.onJointState({t - 1000, ++seq, q, true}, t - 1000);
    engine.onTrackerSample(s, t);
    engine.onJointState({t + 1000, ++seq, q, true}, t + 1000);
    engine.process(t + 2000);
  }
};

double heldOut(const SimulatedCell& cell, const CalibrationSnapshot& s, const std::vector<Eigen::VectorXd>& verify, double t_s) {
  KinematicsData d(cell.model());
  double sum = 0;
  for (const auto& q : verify)
    sum += (forwardKinematics(cell.model(), d, s.params, q).translation() - cell.truePose(q, t_s / 3600.0).translation()).norm();
  return sum / static_cast<double>(verify.size());
}

TEST(PoseRequests, TheProposalIsMeasurableAndItsFirstPoseIsThePlainBest) {
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 6; ++draw) {
    Draw w = makeDraw(rng);
    SCOPED_TRACE(w.d.name + (w.d.kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", draw " + std::to_string(draw));
    const RobotModel& m = w.robot.model;
    PoseRequestSettings s;
    s.count = 8;
    s.candidates = 300;
    s.min_range_m = 0.3;
    s.max_range_m = 8.0;
    EngineSettings es;
    CalibrationEngine engine(w.robot, es, 1.0);
    const PoseRequester req(w.robot, s, rng());
    // An estimate some poses in (0-12 of them, random).
    PoseFeed feed{*w.cell, w.d.kind, std::mt19937_64(rng())};
    const int poses = static_cast<int>(rng() % 13);
    std::mt19937_64 qrng(rng());
    for (const auto& q : w.cell->randomConfigurations(poses, qrng)) feed.measure(engine, q, 30.0 * feed.seq);
    const CalibrationSnapshot& snap = engine.snapshot();
    const PoseProposal p = req.propose(snap);
    ASSERT_EQ(p.q_rad.size(), 8u);
    EXPECT_EQ(p.version, snap.version);
    TrackerSetup t;
    t.position_in_base_m = req.trackerInBase_m();
    t.min_range_m = 0.3;
    t.max_range_m = 8.0;
    for (size_t i = 0; i < p.q_rad.size(); ++i) {
      EXPECT_EQ(visibility(m, m.nominal, p.q_rad[i], t), Visibility::kVisible);
      for (int j = 0; j < m.numJoints(); ++j) {
        EXPECT_GE(p.q_rad[i][j], m.limits[static_cast<size_t>(j)].lower_rad);
        EXPECT_LE(p.q_rad[i][j], m.limits[static_cast<size_t>(j)].upper_rad);
      }
      for (size_t k = 0; k < i; ++k) EXPECT_GT((p.q_rad[i] - p.q_rad[k]).norm(), 0.0);
    }
    // Plain: the position Jacobians over the estimated columns, the information form of one more measurement.
    const auto n = static_cast<Eigen::Index>(snap.estimated.size());
    const Eigen::MatrixXd P = snap.covariance.topLeftCorner(n, n);
    KinematicsData data(m);
    Eigen::MatrixXd J(6, m.numParams());
    const int rows = w.d.kind == MeasurementKind::kPose6D ? 6 : 3;
    const auto& cand = req.candidates().q;
    std::vector<Eigen::MatrixXd> A, B;
    Eigen::MatrixXd M = Eigen::MatrixXd::Zero(n, n);
    for (const auto& q : cand) {
      forwardKinematics(m, data, snap.params, q);
      computePoseJacobian(m, data, J);
      Eigen::MatrixXd a(rows, n), b(3, n);
      for (Eigen::Index k = 0; k < n; ++k) {
        const int c = snap.estimated[static_cast<size_t>(k)];
        for (int r = 0; r < rows; ++r) a(r, k) = J(r, c) / (r < 3 ? s.sigma_position_m : s.sigma_orientation_rad);
        b.col(k) = J.col(c).head<3>();
      }
      M += b.transpose() * b;
      A.push_back(a);
    }
    const double now = std::sqrt((M * P).trace() / static_cast<double>(cand.size()));
    EXPECT_NEAR(p.predicted_sigma_now_m, now, 1e-9 * now);
    const Eigen::MatrixXd I = Eigen::MatrixXd::Identity(n, n);
    const Eigen::MatrixXd info = P.llt().solve(I);
    double best = -1;
    size_t best_i = 0;
    std::vector<double> gain(cand.size());
    for (size_t i = 0; i < cand.size(); ++i) {
      const Eigen::MatrixXd Pi = (info + A[i].transpose() * A[i]).llt().solve(I);
      gain[i] = (M * (P - Pi)).trace();
      if (gain[i] > best) best = gain[i], best_i = i;
    }
    size_t first = cand.size();
    for (size_t i = 0; i < cand.size(); ++i)
      if (cand[i] == p.q_rad[0]) first = i;
    ASSERT_LT(first, cand.size());
    EXPECT_GE(gain[first], best * (1 - 1e-6)) << "proposed candidate " << first << ", the plain best is " << best_i;
    // After all eight: the information of the eight added at once.
    Eigen::MatrixXd info8 = info;
    for (const auto& q : p.q_rad)
      for (size_t i = 0; i < cand.size(); ++i)
        if (cand[i] == q) info8 += A[i].transpose() * A[i];
    const double after = std::sqrt((M * info8.llt().solve(I)).trace() / static_cast<double>(cand.size()));
    EXPECT_NEAR(p.predicted_sigma_after_m, after, 1e-6 * after);
    EXPECT_LT(p.predicted_sigma_after_m, p.predicted_sigma_now_m);
  }
}

TEST(PoseRequests, TooFewMeasurableCandidatesAreRefusedSayingWhy) {
  std::mt19937_64 rng(test::testSeed());
  Draw w = makeDraw(rng);
  PoseRequestSettings s;
  s.candidates = 50;
  s.count = 10;
  s.max_range_m = 0.01;  // nothing within 1 cm of the tracker
  try {
    PoseRequester r(w.robot, s, 1);
    FAIL() << "no candidate is within range";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("out of the tracker's range"), std::string::npos) << e.what();
  }
  s.count = 0;
  s.max_range_m = 0;
  EXPECT_THROW(PoseRequester(w.robot, s, 1), std::invalid_argument);
}

// Fifteen poses from an uncalibrated start (the paper's update size): an engine that follows its proposals (each pose
// the first configuration of its newest proposal not measured yet) against as many random configurations of the same
// measurable candidates. The configurations it follows hardly depend on the readings' values (the covariance does
// not), so each set is then measured again under `repeats` draws of the noise and the held-out errors averaged: one
// draw's error scatters by a third about its expectation, more than the gain. Also compared, free of noise: the
// predicted position error (RMS over the candidates) of each engine at the end.
TEST(PoseRequests, FollowingTheProposalsCalibratesBetterThanRandomPoses) {
  std::mt19937_64 rng(test::testSeed());
  const int draws = 24, poses = 15, repeats = 4;
  int better = 0, predicted_better = 0;
  double sum_follow = 0, sum_random = 0;
  for (int draw = 0; draw < draws; ++draw) {
    Draw w = makeDraw(rng);
    SCOPED_TRACE(w.d.name + (w.d.kind == MeasurementKind::kPose6D ? " 6D" : " points") + ", draw " + std::to_string(draw));
    PoseRequestSettings s;
    s.count = 3;
    s.candidates = 300;
    const PoseRequester req(w.robot, s, rng());
    std::mt19937_64 vrng(rng());
    const std::vector<Eigen::VectorXd> verify = w.cell->randomConfigurations(200, vrng);
    EngineSettings es;
    // Following: each pose the first configuration of the newest proposal not measured yet.
    CalibrationEngine follow(w.robot, es, 1.0);
    PoseFeed ff{*w.cell, w.d.kind, std::mt19937_64(rng())};
    std::vector<Eigen::VectorXd> visited;
    for (int k = 0; k < poses; ++k) {
      const PoseProposal p = req.propose(follow.snapshot());
      const Eigen::VectorXd* next = nullptr;
      for (const auto& q : p.q_rad) {
        bool seen = false;
        for (const auto& v : visited) seen = seen || v == q;
        if (!seen) {
          next = &q;
          break;
        }
      }
      ASSERT_NE(next, nullptr);
      visited.push_back(*next);
      ff.measure(follow, *next, 30.0 * k);
    }
    ASSERT_EQ(follow.snapshot().poses_used, static_cast<unsigned>(poses));
    // Random: as many of the same measurable candidates.
    std::vector<Eigen::VectorXd> pool = req.candidates().q;
    std::shuffle(pool.begin(), pool.end(), rng);
    pool.resize(poses);
    const double t_end = 30.0 * poses;
    auto run = [&](const std::vector<Eigen::VectorXd>& qs, std::uint64_t noise, double* predicted) {
      CalibrationEngine e(w.robot, es, 1.0);
      PoseFeed f{*w.cell, w.d.kind, std::mt19937_64(noise)};
      for (int k = 0; k < poses; ++k) f.measure(e, qs[static_cast<size_t>(k)], 30.0 * k);
      EXPECT_EQ(e.snapshot().poses_used, static_cast<unsigned>(poses));
      if (predicted) *predicted = req.propose(e.snapshot()).predicted_sigma_now_m;
      return heldOut(*w.cell, e.snapshot(), verify, t_end);
    };
    double ef = 0, er = 0, pf = 0, pr = 0;
    for (int r = 0; r < repeats; ++r) {
      const std::uint64_t noise = rng();
      ef += run(visited, noise, r == 0 ? &pf : nullptr) / repeats;
      er += run(pool, noise, r == 0 ? &pr : nullptr) / repeats;
    }
    sum_follow += ef;
    sum_random += er;
    better += ef < er;
    predicted_better += pf < pr;
    std::printf("  %-14s %-6s after %d poses: held-out following the proposals %.4f mm, random %.4f mm (uncalibrated "
                "%.3f mm); predicted %.4f against %.4f mm\n",
                w.d.name.c_str(), w.d.kind == MeasurementKind::kPose6D ? "6D" : "points", poses, ef * 1e3, er * 1e3,
                heldOut(*w.cell, CalibrationEngine(w.robot, es, 1.0).snapshot(), verify, t_end) * 1e3, pf * 1e3, pr * 1e3);
  }
  std::printf("  %d draws: following better in %d (predicted: %d); mean %.4f against %.4f mm (%.2f)\n", draws, better,
              predicted_better, sum_follow / draws * 1e3, sum_random / draws * 1e3, sum_follow / sum_random);
  // Measured at 12 draws a run over 1,440 draws (120 runs): the held-out error lower in 82.6 % of the draws, the
  // predicted one in 1,437; a run's mean 0.867 of random's, with a run-to-run deviation of 0.036 (0.026 expected at
  // 24 draws). At 12 draws and 7 required, 4 runs of 141 failed (fresh-clone CI of 7e6f2d5, seed 239246481125345374):
  // hence 24 draws. At 82.6 % fewer than 14 of 24 have a chance of 3e-4, fewer than 23 predicted of 24 about 1e-4;
  // the mean above 0.95 is 3.2 deviations away. Re-measured at 24 draws over 120 runs: 16-24 better, 23-24
  // predicted better, means 0.80-0.94.
  EXPECT_GE(predicted_better, draws - 1);
  EXPECT_GE(better, 14);
  EXPECT_LT(sum_follow, 0.95 * sum_random);
}

}  // namespace
}  // namespace cellcal
