#include "cellcal/core/engine/outlier_gate.hpp"

#include <algorithm>
#include <vector>

namespace cellcal {

double OutlierGate::gate(int rows) const {
  double scale = 1;
  if (window_.size() >= 5) {
    std::vector<double> v(window_.begin(), window_.end());
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    scale = std::max(1.0, v[v.size() / 2]);
  }
  return nis_per_row_ * rows * scale;
}

void OutlierGate::record(double nis_per_row) {
  window_.push_back(nis_per_row);
  while (window_.size() > window_size_) window_.pop_front();
}

void OutlierGate::clear() {
  window_.clear();
  passed();
}

void OutlierGate::gatedStandStill(const Eigen::VectorXd& q_rad, std::int64_t joint_stamp_ns, bool count) {
  gated_q_ = q_rad;
  gated_joint_stamp_ns_ = joint_stamp_ns;
  if (count) ++in_a_row_;
}

void OutlierGate::clearOnceAfter(std::int64_t last_update_ns) {
  if (cleared_after_ns_ == last_update_ns) return;
  window_.clear();
  cleared_after_ns_ = last_update_ns;
}

}  // namespace cellcal
