// Model diagnosis: extensions reproduce the physical effects, and hidden effects drawn at random are found.
#include <gtest/gtest.h>

#include <cstdlib>
#include <functional>

#include "cellcal/core/identification/statistics.hpp"
#include "core/identification/hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

// ---------------------------------------------------------------------------------------------------------------
// Each extension, with the parameters the simulator used, predicts exactly the pose the simulated robot reaches.
// (The simulator applies the effect as a joint error of its own; the extension as a parameter perturbation B e.)
class ExtensionReproducesTheEffect : public ::testing::TestWithParam<std::string> {};

TEST_P(ExtensionReproducesTheEffect, ForEveryCauseAndJoint) {
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const RobotModel nominal = test::robot(GetParam());
  const int n = nominal.numJoints();
  for (Cause cause : extensionCauses())
    for (int j = 0; j < n; ++j) {
      if (cause == Cause::kLinkDeflection) continue;  // not a joint error: LinkDeflection.* below
      SimulationConfig sc;
      sc.seed = rng();
      sc.zero_drift_per_K_max_rad = sc.zero_wear_per_h_max_rad = 0;
      sc.warmup_K = 0;  // no thermal growth unless the cause is thermal
      HiddenJointEffect& e = sc.hidden;
      e.cause = cause;
      e.joint = j;
      SimulatedCell plain(nominal, sc);
      RobotModel m = plain.model();
      Eigen::VectorXd ext_params;
      switch (cause) {
        case Cause::kJointCompliance:
          m.links = test::randomLinks(m, plain.trueParams(0), rng);
          e.links = m.links;
          e.compliance_rad_per_Nm = 1e-5 * u(rng);
          ext_params = Eigen::VectorXd::Constant(1, e.compliance_rad_per_Nm);
          break;
        case Cause::kThermalDrift:
          e.zero_drift_rad_per_K = 1e-4 * u(rng);
          ext_params = Eigen::Vector2d(sc.expansion_per_K, e.zero_drift_rad_per_K);
          break;
        case Cause::kCyclicTransmission:
          e.harmonics_rad = 1e-3 * Eigen::Vector4d(u(rng), u(rng), u(rng), u(rng));
          ext_params = e.harmonics_rad;
          break;
        case Cause::kJointScale:
          e.scale = 1e-3 * u(rng);
          ext_params = Eigen::VectorXd::Constant(1, e.scale);
          break;
        case Cause::kBacklash:
          e.backlash_width_rad = 1e-3 * (1.5 + u(rng));
          ext_params = Eigen::VectorXd::Constant(1, -e.backlash_width_rad);  // the link lags the motor
          break;
        case Cause::kLinkDeflection:
        case Cause::kFrameDrift:
        case Cause::kNone:
          break;
      }
      if (cause == Cause::kThermalDrift) {
        sc.warmup_K = 5.0;
        sc.warmup_tau_h = 1.0;
      }
      const SimulatedCell cell(nominal, sc);
      const Extension ext{cause, j};
      if (cause == Cause::kJointCompliance && !applicable(m, ext, false)) continue;
      ASSERT_EQ(numExtensionParams(m, ext), ext_params.size()) << causeName(cause);
      // A path of large moves, each followed by small ones (a fraction of the backlash width, either way): the play
      // is crossed fully and partly.
      std::vector<Eigen::VectorXd> qs;
      for (const auto& q : cell.randomConfigurations(4, rng)) {
        qs.push_back(q);
        for (int s = 0; s < 2; ++s)
          qs.push_back(qs.back() + Eigen::VectorXd::NullaryExpr(q.size(), [&] { return 1e-3 * u(rng); }));
      }
      const DriverTable table = driversFromSequence(qs, {}, {});
      // The play is known once the path has crossed the whole gap, whatever the state it started in (the simulator
      // starts at +1, the drivers at 0): only then can any model know it. The first large move (qs[3]) usually does;
      // a joint it moves by less than the width (seed 12203532201613656946, joint 1) is known after a later one.
      HiddenJointState state, from_other_side{-1.0};
      int checked = 0;
      for (size_t i = 1; i < qs.size(); ++i) {
        state = cell.advanceHiddenState(state, qs[i - 1], qs[i]);
        from_other_side = cell.advanceHiddenState(from_other_side, qs[i - 1], qs[i]);
        if (i < 3 || (cause == Cause::kBacklash && state.backlash_play != from_other_side.backlash_play)) continue;
        ++checked;
        const double t_h = 0.7 * static_cast<double>(i);
        Drivers d = table.rows[i];
        d.thermal = cell.temperatureRiseK(t_h);  // reference: the cold robot
        const Eigen::VectorXd true0 = cell.trueParams(0.0);
        const Eigen::MatrixXd B = extensionBasis(m, true0, ext, qs[i], d, e.backlash_width_rad);
        const Pose predicted = forwardKinematics(m, Eigen::VectorXd(true0 + B * ext_params), qs[i]);
        const Pose actual = cell.truePose(qs[i], t_h, &state);
        EXPECT_LT((predicted.translation() - actual.translation()).norm(), 1e-9)
            << causeName(cause) << " joint " << j + 1 << " pose " << i;
        EXPECT_LT(logSO3(predicted.linear() * actual.linear().transpose()).norm(), 1e-9)
            << causeName(cause) << " joint " << j + 1 << " pose " << i;
      }
      EXPECT_GE(checked, 3) << causeName(cause) << " joint " << j + 1 << ": the path never crossed the play";
    }
}

