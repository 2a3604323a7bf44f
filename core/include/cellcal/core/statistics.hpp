// Chi-square tail probabilities and quantiles for integer degrees of freedom (outlier gating on the normalized
// innovation squared, which is chi-square with `dof` = measurement rows when the noise model holds).
#pragma once

namespace cellcal {

// P(X > x) for X ~ chi-square(dof), dof >= 1 (closed forms for integer dof). x <= 0 gives 1.
double chiSquareSurvival(double x, int dof);
// x such that P(X > x) = p, for 0 < p < 1 (bisection on chiSquareSurvival to 1e-12 relative).
double chiSquareQuantileUpper(double p, int dof);

}  // namespace cellcal
