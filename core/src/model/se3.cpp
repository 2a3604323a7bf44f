#include "cellcal/core/model/se3.hpp"

#include <cmath>

namespace cellcal {

Pose poseFromXyzRpy(double x_m, double y_m, double z_m, double roll_rad, double pitch_rad, double yaw_rad) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(x_m, y_m, z_m);
  T.linear() = (Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch_rad, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return T;
}

Eigen::Vector3d logSO3(const Eigen::Matrix3d& R) {
  Eigen::Quaterniond q(R);
  q.normalize();
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  const Eigen::Vector3d v = q.vec();
  const double n = v.norm();
  if (n < 1e-12) return 2.0 * v;  // first order: angle = 2|v|
  return (2.0 * std::atan2(n, q.w()) / n) * v;
}

Eigen::Matrix3d expSO3(const Eigen::Vector3d& w_rad) {
  const double angle = w_rad.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w_rad / angle).toRotationMatrix();
}

Eigen::Matrix<double, 6, 1> poseError(const Pose& measured, const Pose& model) {
  Eigen::Matrix<double, 6, 1> e;
  e.head<3>() = measured.translation() - model.translation();
  e.tail<3>() = logSO3(measured.linear() * model.linear().transpose());
  return e;
}

}  // namespace cellcal
