// The model-error variance component (model_error.hpp): rows that carry the tracker's own sigmas, on random robots and
// placements, with each row's noise drawn from its own sigma (0.005-0.05 mm, log-uniform; orientation alike).
// Two regimes, judged at fresh configurations against the true poses:
//  - a hidden joint compliance far above the noise (the model error dominates, as on real robots): sigma_m comes out
//    near the geometric fit's residual per axis, and the fit weighted by sigma_i with sigma_m beats the fit weighted by
//    sigma_i alone and matches the plain reference, equal weights, within 5 % (averaged over the draws);
//  - no hidden effect (the sigmas are the whole truth): sigma_m stays below the median sigma_i, and the weighting keeps
//    its gain over equal weights.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/model_error.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/placements.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

struct Draw {
  RobotModel robot;
  std::vector<Observation> ident, fresh;
  Eigen::VectorXd start;
};

// n readings of `cell` with each row's noise drawn from its own sigmas, and 100 fresh configurations' true poses.
Draw draw(const RobotModel& robot, const SimulatedCell& cell, int n, std::mt19937_64& rng) {
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> u(0, 1);
  Draw d{robot, {}, {}, {}};
  for (const auto& q : cell.randomConfigurations(n, rng)) {
    Observation o;
    o.q_rad = q;
    o.kind = MeasurementKind::kPose6D;
    o.sigma_position_m = 5e-6 * std::pow(10.0, u(rng));
    o.sigma_orientation_rad = o.sigma_position_m / 0.2;  // a 0.2 m probe
    Pose p = cell.truePose(q, 0.0);
    p.translation() += o.sigma_position_m * Eigen::Vector3d(g(rng), g(rng), g(rng));
    const Eigen::Vector3d w = o.sigma_orientation_rad * Eigen::Vector3d(g(rng), g(rng), g(rng));
    p.linear() = Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix() * p.linear();
    o.measured_in_tracker = p;
    d.ident.push_back(o);
  }
  for (const auto& q : cell.randomConfigurations(100, rng)) {
    Observation o;
    o.q_rad = q;
    o.measured_in_tracker = cell.truePose(q, 0.0);
    d.fresh.push_back(o);
  }
  Eigen::VectorXd start = robot.nominal;
  start.tail<12>().setZero();
  d.start = registerFrames(robot, start, d.ident).params;
  return d;
}

double freshMeanMm(const Draw& d, const std::vector<Observation>& obs) {
  CalibrationProblem p{&d.robot, d.start, obs, std::nullopt, {}, {}};
  const CalibrationResult r = solveGaussNewton(p);
  EXPECT_TRUE(r.converged);
  return mean(positionErrors(d.robot, r.params, d.fresh)) * 1e3;
}

std::vector<Observation> equalWeights(std::vector<Observation> obs) {
  for (auto& o : obs) {
    o.sigma_position_m = 25e-6;
    o.sigma_orientation_rad = 25e-6 / 0.2;
  }
  return obs;
}

// The draw fitted three ways: by sigma_i, by sigma_i with sigma_m (estimated on a first fit by sigma_i, its gross
// errors left out), and with equal weights; the fresh mean error of each, mm.
struct Compared {
  ModelErrorSigma m;
  double first_residual_axis_m = 0;  // the first fit's mean position residual, per axis
  double by_sigma_i = 0, with_sigma_m = 0, equal = 0;
};
Compared compare(const Draw& d) {
  CalibrationProblem p{&d.robot, d.start, d.ident, std::nullopt, {}, {}};
  const CalibrationResult first = solveGaussNewton(p);
  Compared c;
  c.m = modelErrorSigma(d.robot, first.params, d.ident, first.outliers.rows);
  c.first_residual_axis_m = mean(positionErrors(d.robot, first.params, d.ident)) / std::sqrt(3.0);
  std::vector<Observation> weighted = d.ident;
  addModelError(weighted, c.m);
  c.by_sigma_i = freshMeanMm(d, d.ident);
  c.with_sigma_m = freshMeanMm(d, weighted);
  c.equal = freshMeanMm(d, equalWeights(d.ident));
  return c;
}