INSTANTIATE_TEST_SUITE_P(Robots, ExtensionReproducesTheEffect, ::testing::Values("staubli_tx60", "ur10"));

// The link_deflection extension moves the target as the test generator's beam does (its own Cartesian
// implementation: the link's far end displaced and turned, every frame beyond it with it), to first order: for sags
// of 0.01-0.5 mm the two poses agree to 1 % of the beam's motion at the target (|sag| + |slope| x the lever from the
// link's far end to the target; the net target motion can be far smaller where sag and slope cancel), and the
// difference is second order: a deflection ten times smaller leaves it at least 30 times smaller. Random robot frames,
// configurations and links.
TEST(LinkDeflection, ExtensionMovesTheTargetAsABendingLinkDoes) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (const char* name : {"staubli_tx60", "ur10"}) {
    SimulationConfig sc;
    sc.seed = rng();
    sc.base_in_tracker.tail<3>() << u(rng), u(rng), 3 * u(rng);
    sc.tool_in_flange << 0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng), u(rng), u(rng), u(rng);
    const SimulatedCell cell(test::robot(name), sc);
    const RobotModel& m = cell.model();
    const Eigen::VectorXd p = cell.trueParams(0.0);
    int links = 0;
    for (int j = 0; j < m.numJoints(); ++j) {
      if (!applicable(m, Extension{Cause::kLinkDeflection, j}, false)) continue;
      ++links;
      for (const auto& q : cell.randomConfigurations(5, rng)) {
        test::detail::Cartesian beam;
        beam.link = j;
        beam.sag_m = (1e-5 + 5e-4 * u(rng)) * (u(rng) < 0.5 ? -1 : 1);
        beam.slope_rad = (u(rng) - 0.5) * 4 * std::abs(beam.sag_m) / linkLength(m, p, j);
        const Eigen::MatrixXd B = extensionBasis(m, p, Extension{Cause::kLinkDeflection, j}, q, Drivers{});
        auto difference = [&](double scale, double* rotation) {
          test::detail::Cartesian b = beam;
          b.sag_m *= scale;
          b.slope_rad *= scale;
          const Pose want = b.apply(m, p, q, forwardKinematics(m, p, q), 0.0);
          const Pose got = forwardKinematics(m, Eigen::VectorXd(p + B * Eigen::Vector2d(b.sag_m, b.slope_rad)), q);
          if (rotation) *rotation = logSO3(got.linear() * want.linear().transpose()).norm();
          return (got.translation() - want.translation()).norm();
        };
        const std::vector<Pose> F = chainFrames(m, p, q);
        const double lever = (F.back().translation() - F[static_cast<size_t>(j) + 1].translation()).norm();
        const double motion = std::abs(beam.sag_m) + std::abs(beam.slope_rad) * lever;
        double rotation = 0;
        const double full = difference(1.0, &rotation), tenth = difference(0.1, nullptr);
        EXPECT_LT(full, 0.01 * motion + 1e-12) << name << " link " << j + 1;
        EXPECT_LT(tenth, full / 30 + 1e-12) << name << " link " << j + 1 << ": not second order";
        EXPECT_LT(rotation, 0.01 * std::abs(beam.slope_rad) + 1e-9);
      }
    }
    // The arms' upper arm and forearm (TX60: links 2 and 4, its forearm runs along joint 4's axis; UR10: 2 and 3).
    EXPECT_EQ(links, 2) << name;
  }
}

// The F distribution's tail against values any table gives, and the incomplete beta against closed forms.
TEST(Statistics, FDistributionTail) {
  EXPECT_NEAR(fSurvival(4.964603, 1, 10), 0.05, 1e-6);
  EXPECT_NEAR(fSurvival(4.102821, 2, 10), 0.05, 1e-6);
  EXPECT_NEAR(fSurvival(1.0, 4, 4), 0.5, 1e-12);
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.01, 0.99);
  for (int k = 0; k < 20; ++k) {
    const double x = u(rng), a = 0.5 + 5 * u(rng);
    EXPECT_NEAR(regularizedIncompleteBeta(a, 1.0, x), std::pow(x, a), 1e-12);
    EXPECT_NEAR(regularizedIncompleteBeta(1.0, a, x), 1 - std::pow(1 - x, a), 1e-12);
    // Two numerator degrees of freedom: P(F > f) = (1 + 2 f / d2)^(-d2 / 2).
    const double f = 10 * u(rng), d2 = 1 + 40 * u(rng);
    EXPECT_NEAR(fSurvival(f, 2, d2), std::pow(1 + 2 * f / d2, -d2 / 2), 1e-12);
    // F(d1, d2) -> chi-square(d1) / d1 as d2 grows.
    const int d1 = 1 + static_cast<int>(8 * u(rng));
    const double c = 20 * u(rng);
    EXPECT_NEAR(fSurvival(c / d1, d1, 1e8), chiSquareSurvival(c, d1), 1e-6);
  }
}

