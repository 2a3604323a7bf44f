#include "cellcal/core/identification/setup_change.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <limits>
#include <random>

#include "cellcal/core/identification/setups.hpp"
#include "cellcal/core/identification/statistics.hpp"

namespace cellcal {

bool SetupChangeOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* why) {
    if (error) *error = why;
    return false;
  };
  if (min_rows < 2) return fail("min_rows must be at least 2");
  if (!(false_alarm > 0 && false_alarm < 1)) return fail("false_alarm must lie in (0, 1)");
  if (!(clip_sigmas > 0)) return fail("clip_sigmas must be positive");
  return true;
}

namespace {

constexpr double kChi2OneMedian = 0.454936423119572;  // median of chi-square with 1 degree of freedom
constexpr double kRankTolerance = 1e-10;
// The warm-up shapes tried: tau from 1/40 of the file to twice its length (beyond that, the straight line).
constexpr double kWarmupFractionMin = 0.025, kWarmupFractionMax = 2.0;
// Splits scored, at the most: beyond it, every (splits / kMaxSplits)-th row, then each row beside the best one.
constexpr int kMaxSplits = 400;
// A thermometer whose reading moves less than this over the file is no drift's clock.
constexpr double kMovingTemperatureK = 0.05;

// Robust per-axis sigma of residual components (median of their squares over chi-square's): 1 when none.
double robustSigma(std::vector<double> squares) {
  if (squares.empty()) return 1.0;
  std::nth_element(squares.begin(), squares.begin() + static_cast<long>(squares.size() / 2), squares.end());
  const double s = std::sqrt(squares[squares.size() / 2] / kChi2OneMedian);
  return s > 0 ? s : 1.0;
}

// The pseudo-inverse of a symmetric positive semi-definite matrix, through its scaled eigen-decomposition (columns of
// zero norm and directions below `tolerance` of the largest eigenvalue left out), and its rank.
struct PseudoInverse {
  Eigen::MatrixXd inverse;
  int rank = 0;
};
PseudoInverse pseudoInverse(const Eigen::MatrixXd& N, double tolerance) {
  const Eigen::Index p = N.rows();
  Eigen::VectorXd d(p);
  for (Eigen::Index i = 0; i < p; ++i) d[i] = N(i, i) > 0 ? 1.0 / std::sqrt(N(i, i)) : 0.0;
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(d.asDiagonal() * N * d.asDiagonal());
  const Eigen::VectorXd& l = es.eigenvalues();
  const double floor = tolerance * std::max(l.maxCoeff(), 0.0);
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(p);
  PseudoInverse out;
  for (Eigen::Index i = 0; i < p; ++i)
    if (l[i] > floor && l[i] > 0) {
      inv[i] = 1.0 / l[i];
      ++out.rank;
    }
  out.inverse = d.asDiagonal() * es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose() * d.asDiagonal();
  return out;
}

// The warm-up shape over the row's place u in the file (0 .. 1): 0 at the start, 1 at the end, reaching 63 % of the
// way at u = tau; tau <= 0: the straight line u.
// kTemperatureShape: the row's temperature instead (0 at the file's lowest, 1 at its highest).
constexpr double kTemperatureShape = -1.0;
double shape(double u, double tau, double temperature) {
  if (tau == kTemperatureShape) return temperature;
  return tau > 0 ? std::expm1(-u / tau) / std::expm1(-1.0 / tau) : u;
}

// The rows of the scan: each observation's residual (re-whitened by the residual's robust scales, clipped) and its
// columns: the calibration's estimated ones (A), the frame columns (F), and the columns that drift (the frames and the
// joints' zeros), which times a shape over time are the drift's columns.
struct ScanRows {
  double position_scale = 1, orientation_scale = 1;
  std::vector<Eigen::VectorXd> r;
  std::vector<double> position_sigma_m;  // each row's position sigma in those units (stated x robust scale), m
  std::vector<Eigen::MatrixXd> A, F, D;
  std::vector<double> u;                 // the row's place in the file, 0 .. 1
  std::vector<double> temp;              // its temperature, 0 .. 1 over the file's range (empty: none that moves)
};

ScanRows scanRows(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                  const std::vector<Observation>& obs, const SetupChangeOptions& o, const std::vector<double>& times,
                  const std::vector<double>& temperatures) {
  const auto n = obs.size();
  std::vector<int> frames;
  for (int k = 0; k < 6; ++k) frames.push_back(model.baseParam(static_cast<FrameParam>(k)));
  for (int k = 0; k < 6; ++k) frames.push_back(model.toolParam(static_cast<FrameParam>(k)));
  std::vector<int> drifting = frames;
  for (int j = 0; j < model.numJoints(); ++j) drifting.push_back(model.jointParam(j, JointParam::kThetaOffset));
  ScanRows out;
  KinematicsData data(model);
  Eigen::MatrixXd J;
  std::vector<double> pos_sq, ori_sq;
  for (size_t i = 0; i < n; ++i) {
    Eigen::VectorXd r(obs[i].rows());
    whitenedResidual(model, data, params, obs[i], r, &J);
    Eigen::MatrixXd A(r.size(), static_cast<Eigen::Index>(estimated.size())), F(r.size(), 12),
        D(r.size(), static_cast<Eigen::Index>(drifting.size()));
    for (size_t k = 0; k < estimated.size(); ++k) A.col(static_cast<Eigen::Index>(k)) = J.col(estimated[k]);
    for (size_t k = 0; k < frames.size(); ++k) F.col(static_cast<Eigen::Index>(k)) = J.col(frames[k]);
    for (size_t k = 0; k < drifting.size(); ++k) D.col(static_cast<Eigen::Index>(k)) = J.col(drifting[k]);
    for (Eigen::Index k = 0; k < r.size(); ++k) (k < 3 ? pos_sq : ori_sq).push_back(r[k] * r[k]);
    out.r.push_back(std::move(r));
    out.A.push_back(std::move(A));
    out.F.push_back(std::move(F));
    out.D.push_back(std::move(D));
    const double span = times.empty() ? 0.0 : times.back() - times.front();
    out.u.push_back(span > 0 ? (times[i] - times.front()) / span
                    : n > 1  ? static_cast<double>(i) / static_cast<double>(n - 1)
                             : 0.0);
  }
  if (!temperatures.empty()) {
    const auto [lo, hi] = std::minmax_element(temperatures.begin(), temperatures.end());
    if (*hi - *lo >= kMovingTemperatureK)
      for (double t : temperatures) out.temp.push_back((t - *lo) / (*hi - *lo));
  }
  // The calibration's residual is what the model leaves; its robust sigmas re-whiten every row (a model error larger
  // than the readings' noise counts as noise), and a row's part is clipped at clip_sigmas of them (a gross error cannot
  // make a split on its own; a block of rows that moved alike still does).
  out.position_scale = robustSigma(pos_sq);
  out.orientation_scale = robustSigma(ori_sq);
  const double limit = o.clip_sigmas * std::sqrt(3.0);
  Eigen::VectorXd fs = Eigen::VectorXd::Zero(12);
  for (size_t i = 0; i < n; ++i) {
    out.position_sigma_m.push_back(obs[i].sigma_position_m * out.position_scale);
    for (Eigen::Index start = 0; start < out.r[i].size(); start += 3) {
      const double w = 1.0 / (start < 3 ? out.position_scale : out.orientation_scale);
      out.r[i].segment<3>(start) *= w;
      out.A[i].middleRows<3>(start) *= w;
      out.F[i].middleRows<3>(start) *= w;
      out.D[i].middleRows<3>(start) *= w;
      const double norm = out.r[i].segment<3>(start).norm();
      if (norm > limit) out.r[i].segment<3>(start) *= limit / norm;
    }
    fs += out.F[i].colwise().squaredNorm().transpose();
  }
  // The frame columns scaled to unit norm over the rows (the rank tolerance then compares like with like).
  for (Eigen::Index k = 0; k < 12; ++k) fs[k] = fs[k] > 0 ? 1.0 / std::sqrt(fs[k]) : 0.0;
  for (auto& F : out.F) F = F * fs.asDiagonal();
  return out;
}

// A row's columns of the null model: the estimated ones, then the drifting ones times each shape.
Eigen::MatrixXd nullColumns(const ScanRows& rows, size_t i, const std::vector<double>& taus) {
  const Eigen::Index pa = rows.A[i].cols(), pd = rows.D[i].cols();
  Eigen::MatrixXd X(rows.r[i].size(), pa + pd * static_cast<Eigen::Index>(taus.size()));
  X.leftCols(pa) = rows.A[i];
  for (size_t s = 0; s < taus.size(); ++s)
    X.middleCols(pa + pd * static_cast<Eigen::Index>(s), pd) = shape(rows.u[i], taus[s], rows.temp.empty() ? 0.0 : rows.temp[i]) * rows.D[i];
  return X;
}

// The sums the null model's normal equations are made of, per stretch of the file (1/kTimeBins of its time): the
// drift's columns are a row's drifting columns times a shape of its time, which is taken at the stretch's middle
// here, so each shape tried costs a sum over the stretches, not over the rows (the shape chosen is then fitted row by
// row).
constexpr int kTimeBins = 256;
struct TimeBins {
  std::vector<double> u, temp;
  std::vector<Eigen::MatrixXd> AA, AD, DD;
  std::vector<Eigen::VectorXd> Ar, Dr;
  double rr = 0;
};
TimeBins timeBins(const ScanRows& rows) {
  TimeBins t;
  const Eigen::Index pa = rows.A.front().cols(), pd = rows.D.front().cols();
  for (int b = 0; b < kTimeBins; ++b) {
    t.u.push_back((b + 0.5) / kTimeBins);
    t.temp.push_back(0.0);
    t.AA.push_back(Eigen::MatrixXd::Zero(pa, pa));
    t.AD.push_back(Eigen::MatrixXd::Zero(pa, pd));
    t.DD.push_back(Eigen::MatrixXd::Zero(pd, pd));
    t.Ar.push_back(Eigen::VectorXd::Zero(pa));
    t.Dr.push_back(Eigen::VectorXd::Zero(pd));
  }
  std::vector<double> count(kTimeBins, 0.0);
  for (size_t i = 0; i < rows.r.size(); ++i) {
    const auto b = static_cast<size_t>(std::clamp(static_cast<int>(rows.u[i] * kTimeBins), 0, kTimeBins - 1));
    t.AA[b].noalias() += rows.A[i].transpose() * rows.A[i];
    t.AD[b].noalias() += rows.A[i].transpose() * rows.D[i];
    t.DD[b].noalias() += rows.D[i].transpose() * rows.D[i];
    t.Ar[b].noalias() += rows.A[i].transpose() * rows.r[i];
    t.Dr[b].noalias() += rows.D[i].transpose() * rows.r[i];
    t.rr += rows.r[i].squaredNorm();
    if (!rows.temp.empty()) t.temp[b] += rows.temp[i];
    ++count[b];
  }
  for (size_t b = 0; b < count.size(); ++b)
    if (count[b] > 0) t.temp[b] /= count[b];
  return t;
}

// What the null model with these shapes leaves of the squared residual (the shapes at each stretch's middle).
double nullSse(const TimeBins& t, const std::vector<double>& taus) {
  const Eigen::Index pa = t.AA.front().rows(), pd = t.DD.front().rows();
  const auto S = static_cast<Eigen::Index>(taus.size());
  Eigen::MatrixXd N = Eigen::MatrixXd::Zero(pa + pd * S, pa + pd * S);
  Eigen::VectorXd c = Eigen::VectorXd::Zero(pa + pd * S);
  for (size_t b = 0; b < t.u.size(); ++b) {
    N.topLeftCorner(pa, pa) += t.AA[b];
    c.head(pa) += t.Ar[b];
    for (Eigen::Index x = 0; x < S; ++x) {
      const double wx = shape(t.u[b], taus[static_cast<size_t>(x)], t.temp[b]);
      N.block(0, pa + pd * x, pa, pd) += wx * t.AD[b];
      c.segment(pa + pd * x, pd) += wx * t.Dr[b];
      for (Eigen::Index y = 0; y < S; ++y)
        N.block(pa + pd * x, pa + pd * y, pd, pd) += wx * shape(t.u[b], taus[static_cast<size_t>(y)], t.temp[b]) * t.DD[b];
    }
  }
  N.bottomLeftCorner(pd * S, pa) = N.topRightCorner(pa, pd * S).transpose();
  return t.rr - c.dot(pseudoInverse(N, kRankTolerance).inverse * c);
}

// How many consecutive rows share their scatter: twice the first lag at which the rows' scatter correlates by less
// than 0.1 with the rows that many later (at least 1, at most a quarter of the rows).
int correlationLength(const std::vector<Eigen::VectorXd>& e) {
  const auto n = e.size();
  double c0 = 0;
  for (const auto& x : e) c0 += x.squaredNorm();
  if (!(c0 > 0)) return 1;
  const size_t most = std::max<size_t>(1, n / 4);
  for (size_t h = 1; h <= most; ++h) {
    double c = 0;
    for (size_t i = 0; i + h < n; ++i)
      if (e[i].size() == e[i + h].size()) c += e[i].dot(e[i + h]);
    if (c / c0 < 0.1) return static_cast<int>(std::min(most, std::max<size_t>(1, 2 * (h - 1))));
  }
  return static_cast<int>(most);
}

// The drift's shapes: the straight line, the temperature where a thermometer moved, and the warm-up shape that
// leaves the least beside them (a grid of tau, then a golden-section search on log tau between the best one's
// neighbours). Empty without drift.
std::vector<double> driftShapes(const ScanRows& rows, const TimeBins& bins) {
  std::vector<double> fixed = {0.0};
  if (!rows.temp.empty()) fixed.push_back(kTemperatureShape);
  auto with = [&](double tau) {
    std::vector<double> v = fixed;
    v.push_back(tau);
    return v;
  };
  std::vector<double> grid, sse;
  for (double t = kWarmupFractionMin; t < kWarmupFractionMax * 1.0001; t *= 2) grid.push_back(t);
  for (double t : grid) sse.push_back(nullSse(bins, with(t)));
  const auto at = static_cast<size_t>(std::min_element(sse.begin(), sse.end()) - sse.begin());
  double lo = std::log(grid[at > 0 ? at - 1 : at]), hi = std::log(grid[std::min(at + 1, grid.size() - 1)]);
  const double phi = 0.5 * (std::sqrt(5.0) - 1);
  double x1 = hi - phi * (hi - lo), x2 = lo + phi * (hi - lo);
  double f1 = nullSse(bins, with(std::exp(x1))), f2 = nullSse(bins, with(std::exp(x2)));
  for (int it = 0; it < 12; ++it) {
    if (f1 < f2) {
      hi = x2, x2 = x1, f2 = f1;
      x1 = hi - phi * (hi - lo);
      f1 = nullSse(bins, with(std::exp(x1)));
    } else {
      lo = x1, x1 = x2, f1 = f2;
      x2 = lo + phi * (hi - lo);
      f2 = nullSse(bins, with(std::exp(x2)));
    }
  }
  return with(sse[at] <= std::min(f1, f2) ? grid[at] : std::exp(f1 < f2 ? x1 : x2));
}

// The null model fitted row by row: its columns X, the pseudo-inverse of their normal matrix, what it leaves of each
// row (e) and the residual variance per component (s^2) over m components.
struct NullModel {
  std::vector<Eigen::MatrixXd> X;
  PseudoInverse all;
  std::vector<Eigen::VectorXd> e;
  double s2 = 0;
  int m = 0;
  Eigen::Index p = 0;
};
NullModel fitNull(const ScanRows& rows, const std::vector<double>& taus) {
  NullModel nm;
  const size_t n = rows.r.size();
  for (size_t i = 0; i < n; ++i) nm.X.push_back(nullColumns(rows, i, taus));
  nm.p = nm.X.front().cols();
  Eigen::MatrixXd N = Eigen::MatrixXd::Zero(nm.p, nm.p);
  Eigen::VectorXd c = Eigen::VectorXd::Zero(nm.p);
  double rr = 0;
  for (size_t i = 0; i < n; ++i) {
    N.noalias() += nm.X[i].transpose() * nm.X[i];
    c.noalias() += nm.X[i].transpose() * rows.r[i];
    rr += rows.r[i].squaredNorm();
    nm.m += static_cast<int>(rows.r[i].size());
  }
  nm.all = pseudoInverse(N, kRankTolerance);
  const Eigen::VectorXd g = nm.all.inverse * c;
  nm.s2 = std::max(rr - c.dot(g), 0.0) / std::max(1, nm.m - nm.all.rank);
  for (size_t i = 0; i < n; ++i) nm.e.push_back(rows.r[i] - nm.X[i] * g);
  return nm;
}

// A split at k adds the frame columns on the rows from k on (S_k F). Its score is |W_k b_k|^2 / s^2 with
// b_k = sum over rows >= k of F_i^T e_i (SF) and W_k whitening M_k = (S_k F)^T (I - H) (S_k F) in the directions the
// null model does not already hold; W_k and P_k = W_k (X^T S_k F)^T do not depend on the residuals.
struct Split {
  int k = 0;
  Eigen::MatrixXd W, P, XF;
  Eigen::VectorXd SF;
};
Eigen::MatrixXd whitening(const Eigen::MatrixXd& FF, const Eigen::MatrixXd& XF, const PseudoInverse& all) {
  const Eigen::MatrixXd M = FF - XF.transpose() * (all.inverse * XF);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(0.5 * (M + M.transpose()));
  const double floor = 1e-8 * std::max(FF.diagonal().maxCoeff(), 0.0);
  std::vector<Eigen::Index> kept;
  for (Eigen::Index j = 0; j < 12; ++j)
    if (es.eigenvalues()[j] > floor) kept.push_back(j);
  Eigen::MatrixXd W(static_cast<Eigen::Index>(kept.size()), 12);
  for (size_t j = 0; j < kept.size(); ++j)
    W.row(static_cast<Eigen::Index>(j)) = es.eigenvectors().col(kept[j]).transpose() / std::sqrt(es.eigenvalues()[kept[j]]);
  return W;
}
double scoreOf(const Eigen::MatrixXd& W, const Eigen::VectorXd& b, double s2, double* log_tail) {
  const double score = (W * b).squaredNorm() / s2;
  const double tail = chiSquareSurvival(score, static_cast<int>(W.rows()));
  *log_tail = tail > 0 ? -std::log(tail) : std::numeric_limits<double>::infinity();
  return score;
}
// The splits at the rows `wanted` picks, from the last row back with running sums.
template <typename Wanted>
std::vector<Split> splitsAt(const ScanRows& rows, const NullModel& nm, int min_rows, Wanted wanted) {
  const int n = static_cast<int>(rows.r.size());
  std::vector<Split> out;
  Eigen::MatrixXd FF = Eigen::MatrixXd::Zero(12, 12), XF = Eigen::MatrixXd::Zero(nm.p, 12);
  Eigen::VectorXd SF = Eigen::VectorXd::Zero(12);
  for (int k = n - 1; k >= min_rows; --k) {
    const auto i = static_cast<size_t>(k);
    FF.noalias() += rows.F[i].transpose() * rows.F[i];
    XF.noalias() += nm.X[i].transpose() * rows.F[i];
    SF.noalias() += rows.F[i].transpose() * nm.e[i];
    if (k > n - min_rows || !wanted(k)) continue;
    Split sp;
    sp.k = k;
    sp.W = whitening(FF, XF, nm.all);
    sp.P = sp.W * XF.transpose();
    sp.XF = XF;
    sp.SF = SF;
    if (sp.W.rows() > 0) out.push_back(std::move(sp));
  }
  return out;
}

// What the split fitted leaves of each row: in the whitened directions its coefficients are W b, so row i keeps
// e_i - [i >= k] F_i a + X_i h, a = W^T W b, h = N^+ (X^T S_k F) a: each row's own scatter, change or none.
// *sq_after: the squared position change the split makes over the rows after it, m^2.
std::vector<Eigen::VectorXd> linearScatter(const ScanRows& rows, const NullModel& nm, const Split& sp,
                                           double* sq_after) {
  const Eigen::VectorXd a = sp.W.transpose() * (sp.W * sp.SF);
  const Eigen::VectorXd h = nm.all.inverse * (sp.XF * a);
  std::vector<Eigen::VectorXd> scatter(rows.r.size());
  *sq_after = 0;
  for (size_t i = 0; i < rows.r.size(); ++i) {
    scatter[i] = nm.e[i] + nm.X[i] * h;
    if (static_cast<int>(i) >= sp.k) {
      const Eigen::VectorXd step_i = rows.F[i] * a;
      scatter[i] -= step_i;
      *sq_after += (step_i.head<3>() * rows.position_sigma_m[i]).squaredNorm();
    }
  }
  return scatter;
}

// The split fitted as two set-ups (common kinematics, frames each; setups.hpp) where it converges: a change of
// millimetres and milliradians leaves the turn's second order in the linear step's scatter (tenths of a millimetre
// at a metre), which would widen the law. The null model's columns are taken out as from the rows; the two set-ups'
// scatter replaces the linear step's where it is the smaller (the linear step holds the drift inside its fit).
void twoSetUpScatter(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                     const ScanRows& rows, const NullModel& nm, int k, double clip_sigmas,
                     std::vector<Eigen::VectorXd>* scatter) {
  SetupsProblem two;
  two.model = &model;
  two.starts = {params, params};
  two.observations = {std::vector<Observation>(obs.begin(), obs.begin() + k),
                      std::vector<Observation>(obs.begin() + k, obs.end())};
  const SetupsFit fit = fitSetups(two);
  if (!fit.converged) return;
  KinematicsData data(model);
  const double limit = clip_sigmas * std::sqrt(3.0);
  std::vector<Eigen::VectorXd> r2(obs.size());
  Eigen::VectorXd c2 = Eigen::VectorXd::Zero(nm.p);
  for (size_t i = 0; i < obs.size(); ++i) {
    r2[i].resize(obs[i].rows());
    whitenedResidual(model, data, fit.params[static_cast<int>(i) < k ? 0 : 1], obs[i], r2[i], nullptr);
    for (Eigen::Index start = 0; start < r2[i].size(); start += 3) {
      r2[i].segment<3>(start) /= start < 3 ? rows.position_scale : rows.orientation_scale;
      const double norm = r2[i].segment<3>(start).norm();
      if (norm > limit) r2[i].segment<3>(start) *= limit / norm;
    }
    c2.noalias() += nm.X[i].transpose() * r2[i];
  }
  const Eigen::VectorXd g2 = nm.all.inverse * c2;
  double linear = 0, nonlinear = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    r2[i] -= nm.X[i] * g2;
    linear += (*scatter)[i].squaredNorm();
    nonlinear += r2[i].squaredNorm();
  }
  if (nonlinear < linear) *scatter = std::move(r2);
}

