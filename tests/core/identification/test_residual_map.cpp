// The residual map (identification/residual_map.hpp): its prediction against the Gaussian-process formulas written out
// here (kernel by loops, a full-pivot LU solve), its hyperparameters against a smooth effect of known structure drawn
// at random (which joints it depends on, how fast, how large), and that it never corrects far from its rows.
#include <gtest/gtest.h>

#include <Eigen/LU>
#include <cmath>
#include <random>

#include "cellcal/core/identification/residual_map.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

std::vector<Eigen::VectorXd> randomQ(int n, int joints, double spread, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-spread, spread);
  std::vector<Eigen::VectorXd> q;
  for (int i = 0; i < n; ++i) {
    Eigen::VectorXd x(joints);
    for (int j = 0; j < joints; ++j) x[j] = u(rng);
    q.push_back(x);
  }
  return q;
}

TEST(ResidualMap, PredictsWhatThePlainFormulasGive) {
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 5; ++draw) {
    const int joints = 2 + static_cast<int>(rng() % 5), n = 20 + static_cast<int>(rng() % 60);
    const auto q = randomQ(n, joints, 1.0, rng);
    std::normal_distribution<double> g(0.0, 1e-4);
    std::vector<Eigen::Vector3d> y;
    for (int i = 0; i < n; ++i) y.emplace_back(g(rng), g(rng), g(rng));
    ResidualMapOptions o;
    o.fit_rows = n;
    o.max_rows = n;
    o.max_distance = 1e9;
    const ResidualMap map = fitResidualMap(q, y, o);
    ASSERT_EQ(map.rows(), static_cast<size_t>(n));
    const Eigen::VectorXd l = map.lengthScales_rad();
    const double s2 = map.signalSigma_m() * map.signalSigma_m(), n2 = map.noiseSigma_m() * map.noiseSigma_m();
    auto k = [&](const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
      double d2 = 0;
      for (int j = 0; j < joints; ++j) d2 += std::pow((a[j] - b[j]) / l[j], 2);
      return s2 * std::exp(-0.5 * d2);
    };
    Eigen::MatrixXd K(n, n), Y(n, 3);
    for (int i = 0; i < n; ++i) {
      Y.row(i) = y[static_cast<size_t>(i)].transpose();
      for (int m = 0; m < n; ++m) K(i, m) = k(q[static_cast<size_t>(i)], q[static_cast<size_t>(m)]) + (i == m ? n2 : 0.0);
    }
    const Eigen::FullPivLU<Eigen::MatrixXd> lu(K);
    for (const auto& x : randomQ(10, joints, 1.2, rng)) {
      Eigen::VectorXd ks(n);
      for (int i = 0; i < n; ++i) ks[i] = k(x, q[static_cast<size_t>(i)]);
      const Eigen::Vector3d mean = (ks.transpose() * lu.solve(Y)).transpose();
      const double var = s2 - ks.dot(lu.solve(ks));
      const ResidualMap::Prediction p = map.predict(x, true);
      ASSERT_TRUE(p.applies);
      EXPECT_LT((p.correction_m - mean).norm(), 1e-8 * std::max(mean.norm(), 1e-6));
      EXPECT_NEAR(p.sigma_m, std::sqrt(std::max(0.0, var)), 1e-6 * map.signalSigma_m());
      double nearest = 1e300;
      for (const auto& r : q) nearest = std::min(nearest, (x - r).cwiseQuotient(l).norm());
      EXPECT_NEAR(p.distance, nearest, 1e-12 * nearest + 1e-15);
      // The bounded-cost sigma: the full posterior's with every row, never below it with fewer.
      EXPECT_NEAR(map.sigmaBound_m(x, n), p.sigma_m, 1e-6 * map.signalSigma_m());
      EXPECT_GE(map.sigmaBound_m(x, 1 + n / 4), p.sigma_m - 1e-9 * map.signalSigma_m());
    }
  }
}

