// The shared suite every registered cause (cause_list.hpp) passes, on both robots (the TX60 without link masses, the
// UR10 with them): its names and applicability keep CauseModel's contract, its basis perturbs only the parameters its
// subject names, and the pose Jacobian a fit uses for its parameters (J B at the extended parameters) is the derivative
// of the prediction extendedParams -> forwardKinematics: against central finite differences of that prediction and
// against ceres::Jet through the templated chain. Random configurations, kinematics, frames, drivers and parameter
// values. A new cause is checked here by registering it, with no edit to this file.
#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "cellcal/core/model/cause.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "core/model/jet_twist.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

struct CauseCase {
  const CauseModel* cause;
  std::string robot;
};
void PrintTo(const CauseCase& c, std::ostream* os) { *os << c.cause->name() << " on " << c.robot; }

class CauseSuite : public ::testing::TestWithParam<CauseCase> {
 protected:
  void SetUp() override {
    model_ = test::robot(GetParam().robot);
    rng_.seed(test::testSeed());
  }
  const CauseModel& cause() const { return *GetParam().cause; }
  // Every value Extension::joint can take for this robot, and those an extension of the cause applies to.
  std::vector<int> joints() const {
    std::vector<int> out;
    for (int j = -1; j < model_.numJoints(); ++j) out.push_back(j);
    return out;
  }
  std::vector<Extension> applicableExtensions() const {
    std::vector<Extension> out;
    for (int j : joints())
      if (applicable(model_, Extension{cause().id(), j}, true)) out.push_back(Extension{cause().id(), j});
    return out;
  }
  double uniform(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng_); }
  // Kinematics off nominal (frames included: gravity comes in at any angle), a configuration within the limits.
  Eigen::VectorXd randomParams() {
    Eigen::VectorXd p = model_.nominal;
    for (int i = 0; i < p.size(); ++i) p[i] += model_.isLength(i) ? uniform(-0.02, 0.02) : uniform(-0.3, 0.3);
    return p;
  }
  Eigen::VectorXd randomQ() {
    Eigen::VectorXd q(model_.numJoints());
    for (int j = 0; j < q.size(); ++j)
      q[j] = uniform(std::max(model_.limits[j].lower_rad, -kPi), std::min(model_.limits[j].upper_rad, kPi));
    return q;
  }
  // Drivers with a thermal value (temperature or time), directions and recent moves. Every joint's last move is
  // larger than 1.5 x `play_rad`, so a play of that width is crossed fully (its state does not depend on the width,
  // and the prediction is differentiable in it).
  Drivers randomDrivers(double play_rad) {
    const int n = model_.numJoints();
    Drivers d;
    d.thermal_is_time = uniform(0, 1) < 0.5;
    d.thermal = d.thermal_is_time ? uniform(0.1, 6.0) : uniform(-4.0, 4.0);
    d.elapsed_h = d.thermal_is_time ? d.thermal : uniform(0.1, 6.0);
    d.recent_steps_rad = Eigen::MatrixXd::Zero(n, kPlayHistory);
    d.motion_direction = Eigen::VectorXd::Zero(n);
    for (int j = 0; j < n; ++j) {
      for (int c = 0; c < kPlayHistory; ++c) d.recent_steps_rad(j, c) = uniform(-0.2, 0.2);
      const double sign = uniform(0, 1) < 0.5 ? -1.0 : 1.0;
      d.recent_steps_rad(j, kPlayHistory - 1) = sign * (1.5 * play_rad + uniform(0.0, 0.2));
      d.motion_direction[j] = sign;
    }
    return d;
  }
  RobotModel model_;
  std::mt19937_64 rng_;
};

