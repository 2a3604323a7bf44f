#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <random>

#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include <numeric>
#include <Eigen/QR>

#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/placements.hpp"
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

// What the data cannot tell from the base or the target frame is held in the kinematic chain and carried by the
// frames, on every robot file and every arm of ../shared: the plain reference projects each joint parameter's column
// onto the twelve frame columns over random configurations (its own QR, a random target offset); frameGauge names
// exactly the columns inside that span (joint 1's offset about and along its axis, the last joint's flange-side
// parameters among them), the analysis never estimates one of them where the frames are free and says each merges
// into frame parameters only, and every frame parameter is estimated (6D) or not excited (the tool's angles, points).
TEST(Identifiability, WhatTheFramesStandForIsHeldAndTheFramesCarryIt) {
  std::vector<RobotModel> robots = {test::robot("staubli_tx60"), test::robot("ur10")};
  const std::filesystem::path arms = std::filesystem::path(CELLCAL_CONFIG_DIR) / "../../shared/robots/ros-industrial";
  if (std::filesystem::is_directory(arms))
    for (const auto& e : std::filesystem::recursive_directory_iterator(arms))
      if (e.path().extension() == ".urdf") robots.push_back(loadRobotFile(e.path().string()).model);
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1, 1);
  for (RobotModel m : robots) {
    SCOPED_TRACE(m.name);
    m.nominal[m.toolParam(FrameParam::kX)] = 0.05 * u(rng);
    m.nominal[m.toolParam(FrameParam::kY)] = 0.05 * u(rng);
    m.nominal[m.toolParam(FrameParam::kZ)] = 0.1 * std::abs(u(rng));
    // The plain reference.
    SimulationConfig sc;
    sc.seed = rng();
    const SimulatedCell cell(m, sc);
    std::vector<Observation> obs;
    for (const auto& q : cell.randomConfigurations(150, rng)) obs.push_back(cell.measure(q, 0.0, rng));
    Eigen::VectorXd r;
    Eigen::MatrixXd J;
    stackResiduals(m, m.nominal, obs, r, &J);
    Eigen::MatrixXd F(J.rows(), 12);
    std::vector<int> frames;
    for (int k = 0; k < 6; ++k) {
      frames.push_back(m.baseParam(static_cast<FrameParam>(k)));
      frames.push_back(m.toolParam(static_cast<FrameParam>(k)));
    }
    for (int k = 0; k < 12; ++k) F.col(k) = J.col(frames[static_cast<size_t>(k)]).normalized();
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(F);
    std::vector<int> reference;
    for (int c : m.canonicalParams()) {
      if (c >= 5 * m.numJoints()) continue;
      const Eigen::VectorXd col = J.col(c).normalized();
      const double outside = (F * qr.solve(col) - col).norm();
      if (outside < 1e-6) reference.push_back(c);
      else EXPECT_GT(outside, 1e-3) << m.paramName(c) << ": neither inside the frames' span nor clearly outside";
    }
    const std::vector<int> gauge = frameGauge(m, m.nominal);
    EXPECT_EQ(gauge, reference);
    std::string names;
    for (int c : gauge) names += " " + m.paramName(c);
    std::printf("  %-18s the frames stand for:%s\n", m.name.c_str(), names.c_str());
    for (JointParam jp : {JointParam::kThetaOffset, JointParam::kD}) {
      const int c = m.jointParam(0, jp);
      if (m.isCanonical(c)) {
        EXPECT_TRUE(contains(gauge, c)) << m.paramName(c);
      }
    }
    for (const auto kind : {MeasurementKind::kPose6D, MeasurementKind::kPosition3D}) {
      const auto rep = structuralIdentifiability(m, m.nominal, kind);
      for (int c : gauge) {
        EXPECT_FALSE(contains(rep.identifiable, c)) << m.paramName(c) << "\n" << rep.summary(m);
        for (const auto& d : rep.dropped) {
          if (d.index != c) continue;
          for (const auto& [k, coef] : d.merged_into) {
            EXPECT_TRUE(contains(frames, k)) << m.paramName(c) << " merged into " << m.paramName(k);
          }
        }
      }
      for (int c : frames) {
        const bool tool_angle = c >= m.toolParam(FrameParam::kRoll) && c < m.toolParam(FrameParam::kX) + 6;
        if (kind == MeasurementKind::kPose6D || !tool_angle) {
          EXPECT_TRUE(contains(rep.identifiable, c)) << m.paramName(c) << "\n" << rep.summary(m);
        }
      }
    }
  }
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

