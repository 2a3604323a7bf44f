// Small SE(3)/SO(3) helpers shared by the whole library. SI units throughout (metres, radians).
#pragma once

#include <Eigen/Geometry>

namespace cellcal {

using Pose = Eigen::Isometry3d;

// T = Trans(x, y, z) * Rz(yaw) * Ry(pitch) * Rx(roll): the convention of base_in_tracker and tool_in_flange.
Pose poseFromXyzRpy(double x_m, double y_m, double z_m, double roll_rad, double pitch_rad, double yaw_rad);

// Rotation vector (axis * angle, |angle| <= pi) of R. Accurate for tiny angles.
Eigen::Vector3d logSO3(const Eigen::Matrix3d& R);

// exp of a rotation vector.
Eigen::Matrix3d expSO3(const Eigen::Vector3d& w_rad);

// 6-vector pose error of `measured` relative to `model`, both in the same frame:
// [p_measured - p_model ; log(R_measured * R_model^T)]  (metres, radians; orientation error in the common frame).
Eigen::Matrix<double, 6, 1> poseError(const Pose& measured, const Pose& model);

constexpr double kPi = 3.14159265358979323846;
constexpr double degToRad(double deg) { return deg * kPi / 180.0; }
constexpr double radToDeg(double rad) { return rad * 180.0 / kPi; }

}  // namespace cellcal
