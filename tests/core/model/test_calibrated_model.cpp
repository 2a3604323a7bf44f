// CalibratedModel (calibrated_model.hpp): its contract (IsValid names the first fault), its covariance lookups against
// a plain search by name, and the shapes built on it passing the model part unchanged.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "cellcal/core/model/calibrated_model.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

// A valid model of `m` with random extensions (those that apply), values, estimated sets and an SPD covariance.
CalibratedModel randomModel(const RobotModel& m, std::mt19937_64& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  CalibratedModel c;
  c.params = m.nominal + Eigen::VectorXd::NullaryExpr(m.numParams(), [&] { return 1e-3 * g(rng); });
  for (Cause cause : extensionCauses()) {
    if (u(rng) > 0.3) continue;
    const Extension e{cause, static_cast<int>(u(rng) * m.numJoints())};
    if (applicable(m, e, true)) c.extensions.push_back(e);
  }
  const int k = numExtensionParams(m, c.extensions);
  c.extension_params = Eigen::VectorXd::NullaryExpr(k, [&] { return 1e-4 * g(rng); });
  for (int i = 0; i < m.numParams(); ++i)
    if (u(rng) < 0.6) c.estimated.push_back(i);
  for (int e = 0; e < k; ++e)
    if (u(rng) < 0.7) c.estimated_extension.push_back(e);
  std::shuffle(c.estimated.begin(), c.estimated.end(), rng);  // any order: the covariance follows the lists
  const Eigen::Index n = c.numEstimated();
  const Eigen::MatrixXd A = Eigen::MatrixXd::NullaryExpr(n, n, [&] { return 1e-4 * g(rng); });
  c.covariance = A * A.transpose() + 1e-12 * Eigen::MatrixXd::Identity(n, n);
  return c;
}

TEST(CalibratedModel, LookupsAgreeWithAPlainSearchByName) {
  std::mt19937_64 rng(test::testSeed());
  for (int d = 0; d < 20; ++d) {
    const RobotModel m = test::robot(d % 2 ? "ur10" : "staubli_tx60");
    const CalibratedModel c = randomModel(m, rng);
    std::string why;
    ASSERT_TRUE(c.IsValid(m, &why)) << why;
    // The covariance's columns by name, in order: the estimated kinematic names, then the estimated extension names.
    const std::vector<std::string> ext_names = extensionParamNames(m, c.extensions);
    std::vector<std::string> names;
    for (int i : c.estimated) names.push_back(m.paramName(i));
    for (int e : c.estimated_extension) names.push_back(ext_names[static_cast<size_t>(e)]);
    ASSERT_EQ(static_cast<int>(names.size()), c.numEstimated());
    const std::vector<int> cols = c.columns(m);
    for (int col = 0; col < c.numEstimated(); ++col) {
      EXPECT_EQ(c.columnName(m, col), names[static_cast<size_t>(col)]);
      const int which = cols[static_cast<size_t>(col)];
      EXPECT_EQ(which < m.numParams() ? m.paramName(which) : ext_names[static_cast<size_t>(which - m.numParams())],
                names[static_cast<size_t>(col)]);
    }
    for (int i = 0; i < m.numParams(); ++i) {
      const auto it = std::find(names.begin(), names.end(), m.paramName(i));
      if (it == names.end()) {
        EXPECT_TRUE(std::isnan(c.paramStddev(i))) << m.paramName(i);
      } else {
        const auto at = it - names.begin();
        EXPECT_EQ(c.paramStddev(i), std::sqrt(c.covariance(at, at))) << m.paramName(i);
      }
    }
    for (size_t e = 0; e < ext_names.size(); ++e) {
      const auto it = std::find(names.begin(), names.end(), ext_names[e]);
      if (it == names.end()) {
        EXPECT_TRUE(std::isnan(c.extensionStddev(static_cast<int>(e)))) << ext_names[e];
      } else {
        const auto at = it - names.begin();
        EXPECT_EQ(c.extensionStddev(static_cast<int>(e)), std::sqrt(c.covariance(at, at))) << ext_names[e];
      }
    }
    const Eigen::MatrixXd K = c.kinematicCovariance();
    ASSERT_EQ(K.rows(), static_cast<Eigen::Index>(c.estimated.size()));
    for (Eigen::Index a = 0; a < K.rows(); ++a)
      for (Eigen::Index b = 0; b < K.cols(); ++b) EXPECT_EQ(K(a, b), c.covariance(a, b));
  }
}

// Each fault of a valid model is refused, and the message names the field at fault.
TEST(CalibratedModel, IsValidNamesTheFirstFault) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const RobotModel m = test::robot("ur10");
  int checked = 0;
  for (int d = 0; d < 30; ++d) {
    CalibratedModel c = randomModel(m, rng);
    std::string why;
    ASSERT_TRUE(c.IsValid(m, &why)) << why;
    EXPECT_TRUE(CalibratedModel::geometric(m.nominal).IsValid(m, &why)) << why;
    std::string field;
    switch (d % 9) {
      case 0: c.params.conservativeResize(c.params.size() - 1), field = "params"; break;
      case 1: c.params[static_cast<Eigen::Index>(u(rng) * c.params.size())] = NAN, field = "params"; break;
      case 2: c.extension_params.conservativeResize(c.extension_params.size() + 1), field = "extension_params"; break;
      case 3:
        if (c.estimated.empty()) continue;
        c.estimated[0] = m.numParams(), field = "estimated";
        break;
      case 4:
        if (c.estimated.size() < 2) continue;
        c.estimated[1] = c.estimated[0], field = "estimated";
        break;
      case 5: c.estimated_extension.push_back(static_cast<int>(c.extension_params.size())), field = "estimated_extension"; break;
      case 6: c.covariance.conservativeResize(c.covariance.rows() + 1, c.covariance.cols() + 1), field = "covariance"; break;
      case 7:
        if (c.numEstimated() == 0) continue;
        c.covariance(0, 0) = -1e-9, field = "covariance";
        break;
      case 8:
        // joint_compliance on the UR10's first joint: gravity never loads it.
        c.extensions.push_back(Extension{Cause::kJointCompliance, 0}), field = "extensions";
        break;
    }
    EXPECT_FALSE(c.IsValid(m, &why)) << "case " << d % 9;
    EXPECT_EQ(why.rfind(field + ":", 0), 0u) << why;
    ++checked;
  }
  EXPECT_GE(checked, 20);
}

}  // namespace
}  // namespace cellcal