// Without link masses, compliance uses a gravity-shaped basis: a mass at any chosen frame origin is exactly one basis
// function (so the torque of a real arm, whose masses lie along its links, is close to a combination of them).
TEST(GravityBasis, UnitMassAtABasisPointIsOneBasisFunction) {
  const RobotModel m = test::robot("staubli_tx60");
  const int n = m.numJoints();
  std::mt19937_64 rng(test::testSeed());
  SimulationConfig sc;
  SimulatedCell cell(m, sc);
  const auto qs = cell.randomConfigurations(4, rng);
  for (int j = 1; j < 3; ++j) {
    const Extension ext{Cause::kJointCompliance, j};
    ASSERT_TRUE(applicable(cell.model(), ext, false));
    const auto names = extensionParamNames(cell.model(), ext);
    ASSERT_GE(names.size(), 1u);
    for (const auto& q : qs) {
      const Eigen::MatrixXd B = extensionBasis(cell.model(), cell.nominalParams(), ext, q, Drivers{});
      // The basis entries are torques of unit masses: bounded by g times the reach.
      EXPECT_LE(B.row(cell.model().jointParam(j, JointParam::kThetaOffset)).cwiseAbs().maxCoeff(), 9.81 * 1.5);
    }
  }
  // Joint 1 of a floor-mounted arm has a vertical axis: gravity never loads it.
  EXPECT_FALSE(applicable(cell.model(), Extension{Cause::kJointCompliance, 0}, false));
  EXPECT_EQ(n, 6);
}

TEST(Drivers, DirectionAndThermalSources) {
  std::vector<Eigen::VectorXd> q = {Eigen::Vector2d(0, 0), Eigen::Vector2d(0.1, -0.1), Eigen::Vector2d(0.1, 0.0),
                                    Eigen::Vector2d(0.05, 0.2)};
  const DriverTable none = driversFromSequence(q, {}, {});
  EXPECT_FALSE(none.has_thermal);
  EXPECT_EQ(none.rows[1].motion_direction, Eigen::Vector2d(1, -1));
  EXPECT_EQ(none.rows[2].motion_direction, Eigen::Vector2d(1, 1));   // joint 1 still: keeps its last direction
  EXPECT_EQ(none.rows[3].motion_direction, Eigen::Vector2d(-1, 1));
  // Play state. Joint 1 moves +0.1, 0, -0.05: a 0.1 rad play goes 0 -> 1 -> 1 -> 0 (half the gap crossed back),
  // a 0.4 rad one 0 -> 0.5 -> 0.5 -> 0.25. Joint 2 moves -0.1, +0.1, +0.2: crossed fully each time.
  EXPECT_DOUBLE_EQ(playState(none.rows[1], 0, 0.1), 1.0);
  EXPECT_DOUBLE_EQ(playState(none.rows[3], 0, 0.1), 0.0);
  EXPECT_DOUBLE_EQ(playState(none.rows[3], 0, 0.4), 0.25);  // 0 -> 0.5 -> 0.5 -> 0.25
  EXPECT_DOUBLE_EQ(playState(none.rows[3], 1, 0.1), 1.0);
  EXPECT_DOUBLE_EQ(playState(none.rows[3], 1, 0.0), 1.0);   // width 0: the direction of the last move
  EXPECT_DOUBLE_EQ(playState(none.rows[0], 0, 0.1), 0.0);   // nothing known before the first move
  const DriverTable time = driversFromSequence(q, {}, {0.0, 3600.0, 7200.0, 9000.0});
  EXPECT_EQ(time.thermal_source, "stamp_s");
  EXPECT_DOUBLE_EQ(time.rows[3].thermal, 2.5);
  const DriverTable temp = driversFromSequence(q, {20.0, 21.0, 22.0, 23.0}, {0.0, 1.0, 2.0, 3.0});
  EXPECT_EQ(temp.thermal_source, "temperature_c");
  EXPECT_DOUBLE_EQ(temp.rows[0].thermal, -1.5);
  const DriverTable partial = driversFromSequence(q, {20.0, std::nullopt, 22.0, 23.0}, {});
  EXPECT_FALSE(partial.has_thermal);  // a thermal driver only when every row has one
  // A temperature that does not change (within 0.05 C) drives nothing: the stamps do, and it is said.
  const DriverTable still = driversFromSequence(q, {22.4, 22.41, 22.42, 22.4}, {0.0, 3600.0, 7200.0, 9000.0});
  EXPECT_EQ(still.thermal_source, "stamp_s");
  ASSERT_TRUE(still.constant_temperature_c.has_value());
  EXPECT_NEAR(*still.constant_temperature_c, 22.4075, 1e-12);
  DiagnosisData data;
  data.has_thermal = still.has_thermal;
  data.thermal_source = still.thermal_source;
  data.constant_temperature_c = still.constant_temperature_c;
  EXPECT_EQ(data.thermalText(), "stamp_s (temperature_c constant at 22.41 C)");
  const DriverTable still_no_stamps = driversFromSequence(q, {22.4, 22.4, 22.4, 22.4}, {});
  EXPECT_FALSE(still_no_stamps.has_thermal);
  EXPECT_TRUE(still_no_stamps.constant_temperature_c.has_value());
  const DriverTable barely = driversFromSequence(q, {22.4, 22.4, 22.46, 22.4}, {});  // 0.06 C: it changes
  EXPECT_EQ(barely.thermal_source, "temperature_c");
  EXPECT_FALSE(barely.constant_temperature_c.has_value());
}

