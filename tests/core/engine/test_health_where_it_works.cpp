// Health judged where the cell works (work_configurations.hpp, health.hpp): a cell whose robot keeps one tool
// orientation or one region of its joints, as a production program does, pins the model there and nowhere else. The
// engine reaches ok on what it measured, the compensation publisher's rule (compensate() with the published model)
// corrects the cell's own targets to within their predicted error and passes through targets far from anything
// measured. Where the program, the measurement kind and the hidden errors lie is drawn at random; the engine only sees
// samples, and the truth only judges.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <string>

#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/engine/work_configurations.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "core/engine/engine_feed.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

const std::string kCell = std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml";

double minPairDistance(const std::vector<Eigen::VectorXd>& qs) {
  double d = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < qs.size(); ++i)
    for (size_t j = i + 1; j < qs.size(); ++j) d = std::min(d, (qs[i] - qs[j]).norm());
  return d;
}

// The set's rule as its header states it: every distinct configuration kept, in order, until kKept; after that it
// changes only by a replacement that leaves the closest pair no closer; a repeat within kSameRad changes nothing; work
// that moves to another region is followed.
TEST(WorkConfigurations, KeepTheExtremesOfWhereTheRobotWasMeasured) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto near = [&](const Eigen::VectorXd& centre, double r) {
    Eigen::VectorXd q = centre;
    for (Eigen::Index j = 0; j < q.size(); ++j) q[j] += r * u(rng);
    return q;
  };
  for (int draw = 0; draw < 20; ++draw) {
    const int joints = 6 + static_cast<int>(rng() % 2);
    const Eigen::VectorXd a = near(Eigen::VectorXd::Zero(joints), 2.0), b = near(Eigen::VectorXd::Zero(joints), 2.0);
    WorkConfigurations set;
    std::vector<Eigen::VectorXd> offered;
    for (size_t k = 0; k < WorkConfigurations::kKept; ++k) {
      offered.push_back(near(a, 0.3));
      EXPECT_EQ(set.offer(offered.back()), std::optional<std::size_t>(k));
      Eigen::VectorXd again = offered.back();
      again[static_cast<Eigen::Index>(rng() % joints)] += 0.9 * WorkConfigurations::kSameRad;
      EXPECT_FALSE(set.offer(again).has_value()) << "a repeat of a member is no new configuration";
    }
    ASSERT_EQ(set.configurations(), offered);
    double spread = minPairDistance(set.configurations());
    for (int k = 0; k < 300; ++k) {
      const std::vector<Eigen::VectorXd> before = set.configurations();
      const Eigen::VectorXd q = near(a, 0.3);
      const std::optional<std::size_t> changed = set.offer(q);
      EXPECT_EQ(changed.has_value(), before != set.configurations());
      if (changed) {  // only that member changed, to the configuration offered
        EXPECT_EQ(set.configurations()[*changed], q);
        for (size_t m = 0; m < before.size(); ++m) {
          if (m != *changed) {
            EXPECT_EQ(set.configurations()[m], before[m]);
          }
        }
      }
      EXPECT_EQ(set.configurations().size(), WorkConfigurations::kKept);
      const double now = minPairDistance(set.configurations());
      EXPECT_GE(now, spread) << "a replacement brought the set's closest pair closer";
      spread = now;
    }
    // The robot's work moves to another region: it joins the set.
    if ((a - b).norm() > 1.0) {
      for (int k = 0; k < 50; ++k) set.offer(near(b, 0.3));
      const auto in_b = std::count_if(set.configurations().begin(), set.configurations().end(),
                                      [&](const Eigen::VectorXd& q) { return (q - b).cwiseAbs().maxCoeff() <= 0.3; });
      EXPECT_GE(in_b, 2);
    }
    WorkConfigurations restored;
    restored.restore(set.configurations());
    EXPECT_EQ(restored.configurations(), set.configurations());
  }
}

