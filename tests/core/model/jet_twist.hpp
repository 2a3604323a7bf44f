// The first-order motion a one-dimensional ceres::Jet carries through the templated chain: the translation's
// derivative and the rotation's, as the twist the pose Jacobian's column holds (tracker frame).
#pragma once

#include <ceres/jet.h>

#include <Eigen/Core>

#include "cellcal/core/model/kinematics.hpp"

namespace cellcal::test {

struct JetTwist {
  Eigen::Vector3d translation, rotation;
  Eigen::Matrix3d omega_hat;  // dR R^T: skew-symmetric when the derivative is a rotation's
};

inline JetTwist jetTwist(const PoseT<ceres::Jet<double, 1>>& X) {
  JetTwist t;
  Eigen::Matrix3d R, dR;
  for (int r = 0; r < 3; ++r) {
    t.translation[r] = X.p[r].v[0];
    for (int c = 0; c < 3; ++c) {
      R(r, c) = X.R(r, c).a;
      dR(r, c) = X.R(r, c).v[0];
    }
  }
  t.omega_hat = dR * R.transpose();
  t.rotation = Eigen::Vector3d(t.omega_hat(2, 1), t.omega_hat(0, 2), t.omega_hat(1, 0));
  return t;
}

}  // namespace cellcal::test
