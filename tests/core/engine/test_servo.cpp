// A servo loop's setpoint stream through ServoCompensator: each answer against the plain reference (compensate() with
// each version), and a new calibration version blended in without a step. The versions differ by random joint-zero
// and link-length changes; the path, the blend time and the moment each version arrives are drawn from the test seed.
#include <gtest/gtest.h>

#include <random>

#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/engine/servo.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

const std::string kCell = std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml";

struct ServoFixture : ::testing::Test {
  std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng{seed};
  CellConfig config = loadCellConfig(kCell);
  std::optional<SimulatedCell> cell;
  void SetUp() override {
    SimulationSettings ss = config.simulation;
    ss.seed = seed;
    cell.emplace(makeSimulatedCell(config.robots[0], ss, 0));
  }
  const RobotModel& model() const { return cell->model(); }
  // Another version: the truth with each joint's zero moved by 0.005-0.03 deg and its d and a by 20-100 um, either way.
  Eigen::VectorXd changed(const Eigen::VectorXd& p) {
    std::uniform_real_distribution<double> u(0, 1);
    auto sign = [&] { return u(rng) < 0.5 ? -1.0 : 1.0; };
    Eigen::VectorXd out = p;
    for (int j = 0; j < model().numJoints(); ++j) {
      out[model().jointParam(j, JointParam::kThetaOffset)] += sign() * (0.005 + 0.025 * u(rng)) * kPi / 180;
      out[model().jointParam(j, JointParam::kD)] += sign() * (20 + 80 * u(rng)) * 1e-6;
      out[model().jointParam(j, JointParam::kA)] += sign() * (20 + 80 * u(rng)) * 1e-6;
    }
    return out;
  }
  // A smooth joint path between two random configurations, one setpoint per cycle.
  std::vector<Eigen::VectorXd> path(int cycles) {
    const auto ends = cell->randomConfigurations(2, rng);
    std::vector<Eigen::VectorXd> qs;
    for (int k = 0; k < cycles; ++k) {
      const double s = 0.5 - 0.5 * std::cos(kPi * k / (cycles - 1));
      qs.push_back(ends[0] + s * (ends[1] - ends[0]));
    }
    return qs;
  }
};