// The absorption map against a plain reference, on random placements (tracker, base tilt, target 50-150 mm off the
// flange) and both measurement kinds: for a random change dp of every canonical parameter, T dp is the least-squares
// solution of J_kept x = J dp, and J_kept T dp reproduces J dp (the kept columns span every candidate direction).
TEST_P(Identifiability, AbsorptionMapStandsForEveryCanonicalChange) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  for (int trial = 0; trial < 6; ++trial) {
    const SimulatedCell cell(test::robot(GetParam()), test::randomPlacement(rng));
    const RobotModel& m = cell.model();
    const MeasurementKind kind = trial % 2 ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
    std::vector<Observation> obs;
    for (const auto& q : cell.randomConfigurations(60, rng)) obs.push_back(cell.measure(q, 0.0, rng, kind));
    Eigen::VectorXd r;
    Eigen::MatrixXd J;
    stackResiduals(m, m.nominal, obs, r, &J);
    const auto rep = analyzeIdentifiability(m, J);
    const Eigen::MatrixXd& T = rep.absorption;
    ASSERT_EQ(T.rows(), rep.rank);
    ASSERT_EQ(T.cols(), m.numParams());
    Eigen::MatrixXd Jk(J.rows(), rep.rank);
    for (int i = 0; i < rep.rank; ++i) Jk.col(i) = J.col(rep.identifiable[static_cast<size_t>(i)]);
    for (const auto& d : rep.dropped) {
      if (!d.merged_into.empty()) {
        EXPECT_GT(T.col(d.index).norm(), 0) << d.name << " merges but is not absorbed";
      }
    }
    for (int draw = 0; draw < 5; ++draw) {
      Eigen::VectorXd dp = Eigen::VectorXd::Zero(m.numParams());
      for (int c : m.canonicalParams()) dp[c] = (m.isLength(c) ? 1e-4 : 2e-4) * g(rng);
      const Eigen::VectorXd Jdp = J * dp;
      const Eigen::VectorXd x_ref = Jk.colPivHouseholderQr().solve(Jdp);
      const Eigen::VectorXd x = T * dp;
      EXPECT_LT((Jk * x - Jdp).norm(), 1e-4 * Jdp.norm()) << rep.summary(m);
      EXPECT_LT((Jk * (x - x_ref)).norm(), 1e-6 * Jdp.norm()) << rep.summary(m);
    }
  }
}

// priorOverEstimated against plain formulas: a diagonal prior over every canonical parameter maps to T P T^T; a
// prior over the estimated parameters and one held parameter (one the rows separate from them, so it stands for
// nothing) is conditioned on it, P_ee - P_eh P_hh^-1 P_he.
TEST_P(Identifiability, PriorOverEstimatedMapsAndConditions) {
  std::mt19937_64 rng(test::testSeed());
  const SimulatedCell cell(test::robot(GetParam()), test::randomPlacement(rng));
  const RobotModel& m = cell.model();
  const auto rep = structuralIdentifiability(m, m.nominal, MeasurementKind::kPose6D);
  const auto& est = rep.identifiable;
  const auto ne = static_cast<Eigen::Index>(est.size());

  const GaussianPrior diag = diagonalPrior(m, m.nominal, m.canonicalParams(), 1e-3, 1e-3);
  Eigen::MatrixXd Tc(ne, static_cast<Eigen::Index>(diag.indices.size()));
  for (size_t b = 0; b < diag.indices.size(); ++b) Tc.col(static_cast<Eigen::Index>(b)) = rep.absorption.col(diag.indices[b]);
  const Eigen::MatrixXd ref = Tc * diag.covariance * Tc.transpose();
  EXPECT_LT((priorOverEstimated(diag, est, rep.absorption) - ref).norm(), 1e-12 * ref.norm());
  // Something was absorbed: the dropped parameters widen the ones that stand for them.
  EXPECT_GT(ref.trace(), static_cast<double>(ne) * 1e-6 * (1 + 1e-3));

  // Estimated plus one held parameter that stands for nothing: a joint parameter kept (so its column is
  // independent), moved out of the estimated set by hand.
  std::vector<int> est_less = est;
  est_less.pop_back();
  Eigen::MatrixXd T_less = Eigen::MatrixXd::Zero(ne - 1, m.numParams());
  for (Eigen::Index i = 0; i < ne - 1; ++i) T_less(i, est_less[static_cast<size_t>(i)]) = 1;
  GaussianPrior corr;
  corr.mean = m.nominal;
  corr.indices = est;  // est_less then `held` last
  const Eigen::MatrixXd A = Eigen::MatrixXd::Random(ne, ne);
  corr.covariance = 1e-6 * (A * A.transpose() + Eigen::MatrixXd::Identity(ne, ne));
  const Eigen::MatrixXd Pee = corr.covariance.topLeftCorner(ne - 1, ne - 1);
  const Eigen::VectorXd Peh = corr.covariance.col(ne - 1).head(ne - 1);
  const double Phh = corr.covariance(ne - 1, ne - 1);
  const Eigen::MatrixXd cond = Pee - Peh * Peh.transpose() / Phh;
  EXPECT_LT((priorOverEstimated(corr, est_less, T_less) - cond).norm(), 1e-9 * cond.norm());
}

