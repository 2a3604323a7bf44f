// Planning a calibration campaign: which K joint configurations the tracker should measure.
//
// Candidates are drawn at random within the joint limits and kept where the tracker can measure the target: within
// its range, the beam clear of the robot's links (each link a capsule of `link_radius_m` from one joint frame's
// origin to the next; the last two links, which carry the target, are not judged), and, when an acceptance angle is
// given, the target's z axis turned towards the tracker within it. Of those, K are chosen greedily to minimise the
// predicted position variance over the working volume (pose_selection.hpp, kPredictionVariance: the candidates
// themselves stand for the volume), from the prior of an uncalibrated robot.
//
// Observability indices (Sun and Hollerbach, "Observability index selection for robot calibration", 2008) of a set
// of configurations: of the stacked identification Jacobian over the estimated parameters, rows whitened by the
// measurement sigmas and columns scaled by each parameter's prior sigma (a millimetre and a tenth of a degree
// compare), with singular values s_1 >= ... >= s_n over m rows:
//   O1 = (s_1 s_2 ... s_n)^(1/n) / sqrt(m)   Borm and Menq: the volume of the error ellipsoid
//   O2 = s_n / s_1                           the inverse condition number
//   O3 = s_n                                 the smallest singular value: the worst direction
//   O4 = s_n^2 / s_1                         Nahvi and Hollerbach's noise amplification index
// Larger is better for all four.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "cellcal/core/model/measurement_kind.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct TrackerSetup {
  Eigen::Vector3d position_in_base_m = Eigen::Vector3d::Zero();  // the tracker head, in the robot's base frame
  double min_range_m = 0.0, max_range_m = std::numeric_limits<double>::infinity();
  double link_radius_m = 0.06;  // the beam keeps this far from every link but the last two
  double acceptance_rad = 0.0;  // > 0: the target's z axis within this of the direction to the tracker
};

enum class Visibility { kVisible, kOutOfRange, kOccluded, kFacingAway };
const char* visibilityName(Visibility v);

// Whether the tracker can measure the target at q (`params`: the model's, its base frame is ignored: the tracker is
// placed in the robot's base frame).
Visibility visibility(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad,
                      const TrackerSetup& tracker);

struct ObservabilityIndices {
  double O1 = 0, O2 = 0, O3 = 0, O4 = 0;
};

ObservabilityIndices observabilityIndices(const RobotModel& model, const Eigen::VectorXd& params,
                                          const std::vector<int>& estimated, const std::vector<Eigen::VectorXd>& qs,
                                          MeasurementKind kind, double sigma_position_m, double sigma_orientation_rad,
                                          double prior_length_m, double prior_angle_rad);

// The predicted 1-sigma position error (RMS over `volume`) of a robot whose parameters over `estimated` have the
// covariance P0 before, after measuring the configurations `qs` (sigmas and kind of `options`).
struct PosePlanOptions;
double predictedPositionRms(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                            const Eigen::MatrixXd& P0, const std::vector<Eigen::VectorXd>& qs,
                            const std::vector<Eigen::VectorXd>& volume, const PosePlanOptions& options);

struct PosePlanOptions {
  int count = 25;
  int candidates = 2000;           // drawn at random within the limits (then kept where the tracker sees them)
  MeasurementKind kind = MeasurementKind::kPose6D;
  double sigma_position_m = 15e-6, sigma_orientation_rad = 8.7e-5;  // the tracker's, for the whitening
  double prior_length_m = 1e-3, prior_angle_rad = 0.1 * 3.14159265358979323846 / 180;  // an uncalibrated robot
  double range_fraction = 0.9;     // of each joint's range (and of +-180 deg) the candidates use
  double min_radius_m = 0.2;       // the target this far from joint 1's axis (base frame z) at least
  std::optional<TrackerSetup> tracker;  // none: every candidate within the limits is measurable
  std::uint64_t seed = 1;
  bool IsValid(std::string* error) const;
};

struct PosePlan {
  std::vector<Eigen::VectorXd> chosen_q;  // in the order chosen
  std::vector<Eigen::VectorXd> random_q;  // as many feasible candidates at random, for comparison
  ObservabilityIndices chosen, random;
  // The predicted 1-sigma position error over the working volume (RMS over the feasible candidates) after measuring
  // each set, from the prior: what the choice is meant to minimise.
  double chosen_predicted_rms_m = 0, random_predicted_rms_m = 0;
  std::vector<int> estimated;
  Eigen::MatrixXd prior_covariance;  // over `estimated`: the uncalibrated robot's
  std::vector<Eigen::VectorXd> feasible_q;  // the candidates the tracker can measure (the working volume)
  int drawn = 0, feasible = 0, out_of_range = 0, occluded = 0, facing_away = 0, near_axis = 0;
  int exchanges = 0;  // greedy choices swapped for better ones afterwards
};

// The configurations planPoses chooses from: `options.candidates` drawn at random within the limits (options.seed),
// kept where the target is `min_radius_m` from joint 1's axis and the tracker (when given) can measure it.
struct CandidateSet {
  std::vector<Eigen::VectorXd> q;
  int drawn = 0, out_of_range = 0, occluded = 0, facing_away = 0, near_axis = 0;
  // "only 12 of 2000 random configurations can be measured (...): fewer than the 25 asked; ..." for `count`.
  std::string tooFewText(int count, double min_radius_m) const;
};
CandidateSet measurableCandidates(const RobotModel& model, const Eigen::VectorXd& params, const PosePlanOptions& options);

// `count` configurations around q, for measuring near a configuration rather than at one row (`cellcal plan cover`):
// each joint moved by a uniform draw within +-spread_rad, kept where within the limits and, with a tracker, where it
// can measure the target; up to 50 draws per configuration kept, so fewer than `count` may come back near a limit or
// an occlusion.
std::vector<Eigen::VectorXd> configurationsAround(const RobotModel& model, const Eigen::VectorXd& params,
                                                  const Eigen::VectorXd& q_rad, int count, double spread_rad,
                                                  const std::optional<TrackerSetup>& tracker, std::mt19937_64& rng);
// Throws std::invalid_argument when fewer feasible candidates than `count` were found (the message says why they
// were refused: range, line of sight, acceptance angle).
PosePlan planPoses(const RobotModel& model, const Eigen::VectorXd& params, const PosePlanOptions& options);

}  // namespace cellcal
