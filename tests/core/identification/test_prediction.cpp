// The predicted error of a fitted model (prediction.hpp) against the truth, and excitation deficits against a plain
// finite-difference reference, on robots, tracker placements, target offsets, measurement types and pose counts drawn
// at random (few poses on purpose: the model's own error must be comparable to the readings' noise to be judged).
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/cause.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

// A robot, measurement type, tracker placement and target offset drawn at random; the cell with hidden errors.
struct Draw {
  std::string name;
  MeasurementKind kind;
  RobotModel model;
  SimulationConfig config;
};
Draw draw(std::mt19937_64& rng) {
  const test::RandomDraw r = test::randomDraw(rng);
  return {r.name, r.kind, test::robot(r.name), r.sc};
}

// Predicted sigma of the model's position error against the true error (simulator truth, no reading noise) on
// held-out configurations: the RMS of their ratio is 1 when the covariance can be trusted.
TEST(Prediction, SigmaOfTheModelErrorMatchesTheTrueErrorOnRandomRobots) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const int draws = 40;
  double sum_sq_ratio = 0;
  int n = 0;
  std::vector<double> per_draw;
  for (int d = 0; d < draws; ++d) {
    const Draw dr = draw(rng);
    const std::string& name = dr.name;
    const MeasurementKind kind = dr.kind;
    const RobotModel& file_model = dr.model;
    const SimulatedCell cell(file_model, dr.config);
    const int poses = 12 + static_cast<int>(40 * u(rng));
    std::vector<Observation> ident;
    for (const auto& q : cell.randomConfigurations(poses, rng)) ident.push_back(cell.measure(q, 0.0, rng, kind));
    const RegistrationResult reg = registerFrames(file_model, file_model.nominal, ident);
    const CalibrationProblem p{&file_model, reg.params, ident, std::nullopt, {}, {}};
    const ExtendedFit fit = geometricFit(solveGaussNewton(p));
    const std::vector<Drivers> drivers(ident.size());
    const PredictionModel pm = predictionModel(file_model, fit, ident, drivers);
    KinematicsData data(file_model);
    double draw_sq = 0;
    const auto held_out = cell.randomConfigurations(50, rng);
    for (const auto& q : held_out) {
      const double truth_m = (forwardKinematics(file_model, data, fit.params, q).translation() -
                              cell.truePose(q, 0.0).translation()).norm();
      const double sigma_m = predictedPositionSigma(file_model, fit, pm, q, Drivers{});
      ASSERT_GT(sigma_m, 0);
      const double ratio = truth_m / sigma_m;
      draw_sq += ratio * ratio;
      sum_sq_ratio += ratio * ratio;
      ++n;
    }
    per_draw.push_back(std::sqrt(draw_sq / static_cast<double>(held_out.size())));
    std::printf("draw %2d: %s %s, %2d poses, s^2 %.2f: RMS(true / predicted) %.2f\n", d, name.c_str(),
                kind == MeasurementKind::kPose6D ? "6D" : "points", poses, pm.variance_factor, per_draw.back());
  }
  const double rms = std::sqrt(sum_sq_ratio / n);
  std::sort(per_draw.begin(), per_draw.end());
  std::printf("RMS(true / predicted) over %d draws x 50 held-out poses: %.3f (per draw: min %.2f, median %.2f, max %.2f)\n",
              draws, rms, per_draw.front(), per_draw[per_draw.size() / 2], per_draw.back());
  EXPECT_GT(rms, 0.7);
  EXPECT_LT(rms, 1.4);
}

