#include "cellcal/core/identification/observation.hpp"

#include <numeric>

namespace cellcal {

int whitenedResidual(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params,
                     const Observation& obs, Eigen::Ref<Eigen::VectorXd> r, Eigen::MatrixXd* J) {
  const Pose& model_pose = forwardKinematics(model, data, params, obs.q_rad);
  const Eigen::Matrix<double, 6, 1> e = poseError(obs.measured_in_tracker, model_pose);
  const int rows = obs.rows();
  const double wp = 1.0 / obs.sigma_position_m;
  const double wo = 1.0 / obs.sigma_orientation_rad;
  r.head<3>() = wp * e.head<3>();
  if (rows == 6) r.segment<3>(3) = wo * e.tail<3>();
  if (J) {
    J->resize(6, model.numParams());
    computePoseJacobian(model, data, *J);
    J->topRows<3>() *= wp;
    J->bottomRows<3>() *= wo;
    if (rows == 3) J->conservativeResize(3, Eigen::NoChange);
  }
  return rows;
}

int totalRows(const std::vector<Observation>& obs) {
  int m = 0;
  for (const auto& o : obs) m += o.rows();
  return m;
}

void stackResiduals(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                    Eigen::VectorXd& r, Eigen::MatrixXd* J) {
  KinematicsData data(model);
  const int m = totalRows(obs);
  r.resize(m);
  if (J) J->resize(m, model.numParams());
  Eigen::MatrixXd Ji;
  Eigen::Matrix<double, 6, 1> ri;
  int row = 0;
  for (const auto& o : obs) {
    const int k = whitenedResidual(model, data, params, o, ri, J ? &Ji : nullptr);
    r.segment(row, k) = ri.head(k);
    if (J) J->middleRows(row, k) = Ji.topRows(k);
    row += k;
  }
}

std::vector<double> positionErrors(const RobotModel& model, const Eigen::VectorXd& params,
                                   const std::vector<Observation>& obs) {
  KinematicsData data(model);
  std::vector<double> out;
  out.reserve(obs.size());
  for (const auto& o : obs)
    out.push_back((o.measured_in_tracker.translation() -
                   forwardKinematics(model, data, params, o.q_rad).translation())
                      .norm());
  return out;
}

double mean(const std::vector<double>& v) {
  return v.empty() ? 0.0 : std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
}

}  // namespace cellcal