// 500 Hz joint setpoints for 3 s; version 2 arrives at a random cycle, version 3 (in half the runs) during the blend.
// Before the switch every answer is version 1's compensate(); from the first setpoint after it, the answer is
// q1* + w (q2* - q1*) with w rising linearly over blend_s of the setpoints' stamps; after the blends, version 3's (or
// 2's) compensate(). Between consecutive setpoints the correction moves by no more than either version's own does plus
// w's step times their difference; without blending (blend_s = 0) the switch is a step many times larger.
TEST_F(ServoFixture, ANewVersionIsBlendedInWithoutAStep) {
  const RobotModel& m = model();
  const Eigen::VectorXd v1 = cell->trueParams(0.0), v2 = changed(v1), v3 = changed(v2);
  std::uniform_real_distribution<double> u(0, 1);
  const double blend_s = 0.2 + 0.8 * u(rng);
  const int cycles = 1500, switch_at = 100 + static_cast<int>(u(rng) * 400);
  const bool third = u(rng) < 0.5;
  const int third_at = switch_at + 1 + static_cast<int>(u(rng) * blend_s * 500 * 0.8);
  const std::int64_t t0 = 1'700'000'000'000'000'000, dt = 2'000'000;  // 500 Hz
  ServoCompensator blended(m, config.compensation, blend_s), stepped(m, config.compensation, 0.0);
  for (ServoCompensator* s : {&blended, &stepped}) s->setCalibration(1, IdentifiedModel(CalibratedModel::geometric(v1)));
  // A path the versions can correct at its ends and middle (the test is of the blend, not of reachability): seed
  // 5765261486140875056 drew one within a millimetre of the joint limits all along, none of it answerable.
  auto correctable = [&](const Eigen::VectorXd& q) {
    for (const Eigen::VectorXd* v : {&v1, &v2, &v3}) {
      const CompensationResult r = compensate(m, *v, forwardKinematics(m, m.nominal, q), q, config.compensation);
      if (!r.applied || (r.q_rad - q).cwiseAbs().maxCoeff() > config.compensation.max_joint_correction_rad) return false;
    }
    return true;
  };
  std::vector<Eigen::VectorXd> qs = path(cycles);
  for (int tries = 1; tries < 20 && !(correctable(qs.front()) && correctable(qs[cycles / 2]) && correctable(qs.back()));
       ++tries)
    qs = path(cycles);
  Eigen::VectorXd last_blended, last_stepped, last_q;
  std::optional<Eigen::VectorXd> last_c[3];
  double worst_excess = 0, worst_step_blended = 0, worst_step_stepped = 0, worst_ref = 0;
  double blended_extra = 0, stepped_extra = 0;  // steps beyond what the versions' own corrections did
  const std::int64_t start2 = t0 + switch_at * dt;  // the first setpoint after version 2 arrived
  std::optional<std::int64_t> start3;
  int answered = 0;
  bool switch_seen = false;  // the cycles before and at the switch both answered: the step there measured
  for (int k = 0; k < cycles; ++k) {
    const std::int64_t t = t0 + k * dt;
    if (k == switch_at)
      for (ServoCompensator* s : {&blended, &stepped}) s->setCalibration(2, IdentifiedModel(CalibratedModel::geometric(v2)));
    if (third && k == third_at)
      for (ServoCompensator* s : {&blended, &stepped}) s->setCalibration(3, IdentifiedModel(CalibratedModel::geometric(v3)));
    const ServoAnswer a = blended.answerJoints(t, qs[k]), b = stepped.answerJoints(t, qs[k]);
    // The plain reference: each version's compensate() of the setpoint's nominal pose, seeded at the setpoint.
    const Pose desired = forwardKinematics(m, m.nominal, qs[k]);
    const CompensationResult c[3] = {compensate(m, v1, desired, qs[k], config.compensation),
                                     compensate(m, v2, desired, qs[k], config.compensation),
                                     compensate(m, v3, desired, qs[k], config.compensation)};
    // Which versions the answer should blend, and how: (from, to, w).
    int from = 0, to = 0;
    double w = 1.0;
    if (k >= switch_at) {
      const double w2 = static_cast<double>(t - start2) * 1e-9 / blend_s;
      if (w2 < 1.0) {
        from = 0, to = 1, w = w2;
      } else if (!third) {
        from = to = 1;
      } else {
        if (!start3) start3 = t;  // version 3 waited for the first blend to end
        const double w3 = static_cast<double>(t - *start3) * 1e-9 / blend_s;
        from = w3 < 1.0 ? 1 : 2, to = 2, w = std::min(1.0, w3);
      }
    }
    // Near a singularity: said, not answered. Either a version cannot reach the pose, or reaches it on another branch.
    bool answerable = true;
    for (const auto& r : c)
      answerable = answerable && r.applied &&
                   (r.q_rad - qs[k]).cwiseAbs().maxCoeff() <= config.compensation.max_joint_correction_rad;
    if (!a.applied || !answerable) {
      if (!a.applied) {
        EXPECT_EQ(a.q_rad, qs[k]) << describe(a);
      }
      last_blended.resize(0);
      continue;
    }
    ++answered;
    EXPECT_EQ(a.version, static_cast<std::uint64_t>(to + 1));
    EXPECT_EQ(a.from_version, static_cast<std::uint64_t>(from + 1));
    EXPECT_NEAR(a.weight, from == to ? 1.0 : w, 1e-12);
    const Eigen::VectorXd want = c[from].q_rad + w * (c[to].q_rad - c[from].q_rad);
    worst_ref = std::max(worst_ref, (a.q_rad - want).cwiseAbs().maxCoeff());
    EXPECT_EQ(b.q_rad, c[k < switch_at ? 0 : third && k >= third_at ? 2 : 1].q_rad);
    // Steps of the correction (answer - setpoint) between consecutive answered cycles.
    if (last_blended.size() > 0) {
      const Eigen::VectorXd step = (a.q_rad - qs[k]) - (last_blended - last_q);
      double own = 0;
      for (int v = 0; v < 3; ++v)
        own = std::max(own, ((c[v].q_rad - qs[k]) - (*last_c[v] - last_q)).cwiseAbs().maxCoeff());
      const double bound = own + ((c[1].q_rad - c[0].q_rad).cwiseAbs().maxCoeff() +
                                  (c[2].q_rad - c[1].q_rad).cwiseAbs().maxCoeff()) * dt * 1e-9 / blend_s;
      worst_excess = std::max(worst_excess, step.cwiseAbs().maxCoeff() - bound);
      const double step_stepped = ((b.q_rad - qs[k]) - (last_stepped - last_q)).cwiseAbs().maxCoeff();
      worst_step_blended = std::max(worst_step_blended, step.cwiseAbs().maxCoeff());
      worst_step_stepped = std::max(worst_step_stepped, step_stepped);
      blended_extra = std::max(blended_extra, step.cwiseAbs().maxCoeff() - own);
      stepped_extra = std::max(stepped_extra, step_stepped - own);
      switch_seen = switch_seen || k == switch_at;
    }
    last_blended = a.q_rad;
    last_stepped = b.q_rad;
    last_q = qs[k];
    for (int v = 0; v < 3; ++v) last_c[v] = c[v].q_rad;
  }
  std::printf("  blend %.2f s, switch at cycle %d%s: %d of %d answered; largest step of the correction %.3g rad "
              "blended, %.3g rad switched at once; beyond the versions' own %.3g and %.3g rad\n",
              blend_s, switch_at, third ? (", a third version at " + std::to_string(third_at)).c_str() : "", answered,
              cycles, worst_step_blended, worst_step_stepped, blended_extra, stepped_extra);
  // A path between two random configurations may pass a wrist singularity, where setpoints are passed through by
  // design (unreachable, or another branch): most are answered.
  EXPECT_GE(answered, cycles / 2);
  EXPECT_LT(worst_ref, 1e-12);
  EXPECT_LE(worst_excess, 1e-12);
  if (switch_seen) {
    EXPECT_GT(stepped_extra, 5 * blended_extra);
  }
  EXPECT_EQ(blended.version(), third ? 3u : 2u);
  EXPECT_FALSE(blended.blending());
}