// The extended fit's covariance describes the scatter of its estimates: the same robot with a hidden joint scale
// error (random joint and size) measured again and again with fresh noise; the estimates' errors in units of their
// reported sigma have unit RMS. Backlash too (its basis is iterated to the fitted width).
TEST(ExtendedFit, CovarianceMatchesTheScatterOfEstimates) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const RobotModel nominal = test::robot("staubli_tx60");
  for (Cause cause : {Cause::kJointScale, Cause::kBacklash}) {
    SimulationConfig sc;
    sc.seed = rng();
    sc.zero_drift_per_K_max_rad = sc.zero_wear_per_h_max_rad = 0;
    sc.warmup_K = 0;
    sc.hidden.cause = cause;
    sc.hidden.joint = std::uniform_int_distribution<int>(0, 5)(rng);
    sc.hidden.scale = (u(rng) < 0.5 ? -1 : 1) * (2e-4 + 1e-3 * u(rng));
    sc.hidden.backlash_width_rad = 2e-4 + 1e-3 * u(rng);
    const double truth = cause == Cause::kJointScale ? sc.hidden.scale : -sc.hidden.backlash_width_rad;
    const SimulatedCell cell(nominal, sc);
    const Extension ext{cause, sc.hidden.joint};
    double z2 = 0;
    const int trials = 60;
    for (int t = 0; t < trials; ++t) {
      const auto qs = cell.randomConfigurations(120, rng);
      std::vector<Observation> obs;
      HiddenJointState state;
      for (size_t i = 0; i < qs.size(); ++i) {
        if (i) state = cell.advanceHiddenState(state, qs[i - 1], qs[i]);
        obs.push_back(cell.measure(qs[i], &state, 0.0, rng));
      }
      // The first row's play state is unknown to anyone (no move before it; the simulator starts it at one side of
      // the gap): a backlash fit leaves it out by itself.
      const DriverTable d = driversFromSequence(qs, {}, {});
      const ExtendedFit f = fitExtended(cell.model(), cell.nominalParams(), obs, d.rows, ext);
      ASSERT_TRUE(f.converged) << f.message;
      EXPECT_EQ(f.rows_left_out, cause == Cause::kBacklash ? 1 : 0);
      ASSERT_EQ(f.estimated_extension.size(), 1u);
      ASSERT_EQ(f.covariance.rows(), static_cast<Eigen::Index>(f.estimated.size() + 1));
      const double z = (f.extension_params[0] - truth) / f.extensionStddev(0);
      z2 += z * z;
    }
    const double z_rms = std::sqrt(z2 / trials);
    // The RMS of 60 unit normals: 1 +- 0.09; these bounds are 3.8 sigma off (a covariance 1.5x off fails).
    EXPECT_GT(z_rms, 0.65) << causeName(cause);
    EXPECT_LT(z_rms, 1.35) << causeName(cause) << " joint " << ext.joint + 1;
  }
}

