#include "cellcal/core/identification/model_error.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

namespace {

// The sigma_m^2 >= 0 with mean_i e2_i / (3 (s2_i + sigma_m^2)) = 1, e2_i the squared residual norm of row i.
double varianceComponent(const std::vector<double>& e2, const std::vector<double>& s2) {
  if (e2.empty()) return 0;
  auto excess = [&](double m2) {
    double sum = 0;
    for (size_t i = 0; i < e2.size(); ++i) sum += e2[i] / (3 * (s2[i] + m2));
    return sum / static_cast<double>(e2.size()) - 1;
  };
  if (excess(0) <= 0) return 0;
  double lo = 0, hi = *std::max_element(e2.begin(), e2.end()) / 3;  // every term <= 1 there
  for (int k = 0; k < 200 && hi - lo > 1e-12 * hi; ++k) {
    const double mid = 0.5 * (lo + hi);
    (excess(mid) > 0 ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace

ModelErrorSigma modelErrorSigma(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                                const std::vector<int>& skip) {
  KinematicsData data(model);
  std::vector<double> pe2, ps2, oe2, os2;
  for (size_t i = 0; i < obs.size(); ++i) {
    if (std::count(skip.begin(), skip.end(), static_cast<int>(i))) continue;
    const Observation& o = obs[i];
    const Pose p = forwardKinematics(model, data, params, o.q_rad);
    pe2.push_back((o.measured_in_tracker.translation() - p.translation()).squaredNorm());
    ps2.push_back(o.sigma_position_m * o.sigma_position_m);
    if (o.kind == MeasurementKind::kPose6D) {
      const double angle = Eigen::AngleAxisd(o.measured_in_tracker.linear() * p.linear().transpose()).angle();
      oe2.push_back(angle * angle);
      os2.push_back(o.sigma_orientation_rad * o.sigma_orientation_rad);
    }
  }
  ModelErrorSigma m;
  m.position_m = std::sqrt(varianceComponent(pe2, ps2));
  m.orientation_rad = std::sqrt(varianceComponent(oe2, os2));
  m.position_rows = static_cast<int>(pe2.size());
  m.orientation_rows = static_cast<int>(oe2.size());
  return m;
}

void addModelError(std::vector<Observation>& obs, const ModelErrorSigma& m) {
  for (auto& o : obs) {
    o.sigma_position_m = std::hypot(o.sigma_position_m, m.position_m);
    o.sigma_orientation_rad = std::hypot(o.sigma_orientation_rad, m.orientation_rad);
  }
}

}  // namespace cellcal
