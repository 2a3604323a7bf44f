// Which kinematic parameters a set of observations can identify.
//
// The whitened Jacobian's columns are scaled to unit norm first (so metres and radians compare), then kept one at a
// time while some column leaves the span of the kept ones by more than rank_tolerance (the sine of its angle to that
// span): greedy QR with column pivoting, where the pivot is the highest-priority column whose sine is at least
// conditioning_guard times the largest one left. Priority (identificationPriority): the tool frame, then the base
// frame, then the joints from base to flange; only canonical parameters are candidates.
//   - The tool frame first: with the last joint's parameters the tool frame describes one rigid motion, and the
//     tool's Cartesian parameters describe it for any target (a point target 1 mm or 100 mm off the flange axis,
//     any orientation). Keeping joint n's offset and a instead parametrizes a sideways target in polar form, which
//     degenerates where the fixed part is small: a fit in such a basis stalls above the optimum.
//   - The base before the joints: base z stays and joint 1's d, which only duplicates it, is held (frameGauge).
//   - The guard: a column nearly inside the kept span (a tool roll next to joint 6's alpha, separated only by a tool
//     tilt of a few hundredths of a degree) is not taken while a clearly separable one is left; a basis of
//     nearly parallel columns identifies the same span linearly but is ill-conditioned and nonlinear far from it.
// The kept set spans every direction of the candidate columns above rank_tolerance; every dropped parameter lies
// within rank_tolerance of that span and is reported with the kept parameters it is (nearly) a combination of: it
// is fixed at its current value, and the ones it merges into absorb its error.
//
// Plausible ranges (prior_sigma): rank alone keeps a column the rows separate from the others by a sine of 1e-5, which
// on real data (a target 0.15 mm off the flange axis, a grid at one tool orientation) leaves joint 5's offset, d, a and
// alpha free to wander by tens of degrees and millimetres while the fit's cost barely changes. With prior_sigma, a
// column is taken only if a least-squares fit of it with the columns already kept pins each of them that has a range
// better than that range (1 sigma noise_scale sqrt of the diagonal of the inverted normal matrix below prior_sigma):
// a column the rows do not pin, or one that would loosen a kept one beyond its range, is held at its start value (what
// the robot file says is within its plausible range of the truth; the data say no better) and reported. The pivot rule
// above chooses among the columns that pass. The readings' sigmas whiten J; noise_scale is by how much the residual exceeds them (the root of a fit's
// variance factor: model error the geometric model leaves counts as noise here), so the decision follows the data's
// real noise. Frame parameters have no plausible range (the tracker stands anywhere): only rank decides them.
// Extension parameters (fitExtended, fitSetups) have one when prior_sigma is given: extensionPriorSigma at
// kPlausibleExtensionJointErrorRad, the value whose column makes that RMS joint error through the joint limits (an
// extension the rows pin no better than an effect of that size is held at 0, as a kinematic parameter at its start).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct IdentifiabilityOptions {
  double rank_tolerance = 1e-5;      // sine of the angle between a scaled column and the span of the kept ones
  double conditioning_guard = 0.1;  // a pivot's sine is at least this fraction of the largest one left
  std::vector<int> candidates;      // a subset of model.canonicalParams(); empty: all of them
  // Columns never estimated, whatever the data (held at their start value and not reported as unidentifiable):
  // kinematic index, or numParams() + k for extension parameter k. Excitation deficits (prediction.hpp) go here.
  std::vector<int> held;
  // Plausible deviation of each column from its start (SI, indexed like J's columns; a column beyond its size or with
  // 0: none, rank alone decides). plausibleDeviation() gives a nominal robot's.
  Eigen::VectorXd prior_sigma;
  double noise_scale = 1.0;  // >= 1 in use: the root of the variance factor of a fit on the same rows
  bool IsValid(std::string* error) const;
};

// What a robot that no one calibrated may plausibly deviate from its nominal model (the robot file's values): every
// kinematic length by length_m, every kinematic angle by angle_rad (1 sigma); the base and tool frames free (0).
// The same widths as PredictionOptions' priors.
constexpr double kPlausibleLengthM = 5e-3;
constexpr double kPlausibleAngleRad = 0.5 * 3.14159265358979323846 / 180;
constexpr double kPlausibleExtensionJointErrorRad = 0.5 * 3.14159265358979323846 / 180;
Eigen::VectorXd plausibleDeviation(const RobotModel& model, double length_m = kPlausibleLengthM,
                                   double angle_rad = kPlausibleAngleRad);
// The noise_scale a fit implies: the root of its whitened residual's sum of squares over its degrees of freedom
// (rows - estimated), at least 1 (readings whose sigmas overstate the noise do not make a column easier to keep).
double noiseScaleOf(const Eigen::VectorXd& whitened_residual, int estimated);