// Plausible ranges for extension parameters (identifiability.hpp): with prior_sigma given, every extension parameter
// fitExtended estimates is pinned by the rows, fitted with everything it estimates, better than its range
// (extensionPriorSigma at kPlausibleExtensionJointErrorRad), and every one it holds is either within the rank tolerance
// of the kept span or would not be pinned (or would loosen a kept column beyond its range). Checked against a plain
// reference: the whitened Jacobian by central differences of the forward kinematics, its normal matrix inverted.
// Robots, placements, targets, causes, joints, pose counts (6-40, points) and noise scales (1-3000) drawn at random.
TEST(ExtendedFit, AnExtensionParameterIsEstimatedOnlyWhereTheRowsPinItBetterThanItsPlausibleRange) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int held = 0, kept = 0;
  for (int d = 0; d < 24; ++d) {
    const test::RandomDraw r = test::randomDraw(rng);
    const RobotModel model = test::robot(r.name);
    const SimulatedCell cell(model, r.sc);
    const RobotModel& m = cell.model();
    const Extension ext{u(rng) < 0.5 ? Cause::kCyclicTransmission : Cause::kJointScale,
                        static_cast<int>(u(rng) * m.numJoints()) % m.numJoints()};
    const auto qs = cell.randomConfigurations(6 + static_cast<int>(34 * u(rng)), rng);
    std::vector<Observation> obs;
    for (const auto& q : qs) obs.push_back(cell.measure(q, 0.0, rng, MeasurementKind::kPosition3D));
    const DriverTable dt = driversFromSequence(qs, {}, {});
    const Eigen::VectorXd start = cell.nominalParams();
    IdentifiabilityOptions io;
    io.prior_sigma = plausibleDeviation(m);
    io.noise_scale = std::exp(std::log(3000.0) * u(rng));
    const ExtendedFit f = fitExtended(m, start, obs, dt.rows, {ext}, SolverOptions{}, io);
    // The plain reference at the start (extension parameters 0), as the fit decided.
    const int np = m.numParams(), k = numExtensionParams(m, {ext});
    KinematicsData data(m);
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(3 * static_cast<Eigen::Index>(obs.size()), np + k);
    const double h = 1e-7;
    for (int c = 0; c < np + k; ++c) {
      for (int sgn : {1, -1}) {
        Eigen::VectorXd p = start, e = Eigen::VectorXd::Zero(k);
        (c < np ? p[c] : e[c - np]) += sgn * h;
        for (size_t i = 0; i < obs.size(); ++i) {
          const Eigen::VectorXd pe = extendedParams(m, p, {ext}, e, obs[i].q_rad, dt.rows[i]);
          const Eigen::Vector3d pos = forwardKinematics(m, data, pe, obs[i].q_rad).translation() / obs[i].sigma_position_m;
          J.block(3 * static_cast<Eigen::Index>(i), c, 3, 1) += sgn * pos / (2 * h);
        }
      }
    }
    const Eigen::VectorXd range_ext = extensionPriorSigma(m, start, {ext}, kPlausibleExtensionJointErrorRad);
    auto range = [&](int c) { return c < np ? (c < io.prior_sigma.size() ? io.prior_sigma[c] : 0.0) : range_ext[c - np]; };
    std::vector<int> cols = f.estimated;
    for (int e : f.estimated_extension) cols.push_back(np + e);
    // Whether a least-squares fit of `set` pins each column with a range better than it.
    auto pinned = [&](const std::vector<int>& set, double factor) {
      Eigen::MatrixXd A(J.rows(), static_cast<Eigen::Index>(set.size()));
      for (size_t i = 0; i < set.size(); ++i) A.col(static_cast<Eigen::Index>(i)) = J.col(set[i]);
      const Eigen::MatrixXd inv = (A.transpose() * A).inverse();
      for (size_t i = 0; i < set.size(); ++i) {
        const double sigma = io.noise_scale * std::sqrt(inv(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(i)));
        if (range(set[i]) > 0 && !(sigma < factor * range(set[i]))) return false;
      }
      return true;
    };
    auto worst = [&](const std::vector<int>& set) {
      Eigen::MatrixXd A(J.rows(), static_cast<Eigen::Index>(set.size()));
      for (size_t i = 0; i < set.size(); ++i) A.col(static_cast<Eigen::Index>(i)) = J.col(set[i]);
      const Eigen::MatrixXd inv = (A.transpose() * A).inverse();
      double w = 0;
      std::string at;
      for (size_t i = 0; i < set.size(); ++i) {
        const double sigma = io.noise_scale * std::sqrt(inv(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(i)));
        if (range(set[i]) > 0 && sigma / range(set[i]) > w) w = sigma / range(set[i]), at = std::to_string(set[i]);
      }
      return std::to_string(w) + " at " + at;
    };
    const std::string what = m.name + " " + extensionLabel(ext) + ", " + std::to_string(obs.size()) +
                             " points, noise x" + std::to_string(io.noise_scale);
    EXPECT_TRUE(pinned(cols, 1.001)) << what;  // the reference's rounding differs: 0.1 % either way
    kept += static_cast<int>(f.estimated_extension.size());
    for (int e = 0; e < k; ++e) {
      if (range_ext[e] == 0 || std::count(f.estimated_extension.begin(), f.estimated_extension.end(), e)) continue;
      ++held;
      // Its sine to the kept span (columns scaled to unit norm), and whether adding it would still pin everything.
      Eigen::MatrixXd A(J.rows(), static_cast<Eigen::Index>(cols.size()));
      for (size_t i = 0; i < cols.size(); ++i) A.col(static_cast<Eigen::Index>(i)) = J.col(cols[i]).normalized();
      const Eigen::VectorXd x = J.col(np + e).normalized();
      const double sine = cols.empty() ? 1.0 : (x - A * A.colPivHouseholderQr().solve(x)).norm();
      std::vector<int> with = cols;
      with.push_back(np + e);
      EXPECT_TRUE(sine <= 1.01 * io.rank_tolerance || !pinned(with, 0.999))
          << what << ": " << f.extension_names[static_cast<size_t>(e)] << " held, sine " << sine << " worst " << worst(with);
    }
  }
  std::printf("  %d extension parameters estimated, %d held\n", kept, held);
  EXPECT_GT(kept, 0);
  EXPECT_GT(held, 0);
}

TEST(DiagnosisOptions, IsValidNamesTheField) {
  DiagnosisOptions o;
  std::string err;
  EXPECT_TRUE(o.IsValid(&err)) << err;
  o.causes = {Cause::kNone};
  EXPECT_FALSE(o.IsValid(&err));
  EXPECT_NE(err.find("causes"), std::string::npos);
  o = DiagnosisOptions{};
  o.min_gain = 1.5;
  EXPECT_FALSE(o.IsValid(&err));
  EXPECT_NE(err.find("min_gain"), std::string::npos);
  EXPECT_THROW(diagnose(test::robot("ur10"), test::robot("ur10").nominal, DiagnosisData{}, DiagnosisOptions{}),
               std::invalid_argument);
}

// ---------------------------------------------------------------------------------------------------------------
// Hidden effects (hidden_effect.hpp): robot, tracker placement, target offset, points or 6D, causes, joints, sizes,
// thermometer or not, repeated poses and seed drawn at random per file; diagnose sees only the data. Each suite draws
// CELLCAL_DIAGNOSIS_DRAWS files (default: its own smaller number for `make test`); docs/diagnosis.md has the same
// suites over 100+ files each, with the commands. Every suite prints a summary line ("summary: ...").
int drawsOr(int fallback) {
  const char* env = std::getenv("CELLCAL_DIAGNOSIS_DRAWS");
  return env ? std::atoi(env) : fallback;
}

std::mt19937_64 suiteRng() {
  return std::mt19937_64(test::testSeed() ^ std::hash<std::string>{}(::testing::UnitTest::GetInstance()->current_test_info()->name()));
}

bool named(const DiagnosisResult& d, const test::TrueEffect& t) {
  for (const auto& e : d.causes())
    if (e.cause == t.cause && (e.joint == t.joint || (t.cause == Cause::kThermalDrift && e.joint < 0 &&
                                                      t.joint_effect_rms_mm <= 0.0)))
      return true;
  return false;
}

