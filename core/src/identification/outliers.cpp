#include "cellcal/core/identification/outliers.hpp"

#include <algorithm>
#include <cmath>

#include "cellcal/core/identification/statistics.hpp"

namespace cellcal {

bool OutlierOptions::IsValid(std::string* error) const {
  if (!(threshold > 1) || max_rounds < 1) {
    if (error) *error = "outliers: threshold must be > 1 (robust sigmas) and max_rounds >= 1";
    return false;
  }
  return true;
}

bool OutlierScreen::flagged(int row) const { return std::binary_search(rows.begin(), rows.end(), row); }

namespace {
// Per-axis sigma from squared norms of 3-vectors: sqrt(median / median of chi-square with 3 dof).
double robustSigma(std::vector<double> squared) {
  if (squared.empty()) return 0;
  static const double chi2_3_median = chiSquareQuantileUpper(0.5, 3);
  const auto mid = squared.begin() + static_cast<std::ptrdiff_t>(squared.size() / 2);
  std::nth_element(squared.begin(), mid, squared.end());
  return std::sqrt(*mid / chi2_3_median);
}
}  // namespace

OutlierScreen screenOutliers(const std::vector<Eigen::Vector3d>& position_residuals,
                             const std::vector<double>& orientation_residuals, const OutlierOptions& options) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument(err);
  OutlierScreen s;
  const size_t n = position_residuals.size();
  std::vector<double> p2, o2;
  for (const auto& e : position_residuals) p2.push_back(e.squaredNorm());
  for (double o : orientation_residuals)
    if (std::isfinite(o)) o2.push_back(o * o);
  s.sigma_position_m = robustSigma(p2);
  s.sigma_orientation_rad = robustSigma(o2);
  s.z.assign(n, 0.0);
  for (size_t i = 0; i < n; ++i) {
    double z = s.sigma_position_m > 0 ? position_residuals[i].norm() / s.sigma_position_m : 0.0;
    if (options.screen_orientation && i < orientation_residuals.size() && std::isfinite(orientation_residuals[i]) &&
        s.sigma_orientation_rad > 0)
      z = std::max(z, orientation_residuals[i] / s.sigma_orientation_rad);
    s.z[i] = z;
    if (options.enabled && z > options.threshold) s.rows.push_back(static_cast<int>(i));
  }
  return s;
}

std::vector<int> keptRows(int n, const std::vector<int>& flagged) {
  std::vector<int> out;
  for (int i = 0; i < n; ++i)
    if (!std::binary_search(flagged.begin(), flagged.end(), i)) out.push_back(i);
  return out;
}

}  // namespace cellcal