TEST(ModelError, TrackerSigmasWeighOnlyAsFarAsTheModelErrorLetsThem) {
  const std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng(seed);
  double raw = 0, with_m = 0, equal = 0, raw0 = 0, with_m0 = 0, equal0 = 0;
  const int draws = 8;
  for (int k = 0; k < draws; ++k) {
    const RobotModel robot = test::robot(k % 2 ? "ur10" : "staubli_tx60");
    SimulationConfig sc = test::randomPlacement(rng);
    const std::string what = robot.name + ", seed " + std::to_string(seed) + " draw " + std::to_string(k);
    // Model error dominating: joint 2 or 3 compliance of 0.3-0.5 mrad RMS.
    {
      SimulationConfig hidden = sc;
      const SimulatedCell plain(robot, sc);
      const auto links = robot.links.empty() ? plausibleLinks(robot, plain.trueParams(0), rng) : robot.links;
      hidden.hidden = scaledHiddenEffect(robot, plain.trueParams(0), Cause::kJointCompliance, 1 + static_cast<int>(rng() % 2),
                                         (0.3 + 0.2 * std::uniform_real_distribution<double>(0, 1)(rng)) * 1e-3, links,
                                         plain.randomConfigurations(200, rng), rng);
      const Compared c = compare(draw(robot, SimulatedCell(robot, hidden), 80, rng));
      // Near the residual per axis the model leaves (the sigmas are 10-100x smaller).
      EXPECT_GT(c.m.position_m, 0.5 * c.first_residual_axis_m) << what;
      EXPECT_LT(c.m.position_m, 2.0 * c.first_residual_axis_m) << what;
      std::printf("  %-40s model error: sigma_m %.4f mm; fresh mean %.4f (sigma_i) %.4f (with sigma_m) %.4f (equal) mm\n",
                  what.c_str(), c.m.position_m * 1e3, c.by_sigma_i, c.with_sigma_m, c.equal);
      raw += c.by_sigma_i / draws;
      with_m += c.with_sigma_m / draws;
      equal += c.equal / draws;
    }
    // The sigmas are the whole truth.
    {
      const Draw d = draw(robot, SimulatedCell(robot, sc), 80, rng);
      const Compared c = compare(d);
      // At most the scale of the smaller sigmas: a chance excess of the normalized residual (80 rows) can give a few
      // micrometres (seed 6680767190484985571: 5.1 um), far below the median row's sigma.
      std::vector<double> sigmas;
      for (const auto& o : d.ident) sigmas.push_back(o.sigma_position_m);
      std::nth_element(sigmas.begin(), sigmas.begin() + static_cast<long>(sigmas.size() / 2), sigmas.end());
      EXPECT_LT(c.m.position_m, sigmas[sigmas.size() / 2]) << what << ": the readings' sigmas explain the residual";
      std::printf("  %-40s noise only:  sigma_m %.4f mm; fresh mean %.4f (sigma_i) %.4f (with sigma_m) %.4f (equal) mm\n",
                  what.c_str(), c.m.position_m * 1e3, c.by_sigma_i, c.with_sigma_m, c.equal);
      raw0 += c.by_sigma_i / draws;
      with_m0 += c.with_sigma_m / draws;
      equal0 += c.equal / draws;
    }
  }
  std::printf("  means: model error %.4f / %.4f / %.4f mm; noise only %.4f / %.4f / %.4f mm (sigma_i / with sigma_m / equal)\n",
              raw, with_m, equal, raw0, with_m0, equal0);
  EXPECT_LT(with_m, raw) << "with the model error dominating, sigma_m must help";
  EXPECT_LT(with_m, 1.05 * equal);
  EXPECT_LT(with_m0, equal0) << "with the sigmas the whole truth, the weighting must keep its gain";
  EXPECT_LT(with_m0, 1.05 * raw0);
}

}  // namespace
}  // namespace cellcal