// How often one set-up makes a split that unlikely: the grid scanned again on the rows' scatter with signs drawn at
// random (a wild bootstrap: each row keeps its own size and shape, so a model error larger in some configurations
// than in others, or heavier tails than a normal's, are in it; a time order is not). Rows next to each other may
// share their error (a path through nearby configurations, many orientations at one position): the signs are drawn
// per block of consecutive rows as long as the scatter stays correlated. The largest -log(tail) over the splits of
// each draw follows an extreme-value (Gumbel) law, fitted to the draws by its moments. Each draw costs a pass over
// the rows' frame scores and the grid, not a refit: the null model's part of a draw is sum over blocks of
// sign x (X^T scatter over the block).
struct NullLaw {
  bool drawn = false;
  double location = 0, scale = 1;
  int block = 1;
};
NullLaw bootstrapLaw(const ScanRows& rows, const NullModel& nm, const std::vector<Split>& grid,
                     const std::vector<Eigen::VectorXd>& scatter, const SetupChangeOptions& o) {
  NullLaw law;
  const int n = static_cast<int>(rows.r.size());
  law.block = correlationLength(scatter);
  const auto block = static_cast<size_t>(law.block);
  const size_t blocks = (rows.r.size() + block - 1) / block;
  std::vector<Eigen::VectorXd> block_c(blocks, Eigen::VectorXd::Zero(nm.p)), f(rows.r.size());
  double ss = 0;
  for (size_t i = 0; i < rows.r.size(); ++i) {
    block_c[i / block].noalias() += nm.X[i].transpose() * scatter[i];
    f[i] = rows.F[i].transpose() * scatter[i];
    ss += scatter[i].squaredNorm();
  }
  std::mt19937_64 rng(o.seed);
  std::vector<double> draws, sign(blocks);
  for (int d = 0; d < o.bootstrap_draws; ++d) {
    Eigen::VectorXd cd = Eigen::VectorXd::Zero(nm.p);
    for (size_t b = 0; b < blocks; ++b) {
      sign[b] = (rng() & 1U) ? 1.0 : -1.0;
      cd += sign[b] * block_c[b];
    }
    const Eigen::VectorXd gd = nm.all.inverse * cd;
    const double s2d = std::max(ss - cd.dot(gd), 0.0) / std::max(1, nm.m - nm.all.rank);
    if (!(s2d > 0)) continue;
    Eigen::VectorXd SF = Eigen::VectorXd::Zero(12);
    double most = 0;
    size_t j = 0;
    for (int k = n - 1; k >= o.min_rows && j < grid.size(); --k) {
      SF += sign[static_cast<size_t>(k) / block] * f[static_cast<size_t>(k)];
      if (k != grid[j].k) continue;
      const double score = (grid[j].W * SF - grid[j].P * gd).squaredNorm() / s2d;
      const double tail = chiSquareSurvival(score, static_cast<int>(grid[j].W.rows()));
      most = std::max(most, tail > 0 ? -std::log(tail) : std::numeric_limits<double>::infinity());
      ++j;
    }
    if (std::isfinite(most)) draws.push_back(most);
  }
  if (draws.empty()) return law;
  double mean = 0, var = 0;
  for (double x : draws) mean += x / static_cast<double>(draws.size());
  for (double x : draws) var += (x - mean) * (x - mean) / std::max<double>(1, static_cast<double>(draws.size()) - 1);
  law.drawn = true;
  law.scale = std::max(std::sqrt(6.0 * var) / kPi, 1e-6);
  law.location = mean - 0.5772156649015329 * law.scale;  // Euler-Mascheroni: the Gumbel's mean less its location
  return law;
}

}  // namespace

