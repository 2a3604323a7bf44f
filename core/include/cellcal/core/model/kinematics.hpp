// Forward kinematics and the analytic pose Jacobian with respect to every kinematic parameter.
//
// Pinocchio-style: `RobotModel` is immutable, `KinematicsData` is a reusable workspace,
// algorithms are free functions. No allocation after the workspace is built.
//
// Jacobian contract (computePoseJacobian):
//   J is 6 x model.numParams(), column i = d(pose)/d(params[i]) as a spatial velocity in the tracker frame:
//   rows 0-2: d(p_tool)/dparam (m/unit), rows 3-5: omega with dR = [omega]x R (rad/unit).
//   For a small parameter step dx: p(x+dx) ~ p + J.top * dx, R(x+dx) ~ exp(J.bottom * dx) R.
//   This is the minimal 6-row equivalent of the paper's [H_p; H_n; H_o; H_a] form.
//   computeJointJacobian gives the same for the joint angles (6 x n).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

// Workspace: the world axis and origin of every elementary motion of the last FK call.
struct KinematicsData {
  explicit KinematicsData(const RobotModel& model);
  std::vector<Eigen::Vector3d> axis;    // per parameter
  std::vector<Eigen::Vector3d> origin;  // per parameter (only used for rotations)
  std::vector<bool> is_rotation;        // per parameter
  Pose tool_in_tracker = Pose::Identity();
};

// Tool pose in the tracker frame; fills `data` for the Jacobians.
const Pose& forwardKinematics(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params,
                              const Eigen::VectorXd& q_rad);
// Convenience: allocates a workspace.
Pose forwardKinematics(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad);

// Requires a preceding forwardKinematics(model, data, ...). J must be 6 x numParams().
void computePoseJacobian(const RobotModel& model, const KinematicsData& data, Eigen::Ref<Eigen::MatrixXd> J);
// Requires a preceding forwardKinematics. J must be 6 x numJoints().
void computeJointJacobian(const RobotModel& model, const KinematicsData& data, Eigen::Ref<Eigen::MatrixXd> J);

// ---- Scalar-templated forward kinematics (used with ceres::Jet in tests; same chain as above). ----
template <typename T>
struct PoseT {
  Eigen::Matrix<T, 3, 3> R = Eigen::Matrix<T, 3, 3>::Identity();
  Eigen::Matrix<T, 3, 1> p = Eigen::Matrix<T, 3, 1>::Zero();
};

namespace detail {
// X <- X * Rot(axis, angle)
template <typename T>
void rotateLocal(PoseT<T>& X, int axis, const T& angle) {
  using std::cos;
  using std::sin;
  const T c = cos(angle), s = sin(angle);
  const int i = (axis + 1) % 3, j = (axis + 2) % 3;
  const Eigen::Matrix<T, 3, 1> ci = X.R.col(i), cj = X.R.col(j);
  X.R.col(i) = c * ci + s * cj;
  X.R.col(j) = c * cj - s * ci;
}
// X <- X * Trans(axis, d)
template <typename T>
void translateLocal(PoseT<T>& X, int axis, const T& d) {
  X.p += X.R.col(axis) * d;
}
// The index walkChain gives the fixed motions of the mount and the flange (not parameters), and of their last.
constexpr int kMountMotion = -1, kMountEnd = -2, kFlangeMotion = -3, kFlangeEnd = -4;
// Visits the chain as elementary motions: f(param_index, is_rotation, local_axis, value). The mount's and the flange's
// motions (when the model has them) come with the negative indices above.
template <typename T, typename F>
void walkChain(const RobotModel& model, const T* params, const double* q_rad, F&& f) {
  const int n = model.numJoints();
  auto frame = [&](int first) {
    f(first + 0, false, 0, params[first + 0]);
    f(first + 1, false, 1, params[first + 1]);
    f(first + 2, false, 2, params[first + 2]);
    f(first + 5, true, 2, params[first + 5]);  // yaw
    f(first + 4, true, 1, params[first + 4]);  // pitch
    f(first + 3, true, 0, params[first + 3]);  // roll
  };
  auto fixed = [&](const Eigen::Matrix<double, 6, 1>& v, int motion, int end) {
    f(motion, false, 0, T(v[0]));
    f(motion, false, 1, T(v[1]));
    f(motion, false, 2, T(v[2]));
    f(motion, true, 2, T(v[5]));
    f(motion, true, 1, T(v[4]));
    f(end, true, 0, T(v[3]));
  };
  frame(5 * n);
  if (model.hasMount()) fixed(model.mount, kMountMotion, kMountEnd);
  for (int j = 0; j < n; ++j) {
    const int b = 5 * j;
    f(b + 0, true, 2, params[b + 0] + T(q_rad[j]));
    f(b + 1, false, 2, params[b + 1]);
    f(b + 2, false, 0, params[b + 2]);
    f(b + 3, true, 0, params[b + 3]);
    f(b + 4, true, 1, params[b + 4]);
  }
  if (model.hasFlange()) fixed(model.flange, kFlangeMotion, kFlangeEnd);
  frame(5 * n + 6);
}
}  // namespace detail

template <typename T>
PoseT<T> forwardKinematicsT(const RobotModel& model, const T* params, const double* q_rad) {
  PoseT<T> X;
  detail::walkChain<T>(model, params, q_rad, [&](int, bool rot, int axis, const T& v) {
    if (rot)
      detail::rotateLocal(X, axis, v);
    else
      detail::translateLocal(X, axis, v);
  });
  return X;
}

}  // namespace cellcal
