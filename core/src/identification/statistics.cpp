#include "cellcal/core/identification/statistics.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
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

namespace {
// The continued fraction of I_x(a, b) (modified Lentz): 1 / (1 + d1 / (1 + d2 / (1 + ...))), with
// d(2m+1) = -(a+m)(a+b+m) x / ((a+2m)(a+2m+1)) and d(2m) = m(b-m) x / ((a+2m-1)(a+2m)). Converges fast for
// x < (a+1)/(a+b+2).
double betaContinuedFraction(double a, double b, double x) {
  constexpr double tiny = 1e-300;
  double c = 1.0, d = 1.0 - (a + b) * x / (a + 1.0);
  d = 1.0 / (std::abs(d) < tiny ? tiny : d);
  double f = d;
  for (int m = 1; m <= 500; ++m) {
    for (int odd = 0; odd < 2; ++odd) {
      const double num = odd ? -(a + m) * (a + b + m) * x / ((a + 2.0 * m) * (a + 2.0 * m + 1.0))
                             : m * (b - m) * x / ((a + 2.0 * m - 1.0) * (a + 2.0 * m));
      d = 1.0 + num * d;
      d = 1.0 / (std::abs(d) < tiny ? tiny : d);
      c = 1.0 + num / c;
      if (std::abs(c) < tiny) c = tiny;
      f *= c * d;
      if (odd && std::abs(c * d - 1.0) < 1e-15) return f;
    }
  }
  return f;
}
}  // namespace

double regularizedIncompleteBeta(double a, double b, double x) {
  if (!(a > 0 && b > 0) || !(x >= 0 && x <= 1)) throw std::invalid_argument("regularizedIncompleteBeta: bad arguments");
  if (x == 0 || x == 1) return x;
  const double front = std::exp(std::lgamma(a + b) - std::lgamma(a) - std::lgamma(b) + a * std::log(x) + b * std::log1p(-x));
  if (x < (a + 1.0) / (a + b + 2.0)) return front * betaContinuedFraction(a, b, x) / a;
  return 1.0 - front * betaContinuedFraction(b, a, 1.0 - x) / b;
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

double meanZ(const std::vector<double>& d) {
  const auto n = static_cast<double>(d.size());
  double mean = 0, sq = 0;
  for (double x : d) mean += x, sq += x * x;
  mean /= n;
  const double var = n > 1 ? std::max(0.0, (sq - n * mean * mean) / (n - 1)) : 0.0;
  return var > 0 ? mean / std::sqrt(var / n) : (mean > 0 ? INFINITY : 0.0);
}

double fSurvival(double f, double d1, double d2) {
  if (!(d1 > 0 && d2 > 0)) throw std::invalid_argument("fSurvival: degrees of freedom must be > 0");
  if (!(f > 0)) return 1.0;
  return regularizedIncompleteBeta(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f));
}

Eigen::MatrixXd conditionalGaussianCovariance(const Eigen::MatrixXd& P, const std::vector<int>& kept) {
  const auto n = P.rows();
  std::vector<bool> is_kept(static_cast<size_t>(n), false);
  for (int k : kept) {
    if (k < 0 || k >= n || is_kept[static_cast<size_t>(k)])
      throw std::invalid_argument("conditionalGaussianCovariance: entry " + std::to_string(k) + " repeated or outside");
    is_kept[static_cast<size_t>(k)] = true;
  }
  std::vector<int> held;
  for (int j = 0; j < n; ++j)
    if (!is_kept[static_cast<size_t>(j)]) held.push_back(j);
  Eigen::MatrixXd Pkk = P(kept, kept);
  if (held.empty()) return Pkk;
  const Eigen::MatrixXd Pkh = P(kept, held);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(P(held, held));
  const Eigen::VectorXd ev = eig.eigenvalues();
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(ev.size());
  for (Eigen::Index i = 0; i < ev.size(); ++i)
    if (ev[i] > 1e-12 * ev.maxCoeff()) inv[i] = 1.0 / ev[i];
  const Eigen::MatrixXd W = Pkh * eig.eigenvectors();
  Pkk -= W * inv.asDiagonal() * W.transpose();
  return 0.5 * (Pkk + Pkk.transpose());
}

}  // namespace cellcal