std::string namedText(const DiagnosisResult& d) { return describeVerdict(d); }

// A thermal drift whose joint-zero part is itself below the noise may be named with no joint (lengths only).
bool rightJoint(const Extension& e, const test::TrueEffect& t, double noise_rms_mm) {
  return e.joint == t.joint || (t.cause == Cause::kThermalDrift && e.joint < 0 && t.joint_effect_rms_mm <= noise_rms_mm);
}

// Single causes: the right cause and joint (link) first in >= 95 % of the files whose effect is above the tracker
// noise (docs; here >= 85 % of a smaller sample, so a true rate of 95 % fails 1 run in 200), and then the final model
// within 1.2x the noise floor on the verification rows.
TEST(HiddenEffects, SingleCausesAreNamedWithTheirJoint) {
  const int draws = drawsOr(48);
  std::mt19937_64 rng = suiteRng();
  int large = 0, right = 0, exact = 0, alike = 0, small = 0, small_named_other = 0;
  int large_by_kind[2] = {0, 0}, right_by_kind[2] = {0, 0};  // points, 6D
  double worst_ratio = 0;
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = test::DrawCategory::kSingle;
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    const DiagnosisResult d = diagnose(h.model, h.start, h.data);
    const test::TrueEffect& t = h.draw.effects.front();
    const std::vector<Extension> got = d.causes();
    const int kind = h.draw.kind == MeasurementKind::kPose6D;
    if (t.effect_rms_mm > h.noise_rms_mm) {
      ++large;
      ++large_by_kind[kind];
      const bool ok = !got.empty() && got.front().cause == t.cause && rightJoint(got.front(), t, h.noise_rms_mm);
      if (ok) {
        ++right;
        ++right_by_kind[kind];
        exact += got.size() == 1;
        // On the rows the model can predict: before a backlash joint first moves, its play state is unknown to
        // anyone (the fit leaves those rows out; the verification figures report them).
        const ExtendedFit& best = d.best().fit;
        const std::vector<Eigen::Vector3d> res =
            positionResiduals(h.model, best, h.data.verification, h.data.verification_drivers);
        double sq = 0;
        int rows = 0;
        for (size_t i = 0; i < res.size(); ++i) {
          bool known = true;
          for (const auto& e : best.extensions)
            if (e.cause == Cause::kBacklash) {
              const Eigen::VectorXd& dir = h.data.verification_drivers[i].motion_direction;
              known = known && dir.size() > e.joint && dir[e.joint] != 0.0;
            }
          if (!known) continue;
          sq += res[i].squaredNorm();
          ++rows;
        }
        const double ratio = std::sqrt(sq / std::max(1, rows)) * 1e3 / h.noise_rms_mm;
        worst_ratio = std::max(worst_ratio, ratio);
        EXPECT_LE(ratio, 1.2) << "final verification RMS " << d.best().verification.rms_mm << " mm vs noise "
                              << h.noise_rms_mm << " mm | " << h.draw.describe() << " -> " << namedText(d);
      } else {
        bool is_alike = false;
        if (!d.selection.empty())
          for (const auto& e : d.selection.front().alike) is_alike = is_alike || (e.cause == t.cause && e.joint == t.joint);
        alike += is_alike;
        std::printf("  missed%s: %s -> %s\n", is_alike ? " (named as alike)" : "", h.draw.describe().c_str(),
                    namedText(d).c_str());
      }
    } else {
      ++small;
      if (!got.empty() && got.front().cause != t.cause) ++small_named_other;
    }
  }
  std::printf("  summary: %d files; %d/%d effects above the noise named right first (%d with no other cause, %d more "
              "named as alike), %d/%d below the noise named as another cause; worst final/noise RMS %.3f\n",
              draws, right, large, exact, alike, small_named_other, small, worst_ratio);
  std::printf("  summary by kind: points %d/%d, 6D %d/%d named right first\n", right_by_kind[0], large_by_kind[0],
              right_by_kind[1], large_by_kind[1]);
  ASSERT_GE(large, draws / 3) << "too few effects above the noise to judge";
  EXPECT_GE(right, 0.85 * large);
}

// Noise only (random geometric errors and frames, no effect): `none` in >= 97 % of the files (docs), here at most
// 2 of the sample named.
TEST(HiddenEffects, NoiseOnlyNamesNoCause) {
  const int draws = drawsOr(40);
  std::mt19937_64 rng = suiteRng();
  int named_any = 0, structure = 0;
  int files_by_kind[2] = {0, 0}, named_by_kind[2] = {0, 0};  // points, 6D
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = test::DrawCategory::kNoiseOnly;
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    const DiagnosisResult d = diagnose(h.model, h.start, h.data);
    const int kind = h.draw.kind == MeasurementKind::kPose6D;
    ++files_by_kind[kind];
    if (!d.selection.empty()) {
      ++named_by_kind[kind];
      ++named_any;
      std::printf("  false cause: %s | %s\n", namedText(d).c_str(), h.draw.describe().c_str());
    }
    if (const DriverStructure* left = d.structureLeft()) {
      ++structure;
      std::printf("  structure reported on noise: %s %.1f %% (p %.2g) | %s\n", left->driver.c_str(), 100 * left->share,
                  left->p_value, h.draw.describe().c_str());
    }
  }
  std::printf("  summary: %d noise-only files; %d named a cause (%.1f %% none), %d reported structure left\n", draws,
              named_any, 100.0 * (draws - named_any) / draws, structure);
  std::printf("  summary by kind: points %d/%d none, 6D %d/%d none\n", files_by_kind[0] - named_by_kind[0],
              files_by_kind[0], files_by_kind[1] - named_by_kind[1], files_by_kind[1]);
  EXPECT_LE(named_any, 2);
}

