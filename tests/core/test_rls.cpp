#include <gtest/gtest.h>

#include <Eigen/QR>
#include <numeric>
#include <set>

#include "cellcal/core/calibration.hpp"
#include "cellcal/core/pose_selection.hpp"
#include "cellcal/core/rls.hpp"
#include "cellcal/core/simulation.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

// Blocks of the real (whitened) kinematic Jacobian, so the conditioning is that of calibration.
struct LinearProblem {
  std::vector<Eigen::MatrixXd> A;
  std::vector<Eigen::VectorXd> b;
  Eigen::VectorXd x_true;
};

LinearProblem kinematicLinearProblem(std::uint64_t seed, int poses, MeasurementKind kind) {
  SimulationConfig sc;
  sc.seed = seed;
  SimulatedCell cell(test::robot("staubli_tx60"), sc);
  const auto ident = structuralIdentifiability(cell.model(), cell.nominalParams(), kind);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  LinearProblem lp;
  lp.x_true = Eigen::VectorXd(ident.rank);
  for (int k = 0; k < ident.rank; ++k) lp.x_true[k] = 1e-4 * g(rng);
  for (const auto& q : cell.randomConfigurations(poses, rng)) {
    Observation o = cell.measure(q, 0.0, rng, kind);
    Eigen::MatrixXd J;
    Eigen::Matrix<double, 6, 1> r;
    KinematicsData data(cell.model());
    const int rows = whitenedResidual(cell.model(), data, cell.nominalParams(), o, r, &J);
    Eigen::MatrixXd A(rows, ident.rank);
    for (int k = 0; k < ident.rank; ++k) A.col(k) = J.col(ident.identifiable[k]);
    Eigen::VectorXd noise(rows);
    for (int i = 0; i < rows; ++i) noise[i] = g(rng);
    lp.b.push_back(A * lp.x_true + noise);
    lp.A.push_back(A);
  }
  return lp;
}

Eigen::MatrixXd stack(const std::vector<Eigen::MatrixXd>& blocks, size_t first, size_t last) {
  Eigen::Index rows = 0;
  for (size_t i = first; i < last; ++i) rows += blocks[i].rows();
  Eigen::MatrixXd out(rows, blocks[first].cols());
  rows = 0;
  for (size_t i = first; i < last; ++i) {
    out.middleRows(rows, blocks[i].rows()) = blocks[i];
    rows += blocks[i].rows();
  }
  return out;
}
Eigen::VectorXd stackv(const std::vector<Eigen::VectorXd>& blocks, size_t first, size_t last) {
  std::vector<Eigen::MatrixXd> m(blocks.begin() + first, blocks.begin() + last);
  return stack(m, 0, m.size());
}

class RlsEqualsBatch : public ::testing::TestWithParam<MeasurementKind> {};

// lambda = 1: the recursive estimate after every block equals the batch least-squares solution of all blocks so far,
// and P equals (A^T A)^-1.
TEST_P(RlsEqualsBatch, AfterEveryPose) {
  const LinearProblem lp = kinematicLinearProblem(test::testSeed(), 60, GetParam());
  const size_t n0 = 15;  // initial batch, enough rows for P0 = (A0^T A0)^-1
  RlsEstimator rls = RlsEstimator::fromInitialBatch(stack(lp.A, 0, n0), stackv(lp.b, 0, n0));
  for (size_t k = n0; k < lp.A.size(); ++k) {
    rls.update(lp.A[k], lp.b[k]);
    const Eigen::MatrixXd A = stack(lp.A, 0, k + 1);
    const Eigen::VectorXd x_batch = A.colPivHouseholderQr().solve(stackv(lp.b, 0, k + 1));
    const Eigen::MatrixXd P_batch = (A.transpose() * A).inverse();
    const Eigen::VectorXd sd = P_batch.diagonal().cwiseSqrt();
    // Differences measured in units of each parameter's standard deviation.
    EXPECT_LT(((rls.x() - x_batch).cwiseQuotient(sd)).cwiseAbs().maxCoeff(), 1e-6) << "after pose " << k;
    EXPECT_LT((rls.P() - P_batch).norm() / P_batch.norm(), 1e-6) << "after pose " << k;
  }
  // And it is a real estimate: within 5 sigma of the truth.
  EXPECT_LT(((rls.x() - lp.x_true).cwiseQuotient(rls.P().diagonal().cwiseSqrt())).cwiseAbs().maxCoeff(), 5.0);
}