// Names, counts, written form, labels and applicability as CauseModel promises them.
TEST_P(CauseSuite, NamesAndApplicabilityKeepTheContract) {
  const CauseModel& c = cause();
  EXPECT_EQ(causeFromName(c.name()), c.id());
  EXPECT_EQ(&causeModel(c.id()), &c);
  EXPECT_EQ(std::count(extensionCauses().begin(), extensionCauses().end(), c.id()), c.diagnosed() ? 1 : 0);
  const std::vector<Extension> usable = applicableExtensions();
  ASSERT_FALSE(usable.empty()) << c.name() << " applies to no joint of " << model_.name;
  using Subject = CauseModel::Subject;
  std::set<std::string> kinematic;
  for (int i = 0; i < model_.numParams(); ++i) kinematic.insert(model_.paramName(i));
  for (int j : joints()) {
    const Extension e{c.id(), j};
    const bool ok = applicable(model_, e, true);
    if (c.subject() == Subject::kBase) {
      EXPECT_EQ(ok, j == -1);
    }
    if (c.subject() == Subject::kJoint || c.subject() == Subject::kLink) {
      EXPECT_FALSE(j == -1 && ok);
    }
    if (c.driver() == CauseModel::Driver::kThermal) {
      EXPECT_FALSE(applicable(model_, e, false)) << "no thermal driver";
    }
    if (!ok) {
      EXPECT_THROW(parseExtension(extensionSpec(e), model_, true), std::invalid_argument) << extensionSpec(e);
      continue;
    }
    const std::vector<std::string> names = extensionParamNames(model_, e);
    ASSERT_EQ(static_cast<int>(names.size()), numExtensionParams(model_, e)) << extensionSpec(e);
    ASSERT_GT(names.size(), 0u);
    std::set<std::string> seen;
    for (const std::string& n : names) {
      EXPECT_TRUE(seen.insert(n).second) << n << " twice";
      EXPECT_EQ(kinematic.count(n), 0u) << n << " is a kinematic parameter's name";
      const bool has_unit = n.find("_rad") != std::string::npos || n.find("_m") != std::string::npos ||
                            n.find("per_unit") != std::string::npos || n.find("ratio") != std::string::npos;
      EXPECT_TRUE(has_unit) << n << " has no unit in its name";
    }
    const Extension back = parseExtension(extensionSpec(e), model_, true);
    EXPECT_EQ(back.cause, e.cause);
    EXPECT_EQ(back.joint, e.joint);
    EXPECT_NE(c.label(e).find(c.name()), std::string::npos) << c.label(e);
    EXPECT_TRUE(c.conflicts(e, e)) << "an extension conflicts with itself";
  }
  // Every applicable extension's parameters can get a prior (a column that acts has a finite positive sigma).
  const Eigen::VectorXd sigma = extensionPriorSigma(model_, model_.nominal, usable, 1e-3);
  EXPECT_TRUE(sigma.allFinite());
  EXPECT_GT(sigma.maxCoeff(), 0.0);
}

// Every extension has a region its data bound (extensionTransfer judges it beyond, compensation refuses farther): a
// joint's angle (regionJoint), or a driver whose value is finite, deterministic and named with its unit in brackets
// (rangeValue, rangeLabel); never both. A thermal cause's driver is the thermal value the extension sees.
TEST_P(CauseSuite, ItsRegionIsAJointsRangeOrADriversRange) {
  const CauseModel& c = cause();
  for (const Extension& e : applicableExtensions()) {
    const std::string what = extensionSpec(e);
    const Eigen::VectorXd p = randomParams(), q = randomQ();
    const Drivers d = randomDrivers(0.01);
    const double x = c.rangeValue(model_, p, e, q, d);
    if (c.regionJoint(e) >= 0) {
      EXPECT_LT(c.regionJoint(e), model_.numJoints()) << what;
      EXPECT_TRUE(std::isnan(x)) << what << ": a joint and a driver";
      continue;
    }
    ASSERT_TRUE(std::isfinite(x)) << what << ": no region";
    EXPECT_EQ(c.rangeValue(model_, p, e, q, d), x) << what;
    for (const char* source : {"temperature_c", "stamp_s"}) {
      const std::string label = c.rangeLabel(e, source);
      const size_t open = label.rfind(" (");
      ASSERT_NE(open, std::string::npos) << label;
      EXPECT_GT(label.size(), open + 3) << label;
      EXPECT_EQ(label.back(), ')') << label;
    }
    if (c.driver() == CauseModel::Driver::kThermal) {
      EXPECT_EQ(x, thermalDriverValue(e, d)) << what;
    }
  }
}

// B writes only the rows of the parameters the cause's subject names, is finite and the same on a second call.
TEST_P(CauseSuite, BasisPerturbsOnlyWhatItsSubjectNames) {
  const CauseModel& c = cause();
  using Subject = CauseModel::Subject;
  for (const Extension& e : applicableExtensions())
    for (int trial = 0; trial < 3; ++trial) {
      const Eigen::VectorXd p = randomParams(), q = randomQ();
      const Drivers d = randomDrivers(1e-3);
      const Eigen::MatrixXd B = extensionBasis(model_, p, e, q, d, 1e-3);
      ASSERT_TRUE(B.allFinite()) << extensionSpec(e);
      EXPECT_EQ(B, extensionBasis(model_, p, e, q, d, 1e-3)) << extensionSpec(e);
      EXPECT_GT(B.norm(), 0.0) << extensionSpec(e) << " does not act";
      std::set<int> allowed;
      for (int i = 0; i < model_.numParams(); ++i) allowed.insert(i);  // kLink: a Cartesian motion, any parameter
      if (c.subject() == Subject::kJoint) allowed = {model_.jointParam(e.joint, JointParam::kThetaOffset)};
      if (c.subject() == Subject::kBase) {
        allowed.clear();
        for (int k = 0; k < 6; ++k) allowed.insert(model_.baseParam(static_cast<FrameParam>(k)));
      }
      if (c.subject() == Subject::kJointOrLengths) {
        allowed.clear();
        for (int i = 0; i < model_.numJoints(); ++i)
          for (JointParam jp : {JointParam::kA, JointParam::kD}) allowed.insert(model_.jointParam(i, jp));
        if (e.joint >= 0) allowed.insert(model_.jointParam(e.joint, JointParam::kThetaOffset));
      }
      for (int i = 0; i < model_.numParams(); ++i)
        if (!allowed.count(i)) {
          EXPECT_EQ(B.row(i).norm(), 0.0) << extensionSpec(e) << " moves " << model_.paramName(i);
        }
    }
}

