// Plain references the tests check clever solutions against (never used by the code under test).
#pragma once

#include <Eigen/Core>
#include <Eigen/SVD>
#include <cmath>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal::test {

// Unreduced least squares: Gauss-Newton over every canonical parameter at once (no selection of an identifiable
// set), each step the minimum-norm solution in column-scaled units (SVD, singular values below 1e-9 of the largest
// treated as zero), with step halving. Directions the data do not determine are left where they are; every direction
// they do determine is fitted, however weakly. Returns the full parameter vector.
inline Eigen::VectorXd referenceFit(const RobotModel& model, Eigen::VectorXd params, const std::vector<Observation>& obs,
                                    int max_iterations = 100) {
  const std::vector<int> cols = model.canonicalParams();
  const auto k = static_cast<Eigen::Index>(cols.size());
  Eigen::VectorXd r, r_trial;
  Eigen::MatrixXd J;
  stackResiduals(model, params, obs, r, &J);
  double cost = r.squaredNorm();
  for (int it = 0; it < max_iterations; ++it) {
    Eigen::MatrixXd A(J.rows(), k);
    Eigen::VectorXd scale(k);
    for (Eigen::Index c = 0; c < k; ++c) {
      const double n = J.col(cols[c]).norm();
      scale[c] = n > 0 ? 1.0 / n : 0.0;
      A.col(c) = J.col(cols[c]) * scale[c];
    }
    Eigen::BDCSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeThinU | Eigen::ComputeThinV);
    const Eigen::VectorXd& s = svd.singularValues();
    Eigen::VectorXd y = Eigen::VectorXd::Zero(k);
    const Eigen::VectorXd ub = svd.matrixU().transpose() * r;
    for (Eigen::Index i = 0; i < s.size(); ++i)
      if (s[i] > 1e-9 * s[0]) y += svd.matrixV().col(i) * (ub[i] / s[i]);
    const Eigen::VectorXd step = scale.asDiagonal() * y;
    double t = 1.0;
    Eigen::VectorXd trial;
    bool better = false;
    for (int h = 0; h < 30; ++h, t *= 0.5) {
      trial = params;
      for (Eigen::Index c = 0; c < k; ++c) trial[cols[c]] += t * step[c];
      stackResiduals(model, trial, obs, r_trial, nullptr);
      if (r_trial.squaredNorm() < cost) {
        better = true;
        break;
      }
    }
    if (!better) break;
    params = trial;
    const double previous = cost;
    stackResiduals(model, params, obs, r, &J);
    cost = r.squaredNorm();
    if ((t * y).norm() < 1e-10 || previous - cost < 1e-12 * previous) break;
  }
  return params;
}

}  // namespace cellcal::test
