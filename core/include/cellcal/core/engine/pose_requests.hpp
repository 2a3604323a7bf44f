// What the engine asks the robot to measure next: the configurations that would teach the current estimate most.
//
// After a new calibration version the engine's host calls propose() (components' EngineProcess publishes the result
// on cellcal/pose_request, at most once per PoseRequestSettings::min_period_s). It returns the `count` most
// informative of a fixed candidate set, chosen greedily to minimise the predicted position variance over the
// candidates (pose_selection.hpp kPredictionVariance: the candidates stand for the working volume) from the
// estimate's covariance. Poses the recent readings pinned are therefore not asked again until the drift model has
// widened them. The candidates are drawn once per robot (poseRequestSeed: the same cell file gives the same set in
// every process and every run) within the joint limits, the target at least
// min_radius_m from joint 1's axis, and where the tracker at the registration's tracker frame origin can measure it
// (pose_plan.hpp visibility: range, line of sight past the links, acceptance angle).
//
// The choice uses the kinematic and frame block of the estimate's covariance: extension parameters (compliance,
// cyclic errors...) are left out of it, and the figures are of the kinematic part alone.
// No DDS and no clock: the host decides when to ask.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/identification/pose_plan.hpp"

namespace cellcal {

struct PoseProposal {
  std::uint64_t version = 0;           // the calibration version it was made for
  std::vector<Eigen::VectorXd> q_rad;  // the most informative first
  // RMS over the candidates of the predicted 1-sigma position error (x, y, z together) of the estimate, and the same
  // after measuring every configuration of q_rad (without drift meanwhile).
  double predicted_sigma_now_m = 0, predicted_sigma_after_m = 0;
};

class PoseRequester {
 public:
  // `robot` must outlive the requester. Throws std::invalid_argument (the text says why candidates were refused)
  // when fewer than settings.count of them can be measured, or settings.count is 0.
  PoseRequester(const CellRobot& robot, const PoseRequestSettings& settings, std::uint64_t seed);

  // The proposal for the estimate of `snap` (its params, estimated columns and covariance).
  PoseProposal propose(const CalibrationSnapshot& snap) const;

  const CandidateSet& candidates() const { return candidates_; }
  // Where the tracker was taken to be, in the robot's base frame (the registration's tracker frame origin).
  const Eigen::Vector3d& trackerInBase_m() const { return tracker_in_base_m_; }

 private:
  const CellRobot* robot_;
  PoseRequestSettings settings_;
  Eigen::Vector3d tracker_in_base_m_;
  CandidateSet candidates_;
};

// The candidates' seed of robot number `index` of the cell file.
inline std::uint64_t poseRequestSeed(int index) { return 0x9e3779b97f4a7c15ULL + static_cast<std::uint64_t>(index); }

// "the engine proposes 10 of 400 candidates (312 measurable: 60 out of range, ...)" for a log line.
std::string poseRequesterText(const PoseRequester& r, const PoseRequestSettings& s);

}  // namespace cellcal