// The engine's figure at each work configuration, kept current through every update and every replacement of a
// configuration (only its rows are computed again), against the plain reference: kinematicPositionSigma there, with
// the Jacobian at the nominal parameters, after every pose of a random stream long enough to replace members.
TEST(HealthWhereTheCellWorks, EachWorkConfigurationsPredictedErrorIsThePlainOne) {
  CellConfig config = loadCellConfig(kCell);
  std::mt19937_64 rng(test::testSeed());
  config.simulation.seed = rng();
  const CellRobot& robot = config.robots[0];
  const SimulatedCell sim = makeSimulatedCell(robot, config.simulation, 0);
  CalibrationEngine engine(robot, config.engine, 1.0);
  test::Stream st{sim, rng};
  KinematicsData data(robot.model);
  int replaced = 0;
  double worst = 0;
  for (const auto& q : sim.randomConfigurations(150, rng)) {
    const std::vector<Eigen::VectorXd> before = engine.workConfigurations();
    st.advance(30);
    st.feed(engine, q, st.reading(q));
    const auto& work = engine.workConfigurations();
    replaced += before.size() == work.size() && before != work;
    const CalibrationSnapshot& snap = engine.snapshot();
    ASSERT_EQ(engine.workPredictionSigmas().size(), work.size());
    for (size_t k = 0; k < work.size(); ++k) {
      const double plain =
          kinematicPositionSigma(robot.model, data, robot.model.nominal, snap.estimated, snap.covariance, work[k]);
      worst = std::max(worst, std::abs(engine.workPredictionSigmas()[k] - plain) / plain);
    }
  }
  EXPECT_GE(replaced, 5) << "the stream did not replace enough configurations to show anything";
  EXPECT_LT(worst, 1e-9) << replaced << " replacements";
}

// Where a production program works: one tool orientation (positions in a box around a centre, the joints from the
// nominal model's inverse kinematics) or one region of the joints (each within a fraction of its range of a centre).
struct WorkDomain {
  const SimulatedCell& sim;
  bool one_orientation = true;
  Eigen::VectorXd centre;
  Pose centre_pose;
  double box_m = 0, joint_fraction = 0;

  // A configuration of the domain (nullopt: the draw fell out of reach or outside the limits).
  std::optional<Eigen::VectorXd> draw(std::mt19937_64& rng) const {
    const RobotModel& m = sim.model();
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    if (!one_orientation) {
      Eigen::VectorXd q = centre;
      for (int j = 0; j < m.numJoints(); ++j) {
        const double range = std::min(m.limits[j].upper_rad, kPi) - std::max(m.limits[j].lower_rad, -kPi);
        q[j] = std::clamp(q[j] + joint_fraction * range * u(rng), m.limits[j].lower_rad, m.limits[j].upper_rad);
      }
      return q;
    }
    Pose target = centre_pose;
    target.translation() += box_m * Eigen::Vector3d(u(rng), u(rng), u(rng));
    const IkResult ik = solveInverseKinematics(m, m.nominal, target, centre);
    if (!ik.ok() || (ik.q_rad - centre).cwiseAbs().maxCoeff() > 1.5) return std::nullopt;  // another branch
    return ik.q_rad;
  }
};

struct Landed {
  int asked = 0, applied = 0, outside = 0, within_3_sigma = 0;
  std::map<std::string, int> refused;  // by outcome
  double sum_sq_ratio = 0, worst_ratio = 0, sum_sq_error_m = 0;
  double rms() const { return applied ? std::sqrt(sum_sq_ratio / applied) : 0.0; }
  double rmsError_m() const { return applied ? std::sqrt(sum_sq_error_m / applied) : 0.0; }
  void add(const Landed& o) {
    asked += o.asked;
    applied += o.applied;
    outside += o.outside;
    within_3_sigma += o.within_3_sigma;
    sum_sq_ratio += o.sum_sq_ratio;
    sum_sq_error_m += o.sum_sq_error_m;
    worst_ratio = std::max(worst_ratio, o.worst_ratio);
  }
};