// estimatePositionSigmas against a plain reference: refits of the same configurations with fresh reading noise, and
// their scatter at configurations beyond the part of a joint's range the fit saw (how the region check uses it). The
// truth is what the model holds: geometric errors and a cyclic error or scale of a joint drawn at random
// (0.05-0.2 deg RMS), fitted as such on 60-150 poses up to that joint's upper or lower quartile, the others beyond.
// The readings' stated sigmas are 0.5-2x their true noise, so the variance factor must be applied to be right.
TEST(Prediction, AnEstimatesSigmaIsWhatRefitsWithFreshNoiseScatterBy) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const int draws = 4, refits = 60;
  double sum_predicted = 0, sum_scatter = 0;
  for (int d = 0; d < draws; ++d) {
    const Draw dr = draw(rng);
    const RobotModel& model = dr.model;
    SimulationConfig sc = dr.config;
    sc.warmup_K = 0;
    sc.zero_drift_per_K_max_rad = 0;
    sc.zero_wear_per_h_max_rad = 0;
    const int j = static_cast<int>(u(rng) * model.numJoints());
    const Extension ext{u(rng) < 0.5 ? Cause::kCyclicTransmission : Cause::kJointScale, j};
    const SimulatedCell plain(model, sc);
    const std::vector<Eigen::VectorXd> qs = plain.randomConfigurations(80 + static_cast<int>(120 * u(rng)), rng);
    sc.hidden = scaledHiddenEffect(model, plain.trueParams(0), ext.cause, j, (0.05 + 0.15 * u(rng)) * kPi / 180, {},
                                   qs, rng);
    const SimulatedCell cell(model, sc);
    std::vector<double> angle;
    for (const auto& q : qs) angle.push_back(q[j]);
    std::sort(angle.begin(), angle.end());
    const bool upper = u(rng) < 0.5;  // the rows beyond: above the upper quartile, or below the lower one
    const double cut = angle[upper ? angle.size() * 3 / 4 : angle.size() / 4];
    std::vector<Eigen::VectorXd> fitted_q, beyond_q;
    for (const auto& q : qs) ((upper ? q[j] > cut : q[j] < cut) ? beyond_q : fitted_q).push_back(q);
    const double stated = 0.5 + 1.5 * u(rng);
    auto measure = [&](const std::vector<Eigen::VectorXd>& at) {
      std::vector<Observation> rows;
      for (const auto& q : at) {
        rows.push_back(cell.measure(q, 0.0, rng, dr.kind));
        rows.back().sigma_position_m *= stated;
        rows.back().sigma_orientation_rad *= stated;
      }
      return rows;
    };
    const std::vector<Observation> fitted = measure(fitted_q), beyond = measure(beyond_q);
    const std::vector<Drivers> fitted_drivers(fitted.size()), beyond_drivers(beyond.size());
    const Eigen::VectorXd start = registerFrames(model, model.nominal, fitted).params;
    const ExtendedFit fit = fitExtended(model, start, fitted, fitted_drivers, std::vector<Extension>{ext});
    ASSERT_TRUE(fit.hasCovariance());
    double predicted = 0;
    for (double s : estimatePositionSigmas(model, fit, fitted, fitted_drivers, beyond, beyond_drivers))
      predicted += s * s / static_cast<double>(beyond.size());
    // The reference: the refits' predictions at each row beyond (the same readings there, so their residuals differ
    // by what the predictions do), their variance about their mean, averaged over the rows.
    std::vector<std::vector<Eigen::Vector3d>> r(refits);
    for (auto& rk : r) {
      const std::vector<Observation> again = measure(fitted_q);
      const ExtendedFit f = fitExtended(model, start, again, fitted_drivers, std::vector<Extension>{ext}, {}, {},
                                        &fit.params, &fit.extension_params);
      ASSERT_EQ(f.estimated, fit.estimated);
      rk = positionResiduals(model, f, beyond, beyond_drivers);
    }
    double scatter = 0;
    for (size_t i = 0; i < beyond.size(); ++i) {
      Eigen::Vector3d m = Eigen::Vector3d::Zero();
      for (const auto& rk : r) m += rk[i] / refits;
      for (const auto& rk : r) scatter += (rk[i] - m).squaredNorm() / (refits - 1) / static_cast<double>(beyond.size());
    }
    sum_predicted += predicted;
    sum_scatter += scatter;
    std::printf("draw %d: %s %s, %s joint %d, %zu poses fitted, %zu beyond, stated sigma x%.2f: predicted %.4f mm, "
                "refits' scatter %.4f mm (RMS over the rows beyond)\n",
                d, dr.name.c_str(), dr.kind == MeasurementKind::kPose6D ? "6D" : "points",
                causeModel(ext.cause).name(), j + 1, fitted.size(), beyond.size(), stated,
                1e3 * std::sqrt(predicted), 1e3 * std::sqrt(scatter));
    EXPECT_GT(std::sqrt(scatter / predicted), 0.6);
    EXPECT_LT(std::sqrt(scatter / predicted), 1.6);
  }
  const double ratio = std::sqrt(sum_scatter / sum_predicted);
  std::printf("refits' scatter / predicted over %d draws x %d refits: %.3f\n", draws, refits, ratio);
  EXPECT_GT(ratio, 0.8);
  EXPECT_LT(ratio, 1.25);
}

