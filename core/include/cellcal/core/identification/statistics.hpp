// Chi-square tail probabilities and quantiles for integer degrees of freedom (outlier gating on the normalized
// innovation squared, which is chi-square with `dof` = measurement rows when the noise model holds), and the F
// distribution's tail (whether a regression explains more of a residual than noise would).
#pragma once

#include <Eigen/Core>
#include <vector>

namespace cellcal {

// P(X > x) for X ~ chi-square(dof), dof >= 1 (closed forms for integer dof). x <= 0 gives 1.
double chiSquareSurvival(double x, int dof);
// x such that P(X > x) = p, for 0 < p < 1 (bisection on chiSquareSurvival to 1e-12 relative).
double chiSquareQuantileUpper(double p, int dof);

// Regularized incomplete beta function I_x(a, b), a, b > 0, 0 <= x <= 1 (continued fraction, relative error ~1e-14).
double regularizedIncompleteBeta(double a, double b, double x);
// P(X > f) for X ~ F(d1, d2), d1, d2 > 0. f <= 0 gives 1.
double fSurvival(double f, double d1, double d2);

// The sample at rank floor(p n) (clamped to the last) of v: p = 0.5 the median, 0.99 the 99th percentile. NaN when
// v is empty.
double percentile(std::vector<double> v, double p);
// The mean of `d` in standard errors of the mean (0 for fewer than two values without scatter; infinite with a
// positive mean and none): a paired difference's significance.
double meanZ(const std::vector<double>& d);

// Gaussian conditioning: the covariance of the entries `kept` of a Gaussian with covariance P (symmetric, positive
// semi-definite) given the other entries at known values: P_kk - P_kh P_hh^+ P_hk, in the order of `kept`, symmetric.
// The pseudo-inverse drops P_hh's eigenvalues below 1e-12 of its largest (held entries only their sum is pinned of).
// Throws std::invalid_argument when `kept` repeats an entry or leaves P.
Eigen::MatrixXd conditionalGaussianCovariance(const Eigen::MatrixXd& P, const std::vector<int>& kept);

}  // namespace cellcal