// Two causes at once: both named (forward selection) in >= 80 % of the files where each is above the noise (docs);
// here >= 60 %.
TEST(HiddenEffects, PairsOfCausesAreBothNamed) {
  const int draws = drawsOr(24);
  std::mt19937_64 rng = suiteRng();
  int graded = 0, both = 0, one = 0;
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = test::DrawCategory::kPair;
    o.min_amp_deg = 0.005;  // most pairs above the noise
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    const auto& e = h.draw.effects;
    if (e[0].effect_rms_mm <= h.noise_rms_mm || e[1].effect_rms_mm <= h.noise_rms_mm) continue;
    const DiagnosisResult d = diagnose(h.model, h.start, h.data);
    ++graded;
    const bool a = named(d, e[0]), b = named(d, e[1]);
    both += a && b;
    one += a != b;
    if (!(a && b)) std::printf("  not both: %s -> %s\n", h.draw.describe().c_str(), namedText(d).c_str());
  }
  std::printf("  summary: %d files, %d with both effects above the noise: both named in %d, one in %d\n", draws, graded,
              both, one);
  ASSERT_GE(graded, draws / 4) << "too few pairs above the noise to judge";
  EXPECT_GE(both, 0.6 * graded);
}

// Effects outside the library (a tracker's scale drifting over hours, a sag with the square of the reach): never a
// cell-file recommendation without the "structure left" warning when the effect is above the noise.
TEST(HiddenEffects, OutsideTheLibraryIsNeverPassedOffAsAnExplanation) {
  const int draws = drawsOr(24);
  std::mt19937_64 rng = suiteRng();
  int large = 0, warned = 0, unexplained = 0, silent = 0;
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = test::DrawCategory::kOutOfLibrary;
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    if (h.draw.outside_rms_mm <= h.noise_rms_mm) continue;
    ++large;
    const DiagnosisResult d = diagnose(h.model, h.start, h.data);
    bool recommends = false;  // a cell-file line: a cause other than thermal drift
    for (const auto& e : d.causes()) recommends = recommends || e.cause != Cause::kThermalDrift;
    if (d.verdict == Verdict::kPartlyExplained) ++warned;
    if (d.verdict == Verdict::kUnexplained) ++unexplained;
    if (recommends && !d.structureLeft()) {
      ++silent;
      ADD_FAILURE() << "recommended without a warning: " << namedText(d) << " | " << h.draw.describe();
    }
  }
  std::printf("  summary: %d files, %d with the effect above the noise: %d partly explained with a warning, %d "
              "unexplained, %d recommended without a warning\n",
              draws, large, warned, unexplained, silent);
  ASSERT_GE(large, draws / 4);
}

// Thermal drift in a file with stamps but no temperature: the warm-up is fitted (a first-order curve in time, its time
// constant found by the fit), so the final model reaches the noise floor where a straight line in time would not.
TEST(HiddenEffects, ThermalDriftWithoutAThermometerFitsTheWarmUp) {
  const int draws = drawsOr(10);
  std::mt19937_64 rng = suiteRng();
  int graded = 0, right = 0, drawn = 0;
  double worst = 0, worst_line = 0;
  // Files are drawn until `draws` of them are judged or four times as many were drawn (a drift below twice the
  // noise is not judged: about half of them; 10 drawn once gave 2 judged and failed a count of the draws).
  for (int k = 0; graded < draws / 2 && k < 4 * draws; ++k) {
    ++drawn;
    test::DrawOptions o;
    o.force_cause = Cause::kThermalDrift;
    o.no_thermometer_probability = 1.0;
    o.min_amp_deg = 0.01;
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    const test::TrueEffect& t = h.draw.effects.front();
    if (t.effect_rms_mm <= 2 * h.noise_rms_mm) continue;
    ++graded;
    const DiagnosisResult d = diagnose(h.model, h.start, h.data);
    const std::vector<Extension> got = d.causes();
    if (got.empty() || got.front().cause != Cause::kThermalDrift) {
      std::printf("  missed: %s -> %s\n", h.draw.describe().c_str(), namedText(d).c_str());
      continue;
    }
    ++right;
    const double ratio = d.best().verification.rms_mm / h.noise_rms_mm;
    worst = std::max(worst, ratio);
    // The same cause as a straight line in time, for comparison.
    Extension line = got.front();
    line.time_constant_h = INFINITY;
    const ExtendedFit lf = fitExtended(h.model, h.start, h.data.identification, h.data.identification_drivers, line);
    const double line_ratio = errorStats(h.model, lf, h.data.verification, h.data.verification_drivers).rms_mm / h.noise_rms_mm;
    worst_line = std::max(worst_line, line_ratio);
    std::printf("  warm-up %.2f h fitted as %.2f h; final/noise RMS %.3f (straight line in time: %.3f)\n",
                h.draw.warmup_tau_h, got.front().time_constant_h, ratio, line_ratio);
    EXPECT_LE(ratio, 1.2) << h.draw.describe() << " -> " << namedText(d);
  }
  std::printf("  summary: %d files, %d with the drift above twice the noise, %d named thermal drift; worst final/noise "
              "RMS %.3f (straight line in time: %.3f)\n", drawn, graded, right, worst, worst_line);
  ASSERT_GE(graded, draws / 2);
  EXPECT_EQ(right, graded);
}

