// One tracker measurement of the tool target at one joint configuration, and its whitened residual.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/measurement_kind.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

struct Observation {
  Eigen::VectorXd q_rad;                        // joint angles reported by the robot
  Pose measured_in_tracker = Pose::Identity();  // target pose measured by the tracker (rotation unused for 3D)
  MeasurementKind kind = MeasurementKind::kPose6D;
  double sigma_position_m = 10e-6;              // 1-sigma per axis
  double sigma_orientation_rad = 8.7e-5;        // 1-sigma per axis
  int rows() const { return kind == MeasurementKind::kPose6D ? 6 : 3; }
};

// Whitened residual and Jacobian of one observation at `params`:
//   r = W (measured - model(params)),  J = W d model / d params   (rows() x numParams())
// with W = diag(1/sigma). Rows: position x, y, z [, orientation x, y, z]. A Gauss-Newton step solves J dx = r.
// `J` may be null. Returns the number of rows written (3 or 6).
int whitenedResidual(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params,
                     const Observation& obs, Eigen::Ref<Eigen::VectorXd> r, Eigen::MatrixXd* J);

// Stacked whitened residuals/Jacobian of many observations; J has all numParams() columns.
void stackResiduals(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                    Eigen::VectorXd& r, Eigen::MatrixXd* J);
int totalRows(const std::vector<Observation>& obs);

// Position error |p_measured - p_model| (m) for each observation.
std::vector<double> positionErrors(const RobotModel& model, const Eigen::VectorXd& params,
                                   const std::vector<Observation>& obs);
double mean(const std::vector<double>& v);

}  // namespace cellcal