INSTANTIATE_TEST_SUITE_P(Kinds, RlsEqualsBatch,
                         ::testing::Values(MeasurementKind::kPose6D, MeasurementKind::kPosition3D),
                         [](const auto& i) { return i.param == MeasurementKind::kPose6D ? "Pose6D" : "Position3D"; });

TEST(RlsForgetting, BoundStopsWindupOfUnexcitedDirections) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  const int m = 5;
  RlsOptions bounded;
  bounded.forgetting = 0.9;
  bounded.max_covariance_diag = Eigen::VectorXd::Constant(m, 4.0);
  RlsOptions unbounded;
  unbounded.forgetting = 0.9;
  RlsEstimator a(Eigen::VectorXd::Zero(m), Eigen::MatrixXd::Identity(m, m), bounded);
  RlsEstimator b(Eigen::VectorXd::Zero(m), Eigen::MatrixXd::Identity(m, m), unbounded);
  for (int k = 0; k < 300; ++k) {
    Eigen::MatrixXd A(2, m);
    for (int i = 0; i < A.size(); ++i) A.data()[i] = g(rng);
    A.col(0).setZero();  // state 0 is never excited
    const Eigen::VectorXd y = Eigen::VectorXd::Constant(2, 1.0);
    a.update(A, y);
    b.update(A, y);
  }
  EXPECT_LE(a.P()(0, 0), 4.0 + 1e-12);
  EXPECT_GT(b.P()(0, 0), 1e10);  // what the bound prevents
  EXPECT_TRUE(a.x().allFinite());
}

TEST(RlsForgetting, TracksAStepChangeFasterThanLambdaOne) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  const int m = 4;
  Eigen::VectorXd x_true = Eigen::VectorXd::Zero(m);
  RlsOptions o;
  o.forgetting = 0.95;
  o.max_covariance_diag = Eigen::VectorXd::Constant(m, 100.0);
  RlsEstimator forget(Eigen::VectorXd::Zero(m), Eigen::MatrixXd::Identity(m, m), o);
  RlsEstimator plain(Eigen::VectorXd::Zero(m), Eigen::MatrixXd::Identity(m, m));
  for (int k = 0; k < 600; ++k) {
    if (k == 300) x_true.setConstant(1.0);
    Eigen::MatrixXd A(1, m);
    for (int i = 0; i < m; ++i) A(0, i) = g(rng);
    const Eigen::VectorXd y = A * x_true + 0.01 * Eigen::VectorXd::Constant(1, g(rng));
    forget.update(A, y);
    plain.update(A, y);
  }
  EXPECT_LT((forget.x() - x_true).norm(), 0.05);
  EXPECT_GT((plain.x() - x_true).norm(), 0.2);
}

TEST(RlsOptions, InvalidOptionsAreReported) {
  RlsOptions o;
  o.forgetting = 1.5;
  std::string e;
  EXPECT_FALSE(o.IsValid(3, &e));
  EXPECT_THROW(RlsEstimator(Eigen::VectorXd::Zero(3), Eigen::MatrixXd::Identity(3, 3), o), std::invalid_argument);
  EXPECT_THROW(RlsEstimator::fromInitialBatch(Eigen::MatrixXd::Zero(2, 3), Eigen::VectorXd::Zero(2)),
               std::invalid_argument);
}

class RlsCalibration : public ::testing::TestWithParam<MeasurementKind> {};

// The nonlinear RLS calibrator, pose by pose from the prior, reaches the noise floor and agrees with a batch solve
// with the same prior.
TEST_P(RlsCalibration, ConvergesPoseByPoseAndMatchesBatchWithSamePrior) {
  SimulationConfig sc;
  sc.seed = test::testSeed();
  SimulatedCell cell(test::robot("staubli_tx60"), sc);
  std::mt19937_64 rng(sc.seed + 3);
  std::vector<Observation> ident, verify;
  for (const auto& q : cell.randomConfigurations(80, rng)) ident.push_back(cell.measure(q, 0.0, rng, GetParam()));
  for (const auto& q : cell.randomConfigurations(60, rng)) verify.push_back(cell.measure(q, 0.0, rng, GetParam()));
  const double floor = mean(positionErrors(cell.model(), cell.trueParams(0.0), verify));
  const auto prior = diagonalPrior(cell.model(), cell.nominalParams(), cell.model().canonicalParams(), 1e-3,
                                   degToRad(0.1));
  RlsCalibrator rls(cell.model(), cell.nominalParams(), prior, GetParam());
  double nis = 0;
  for (const auto& o : ident) nis += rls.addObservation(o);
  const double after = mean(positionErrors(cell.model(), rls.params(), verify));
  EXPECT_LT(after, 1.3 * floor);
  // Innovations are consistent with their covariance on average (chi-square: mean ~ rows; loose: nonlinear start).
  EXPECT_LT(nis / ident.size(), 3.0 * (GetParam() == MeasurementKind::kPose6D ? 6 : 3));

  CalibrationProblem p{&cell.model(), cell.nominalParams(), ident, prior, {}};
  const auto gn = solveGaussNewton(p);
  ASSERT_EQ(gn.estimated, rls.estimated());
  const double batch = mean(positionErrors(cell.model(), gn.params, verify));
  EXPECT_NEAR(after, batch, 0.05 * floor);
}