// Plausible ranges against a plain reference, on random placements with the target 0.05-0.3 mm off the flange axis
// (joint 6's rotation barely moves it), few poses, points or 6D, and a noise scale drawn at random: a parameter held
// for its range has, as data_sigma, the plain 1 sigma of that parameter in a least-squares fit of the kept columns and
// it (the diagonal of the inverted normal matrix), and in that fit it or a kept one is pinned no better than its
// range; every kept parameter with a range is pinned better than it, fitted with all the others kept and with the
// columns taken before it (the same plain inversion); the frames, which have no range, are kept as
// rank alone keeps them; a tiny noise scale keeps what rank alone keeps, a huge one only the frames.
TEST_P(Identifiability, PlausibleRangesHoldWhatTheRowsPinNoBetter) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0, 1);
  int held_by_range = 0, unranged_held = 0;  // the second: frames held for loosening a ranged kept one
  for (int trial = 0; trial < 6; ++trial) {
    SimulationConfig sc = test::randomPlacement(rng);
    const double off = (0.05 + 0.25 * u(rng)) * 1e-3, dir = 2 * kPi * u(rng);
    sc.tool_in_flange << off * std::cos(dir), off * std::sin(dir), 0.08 * u(rng), 0, 0, 0;
    const SimulatedCell cell(test::robot(GetParam()), sc);
    const RobotModel& m = cell.model();
    const MeasurementKind kind = trial % 2 ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
    std::vector<Observation> obs;
    for (const auto& q : cell.randomConfigurations(15 + static_cast<int>(45 * u(rng)), rng))
      obs.push_back(cell.measure(q, 0.0, rng, kind));
    Eigen::VectorXd r;
    Eigen::MatrixXd J;
    stackResiduals(m, m.nominal, obs, r, &J);
    IdentifiabilityOptions o;
    o.prior_sigma = plausibleDeviation(m);
    o.noise_scale = std::exp(std::log(100.0) * u(rng));  // 1-100
    const IdentifiabilityReport rep = analyzeIdentifiability(m, J, o);
    const IdentifiabilityReport rank_only = analyzeIdentifiability(m, J);
    // The plain 1 sigma of column c fitted together with `cols` (c not among them).
    auto plainSigma = [&](std::vector<int> cols, int c) {
      cols.push_back(c);
      Eigen::MatrixXd A(J.rows(), static_cast<Eigen::Index>(cols.size()));
      for (size_t i = 0; i < cols.size(); ++i) A.col(static_cast<Eigen::Index>(i)) = J.col(cols[i]);
      const Eigen::MatrixXd N = A.transpose() * A;
      return o.noise_scale * std::sqrt(N.inverse()(N.rows() - 1, N.rows() - 1));
    };
    for (const auto& d : rep.dropped) {
      if (!d.below_prior) continue;
      ++held_by_range;
      const double ref = plainSigma(rep.identifiable, d.index);
      EXPECT_NEAR(d.data_sigma_si, ref, 1e-6 * ref) << d.name << "\n" << rep.summary(m);
      // Fitted with the kept ones, it or one of them (with a range) is pinned no better than its range.
      std::vector<int> with = rep.identifiable;
      with.push_back(d.index);
      bool loose = false;
      for (int c : with)
        if (o.prior_sigma[c] > 0) {
          std::vector<int> others;
          for (int x : with)
            if (x != c) others.push_back(x);
          loose |= plainSigma(others, c) >= o.prior_sigma[c];
        }
      EXPECT_TRUE(loose) << d.name << "\n" << rep.summary(m);
    }
    // Every kept parameter with a range, fitted with all the others kept, is pinned better than its range.
    for (int c : rep.identifiable)
      if (o.prior_sigma[c] > 0) {
        std::vector<int> others;
        for (int x : rep.identifiable)
          if (x != c) others.push_back(x);
        EXPECT_LT(plainSigma(others, c), o.prior_sigma[c]) << m.paramName(c) << "\n" << rep.summary(m);
      }
    ASSERT_EQ(rep.taken.size(), rep.identifiable.size());
    std::vector<int> before;  // the columns taken before it
    for (int c : rep.taken) {
      if (o.prior_sigma[c] > 0) {
        EXPECT_LT(plainSigma(before, c), o.prior_sigma[c] * (1 + 1e-9)) << m.paramName(c);
      }
      before.push_back(c);
    }
    // A column without a range that rank alone keeps stays, unless fitted with the kept ones it would loosen one of
    // them beyond its range (a dropped column below_prior: checked above to be so).
    for (int c : rank_only.identifiable)
      if (!(o.prior_sigma[c] > 0) && !contains(rep.identifiable, c)) {
        const auto d = std::find_if(rep.dropped.begin(), rep.dropped.end(), [&](const auto& x) { return x.index == c; });
        ASSERT_NE(d, rep.dropped.end()) << m.paramName(c);
        EXPECT_TRUE(d->below_prior) << m.paramName(c) << "\n" << rep.summary(m);
        ++unranged_held;
      }
    o.noise_scale = 1e-9;
    EXPECT_EQ(analyzeIdentifiability(m, J, o).identifiable, rank_only.identifiable);
    o.noise_scale = 1e9;
    for (int c : analyzeIdentifiability(m, J, o).identifiable) EXPECT_EQ(o.prior_sigma[c], 0) << m.paramName(c);
  }
  EXPECT_GT(held_by_range, 0) << "no draw held a parameter for its range: the check above checked nothing";
  std::printf("held for their range: %d; of them columns without a range that would loosen a kept one: %d\n",
              held_by_range, unranged_held);
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