// A model carried to a new set-up (carriedPrediction): a campaign calibrated on few poses, then the tracker and target
// placed elsewhere (robot, measurement type, both placements and pose counts drawn at random) and the frames
// registered again on the new rows with the campaign's kinematics held. Two checks:
//  - against a plain reference: draw model errors from the carried covariance, make noise-free readings of the new
//    rows with them, register the frames by Gauss-Newton (refineFrames, nonlinear) and take the error that is left at
//    held-out configurations; its RMS against the linear prediction without reading noise;
//  - against the truth: the actual error of the carried model on held-out configurations of the new set-up against
//    its predicted sigma; the RMS of their ratio between 0.7 and 1.4, as for a model on its own set-up.
// A campaign calibrated on few poses, then the tracker and target placed elsewhere and the frames registered again on
// the new rows with the campaign's kinematics held (calibrate --frames-only: closed form, then refined). The new rows'
// orientation sigmas are stated `orientation_sigma_scale` times their true noise (1: as the tracker measures).
struct Carried {
  Draw dr;
  SimulatedCell moved;
  std::vector<Observation> rows;
  std::vector<Drivers> drivers;
  std::size_t campaign_poses = 0;
  PredictionModel pm;          // the campaign's
  ExtendedFit carried;         // its kinematics, the new frames
  std::vector<int> frames;     // the frame columns the new rows determine
  double frames_factor = 0;    // r^T r / (rows - frames) over every row
  std::vector<Eigen::VectorXd> held_out;  // configurations of the new set-up
};
Carried carry(std::mt19937_64& rng, Draw dr, double orientation_sigma_scale) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const RobotModel& model = dr.model;
  const SimulatedCell campaign(model, dr.config);
  SimulationConfig moved_config = dr.config;  // the same robot (its errors drawn from the same seed), moved
  test::randomTrackerAndTarget(rng, moved_config.base_in_tracker, moved_config.tool_in_flange);
  Carried c{dr, SimulatedCell(model, moved_config), {}, {}, 0, {}, {}, {}, 0, {}};
  std::vector<Observation> ident;
  for (const auto& q : campaign.randomConfigurations(12 + static_cast<int>(40 * u(rng)), rng))
    ident.push_back(campaign.measure(q, 0.0, rng, dr.kind));
  for (const auto& q : c.moved.randomConfigurations(10 + static_cast<int>(40 * u(rng)), rng)) {
    c.rows.push_back(c.moved.measure(q, 0.0, rng, dr.kind));
    c.rows.back().sigma_orientation_rad *= orientation_sigma_scale;
  }
  c.campaign_poses = ident.size();
  const RegistrationResult reg = registerFrames(model, model.nominal, ident);
  const ExtendedFit fit = geometricFit(solveGaussNewton(CalibrationProblem{&model, reg.params, ident, std::nullopt, {}, {}}));
  c.pm = predictionModel(model, fit, ident, std::vector<Drivers>(ident.size()));
  c.drivers.resize(c.rows.size());
  c.carried.params = refineFrames(model, registerFrames(model, fit.params, c.rows).params, {}, {}, c.rows, c.drivers).params;
  std::vector<int> frame_columns;
  for (int k = 0; k < 6; ++k)
    frame_columns.insert(frame_columns.end(), {model.baseParam(static_cast<FrameParam>(k)),
                                               model.toolParam(static_cast<FrameParam>(k))});
  Eigen::MatrixXd frame_cov;
  c.frames = conditionalCovariance(model, c.carried, c.rows, c.drivers, frame_columns, &frame_cov, &c.frames_factor);
  c.held_out = c.moved.randomConfigurations(40, rng);
  return c;
}

