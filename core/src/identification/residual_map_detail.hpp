// What residual_map.cpp and residual_map_fit.cpp share (not installed).
#pragma once

#include <Eigen/Core>
#include <vector>

namespace cellcal::residual_map_detail {

// The squared-exponential kernel matrix of the rows of Qs (configurations already divided by the length scales),
// s2 its signal variance, plus n2 on the diagonal.
Eigen::MatrixXd kernel(const Eigen::MatrixXd& Qs, double s2, double n2);
// The configurations `rows` of q, each divided by the length scales l, as the rows of a matrix.
Eigen::MatrixXd scaled(const std::vector<Eigen::VectorXd>& q, const std::vector<int>& rows, const Eigen::VectorXd& l);

}  // namespace cellcal::residual_map_detail
