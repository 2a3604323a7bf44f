#include "cellcal/core/identification/pose_selection.hpp"

#include <Eigen/Cholesky>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

std::vector<int> selectInformativePoses(const RobotModel& model, const Eigen::VectorXd& params,
                                        const std::vector<int>& estimated, const Eigen::MatrixXd& covariance,
                                        const std::vector<Eigen::VectorXd>& candidates_q_rad, int count,
                                        const PoseSelectionOptions& options, SelectionFigures* figures) {
  const auto m = static_cast<Eigen::Index>(estimated.size());
  if (covariance.rows() != m || covariance.cols() != m)
    throw std::invalid_argument("selectInformativePoses: covariance must be |estimated| x |estimated|");
  const int rows = options.kind == MeasurementKind::kPose6D ? 6 : 3;
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numParams());
  std::vector<Eigen::MatrixXd> A;
  A.reserve(candidates_q_rad.size());
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(m, m);  // sum of B^T B over the candidates' position Jacobians
  for (const auto& q : candidates_q_rad) {
    forwardKinematics(model, data, params, q);
    computePoseJacobian(model, data, J);
    Eigen::MatrixXd a(rows, m);
    for (Eigen::Index k = 0; k < m; ++k) {
      a.col(k).head<3>() = J.col(estimated[k]).head<3>() / options.sigma_position_m;
      if (rows == 6) a.col(k).tail<3>() = J.col(estimated[k]).tail<3>() / options.sigma_orientation_rad;
    }
    A.push_back(std::move(a));
    Eigen::MatrixXd B(3, m);
    for (Eigen::Index k = 0; k < m; ++k) B.col(k) = J.col(estimated[k]).head<3>();
    M.noalias() += B.transpose() * B;
  }
  const bool d_optimal = options.criterion == SelectionCriterion::kDOptimal;
  Eigen::MatrixXd P = covariance;
  const double per_candidate = A.empty() ? 0.0 : 1.0 / static_cast<double>(A.size());
  if (figures) figures->mean_position_variance_before_m2 = (M * P).trace() * per_candidate;
  std::vector<bool> used(A.size(), false);
  std::vector<int> chosen;
  const int n = std::min<int>(count, static_cast<int>(A.size()));
  for (int step = 0; step < n; ++step) {
    int best = -1;
    double best_gain = -std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < A.size(); ++i) {
      if (used[i]) continue;
      const Eigen::MatrixXd AP = A[i] * P;
      Eigen::MatrixXd S = AP * A[i].transpose();
      S.diagonal().array() += 1.0;
      const Eigen::LLT<Eigen::MatrixXd> llt(S);
      const double gain = d_optimal ? 2.0 * llt.matrixL().toDenseMatrix().diagonal().array().log().sum()
                                    : (llt.solve(AP * M * AP.transpose())).trace();
      if (gain > best_gain) {
        best_gain = gain;
        best = static_cast<int>(i);
      }
    }
    used[best] = true;
    chosen.push_back(best);
    // P <- P - P A^T (I + A P A^T)^-1 A P
    const Eigen::MatrixXd PA = P * A[best].transpose();
    Eigen::MatrixXd S = A[best] * PA;
    S.diagonal().array() += 1.0;
    P -= PA * S.llt().solve(PA.transpose());
  }
  if (figures) figures->mean_position_variance_after_m2 = (M * P).trace() * per_candidate;
  return chosen;
}

}  // namespace cellcal