TEST(Prediction, ACarriedModelOnANewSetUpPredictsWhatItsNewFramesLeave) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  const int draws = 24;
  double sum_sq_ratio = 0;
  int n = 0;
  for (int d = 0; d < draws; ++d) {
    const Carried c = carry(rng, draw(rng), 1.0);
    const Draw& dr = c.dr;
    const RobotModel& model = dr.model;
    const SimulatedCell& moved = c.moved;
    const std::vector<Observation>& rows = c.rows;
    const std::vector<Drivers>& drivers = c.drivers;
    const ExtendedFit& carried = c.carried;
    const PredictionModel& pm = c.pm;
    const std::vector<int>& frames = c.frames;
    const std::vector<Eigen::VectorXd>& held_out = c.held_out;
    const VarianceFactors noise = residualVarianceFactors(model, carried, rows, drivers, static_cast<int>(frames.size()));
    if (dr.kind != MeasurementKind::kPose6D) {
      EXPECT_NEAR(noise.position, c.frames_factor, 1e-9 * c.frames_factor);
    }
    const PredictionModel cpm = carriedPrediction(model, carried, pm, rows, drivers, frames, noise);
    KinematicsData data(model);

    // The plain reference: sampled model errors, noise-free readings, nonlinear registration.
    const PredictionModel cpm0 = carriedPrediction(model, carried, pm, rows, drivers, frames, VarianceFactors{0.0, 0.0});
    std::vector<Eigen::Index> m_at;
    for (Eigen::Index k = 0; k < static_cast<Eigen::Index>(pm.columns.size()); ++k)
      if (!std::count(frames.begin(), frames.end(), pm.columns[static_cast<size_t>(k)])) m_at.push_back(k);
    Eigen::MatrixXd S(m_at.size(), m_at.size());
    for (size_t i = 0; i < m_at.size(); ++i)
      for (size_t j = 0; j < m_at.size(); ++j) S(i, j) = pm.covariance(m_at[i], m_at[j]);
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(S);  // S = V diag(l) V^T: dm = V sqrt(l) z
    const Eigen::MatrixXd L = es.eigenvectors() * es.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
    double mc_sq = 0, lin_sq = 0;
    const int samples = 60;
    for (int k = 0; k < samples; ++k) {
      Eigen::VectorXd z(S.rows());
      for (Eigen::Index i = 0; i < z.size(); ++i) z[i] = g(rng);
      const Eigen::VectorXd dm = L * z;
      Eigen::VectorXd truth = carried.params;
      for (size_t i = 0; i < m_at.size(); ++i) truth[pm.columns[static_cast<size_t>(m_at[i])]] += dm[static_cast<Eigen::Index>(i)];
      std::vector<Observation> exact = rows;
      for (auto& o : exact) {
        const Pose t = forwardKinematics(model, data, truth, o.q_rad);
        o.measured_in_tracker = t;
      }
      const Eigen::VectorXd registered = refineFrames(model, carried.params, {}, {}, exact, drivers).params;
      for (const auto& q : held_out) {
        const Eigen::Vector3d at = forwardKinematics(model, data, registered, q).translation();  // a copy: data is reused
        mc_sq += (at - forwardKinematics(model, data, truth, q).translation()).squaredNorm();
      }
    }
    for (const auto& q : held_out) lin_sq += std::pow(predictedPositionSigma(model, carried, cpm0, q, Drivers{}), 2);
    const double mc_mm = std::sqrt(mc_sq / (samples * static_cast<double>(held_out.size()))) * 1e3;
    const double lin_mm = std::sqrt(lin_sq / static_cast<double>(held_out.size())) * 1e3;
    // 60 samples: the sampled RMS is within about 10 % of its expectation.
    EXPECT_NEAR(mc_mm / lin_mm, 1.0, 0.25) << dr.name << " draw " << d << ": sampled " << mc_mm << " mm, linear " << lin_mm;

    // Against the truth.
    double draw_sq = 0;
    for (const auto& q : held_out) {
      const double truth_m = (forwardKinematics(model, data, carried.params, q).translation() -
                              moved.truePose(q, 0.0).translation()).norm();
      const double sigma_m = predictedPositionSigma(model, carried, cpm, q, Drivers{});
      ASSERT_GT(sigma_m, 0);
      draw_sq += truth_m * truth_m / (sigma_m * sigma_m);
      sum_sq_ratio += truth_m * truth_m / (sigma_m * sigma_m);
      ++n;
    }
    std::printf("draw %2d: %s %s, %2zu + %2zu poses: frames-only error RMS sampled %.4f / linear %.4f mm; "
                "RMS(true / predicted) %.2f\n",
                d, dr.name.c_str(), dr.kind == MeasurementKind::kPose6D ? "6D" : "points", c.campaign_poses, rows.size(),
                mc_mm, lin_mm, std::sqrt(draw_sq / static_cast<double>(held_out.size())));
  }
  const double rms = std::sqrt(sum_sq_ratio / n);
  std::printf("RMS(true / predicted) over %d carried models x 40 held-out poses: %.3f\n", draws, rms);
  EXPECT_GT(rms, 0.7);
  EXPECT_LT(rms, 1.4);
}

