#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

KinematicsData::KinematicsData(const RobotModel& model)
    : axis(model.numParams()), origin(model.numParams()), is_rotation(model.numParams(), false) {}

const Pose& forwardKinematics(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params,
                              const Eigen::VectorXd& q_rad) {
  PoseT<double> X;
  detail::walkChain<double>(model, params.data(), q_rad.data(), [&](int i, bool rot, int axis, double v) {
    // The axis of a motion about/along its own local axis is the same before and after it.
    if (i >= 0) {
      data.axis[i] = X.R.col(axis);
      data.origin[i] = X.p;
      data.is_rotation[i] = rot;
    }
    if (rot)
      detail::rotateLocal(X, axis, v);
    else
      detail::translateLocal(X, axis, v);
  });
  data.tool_in_tracker.linear() = X.R;
  data.tool_in_tracker.translation() = X.p;
  return data.tool_in_tracker;
}

Pose forwardKinematics(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad) {
  KinematicsData data(model);
  return forwardKinematics(model, data, params, q_rad);
}

void computePoseJacobian(const RobotModel& model, const KinematicsData& data, Eigen::Ref<Eigen::MatrixXd> J) {
  const Eigen::Vector3d p = data.tool_in_tracker.translation();
  for (int i = 0; i < model.numParams(); ++i) {
    if (data.is_rotation[i]) {
      J.col(i).head<3>() = data.axis[i].cross(p - data.origin[i]);
      J.col(i).tail<3>() = data.axis[i];
    } else {
      J.col(i).head<3>() = data.axis[i];
      J.col(i).tail<3>().setZero();
    }
  }
}

void computeJointJacobian(const RobotModel& model, const KinematicsData& data, Eigen::Ref<Eigen::MatrixXd> J) {
  const Eigen::Vector3d p = data.tool_in_tracker.translation();
  for (int j = 0; j < model.numJoints(); ++j) {
    const int i = model.jointParam(j, JointParam::kThetaOffset);  // theta = q + offset: same column
    J.col(j).head<3>() = data.axis[i].cross(p - data.origin[i]);
    J.col(j).tail<3>() = data.axis[i];
  }
}

}  // namespace cellcal
