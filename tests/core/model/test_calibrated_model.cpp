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

// The model by parameter name (parametersByName, the CalibrationState's form) and back, with the names given in a
// random order: checked against a plain reference that looks every value, 1-sigma and covariance entry up by name.
TEST(CalibratedModel, ByNameAndBackInAnyOrderIsTheSameModel) {
  std::mt19937_64 rng(test::testSeed());
  for (int d = 0; d < 20; ++d) {
    const RobotModel m = test::robot(d % 2 ? "ur10" : "staubli_tx60");
    const CalibratedModel c = randomModel(m, rng);
    const std::vector<std::string> names = parameterNames(m, c.extensions);
    std::vector<double> values, sds, correlations;
    parametersByName(m, c, values, sds, correlations);
    ASSERT_EQ(values.size(), names.size());
    ASSERT_EQ(sds.size(), names.size());
    // The plain reference: each name's value, its column in c's covariance (-1: not estimated).
    const std::vector<std::string> ext_names = extensionParamNames(m, c.extensions);
    std::vector<int> column(names.size(), -1);
    const std::vector<int> cols = c.columns(m);
    for (size_t k = 0; k < names.size(); ++k) {
      const bool kin = static_cast<int>(k) < m.numParams();
      EXPECT_EQ(names[k], kin ? m.paramName(static_cast<int>(k)) : ext_names[k - static_cast<size_t>(m.numParams())]);
      EXPECT_EQ(values[k], kin ? c.params[static_cast<Eigen::Index>(k)]
                               : c.extension_params[static_cast<Eigen::Index>(k) - m.numParams()]);
      const auto it = std::find(cols.begin(), cols.end(), static_cast<int>(k));
      if (it != cols.end()) column[k] = static_cast<int>(it - cols.begin());
      const double sd = column[k] < 0 ? 0.0 : std::sqrt(c.covariance(column[k], column[k]));
      EXPECT_EQ(sds[k], sd) << names[k];
    }
    const size_t n = cols.size();
    ASSERT_EQ(correlations.size(), n * (n - 1) / 2);
    // The same parameters in a random order, the correlations among the estimated ones recomputed for that order.
    std::vector<size_t> order(names.size());
    for (size_t k = 0; k < order.size(); ++k) order[k] = k;
    std::shuffle(order.begin(), order.end(), rng);
    std::vector<std::string> names2;
    std::vector<double> values2, sds2, corr2;
    std::vector<size_t> estimated_in_order;
    for (size_t k : order) {
      names2.push_back(names[k]);
      values2.push_back(values[k]);
      sds2.push_back(sds[k]);
      if (column[k] >= 0) estimated_in_order.push_back(k);
    }
    for (size_t a = 0; a < estimated_in_order.size(); ++a)
      for (size_t b = a + 1; b < estimated_in_order.size(); ++b) {
        const int i = column[estimated_in_order[a]], j = column[estimated_in_order[b]];
        corr2.push_back(c.covariance(i, j) / std::sqrt(c.covariance(i, i) * c.covariance(j, j)));
      }
    std::string why;
    const auto back = modelFromParameters(m, c.extensions, names2, values2, sds2, corr2, &why);
    ASSERT_TRUE(back) << why;
    ASSERT_TRUE(back->IsValid(m, &why)) << why;
    EXPECT_EQ((back->params - c.params).cwiseAbs().maxCoeff(), 0.0);
    EXPECT_EQ(back->extension_params, c.extension_params);
    ASSERT_EQ(back->numEstimated(), c.numEstimated());
    const std::vector<int> back_cols = back->columns(m);
    EXPECT_TRUE(std::is_sorted(back_cols.begin(), back_cols.end()));
    for (size_t a = 0; a < n; ++a)
      for (size_t b = 0; b < n; ++b) {
        const int i = column[static_cast<size_t>(back_cols[a])], j = column[static_cast<size_t>(back_cols[b])];
        ASSERT_GE(i, 0);
        ASSERT_GE(j, 0);
        EXPECT_NEAR(back->covariance(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)), c.covariance(i, j),
                    1e-12 * std::sqrt(c.covariance(i, i) * c.covariance(j, j)))
            << names[static_cast<size_t>(back_cols[a])] << " x " << names[static_cast<size_t>(back_cols[b])];
      }
    // Without correlations: the values, nothing estimated.
    const auto plain = modelFromParameters(m, c.extensions, names2, values2, sds2, {}, &why);
    ASSERT_TRUE(plain) << why;
    EXPECT_EQ(plain->numEstimated(), 0);
    EXPECT_EQ(plain->params, back->params);
  }
}