TEST(HealthWhereTheCellWorks, ACellThatKeepsToOneOrientationOrRegionIsOkAndLandsItsTargetsWithinTheirPredictedError) {
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  const int draws = 4;
  Landed own_all, far_applied, far_refused;  // far_refused: what the refused ones would have landed, corrected anyway
  for (int draw = 0; draw < draws; ++draw) {
    CellConfig config = loadCellConfig(kCell);
    config.simulation.seed = rng();
    const MeasurementKind kind = rng() % 3 == 0 ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
    config.robots[0].measurement = kind;
    const CellRobot& robot = config.robots[0];
    const SimulatedCell sim = makeSimulatedCell(robot, config.simulation, 0);
    const RobotModel& m = sim.model();
    KinematicsData d(m);
    WorkDomain domain{sim, true, Eigen::VectorXd(), Pose::Identity(), 0, 0};
    domain.one_orientation = rng() % 2 == 0;
    domain.box_m = std::uniform_real_distribution<double>(0.1, 0.25)(rng);
    domain.joint_fraction = std::uniform_real_distribution<double>(0.02, 0.06)(rng);
    domain.centre = sim.randomConfigurations(1, rng).front();
    domain.centre_pose = forwardKinematics(m, d, m.nominal, domain.centre);
    auto drawMany = [&](int n) {
      std::vector<Eigen::VectorXd> qs;
      for (int tries = 0; tries < 20 * n && static_cast<int>(qs.size()) < n; ++tries)
        if (auto q = domain.draw(rng)) qs.push_back(*q);
      return qs;
    };
    const std::vector<Eigen::VectorXd> program = drawMany(120);
    const std::string what = std::string(domain.one_orientation ? "one orientation, box +-" +
                                                                      std::to_string(domain.box_m * 1e3) + " mm"
                                                                : "one region, +-" + std::to_string(domain.joint_fraction) +
                                                                      " of each range") +
                             (kind == MeasurementKind::kPose6D ? ", 6D" : ", points");
    SCOPED_TRACE("draw " + std::to_string(draw) + ": " + what + ", seed " + std::to_string(seed));
    if (program.size() < 60) {
      ADD_FAILURE() << "the domain gave " << program.size() << " configurations";
      continue;
    }
    CalibrationEngine engine(robot, config.engine, 1.0);
    test::Stream st{sim, rng};
    for (const auto& q : program) {
      st.advance(30);
      const Observation o = sim.measure(q, st.cell_h, rng, kind);
      TrackerSample s = test::trackerSample(o, st.t_ns, ++st.seq);
      for (int i = 0; i < 3; ++i) {  // the tracker's stated noise, as a tracker adapter sends it
        s.covariance[i * 7] = o.sigma_position_m * o.sigma_position_m;
        s.covariance[(i + 3) * 7] = o.sigma_orientation_rad * o.sigma_orientation_rad;
      }
      st.feed(engine, q, s);
    }
    const CalibrationSnapshot& snap = engine.snapshot();
    EXPECT_EQ(snap.health, Health::kOk) << describe(snap.health_verdict);
    EXPECT_LE(snap.prediction_sigma_position_m, config.engine.hold_prediction_sigma_m);
    // The old rule (the worst over the whole workspace) refuses a cell at one tool orientation: what it leaves open
    // there stays at the prior's width.
    if (domain.one_orientation) {
      EXPECT_GT(engine.workspacePredictionSigma(), config.engine.hold_prediction_sigma_m);
    }

    // The compensation publisher's rule with the published model: the cell's own targets, and targets far from
    // anything measured (every joint configuration at least 0.5 rad from each one the program measured); those passed
    // through are also corrected with the guard off, to see what refusing them saved.
    const IdentifiedModel model(static_cast<const CalibratedModel&>(snap));
    CompensationSettings unguarded = config.compensation;
    unguarded.max_predicted_sigma_m = 0;
    auto landAt = [&](const Eigen::VectorXd& q, const CompensationSettings& settings, Landed& out) {
      const Pose desired = forwardKinematics(m, d, m.nominal, q);
      const CompensationResult c = compensate(m, model, desired, q, settings);
      ++out.asked;
      if (c.outcome == CompensationOutcome::kOutsideCalibration) ++out.outside;
      if (!c.applied) ++out.refused[outcomeName(c.outcome)];
      if (!c.applied) return c;
      ++out.applied;
      const double error = (sim.truePose(c.q_rad, st.cell_h).translation() - desired.translation()).norm();
      const double ratio = error / c.predicted_sigma_position_m;
      out.sum_sq_ratio += ratio * ratio;
      out.sum_sq_error_m += error * error;
      out.worst_ratio = std::max(out.worst_ratio, ratio);
      if (ratio <= 3) ++out.within_3_sigma;
      return c;
    };
    Landed own, away, refused;
    for (const auto& q : drawMany(60)) landAt(q, config.compensation, own);
    int far = 0;
    for (const auto& q : sim.randomConfigurations(400, rng)) {
      double nearest = std::numeric_limits<double>::infinity();
      for (const auto& p : program) nearest = std::min(nearest, (p - q).norm());
      if (nearest < 0.5 || ++far > 60) continue;
      if (landAt(q, config.compensation, away).outcome == CompensationOutcome::kOutsideCalibration)
        landAt(q, unguarded, refused);
    }
    std::printf("  %s: workspace %.3f mm, where it works %.4f mm (1 sigma); own targets %d of %d applied, landed/sigma "
                "RMS %.2f max %.2f; far %d of %d passed through (%.3f mm RMS had they been corrected), the others "
                "landed/sigma RMS %.2f\n",
                what.c_str(), engine.workspacePredictionSigma() * 1e3, snap.prediction_sigma_position_m * 1e3,
                own.applied, own.asked, own.rms(), own.worst_ratio, away.outside, away.asked,
                refused.rmsError_m() * 1e3, away.rms());
    // Every own target corrected but those the calibrated arm cannot reach (near a stretched elbow the true arm can
    // be shorter than the nominal one: compensation says so, Compensation.TheTrueRobotLandsOnTheTarget...).
    const int reachable = own.asked - (own.refused.count("unreachable") ? own.refused.at("unreachable") : 0);
    EXPECT_GE(own.applied, reachable * 9 / 10) << [&] {
      std::string why;
      for (const auto& [outcome, n] : own.refused) why += " " + outcome + " " + std::to_string(n);
      return "refused:" + why;
    }();
    EXPECT_GE(own.within_3_sigma, own.applied * 95 / 100);
    own_all.add(own);
    far_applied.add(away);
    far_refused.add(refused);
  }
  // Pooled over the draws (one draw's targets share its few unpinned directions, so one draw is nearly one sample):
  // the landed errors are those predicted, where the cell works and far from it, corrected or not; and what was
  // passed through would have landed far worse than the cell's own targets.
  std::printf("  pooled: own targets landed/sigma RMS %.2f (%.4f mm), far ones corrected %.2f, far ones passed through "
              "%d of %d (%.3f mm, %.2f of their predicted sigma, had they been corrected)\n",
              own_all.rms(), own_all.rmsError_m() * 1e3, far_applied.rms(), far_applied.outside, far_applied.asked,
              far_refused.rmsError_m() * 1e3, far_refused.rms());
  EXPECT_LE(own_all.rms(), 1.3);
  EXPECT_LE(far_applied.rms(), 1.3);
  EXPECT_LE(far_refused.rms(), 1.3);
  if (far_refused.applied > 0) {
    EXPECT_GT(far_refused.rmsError_m(), 5 * own_all.rmsError_m());
  }
}

}  // namespace
}  // namespace cellcal