// A residual that depends on two of six joints (which two, how fast and how large drawn at random), plus noise: the
// map learns it on 400 rows and corrects 200 others within its reach to well under the effect; the joints the effect
// ignores get longer length scales than those it depends on; a configuration far from every row is not corrected.
TEST(ResidualMap, LearnsASmoothEffectAndNeverExtrapolates) {
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 4; ++draw) {
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const int a = static_cast<int>(rng() % 6), b = (a + 1 + static_cast<int>(rng() % 5)) % 6;
    const double wa = 0.3 + 0.5 * u(rng), wb = 0.3 + 0.5 * u(rng), size = 1e-4 + 3e-4 * u(rng), noise = 2e-5;
    auto effect = [&](const Eigen::VectorXd& x) -> Eigen::Vector3d {
      return Eigen::Vector3d(std::sin(x[a] / wa), std::cos(x[b] / wb), std::sin(x[a] / wa + x[b] / wb)) * size;
    };
    std::normal_distribution<double> g(0.0, noise);
    const auto q = randomQ(400, 6, 1.0, rng);
    std::vector<Eigen::Vector3d> y;
    for (const auto& x : q) y.push_back(effect(x) + Eigen::Vector3d(g(rng), g(rng), g(rng)));
    ResidualMapOptions o;
    o.max_distance = 1.5;
    const ResidualMap map = fitResidualMap(q, y, o);
    double with = 0, without = 0;
    int near = 0;
    for (const auto& x : randomQ(200, 6, 0.9, rng)) {
      const ResidualMap::Prediction p = map.predict(x);
      if (!p.applies) continue;
      ++near;
      with += (effect(x) - p.correction_m).norm();
      without += effect(x).norm();
    }
    SCOPED_TRACE("joints " + std::to_string(a + 1) + " and " + std::to_string(b + 1));
    ASSERT_GT(near, 100) << "length scales " << map.lengthScales_rad().transpose() << ", signal " << map.signalSigma_m() << ", noise " << map.noiseSigma_m();
    EXPECT_LT(with, 0.25 * without);
    const Eigen::VectorXd& l = map.lengthScales_rad();
    for (int j = 0; j < 6; ++j)
      if (j != a && j != b) {
        EXPECT_GT(l[j], 2 * std::max(l[a], l[b])) << "joint " << j + 1;
      }
    Eigen::VectorXd far = Eigen::VectorXd::Zero(6);
    far[a] = 1.0 + 3 * l[a];
    const ResidualMap::Prediction p = map.predict(far, true);
    EXPECT_FALSE(p.applies);
    EXPECT_EQ(p.correction_m.norm(), 0.0);
    EXPECT_GT(p.distance, map.maxDistance());
  }
}

TEST(ResidualMap, BadInputIsRefused) {
  std::mt19937_64 rng(test::testSeed());
  const auto q = randomQ(12, 3, 1.0, rng);
  std::vector<Eigen::Vector3d> y(12, Eigen::Vector3d::Zero());
  EXPECT_THROW(fitResidualMap(q, std::vector<Eigen::Vector3d>(11, Eigen::Vector3d::Zero())), std::invalid_argument);
  EXPECT_THROW(fitResidualMap(std::vector<Eigen::VectorXd>(q.begin(), q.begin() + 9),
                              std::vector<Eigen::Vector3d>(9, Eigen::Vector3d::Zero())),
               std::invalid_argument);
  auto bad = q;
  bad[3][1] = std::nan("");
  EXPECT_THROW(fitResidualMap(bad, y), std::invalid_argument);
  ResidualMapOptions o;
  o.max_distance = 0;
  EXPECT_THROW(fitResidualMap(q, y, o), std::invalid_argument);
  // All-zero residuals: a map that corrects nothing.
  const ResidualMap map = fitResidualMap(q, y);
  EXPECT_LT(map.predict(q[0]).correction_m.norm(), 1e-12);
}

}  // namespace
}  // namespace cellcal