// Before any calibration a setpoint passes through, said; a Cartesian setpoint is answered as compensate() answers
// the target (the nominal model's pose of q* to command); a setpoint of the wrong size is refused by name.
TEST_F(ServoFixture, CartesianSetpointsAndTheirRefusals) {
  const RobotModel& m = model();
  const Eigen::VectorXd truth = cell->trueParams(0.0);
  ServoCompensator servo(m, config.compensation, 0.5);
  const auto qs = cell->randomConfigurations(20, rng);
  const Pose target = forwardKinematics(m, m.nominal, qs[0]);
  const ServoAnswer none = servo.answerPose(1, target, qs[0]);
  EXPECT_FALSE(none.applied);
  EXPECT_EQ(none.version, 0u);
  EXPECT_EQ(describe(none), "no calibration received yet");
  EXPECT_EQ(none.q_rad, qs[0]);
  EXPECT_TRUE(none.commanded.isApprox(target));
  servo.setCalibration(7, IdentifiedModel(CalibratedModel::geometric(truth)));
  int matched = 0;
  for (const auto& q : qs) {
    const Pose desired = forwardKinematics(m, m.nominal, q);
    const ServoAnswer a = servo.answerPose(2, desired, q);
    const CompensationResult c = compensate(m, truth, desired, q, config.compensation);
    const bool same_branch = c.applied && (c.q_rad - q).cwiseAbs().maxCoeff() <= config.compensation.max_joint_correction_rad;
    ASSERT_EQ(a.applied, same_branch) << describe(a);
    if (!same_branch) {
      EXPECT_EQ(a.decided_by, 7u);
      EXPECT_NE(describe(a).find("setpoint passed through"), std::string::npos) << describe(a);
      continue;
    }
    EXPECT_EQ(a.q_rad, c.q_rad);
    EXPECT_TRUE(a.commanded.isApprox(c.corrected_in_tracker, 1e-12));
    EXPECT_EQ(a.version, 7u);
    ++matched;
  }
  EXPECT_GE(matched, 10);
  const ServoAnswer bad = servo.answerJoints(3, Eigen::VectorXd::Zero(m.numJoints() + 1));
  EXPECT_FALSE(bad.applied);
  EXPECT_EQ(bad.outcome, CompensationOutcome::kBadInput);
  EXPECT_NE(describe(bad).find("7 joint values (the robot has 6)"), std::string::npos) << describe(bad);
  EXPECT_THROW(ServoCompensator(m, config.compensation, -1.0), std::invalid_argument);
}

}  // namespace
}  // namespace cellcal
