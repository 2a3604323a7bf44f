#include "cellcal/core/statistics.hpp"

#include <cmath>
#include <stdexcept>

namespace cellcal {

// With h = x/2: even dof 2m: Q = e^-h sum_{i<m} h^i / i!;
// odd dof 2m+1: Q = erfc(sqrt h) + e^-h sum_{i=1..m} h^(i-1/2) / Gamma(i+1/2).
double chiSquareSurvival(double x, int dof) {
  if (dof < 1) throw std::invalid_argument("chiSquareSurvival: dof must be >= 1");
  if (!(x > 0)) return 1.0;
  const double h = 0.5 * x;
  double sum = 0;
  if (dof % 2 == 0) {
    double term = 1;  // h^i / i!
    for (int i = 0; i < dof / 2; ++i) {
      if (i > 0) term *= h / i;
      sum += term;
    }
    return std::exp(-h) * sum;
  }
  double term = std::sqrt(h) / std::tgamma(1.5);  // h^(1/2) / Gamma(3/2)
  for (int i = 1; i <= dof / 2; ++i) {
    if (i > 1) term *= h / (i - 0.5);
    sum += term;
  }
  return std::erfc(std::sqrt(h)) + std::exp(-h) * sum;
}

double chiSquareQuantileUpper(double p, int dof) {
  if (!(p > 0 && p < 1)) throw std::invalid_argument("chiSquareQuantileUpper: p must be in (0, 1)");
  double lo = 0, hi = 1;
  while (chiSquareSurvival(hi, dof) > p) hi *= 2;
  for (int k = 0; k < 200 && hi - lo > 1e-12 * hi; ++k) {
    const double mid = 0.5 * (lo + hi);
    (chiSquareSurvival(mid, dof) > p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace cellcal