struct DroppedParameter {
  int index = -1;
  std::string name;
  std::vector<std::pair<int, double>> merged_into;  // (kept parameter, coefficient in scaled units), |coef| >= 0.05
  // Its 1 sigma fitted with the kept parameters (noise_scale applied; SI; infinity where the rows do not move it outside
  // their span), and its plausible deviation (0: none). below_prior: rank alone would keep it, but fitted with the
  // kept ones the rows pin it (data_sigma >= prior_sigma) or one of them no better than the plausible range.
  double data_sigma_si = 0;
  double prior_sigma_si = 0;
  bool below_prior = false;
};

struct IdentifiabilityReport {
  int num_candidates = 0;
  int rank = 0;                     // == identifiable.size()
  double condition_number = 0;      // of the scaled, whitened Jacobian restricted to `identifiable`
  std::vector<int> identifiable;    // parameter indices, ascending
  std::vector<int> taken;           // the same, in the order the rule took them
  std::vector<DroppedParameter> dropped;
  double noise_scale = 1.0;         // the options' noise_scale the decision was made with
  // absorptionMap(model, J, identifiable): how the identifiable parameters stand for the dropped ones.
  Eigen::MatrixXd absorption;
  std::string summary(const RobotModel& model) const;
};

// The canonical parameters in the priority order above: tool frame, base frame, joints base to flange.
std::vector<int> identificationPriority(const RobotModel& model);

// The kinematic parameters the base and tool frames stand for on any data: a change of one moves every reading as a
// change of the frames would (joint 1's offset about and along its axis with the base's yaw and z; the last joint's
// flange-side parameters with the tool frame). Found from the Jacobian, not listed: the canonical kinematic columns
// within rank_tolerance (sine) of the span of the twelve frame columns over the structural pose set, 6D. Taking the
// frames first (identificationPriority) holds them at their start value wherever the frames are estimated, and the
// frames carry them: a calibration moves the kinematic chain only by what the data tell from the base and the target,
// and an exported description's base_link -> tool0 differs from the nominal one only by that. They carry no
// uncertainty of their own either (predictionModel leaves them out: the frames' columns are theirs). Ascending.
std::vector<int> frameGauge(const RobotModel& model, const Eigen::VectorXd& params, double rank_tolerance = 1e-5);

// The columns of J (indices taken from `order`, highest priority first) that the rule above keeps, ascending.
// Works on any stacked Jacobian, e.g. kinematic parameters plus the parameters of a model extension.
// `taken`, when given, receives them in the order they were taken.
std::vector<int> independentColumns(const Eigen::MatrixXd& J, const std::vector<int>& order,
                                    const IdentifiabilityOptions& options = {}, std::vector<int>* taken = nullptr);

// To first order, how the `kept` parameters stand for the canonical parameters left out of them. Returns T
// (kept.size() x model.numParams()): the identity on `kept`; for a left-out canonical column of J within
// `absorb_sine` (sine of the angle) of the span of the kept columns, its least-squares coefficients on them in model
// units (joint 6's zero and the tool yaw are one direction: its column holds 1 at the tool yaw); zero otherwise (a
// column the rows do not excite, or one they separate from the kept ones, e.g. a parameter held for lack of
// excitation). A change dp of the whole parameter vector moves the measurements as the change T dp of the kept
// parameters would, so a drift or an uncertainty of a left-out parameter is carried by the ones that stand for it
// (covariance T P T^T) instead of being lost: a joint 6 zero that drifts makes the tool yaw drift.
constexpr double kDefaultAbsorbSine = 1e-3;
Eigen::MatrixXd absorptionMap(const RobotModel& model, const Eigen::MatrixXd& J, const std::vector<int>& kept,
                              double absorb_sine = kDefaultAbsorbSine);
// absorptionMap on the structural pose set (structuralIdentifiability's).
Eigen::MatrixXd structuralAbsorption(const RobotModel& model, const Eigen::VectorXd& params, MeasurementKind kind,
                                     const std::vector<int>& kept);

// J: stacked whitened Jacobian with all model.numParams() columns.
IdentifiabilityReport analyzeIdentifiability(const RobotModel& model, const Eigen::MatrixXd& J,
                                             const IdentifiabilityOptions& options = {});
IdentifiabilityReport analyzeIdentifiability(const RobotModel& model, const Eigen::VectorXd& params,
                                             const std::vector<Observation>& obs,
                                             const IdentifiabilityOptions& options = {});

// The parameters a rich pose set identifies for this structure and measurement kind (independent of how many poses
// one data set has): 200 poses drawn uniformly within the joint limits with a fixed seed.
IdentifiabilityReport structuralIdentifiability(const RobotModel& model, const Eigen::VectorXd& params,
                                                MeasurementKind kind, const IdentifiabilityOptions& options = {});

}  // namespace cellcal