// A tracker that understates its orientation noise tenfold on the new set-up (6D draws only): the frames' fit leaves
// the orientation rows a hundred times their stated variance and the position rows about theirs. One factor over
// every row would scale the position rows' noise in the frames by that mixture; with the two kinds apart the carried
// prediction still holds against the truth (RMS of actual / predicted between 0.7 and 1.4), and the two factors say
// which kind is understated.
TEST(Prediction, ATrackerThatUnderstatesItsOrientationNoiseKeepsTheCarriedPredictionRight) {
  std::mt19937_64 rng(test::testSeed());
  double sq_apart = 0, sq_one = 0;
  int n = 0;
  for (int d = 0; d < 16; ++d) {
    Draw dr = draw(rng);
    dr.kind = MeasurementKind::kPose6D;
    const Carried c = carry(rng, dr, 0.1);
    const VarianceFactors apart =
        residualVarianceFactors(dr.model, c.carried, c.rows, c.drivers, static_cast<int>(c.frames.size()));
    // Orientation rows 100x their stated variance, position rows about theirs plus what the carried kinematics miss on
    // the new set-up; from a few dozen rows. Over 700 seeds x 16 draws: orientation 35-140, position up to 6.8, their
    // ratio 6.6 or more (20x, asserted before 2026-12-04, failed 8 seeds of 300: position 3.5-6.5).
    EXPECT_GT(apart.orientation, 3 * apart.position) << "draw " << d;
    EXPECT_GT(apart.orientation, 20) << "draw " << d;
    const PredictionModel cpm = carriedPrediction(dr.model, c.carried, c.pm, c.rows, c.drivers, c.frames, apart);
    const PredictionModel one = carriedPrediction(dr.model, c.carried, c.pm, c.rows, c.drivers, c.frames,
                                                  VarianceFactors{c.frames_factor, c.frames_factor});
    KinematicsData data(dr.model);
    for (const auto& q : c.held_out) {
      const double truth_m = (forwardKinematics(dr.model, data, c.carried.params, q).translation() -
                              c.moved.truePose(q, 0.0).translation()).norm();
      sq_apart += std::pow(truth_m / predictedPositionSigma(dr.model, c.carried, cpm, q, Drivers{}), 2);
      sq_one += std::pow(truth_m / predictedPositionSigma(dr.model, c.carried, one, q, Drivers{}), 2);
      ++n;
    }
    std::printf("draw %2d: %s, variance factors position %.2f, orientation %.1f, one for both %.1f\n", d,
                dr.name.c_str(), apart.position, apart.orientation, c.frames_factor);
  }
  const double rms_apart = std::sqrt(sq_apart / n), rms_one = std::sqrt(sq_one / n);
  std::printf("RMS(true / predicted) over 16 carried models x 40 held-out poses: %.3f with the kinds apart, %.3f with "
              "one factor\n", rms_apart, rms_one);
  EXPECT_GT(rms_apart, 0.7);
  EXPECT_LT(rms_apart, 1.4);
}

