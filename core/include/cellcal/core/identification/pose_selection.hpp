// Choosing which poses to measure: greedy D-optimal selection given the current estimate's covariance.
//
// A continuous calibration can ask the robot for the poses that teach it most. Starting from the covariance P over
// the estimated parameters, each step adds the candidate configuration i with the largest gain, then updates P as if
// it had been measured (A_i: whitened pose Jacobian of candidate i over `estimated`,
// dP_i = P A_i^T (I + A_i P A_i^T)^-1 A_i P):
//   kDOptimal:            log det(I + A_i P A_i^T)        the largest reduction of the posterior volume
//   kPredictionVariance:  trace(M dP_i), M = sum_j B_j^T B_j over the candidates' position Jacobians B_j (metres):
//                         the largest reduction of the mean predicted position variance where the robot works.
// Only joint configurations and the measurement model are used, never measured values.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

enum class SelectionCriterion { kDOptimal, kPredictionVariance };

struct PoseSelectionOptions {
  SelectionCriterion criterion = SelectionCriterion::kPredictionVariance;
  MeasurementKind kind = MeasurementKind::kPose6D;
  double sigma_position_m = 15e-6;       // whitening used for selection (tracker spec at a typical distance)
  double sigma_orientation_rad = 8.7e-5;
};

// The predicted position variance over the candidates (the working volume), mean over them of trace(B_j P B_j^T)
// (m^2: x, y and z summed), from `covariance` and after measuring the chosen ones.
struct SelectionFigures {
  double mean_position_variance_before_m2 = 0, mean_position_variance_after_m2 = 0;
};

// Returns the indices of `count` candidates in the order chosen (count is clipped to the number of candidates).
std::vector<int> selectInformativePoses(const RobotModel& model, const Eigen::VectorXd& params,
                                        const std::vector<int>& estimated, const Eigen::MatrixXd& covariance,
                                        const std::vector<Eigen::VectorXd>& candidates_q_rad, int count,
                                        const PoseSelectionOptions& options = {}, SelectionFigures* figures = nullptr);

}  // namespace cellcal