// Each fault of a model given by name is refused, naming it; a kinematic parameter left out keeps its nominal value.
TEST(CalibratedModel, ByNameRefusesWhatIsNotAModel) {
  const RobotModel m = test::robot("ur10");
  const std::vector<Extension> exts = {Extension{Cause::kJointCompliance, 1}};
  CalibratedModel c = CalibratedModel::geometric(m.nominal, {0, 3}, Eigen::Matrix2d{{4e-8, 1e-8}, {1e-8, 9e-8}});
  c.extensions = exts;
  c.extension_params = Eigen::VectorXd::Constant(numExtensionParams(m, exts), 2e-6);
  const std::vector<std::string> names = parameterNames(m, exts);
  std::vector<double> values, sds, corr;
  parametersByName(m, c, values, sds, corr);
  ASSERT_EQ(corr.size(), 1u);
  EXPECT_NEAR(corr[0], 1e-8 / (2e-4 * 3e-4), 1e-15);
  std::string why;
  auto refused = [&](std::vector<std::string> n, std::vector<double> v, std::vector<double> s, std::vector<double> r,
                     const std::string& what) {
    SCOPED_TRACE(what);
    EXPECT_FALSE(modelFromParameters(m, exts, n, v, s, r, &why));
    EXPECT_NE(why.find(what), std::string::npos) << why;
  };
  auto with = [](std::vector<double> v, size_t k, double x) {
    v[k] = x;
    return v;
  };
  auto renamed = names;
  renamed[2] = "joint9.a_m";
  refused(renamed, values, sds, corr, "unknown parameter 'joint9.a_m'");
  refused(names, with(values, 1, std::nan("")), sds, corr, "parameter '" + names[1] + "' is not finite");
  refused(names, std::vector<double>(values.begin(), values.end() - 1), sds, corr, "differ in length");
  refused(names, values, with(sds, 4, -1.0), corr, "parameter_stddevs[4] is not a stddev");
  refused(names, values, sds, {1.5}, "parameter_correlations: 1.5");
  refused(names, values, sds, {0.1, 0.2}, "parameter_correlations: 2 values, expected 1 for 2 parameters with a stddev");
  auto cut = [](auto v) {
    v.pop_back();
    return v;
  };
  refused(cut(names), cut(values), cut(sds), corr, "extension parameter '" + names.back() + "' missing");
  // The first four parameters left out: nominal.
  const std::vector<std::string> tail(names.begin() + 4, names.end());
  const auto back = modelFromParameters(m, exts, tail, std::vector<double>(values.begin() + 4, values.end()),
                                        std::vector<double>(tail.size(), 0.0), {}, &why);
  ASSERT_TRUE(back) << why;
  EXPECT_EQ(back->params, m.nominal);
  EXPECT_EQ(back->extension_params, c.extension_params);
}

// A covariance as 1-sigmas and correlations and back, with a parameter of zero variance (its correlations 0).
TEST(CalibratedModel, ACovarianceIsItsStddevsAndCorrelation) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  for (int d = 0; d < 20; ++d) {
    const Eigen::Index n = 1 + static_cast<Eigen::Index>(rng() % 9);
    const Eigen::MatrixXd A = Eigen::MatrixXd::NullaryExpr(n, n, [&] { return 1e-3 * g(rng); });
    Eigen::MatrixXd C = A * A.transpose();
    const Eigen::Index zero = static_cast<Eigen::Index>(rng() % static_cast<std::uint64_t>(n));
    C.row(zero).setZero();
    C.col(zero).setZero();
    const Eigen::VectorXd sd = stddevsOf(C);
    const Eigen::MatrixXd R = correlationOf(C);
    for (Eigen::Index i = 0; i < n; ++i) {
      EXPECT_EQ(sd[i], std::sqrt(C(i, i)));
      EXPECT_EQ(R(i, i), 1.0);
      for (Eigen::Index j = 0; j < n; ++j)
        if (i != j) {
          EXPECT_NEAR(R(i, j), sd[i] > 0 && sd[j] > 0 ? C(i, j) / (sd[i] * sd[j]) : 0.0, 1e-15);
        }
    }
    EXPECT_LE((covarianceOf(sd, R) - C).cwiseAbs().maxCoeff(), 1e-15 * C.cwiseAbs().maxCoeff());
  }
}

}  // namespace
}  // namespace cellcal