SetupChangeScan scanSetupChange(const RobotModel& model, const Eigen::VectorXd& params,
                                const std::vector<int>& estimated, const std::vector<Observation>& obs,
                                const SetupChangeOptions& o, const std::vector<double>& times_s,
                                const std::vector<double>& temperatures_c) {
  std::string why;
  if (!o.IsValid(&why)) throw std::invalid_argument("SetupChangeOptions: " + why);
  if (params.size() != model.numParams()) throw std::invalid_argument("scanSetupChange: parameter vector size");
  for (int e : estimated)
    if (e < 0 || e >= model.numParams()) throw std::invalid_argument("scanSetupChange: estimated index out of range");
  if (!times_s.empty() && times_s.size() != obs.size()) throw std::invalid_argument("scanSetupChange: times size");
  if (!temperatures_c.empty() && temperatures_c.size() != obs.size())
    throw std::invalid_argument("scanSetupChange: temperatures size");
  for (size_t i = 1; i < times_s.size(); ++i)
    if (!(times_s[i] >= times_s[i - 1])) throw std::invalid_argument("scanSetupChange: times must not decrease");
  SetupChangeScan out;
  const int n = static_cast<int>(obs.size());
  out.profile.assign(obs.size(), 0.0);
  if (n < 2 * o.min_rows) return out;
  const ScanRows rows = scanRows(model, params, estimated, obs, o, times_s, temperatures_c);
  out.position_scale = rows.position_scale;
  out.orientation_scale = rows.orientation_scale;
  const TimeBins bins = timeBins(rows);
  const std::vector<double> taus = o.drift ? driftShapes(rows, bins) : std::vector<double>{};
  out.drift_warmup_fraction = taus.empty() ? 0.0 : taus.back();
  out.drift_temperature = !rows.temp.empty() && o.drift;
  const NullModel nm = fitNull(rows, taus);
  out.residual_scale = std::sqrt(nm.s2);
  if (!(nm.s2 > 0)) return out;
  out.drift_statistic = (nullSse(bins, {}) - nullSse(bins, taus)) / nm.s2;
  double sq_res = 0;
  for (size_t i = 0; i < obs.size(); ++i) sq_res += (nm.e[i].head<3>() * rows.position_sigma_m[i]).squaredNorm();
  out.residual_position_m = std::sqrt(sq_res / static_cast<double>(n));
  // The splits on a grid (every row up to kMaxSplits of them), the best one's tail, then the best row beside it.
  out.splits = n - 2 * o.min_rows + 1;
  const int step = std::max(1, (out.splits + kMaxSplits - 1) / kMaxSplits);
  const std::vector<Split> grid = splitsAt(rows, nm, o.min_rows, [&](int k) { return (k - o.min_rows) % step == 0; });
  if (grid.empty()) return out;
  size_t best = 0;
  double best_log_tail = -1;
  for (size_t j = 0; j < grid.size(); ++j) {
    double lt = 0;
    out.profile[static_cast<size_t>(grid[j].k)] = scoreOf(grid[j].W, grid[j].SF, nm.s2, &lt);
    if (lt > best_log_tail) best = j, best_log_tail = lt;
  }
  Split chosen = grid[best];
  double refined = -1;
  for (Split& sp : splitsAt(rows, nm, o.min_rows, [&](int k) { return std::abs(k - grid[best].k) < step; })) {
    double lt = 0;
    out.profile[static_cast<size_t>(sp.k)] = scoreOf(sp.W, sp.SF, nm.s2, &lt);
    if (lt > refined) refined = lt, chosen = std::move(sp);
  }
  double sq_after = 0;
  std::vector<Eigen::VectorXd> scatter = linearScatter(rows, nm, chosen, &sq_after);
  twoSetUpScatter(model, params, obs, rows, nm, chosen.k, o.clip_sigmas, &scatter);
  const NullLaw law = bootstrapLaw(rows, nm, grid, scatter, o);
  double observed = 0;
  out.first_row = chosen.k;
  out.score = scoreOf(chosen.W, chosen.SF, nm.s2, &observed);
  out.dof = static_cast<int>(chosen.W.rows());
  // Against the grid's law: the grid's best, not the refined row's (which can only be larger).
  out.log_tail = best_log_tail;
  out.block_rows = law.block;
  out.null_location = law.location;
  out.null_scale = law.scale;
  out.probability = !std::isfinite(best_log_tail) ? 0.0
                    : law.drawn ? -std::expm1(-std::exp(-(best_log_tail - law.location) / law.scale))
                                : 1.0;
  out.move_m = std::sqrt(sq_after / (n - chosen.k));
  out.found = law.drawn && out.probability < o.false_alarm && out.move_m >= o.min_move_m;
  return out;
}

}  // namespace cellcal