INSTANTIATE_TEST_SUITE_P(Kinds, RlsCalibration,
                         ::testing::Values(MeasurementKind::kPose6D, MeasurementKind::kPosition3D),
                         [](const auto& i) { return i.param == MeasurementKind::kPose6D ? "Pose6D" : "Position3D"; });

// Mean predicted position variance over `where` after measuring `chosen` (exact Bayesian update of P).
double predictedVariance(const RobotModel& m, const Eigen::VectorXd& params, const std::vector<int>& est,
                         Eigen::MatrixXd P, const std::vector<Eigen::VectorXd>& qs, const std::vector<int>& chosen,
                         const PoseSelectionOptions& o) {
  KinematicsData data(m);
  Eigen::MatrixXd J(6, m.numParams());
  auto rowsOf = [&](const Eigen::VectorXd& q, bool whitened) {
    forwardKinematics(m, data, params, q);
    computePoseJacobian(m, data, J);
    Eigen::MatrixXd A(whitened ? 6 : 3, est.size());
    for (size_t k = 0; k < est.size(); ++k) {
      A.col(k).head<3>() = J.col(est[k]).head<3>() / (whitened ? o.sigma_position_m : 1.0);
      if (whitened) A.col(k).tail<3>() = J.col(est[k]).tail<3>() / o.sigma_orientation_rad;
    }
    return A;
  };
  for (int i : chosen) {
    const Eigen::MatrixXd A = rowsOf(qs[i], true);
    const Eigen::MatrixXd PA = P * A.transpose();
    Eigen::MatrixXd S = A * PA;
    S.diagonal().array() += 1.0;
    P -= PA * S.llt().solve(PA.transpose());
  }
  double v = 0;
  for (const auto& q : qs) {
    const Eigen::MatrixXd B = rowsOf(q, false);
    v += (B * P * B.transpose()).trace();
  }
  return v / static_cast<double>(qs.size());
}

TEST(PoseSelection, ChosenPosesTeachMoreThanRandomOnes) {
  const std::uint64_t seed = test::testSeed();
  SimulationConfig sc;
  sc.seed = seed;
  SimulatedCell cell(test::robot("staubli_tx60"), sc);
  const auto prior = diagonalPrior(cell.model(), cell.nominalParams(), cell.model().canonicalParams(), 1e-3,
                                   degToRad(0.1));
  RlsCalibrator rls(cell.model(), cell.nominalParams(), prior, MeasurementKind::kPose6D);
  std::mt19937_64 rng(seed);
  for (const auto& q : cell.randomConfigurations(50, rng)) rls.addObservation(cell.measure(q, 0.0, rng));
  rls.addProcessNoise(DriftModel{}.sigmas(cell.model()));
  const auto qs = cell.randomConfigurations(50, rng);
  PoseSelectionOptions o;
  const auto chosen =
      selectInformativePoses(cell.model(), rls.params(), rls.estimated(), rls.covariance(), qs, 15, o);
  ASSERT_EQ(chosen.size(), 15u);
  EXPECT_EQ(std::set<int>(chosen.begin(), chosen.end()).size(), 15u);
  const double v_chosen =
      predictedVariance(cell.model(), rls.params(), rls.estimated(), rls.covariance(), qs, chosen, o);
  double v_random = 0;
  for (int t = 0; t < 20; ++t) {
    std::vector<int> idx(qs.size());
    std::iota(idx.begin(), idx.end(), 0);
    std::shuffle(idx.begin(), idx.end(), rng);
    idx.resize(15);
    v_random += predictedVariance(cell.model(), rls.params(), rls.estimated(), rls.covariance(), qs, idx, o) / 20;
  }
  std::printf("predicted position variance: chosen/random = %.3f\n", v_chosen / v_random);
  EXPECT_LT(v_chosen, 0.9 * v_random);
  const double v_none = predictedVariance(cell.model(), rls.params(), rls.estimated(), rls.covariance(), qs, {}, o);
  EXPECT_LT(v_random, v_none);
}

}  // namespace
}  // namespace cellcal
