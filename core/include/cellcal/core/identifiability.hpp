// Which kinematic parameters a set of observations can identify.
//
// The whitened Jacobian's columns are scaled to unit norm first (so metres and radians compare), then taken in a
// fixed priority order (joint parameters base to flange, then base frame, then tool frame; only canonical
// parameters are candidates) and kept when they add a direction the kept ones do not span: relative residual after
// projection > rank_tolerance (greedy QR with column pivoting in a deterministic order, so the kept set is the
// natural one: d1 stays and base z, which only duplicates it, is fixed). Columns within weak_separation of the kept
// span are taken in a second pass, after all well-separated ones, so that a near-duplicate (a tool roll next to joint
// 6's alpha when the tool is tilted by a few hundredths of a degree) does not push out a parameter that is clearly
// separable (the tool pitch). Every dropped parameter is reported with
// the kept parameters it is (nearly) a combination of: it is fixed at its current value, and the ones it merges into
// absorb its error.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cellcal/core/observation.hpp"
#include "cellcal/core/robot_model.hpp"

namespace cellcal {

struct IdentifiabilityOptions {
  double rank_tolerance = 1e-5;  // sine of the angle between a scaled column and the span of the kept ones
  double weak_separation = 1e-2;  // columns closer than this (sine) to the kept span are considered after the others
  std::vector<int> candidates;   // empty: model.canonicalParams()
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
  std::string summary(const RobotModel& model) const;
};

// The columns of J (indices taken from `order`, highest priority first) that the rule above keeps, ascending.
// Works on any stacked Jacobian, e.g. kinematic parameters plus the parameters of a model extension.
std::vector<int> independentColumns(const Eigen::MatrixXd& J, const std::vector<int>& order,
                                    const IdentifiabilityOptions& options = {});

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
