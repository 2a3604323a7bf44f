// Every column of the analytic pose Jacobian (every kinematic parameter plus base and tool frames, both robots)
// against central finite differences and against ceres::Jet forward-mode derivatives of the templated chain.
#include <ceres/jet.h>
#include <gtest/gtest.h>

#include "cellcal/core/model/kinematics.hpp"
#include "core/model/jet_twist.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

struct Case {
  std::string robot;
  int param;
};
void PrintTo(const Case& c, std::ostream* os) { *os << c.robot << " parameter " << c.param; }

class PoseJacobianTest : public ::testing::TestWithParam<Case> {
 protected:
  void SetUp() override {
    model_ = test::robot(GetParam().robot);
    rng_.seed(test::testSeed());
  }
  // Random configuration within limits, and parameters perturbed from nominal (base/tool non-trivial).
  std::pair<Eigen::VectorXd, Eigen::VectorXd> randomPoint() {
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    Eigen::VectorXd q(model_.numJoints());
    for (int j = 0; j < q.size(); ++j) q[j] = 2.5 * u(rng_);
    Eigen::VectorXd p = model_.nominal;
    for (int i = 0; i < p.size(); ++i) p[i] += (model_.isLength(i) ? 0.05 : 0.2) * u(rng_);
    return {q, p};
  }
  RobotModel model_;
  std::mt19937_64 rng_;
};

TEST_P(PoseJacobianTest, ColumnMatchesFiniteDifferences) {
  const int i = GetParam().param;
  KinematicsData data(model_);
  Eigen::MatrixXd J(6, model_.numParams());
  for (int trial = 0; trial < 5; ++trial) {
    auto [q, p] = randomPoint();
    const Pose T = forwardKinematics(model_, data, p, q);
    computePoseJacobian(model_, data, J);
    const double h = 1e-6;
    Eigen::VectorXd pp = p, pm = p;
    pp[i] += h;
    pm[i] -= h;
    const Pose Tp = forwardKinematics(model_, pp, q), Tm = forwardKinematics(model_, pm, q);
    const Eigen::Vector3d dp = (Tp.translation() - Tm.translation()) / (2 * h);
    const Eigen::Vector3d w = logSO3(Tp.linear() * Tm.linear().transpose()) / (2 * h);
    EXPECT_NEAR((J.col(i).head<3>() - dp).norm(), 0.0, 1e-7) << model_.paramName(i) << "\n" << J.col(i).transpose();
    EXPECT_NEAR((J.col(i).tail<3>() - w).norm(), 0.0, 1e-7) << model_.paramName(i);
    (void)T;
  }
}

TEST_P(PoseJacobianTest, ColumnMatchesCeresJets) {
  using Jet = ceres::Jet<double, 1>;
  const int i = GetParam().param;
  KinematicsData data(model_);
  Eigen::MatrixXd J(6, model_.numParams());
  for (int trial = 0; trial < 5; ++trial) {
    auto [q, p] = randomPoint();
    forwardKinematics(model_, data, p, q);
    computePoseJacobian(model_, data, J);
    std::vector<Jet> pj(p.size());
    for (int k = 0; k < p.size(); ++k) pj[k] = Jet(p[k]);
    pj[i].v[0] = 1.0;
    const test::JetTwist t = test::jetTwist(forwardKinematicsT<Jet>(model_, pj.data(), q.data()));
    EXPECT_NEAR((J.col(i).head<3>() - t.translation).norm(), 0.0, 1e-12) << model_.paramName(i);
    EXPECT_NEAR((J.col(i).tail<3>() - t.rotation).norm(), 0.0, 1e-12) << model_.paramName(i);
    EXPECT_NEAR((t.omega_hat + t.omega_hat.transpose()).norm(), 0.0, 1e-12);  // really a rotation derivative
  }
}

std::vector<Case> allCases() {
  std::vector<Case> out;
  for (const std::string r : {"staubli_tx60", "ur10"}) {
    const RobotModel m = test::robot(r);
    for (int i = 0; i < m.numParams(); ++i) out.push_back({r, i});
  }
  return out;
}

INSTANTIATE_TEST_SUITE_P(AllParameters, PoseJacobianTest, ::testing::ValuesIn(allCases()),
                         [](const ::testing::TestParamInfo<Case>& info) {
                           std::string name = info.param.robot + "_" + test::robot(info.param.robot).paramName(info.param.param);
                           for (char& c : name)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return name;
                         });

class JointJacobianTest : public ::testing::TestWithParam<std::string> {};

TEST_P(JointJacobianTest, EveryJointColumnMatchesFiniteDifferences) {
  const RobotModel m = test::robot(GetParam());
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-2.5, 2.5);
  KinematicsData data(m);
  Eigen::MatrixXd Jq(6, m.numJoints());
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::VectorXd q(m.numJoints());
    for (int j = 0; j < q.size(); ++j) q[j] = u(rng);
    forwardKinematics(m, data, m.nominal, q);
    computeJointJacobian(m, data, Jq);
    for (int j = 0; j < m.numJoints(); ++j) {
      const double h = 1e-6;
      Eigen::VectorXd qp = q, qm = q;
      qp[j] += h;
      qm[j] -= h;
      const Pose Tp = forwardKinematics(m, m.nominal, qp), Tm = forwardKinematics(m, m.nominal, qm);
      EXPECT_NEAR((Jq.col(j).head<3>() - (Tp.translation() - Tm.translation()) / (2 * h)).norm(), 0.0, 1e-7) << j;
      EXPECT_NEAR((Jq.col(j).tail<3>() - logSO3(Tp.linear() * Tm.linear().transpose()) / (2 * h)).norm(), 0.0, 1e-7)
          << j;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Robots, JointJacobianTest, ::testing::Values("staubli_tx60", "ur10"));

}  // namespace
}  // namespace cellcal