// The reading noise measured from poses measured twice (10 % of the poses again, later in the run): within 25 % of
// the simulated tracker's and the robot's repeatability (per axis), and said to come from them.
TEST(HiddenEffects, NoiseIsMeasuredFromRepeatedPoses) {
  const int draws = drawsOr(8);
  std::mt19937_64 rng = suiteRng();
  double worst = 1;
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = k % 2 ? test::DrawCategory::kSingle : test::DrawCategory::kNoiseOnly;
    o.repeat_probability = 1.0;
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    const DiagnosisResult d = diagnose(h.model, h.start, h.data);
    ASSERT_TRUE(d.noise.from_repeats) << d.noise.source;
    const double ratio = d.noise.sigma_position_mm / h.sigma_position_mm;
    worst = std::abs(ratio - 1) > std::abs(worst - 1) ? ratio : worst;
    EXPECT_NEAR(ratio, 1.0, 0.25) << d.noise.source << ": " << d.noise.sigma_position_mm << " mm, truth "
                                  << h.sigma_position_mm << " mm | " << h.draw.describe();
    EXPECT_NE(d.noise.source.find("repeated poses"), std::string::npos);
  }
  std::printf("  summary: %d files with repeated poses; worst measured/true noise %.3f\n", draws, worst);
}

// Gross errors (1-5 mm on 0-5 % of the rows): every one flagged (each is above 10 sigma), under 1 % of the clean rows
// flagged, and the held-out error (rows kept) within 1.1x of the same file without them, for the geometric model and
// for the chosen one when both files chose the same (seed 9375305578691527166: a joint_scale of 0.0019 deg named on
// the clean file only, 1.12x).
TEST(HiddenEffects, GrossErrorsAreFlaggedAndDoNotMoveTheFit) {
  const int draws = drawsOr(16);
  std::mt19937_64 rng = suiteRng();
  int outliers = 0, missed = 0, clean_rows = 0, clean_flagged = 0, selection_differs = 0;
  double worst = 0;
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = k % 2 ? test::DrawCategory::kSingle : test::DrawCategory::kNoiseOnly;
    o.max_outlier_fraction = 0.05;
    const std::uint64_t seed = rng();
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, seed);
    o.max_outlier_fraction = 0;
    const test::HiddenEffectData c = test::makeHiddenEffectData(o, seed);  // the same file without them
    const DiagnosisResult d = diagnose(h.model, h.start, h.data), dc = diagnose(c.model, c.start, c.data);
    auto grade = [&](const std::vector<int>& truth, const OutlierScreen& flagged, size_t rows) {
      outliers += static_cast<int>(truth.size());
      for (int i : truth)
        if (!flagged.flagged(i)) {
          ++missed;
          std::printf("  missed gross error: row %d at %.1f robust sigmas (%s) | %s\n", i, flagged.z[static_cast<size_t>(i)],
                      namedText(d).c_str(), h.draw.describe().c_str());
        }
      for (size_t i = 0; i < rows; ++i)
        if (!std::binary_search(truth.begin(), truth.end(), static_cast<int>(i))) {
          ++clean_rows;
          clean_flagged += flagged.flagged(static_cast<int>(i));
        }
    };
    grade(h.outlier_identification, d.identification_outliers, h.data.identification.size());
    grade(h.outlier_verification, d.verification_outliers, h.data.verification.size());
    // The fit: the geometric model always, and the chosen model when both files chose the same. A cause near the
    // detection threshold may be named on the clean file and not on the one whose gross errors were left out (5 %
    // fewer rows): that is the selection's power, not a fit moved by the gross errors; counted and said.
    const double geometric = d.geometric.verification.mean_mm / dc.geometric.verification.mean_mm;
    EXPECT_LE(geometric, 1.1) << h.draw.describe() << ": geometric " << d.geometric.verification.mean_mm
                              << " mm with the gross errors, " << dc.geometric.verification.mean_mm << " mm without";
    worst = std::max(worst, geometric);
    if (modelLabel(d.causes()) == modelLabel(dc.causes())) {
      const double ratio = d.best().verification.mean_mm / dc.best().verification.mean_mm;
      worst = std::max(worst, ratio);
      EXPECT_LE(ratio, 1.1) << h.draw.describe() << ": " << d.best().verification.mean_mm << " mm with the gross errors, "
                            << dc.best().verification.mean_mm << " mm without (" << namedText(dc) << ")";
    } else {
      ++selection_differs;
      std::printf("  another model chosen with the gross errors left out: %s, against %s without them | %s\n",
                  namedText(d).c_str(), namedText(dc).c_str(), h.draw.describe().c_str());
    }
  }
  std::printf("  summary: %d files, %d gross errors, %d missed; %d of %d clean rows flagged (%.2f %%); worst held-out "
              "mean with / without them %.3f (the same model); another model chosen in %d\n",
              draws, outliers, missed, clean_flagged, clean_rows, 100.0 * clean_flagged / std::max(1, clean_rows), worst,
              selection_differs);
  EXPECT_LE(selection_differs, draws / 4);
  EXPECT_EQ(missed, 0);
  EXPECT_LT(clean_flagged, 0.01 * clean_rows);
}

}  // namespace
}  // namespace cellcal
