// Which kinematic parameters a set of observations can identify.
//
// The whitened Jacobian's columns are scaled to unit norm first (so metres and radians compare), then kept one at a
// time while some column leaves the span of the kept ones by more than rank_tolerance (the sine of its angle to that
// span): greedy QR with column pivoting, where the pivot is the highest-priority column whose sine is at least
// conditioning_guard times the largest one left. Priority (identificationPriority): the tool frame, then the joints
// from base to flange, then the base frame; only canonical parameters are candidates.
//   - The tool frame first: with the last joint's parameters the tool frame describes one rigid motion, and the
//     tool's Cartesian parameters describe it for any target (a point target 1 mm or 100 mm off the flange axis,
//     any orientation). Keeping joint n's offset and a instead parametrizes a sideways target in polar form, which
//     degenerates where the fixed part is small: a fit in such a basis stalls above the optimum.
//   - Joints before the base: d1 stays and base z, which only duplicates it, is fixed.
//   - The guard: a column nearly inside the kept span (a tool roll next to joint 6's alpha, separated only by a tool
//     tilt of a few hundredths of a degree) is not taken while a clearly separable one is left; a basis of
//     nearly parallel columns identifies the same span linearly but is ill-conditioned and nonlinear far from it.
// The kept set spans every direction of the candidate columns above rank_tolerance; every dropped parameter lies
// within rank_tolerance of that span and is reported with the kept parameters it is (nearly) a combination of: it
// is fixed at its current value, and the ones it merges into absorb its error.
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
  bool IsValid(std::string* error) const;
};

struct DroppedParameter {
  int index = -1;
  std::string name;
  std::vector<std::pair<int, double>> merged_into;  // (kept parameter, coefficient in scaled units), |coef| >= 0.05
};

struct IdentifiabilityReport {
  int num_candidates = 0;
  int rank = 0;                     // == identifiable.size()
  double condition_number = 0;      // of the scaled, whitened Jacobian restricted to `identifiable`
  std::vector<int> identifiable;    // parameter indices, ascending
  std::vector<DroppedParameter> dropped;
  // absorptionMap(model, J, identifiable): how the identifiable parameters stand for the dropped ones.
  Eigen::MatrixXd absorption;
  std::string summary(const RobotModel& model) const;
};

// The canonical parameters in the priority order above: tool frame, joints base to flange, base frame.
std::vector<int> identificationPriority(const RobotModel& model);

// The columns of J (indices taken from `order`, highest priority first) that the rule above keeps, ascending.
// Works on any stacked Jacobian, e.g. kinematic parameters plus the parameters of a model extension.
std::vector<int> independentColumns(const Eigen::MatrixXd& J, const std::vector<int>& order,
                                    const IdentifiabilityOptions& options = {});

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