namespace cellcal {
namespace {

// Gaussian conditioning (statistics.hpp), as the engine's start from a calibrated robot file uses it: against the
// inverse of the precision's block (a full-rank held block), and against a pseudo-inverse by complete orthogonal
// decomposition where the held entries are only pinned in sum.
TEST(GaussianConditioning, TheKeptEntriesGivenTheHeldOnesMatchAPlainReference) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g;
  for (int draw = 0; draw < 20; ++draw) {
    const int n = 4 + static_cast<int>(rng() % 12);
    Eigen::MatrixXd A(n, n + 3);
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n + 3; ++j) A(i, j) = g(rng) * std::pow(10.0, -(i % 3));  // entries of mixed units
    Eigen::MatrixXd P = A * A.transpose();
    std::vector<int> order(static_cast<size_t>(n));
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), rng);
    const std::vector<int> kept(order.begin(), order.begin() + 1 + static_cast<long>(rng() % (n - 1)));
    const std::vector<int> held(order.begin() + static_cast<long>(kept.size()), order.end());
    const bool singular = draw % 2 == 1 && held.size() >= 2;
    if (singular) {  // the first two held entries the same: only their sum is pinned
      P.row(held[1]) = P.row(held[0]);
      P.col(held[1]) = P.col(held[0]);
    }
    auto block = [&](const Eigen::MatrixXd& M, const std::vector<int>& r, const std::vector<int>& c) {
      Eigen::MatrixXd m(r.size(), c.size());
      for (size_t i = 0; i < r.size(); ++i)
        for (size_t j = 0; j < c.size(); ++j) m(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = M(r[i], c[j]);
      return m;
    };
    // Full rank: the inverse of the precision's kept block. Singular: the formula with a pseudo-inverse of its own.
    const Eigen::MatrixXd want =
        singular ? Eigen::MatrixXd(block(P, kept, kept) - block(P, kept, held) *
                                                              block(P, held, held).completeOrthogonalDecomposition().pseudoInverse() *
                                                              block(P, held, kept))
                 : Eigen::MatrixXd(block(P.inverse(), kept, kept).inverse());
    const Eigen::MatrixXd got = conditionalGaussianCovariance(P, kept);
    ASSERT_EQ(got.rows(), static_cast<Eigen::Index>(kept.size()));
    const Eigen::VectorXd sd = want.diagonal().cwiseSqrt();
    const Eigen::MatrixXd err = (got - want).cwiseQuotient(sd * sd.transpose());
    EXPECT_LT(err.cwiseAbs().maxCoeff(), 1e-6) << "n " << n << ", kept " << kept.size()
                                               << (singular ? ", singular held block" : "");
    EXPECT_EQ((got - got.transpose()).cwiseAbs().maxCoeff(), 0.0);
  }
  EXPECT_THROW(conditionalGaussianCovariance(Eigen::MatrixXd::Identity(3, 3), {0, 0}), std::invalid_argument);
  EXPECT_THROW(conditionalGaussianCovariance(Eigen::MatrixXd::Identity(3, 3), {3}), std::invalid_argument);
}

}  // namespace
}  // namespace cellcal
