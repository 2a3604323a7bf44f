#include "cellcal/core/engine/work_configurations.hpp"

#include <algorithm>
#include <limits>

namespace cellcal {

namespace {

double distance(const Eigen::VectorXd& a, const Eigen::VectorXd& b) { return (a - b).norm(); }

}  // namespace

std::optional<std::size_t> WorkConfigurations::offer(const Eigen::VectorXd& q_rad) {
  if (!q_.empty() && q_.front().size() != q_rad.size()) q_.clear();  // another robot's joints: start over
  double nearest = std::numeric_limits<double>::infinity();
  for (const auto& q : q_) {
    if ((q - q_rad).cwiseAbs().maxCoeff() <= kSameRad) return std::nullopt;
    nearest = std::min(nearest, distance(q, q_rad));
  }
  if (q_.size() < kKept) {
    q_.push_back(q_rad);
    return q_.size() - 1;
  }
  // The closest pair, and of its two the one nearer to the rest of the set (the one the set misses less).
  std::size_t a = 0, b = 1;
  double closest = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < q_.size(); ++i)
    for (std::size_t j = i + 1; j < q_.size(); ++j)
      if (const double d = distance(q_[i], q_[j]); d < closest) {
        closest = d;
        a = i;
        b = j;
      }
  if (nearest <= closest) return std::nullopt;
  auto toRest = [&](std::size_t k, std::size_t partner) {
    double d = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < q_.size(); ++i)
      if (i != k && i != partner) d = std::min(d, distance(q_[i], q_[k]));
    return d;
  };
  const std::size_t replaced = toRest(a, b) <= toRest(b, a) ? a : b;
  q_[replaced] = q_rad;
  return replaced;
}

void WorkConfigurations::restore(const std::vector<Eigen::VectorXd>& q_rad) {
  q_.assign(q_rad.begin(), q_rad.begin() + static_cast<long>(std::min(q_rad.size(), kKept)));
}

}  // namespace cellcal
