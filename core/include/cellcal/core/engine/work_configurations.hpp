// Where the cell works: a bounded, spread set of the joint configurations the engine has used. The engine's health
// judges the estimate's predicted error over these (health.hpp), not over the whole workspace: a cell whose program
// keeps one tool orientation or one region pins the model there and nowhere else, and each target is then gated by
// its own predicted error (compensation.hpp). The set keeps every used configuration until it holds kKept; after that a
// new one replaces a member of the closest pair when it lies farther from the set than that pair lies apart, so the
// set keeps the extremes of where the robot was measured (the worst-pinned ones among them). A configuration within
// kSameRad (every joint) of a member is already there.
// Deterministic in the order of the configurations offered (the same in validate, after a restart: EngineState saves
// the set).
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <optional>
#include <vector>

namespace cellcal {

class WorkConfigurations {
 public:
  static constexpr std::size_t kKept = 16;
  static constexpr double kSameRad = 1e-3;

  // A used pose's joints; when the set changed, the index it now has (appended at the end, or the member it replaced).
  std::optional<std::size_t> offer(const Eigen::VectorXd& q_rad);
  const std::vector<Eigen::VectorXd>& configurations() const { return q_; }
  bool empty() const { return q_.empty(); }
  // As saved (at most kKept are taken, in order).
  void restore(const std::vector<Eigen::VectorXd>& q_rad);

 private:
  std::vector<Eigen::VectorXd> q_;
};

}  // namespace cellcal
