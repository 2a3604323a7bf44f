// BeyondRange (prediction.hpp): a joint's error beyond the range of a model's data. Apart from extensionTransfer,
// which measures it, so that the robot file's parser (and its fuzz target) reaches it without the solvers.
#include <algorithm>
#include <cmath>
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