// The pose Jacobian of the extension's parameters as fits use it (J at the extended parameters times B) against the
// derivative of the prediction: central differences of forwardKinematics(extendedParams(e)), and Jets carrying the
// column of B through the templated chain.
TEST_P(CauseSuite, PoseJacobianMatchesFiniteDifferencesAndJets) {
  using Jet = ceres::Jet<double, 1>;
  const CauseModel& c = cause();
  KinematicsData data(model_);
  Eigen::MatrixXd J(6, model_.numParams());
  int columns = 0;
  for (const Extension& base_ext : applicableExtensions())
    for (int trial = 0; trial < 3; ++trial) {
      Extension e = base_ext;
      if (followsThermalDriver(e.cause)) {  // before a fit, fitted, or a straight line in time
        const double pick = uniform(0, 1);
        e.time_constant_h = pick < 0.33 ? 0.0 : (pick < 0.67 ? uniform(0.3, 3.0) : std::numeric_limits<double>::infinity());
      }
      const std::vector<Extension> exts = {e};
      const Eigen::VectorXd p = randomParams(), q = randomQ();
      const Eigen::VectorXd sigma = extensionPriorSigma(model_, p, exts, 1e-3);
      Eigen::VectorXd x(sigma.size());
      for (Eigen::Index k = 0; k < x.size(); ++k) x[k] = sigma[k] * uniform(-2.0, 2.0);
      // A play's width is |its parameter|: every joint's last move crosses it.
      const double play = followsPath(e.cause) ? std::abs(x[0]) : 0.0;
      const Drivers d = randomDrivers(play);
      const Eigen::VectorXd pe = extendedParams(model_, p, exts, x, q, d);
      const Eigen::MatrixXd B = extensionBasis(model_, p, exts, q, d, x);
      forwardKinematics(model_, data, pe, q);
      computePoseJacobian(model_, data, J);
      const Eigen::MatrixXd JB = J * B;
      for (Eigen::Index k = 0; k < x.size(); ++k) {
        const double col = B.col(k).norm();
        if (col == 0.0) continue;  // a column that does not act at this configuration
        ++columns;
        const std::string what = extensionSpec(e) + " " + extensionParamNames(model_, exts)[static_cast<size_t>(k)];
        // Finite differences: a step moving the kinematic parameters by 1e-6 (rad or m).
        const double h = 1e-6 / col;
        Eigen::VectorXd xp = x, xm = x;
        xp[k] += h;
        xm[k] -= h;
        const Pose Tp = forwardKinematics(model_, extendedParams(model_, p, exts, xp, q, d), q);
        const Pose Tm = forwardKinematics(model_, extendedParams(model_, p, exts, xm, q, d), q);
        const Eigen::Vector3d dp = (Tp.translation() - Tm.translation()) / (2 * h);
        const Eigen::Vector3d dw = logSO3(Tp.linear() * Tm.linear().transpose()) / (2 * h);
        const double scale = JB.col(k).norm() + 1e-3 * col;  // floor: rounding of the poses over the step
        EXPECT_LT((JB.col(k).head<3>() - dp).norm(), 1e-6 * scale) << what << " (translation, finite differences)";
        EXPECT_LT((JB.col(k).tail<3>() - dw).norm(), 1e-6 * scale) << what << " (rotation, finite differences)";
        // Jets: the kinematic parameters at pe with derivative B's column.
        std::vector<Jet> pj(static_cast<size_t>(pe.size()));
        for (Eigen::Index i = 0; i < pe.size(); ++i) {
          pj[static_cast<size_t>(i)] = Jet(pe[i]);
          pj[static_cast<size_t>(i)].v[0] = B(i, k);
        }
        const test::JetTwist t = test::jetTwist(forwardKinematicsT<Jet>(model_, pj.data(), q.data()));
        EXPECT_LT((JB.col(k).head<3>() - t.translation).norm(), 1e-10 * scale) << what << " (translation, Jets)";
        EXPECT_LT((JB.col(k).tail<3>() - t.rotation).norm(), 1e-10 * scale) << what << " (rotation, Jets)";
      }
    }
  EXPECT_GT(columns, 0) << c.name() << ": no column acted";
}

std::vector<CauseCase> allCauses() {
  std::vector<CauseCase> out;
  for (const CauseModel* c : causeModels())
    for (const std::string r : {"staubli_tx60", "ur10"}) out.push_back({c, r});
  return out;
}

INSTANTIATE_TEST_SUITE_P(Registered, CauseSuite, ::testing::ValuesIn(allCauses()),
                         [](const ::testing::TestParamInfo<CauseCase>& info) {
                           return std::string(info.param.cause->name()) + "_" + info.param.robot;
                         });

}  // namespace
}  // namespace cellcal
