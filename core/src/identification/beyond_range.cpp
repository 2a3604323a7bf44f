// BeyondRange (prediction.hpp): a joint's error beyond the range of a model's data. Apart from extensionTransfer,
// which measures it, so that the robot file's parser (and its fuzz target) reaches it without the solvers.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "cellcal/core/identification/prediction.hpp"

namespace cellcal {

double BeyondRange::beyondRad(double q_rad) const {
  return q_rad < lower_rad ? lower_rad - q_rad : q_rad > upper_rad ? q_rad - upper_rad : 0.0;
}

double BeyondRange::sigmaRad(double q_rad) const {
  double d = beyondRad(q_rad);
  if (d <= 0 || sigma_at_1_rad <= 0) return 0.0;
  if (checked_rad > 0) d = std::min(d, checked_rad);
  return sigma_at_1_rad * std::pow(d, growth);
}

bool BeyondRange::judged(double q_rad) const { return beyondRad(q_rad) <= checked_rad; }

const BeyondRange* firstUnjudged(const std::vector<BeyondRange>& ranges, const Eigen::VectorXd& q_rad) {
  for (const BeyondRange& b : ranges)
    if (b.joint >= 0 && b.joint < q_rad.size() && !b.judged(q_rad[b.joint])) return &b;
  return nullptr;
}

std::string unjudgedText(const BeyondRange& b, double q_rad) {
  char t[300];
  std::snprintf(t, sizeof t, "joint %d at %.1f deg lies %.1f deg beyond [%.1f, %.1f] deg, the range its model extensions "
                "were fitted on; ", b.joint + 1, q_rad * 180 / kPi, b.beyondRad(q_rad) * 180 / kPi,
                b.lower_rad * 180 / kPi, b.upper_rad * 180 / kPi);
  char u[80];
  if (b.checked_rad > 0) std::snprintf(u, sizeof u, "they were judged up to %.1f deg beyond it", b.checked_rad * 180 / kPi);
  else std::snprintf(u, sizeof u, "they were not judged beyond it");
  return std::string(t) + u;
}

const char* BeyondRange::growthText() const {
  return growth == 0 ? "" : growth == 1 ? " per rad beyond" : " per rad^2 beyond";
}

bool BeyondRange::IsValid(int num_joints, std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (joint < 0 || joint >= num_joints) return fail("joint " + std::to_string(joint + 1) + " out of range");
  if (!std::isfinite(lower_rad) || !std::isfinite(upper_rad) || lower_rad > upper_rad)
    return fail("lower and upper must be finite, lower <= upper");
  if (!(sigma_at_1_rad >= 0) || !std::isfinite(sigma_at_1_rad)) return fail("sigma must be finite and >= 0");
  if (growth < 0 || growth > 2) return fail("growth must be 0, 1 or 2");
  if (!(checked_rad >= 0) || !std::isfinite(checked_rad)) return fail("checked must be finite and >= 0");
  return true;
}

}  // namespace cellcal