// Excitation of one column on one observation by a plain reference: the change of the whitened pose residual when
// the parameter moves by h, over h (central differences through the extended model's parameters).
double plainExcitation(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Extension>& exts,
                       int column, const Observation& obs, const Drivers& drivers) {
  const int np = model.numParams();
  const int k = numExtensionParams(model, exts);
  auto residual = [&](double h) {
    Eigen::VectorXd p = params, e = Eigen::VectorXd::Zero(k);
    (column < np ? p[column] : e[column - np]) += h;
    const Eigen::VectorXd pe = k ? extendedParams(model, p, exts, e, obs.q_rad, drivers) : p;
    KinematicsData data(model);
    Eigen::Matrix<double, 6, 1> r;
    const int rows = whitenedResidual(model, data, pe, obs, r, nullptr);
    return Eigen::VectorXd(r.head(rows));
  };
  const double h = 1e-6;
  return (residual(h) - residual(-h)).norm() / (2 * h);
}

// A parameter the identification rows leave unexcited while a held-out row excites it: drawn at random (robot,
// measurement type, frames, and which column: a kinematic one or one of a joint_compliance's gravity-regressor
// columns), by choosing as identification rows the configurations of a large pool that excite that column least.
// Every column the plain reference finds below 0.08x is held and named; none above 0.12x is.
TEST(Prediction, ExcitationDeficitsAgreeWithAPlainReferenceAndAreHeld) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int deficits_drawn = 0, held_ok = 0;
  constexpr int kDraws = 60;
  for (int d = 0; d < kDraws; ++d) {
    const Draw dr = draw(rng);
    const MeasurementKind kind = dr.kind;
    const RobotModel& model = dr.model;
    const SimulationConfig& sc = dr.config;
    const SimulatedCell cell(model, sc);
    Eigen::VectorXd params = model.nominal;
    params.segment(model.baseParam(FrameParam::kX), 6) = sc.base_in_tracker;
    params.segment(model.toolParam(FrameParam::kX), 6) = sc.tool_in_flange;
    const int joint = 1 + static_cast<int>(2 * u(rng));  // joint 2 or 3 (0-based 1, 2): gravity loads them
    const std::vector<Extension> exts = {Extension{Cause::kJointCompliance, joint}};
    const int np = model.numParams(), k = numExtensionParams(model, exts);
    std::vector<int> columns = model.canonicalParams();
    for (int e = 0; e < k; ++e) columns.push_back(np + e);
    const int target = columns[static_cast<size_t>(u(rng) * columns.size())];
    // A pool of configurations; the identification rows are the 40 that excite `target` least.
    auto pool = cell.randomConfigurations(3000, rng);
    std::vector<std::pair<double, Observation>> scored;
    for (const auto& q : pool) {
      Observation o = cell.measure(q, 0.0, rng, kind);
      scored.push_back({plainExcitation(model, params, exts, target, o, Drivers{}), o});
    }
    std::sort(scored.begin(), scored.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<Observation> ident, other;
    for (int i = 0; i < 40; ++i) ident.push_back(scored[static_cast<size_t>(i)].second);
    for (int i = 0; i < 40; ++i) other.push_back(scored[static_cast<size_t>(40 + u(rng) * 2900)].second);
    other.push_back(scored.back().second);  // the one that excites it most
    const std::vector<Drivers> di(ident.size()), dv(other.size());
    const auto deficits = excitationDeficits(model, params, exts, ident, di, other, dv);
    // The plain reference, column by column.
    for (int c : columns) {
      double sq = 0, most = 0;
      for (const auto& o : ident) sq += std::pow(plainExcitation(model, params, exts, c, o, Drivers{}), 2);
      for (const auto& o : other) most = std::max(most, plainExcitation(model, params, exts, c, o, Drivers{}));
      const double ratio = most > 0 ? std::sqrt(sq / ident.size()) / most : 1.0;
      const bool named = std::any_of(deficits.begin(), deficits.end(), [&](const auto& x) { return x.column == c; });
      if (ratio < 0.08) { EXPECT_TRUE(named) << "draw " << d << ": column " << c << " ratio " << ratio << " not held"; }
      if (ratio > 0.12) { EXPECT_FALSE(named) << "draw " << d << ": column " << c << " ratio " << ratio << " held"; }
      if (c == target && ratio < 0.08) {
        ++deficits_drawn;
        // Held: the fit does not estimate it.
        IdentifiabilityOptions io;
        io.held = heldColumns(deficits);
        const ExtendedFit fit = fitExtended(model, params, ident, di, exts, {}, io);
        const bool estimated = c < np ? std::count(fit.estimated.begin(), fit.estimated.end(), c) > 0
                                      : std::count(fit.estimated_extension.begin(), fit.estimated_extension.end(), c - np) > 0;
        EXPECT_FALSE(estimated) << "draw " << d << ": held column " << c << " estimated";
        if (!estimated) ++held_ok;
      }
    }
  }
  std::printf("%d of %d draws left their drawn column below 0.08x on the identification rows; %d held\n", deficits_drawn,
              kDraws, held_ok);
  // The construction makes deficits (mostly in the extension's columns: a UR10's compliance, with its link masses,
  // is one column; a TX60's, without, four per link): 8-22 of 60 over 40 seeds.
  EXPECT_GE(deficits_drawn, 5);
}

}  // namespace
}  // namespace cellcal

namespace cellcal {
namespace {

// A joint angle inside the range of the data but in a stretch no row reached (BeyondRange::gaps_rad, rangeGaps) against
// a plain reference: the distance to the nearer of the data values on either side where they lie farther apart than
// kBeyondGapShare of the range, 0 where they are nearer; beyond the range the distance to its end. Data drawn as 1-4
// clusters of random place, spread and size (a grid at one tool orientation leaves a wrist joint's angles so).
TEST(Prediction, AnAngleInAGapOfTheDataIsJudgedByItsDistanceFromTheData) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int in_gaps = 0, beyond = 0, flagged_in_gaps = 0;
  for (int d = 0; d < 40; ++d) {
    std::vector<double> x;
    for (int c = 1 + static_cast<int>(4 * u(rng)) % 4; c > 0; --c) {
      const double centre = -3 + 6 * u(rng), spread = 0.5 * u(rng);
      for (int k = 2 + static_cast<int>(60 * u(rng)); k > 0; --k) x.push_back(centre + spread * (2 * u(rng) - 1));
    }
    const double lo = *std::min_element(x.begin(), x.end()), hi = *std::max_element(x.begin(), x.end());
    const double min_width = kBeyondGapShare * (hi - lo);
    BeyondRange b{1, lo, hi, 1e-3 * u(rng), static_cast<int>(3 * u(rng)) % 3, 0.5 * u(rng), rangeGaps(x, min_width)};
    std::string why;
    ASSERT_TRUE(b.IsValid(6, &why)) << why;
    std::vector<double> sorted = x;
    std::sort(sorted.begin(), sorted.end());
    for (int k = 0; k < 200; ++k) {
      const double q = -4 + 8 * u(rng);
      double plain = 0;
      if (q < lo) plain = lo - q;
      else if (q > hi) plain = q - hi;
      else
        for (size_t i = 1; i < sorted.size(); ++i)
          if (sorted[i - 1] <= q && q <= sorted[i] && sorted[i] - sorted[i - 1] > min_width)
            plain = std::min(q - sorted[i - 1], sorted[i] - q);
      EXPECT_NEAR(b.beyondRad(q), plain, 1e-15) << q;
      EXPECT_EQ(b.judged(q), plain <= b.checked_rad) << q;
      Eigen::VectorXd qv = Eigen::VectorXd::Zero(6);
      qv[1] = q;
      EXPECT_EQ(firstUnjudged({b}, qv) != nullptr, plain > b.checked_rad) << q;
      const bool gap = q >= lo && q <= hi && plain > 0;
      EXPECT_EQ(b.inGap(q), gap) << q;
      in_gaps += gap;
      beyond += !gap && plain > 0;
      if (gap && plain > b.checked_rad) {
        ++flagged_in_gaps;
        EXPECT_NE(unjudgedText(b, q).find("that its data never reached"), std::string::npos) << unjudgedText(b, q);
      }
      // The sigma there is the range's law at that distance, held at the judged distance.
      EXPECT_NEAR(b.sigmaRad(q), plain > 0 && b.sigma_at_1_rad > 0
                                     ? b.sigma_at_1_rad * std::pow(b.checked_rad > 0 ? std::min(plain, b.checked_rad) : plain, b.growth)
                                     : 0.0,
                  1e-15);
    }
  }
  std::printf("  %d angles in gaps of the data (%d farther than judged), %d beyond the range\n", in_gaps,
              flagged_in_gaps, beyond);
  EXPECT_GT(in_gaps, 100);
  EXPECT_GT(flagged_in_gaps, 10);
}

// The error beyond a joint's range (BeyondRange) in predictedPositionSigma against a plain reference: that joint turned
// by sigmaRad(q) in the forward kinematics moves the target by sigma |dp/dq| to first order (central differences);
// inside the range it adds nothing, and beyond the checked distance it stays at its value there. Robots, ranges, sizes, growths and configurations drawn at random.
TEST(Prediction, AnErrorBeyondAJointsRangeMovesTheTargetAsThatJointWould) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int d = 0; d < 30; ++d) {
    const RobotModel m = test::robot(d % 2 ? "ur10" : "staubli_tx60");
    KinematicsData data(m);
    ExtendedFit fit;
    fit.params = m.nominal;
    PredictionModel pm;  // no parameter covariance: the beyond term alone
    BeyondRange b;
    b.joint = static_cast<int>(u(rng) * m.numJoints()) % m.numJoints();
    b.lower_rad = -2 * u(rng);
    b.upper_rad = b.lower_rad + 2 * u(rng);
    b.sigma_at_1_rad = 1e-4 + 1e-3 * u(rng);
    b.growth = d % 3;
    b.checked_rad = d % 2 ? 0.0 : 0.3 + u(rng);  // 0: no limit
    pm.beyond = {b};
    std::string why;
    ASSERT_TRUE(b.IsValid(m.numJoints(), &why)) << why;
    for (int t = 0; t < 20; ++t) {
      Eigen::VectorXd q(m.numJoints());
      for (int j = 0; j < q.size(); ++j) q[j] = -3 + 6 * u(rng);
      const double x = q[b.joint];
      double beyond = x < b.lower_rad ? b.lower_rad - x : x > b.upper_rad ? x - b.upper_rad : 0.0;
      if (b.checked_rad > 0) beyond = std::min(beyond, b.checked_rad);
      const double sigma = beyond > 0 ? b.sigma_at_1_rad * std::pow(beyond, b.growth) : 0.0;
      EXPECT_NEAR(b.sigmaRad(x), sigma, 1e-15);
      const double h = 1e-6;
      Eigen::VectorXd qp = q, qm = q;
      qp[b.joint] += h;
      qm[b.joint] -= h;
      const Eigen::Vector3d pp = forwardKinematics(m, data, m.nominal, qp).translation();
      const Eigen::Vector3d pn = forwardKinematics(m, data, m.nominal, qm).translation();
      const double reference = sigma * ((pp - pn) / (2 * h)).norm();
      const double got = predictedPositionSigma(m, fit, pm, q, Drivers{});
      EXPECT_NEAR(got, reference, 1e-7 * (reference + 1e-6)) << "joint " << b.joint + 1 << " at " << x;
    }
  }
}

}  // namespace
}  // namespace cellcal
