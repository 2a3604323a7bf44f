#include "cellcal/core/identification/setups.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

bool SetupsProblem::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (!model) return fail("no model");
  if (starts.empty() || starts.size() != observations.size()) return fail("one start and one observation list per set-up");
  const int frames = model->baseParam(FrameParam::kX);
  for (size_t s = 0; s < starts.size(); ++s) {
    if (starts[s].size() != model->numParams() || !starts[s].allFinite()) return fail("set-up " + std::to_string(s + 1) + ": bad start");
    if (starts[s].head(frames) != starts[0].head(frames))
      return fail("set-up " + std::to_string(s + 1) + ": its start has other kinematics than set-up 1's");
    if (observations[s].size() < 4) return fail("set-up " + std::to_string(s + 1) + ": fewer than 4 observations");
  }
  return identifiability.IsValid(error);
}

namespace {

// The state (common parameter vector, then 12 frame parameters per further set-up) from per-set-up vectors, and back.
Eigen::VectorXd stateOf(const RobotModel& m, const std::vector<Eigen::VectorXd>& p) {
  const int np = m.numParams(), f = m.baseParam(FrameParam::kX);
  Eigen::VectorXd x(np + 12 * static_cast<int>(p.size() - 1));
  x.head(np) = p[0];
  for (size_t s = 1; s < p.size(); ++s) x.segment(np + 12 * static_cast<int>(s - 1), 12) = p[s].segment(f, 12);
  return x;
}
Eigen::VectorXd setupParams(const RobotModel& m, const Eigen::VectorXd& x, size_t s) {
  const int np = m.numParams(), f = m.baseParam(FrameParam::kX);
  Eigen::VectorXd p = x.head(np);
  if (s > 0) p.segment(f, 12) = x.segment(np + 12 * static_cast<int>(s - 1), 12);
  return p;
}

// Stacked whitened residual and state Jacobian over every set-up's rows.
void stack(const RobotModel& m, const Eigen::VectorXd& x, const std::vector<std::vector<Observation>>& obs,
           Eigen::VectorXd& r, Eigen::MatrixXd* J) {
  const int np = m.numParams(), f = m.baseParam(FrameParam::kX);
  int rows = 0;
  for (const auto& o : obs) rows += totalRows(o);
  r.resize(rows);
  if (J) J->setZero(rows, x.size());
  KinematicsData data(m);
  Eigen::MatrixXd Ji;
  Eigen::Matrix<double, 6, 1> ri;
  int row = 0;
  for (size_t s = 0; s < obs.size(); ++s) {
    const Eigen::VectorXd p = setupParams(m, x, s);
    for (const auto& o : obs[s]) {
      const int k = whitenedResidual(m, data, p, o, ri, J ? &Ji : nullptr);
      r.segment(row, k) = ri.head(k);
      if (J) {
        J->block(row, 0, k, f) = Ji.topLeftCorner(k, f);
        const int fc = s == 0 ? f : np + 12 * static_cast<int>(s - 1);
        J->block(row, fc, k, 12) = Ji.block(0, f, k, 12);
      }
      row += k;
    }
  }
}

}  // namespace

SetupsFit fitSetups(const SetupsProblem& pr, const SolverOptions& options) {
  std::string err;
  if (!pr.IsValid(&err)) throw std::invalid_argument("fitSetups: " + err);
  const RobotModel& m = *pr.model;
  const int np = m.numParams();
  Eigen::VectorXd x = stateOf(m, pr.starts);
  const auto n = x.size();
  // Identifiable columns of the stacked Jacobian at the start, in the model's priority (frames of further set-ups
  // last: a base of set-up 2 never replaces a kinematic parameter).
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  stack(m, x, pr.observations, r, &J);
  std::vector<int> order;
  const auto& cand = pr.identifiability.candidates.empty() ? m.canonicalParams() : pr.identifiability.candidates;
  for (int c : identificationPriority(m))
    if (std::count(cand.begin(), cand.end(), c)) order.push_back(c);
  const int f = m.baseParam(FrameParam::kX);
  for (Eigen::Index c = np; c < n; ++c) {
    // A further set-up's frame parameter is a candidate when the same parameter of set-up 0 is.
    const int same = f + static_cast<int>((c - np) % 12);
    if (std::count(cand.begin(), cand.end(), same)) order.push_back(static_cast<int>(c));
  }
  SetupsFit out;
  out.estimated = independentColumns(J, order, pr.identifiability);
  for (int c : out.estimated)
    if (c < f) out.estimated_kinematic.push_back(c);
  const auto ne = static_cast<Eigen::Index>(out.estimated.size());
  auto cost = [&](const Eigen::VectorXd& state) {
    Eigen::VectorXd rr;
    stack(m, state, pr.observations, rr, nullptr);
    return rr.squaredNorm();
  };
  double c0 = r.squaredNorm(), lambda = 1e-3;
  for (out.iterations = 1; out.iterations <= options.max_iterations; ++out.iterations) {
    stack(m, x, pr.observations, r, &J);
    Eigen::MatrixXd Js(J.rows(), ne);
    for (Eigen::Index k = 0; k < ne; ++k) Js.col(k) = J.col(out.estimated[static_cast<size_t>(k)]);
    const Eigen::VectorXd scale = Js.colwise().norm().transpose().cwiseMax(1e-300).cwiseInverse();
    Js = Js * scale.asDiagonal();
    const Eigen::MatrixXd H = Js.transpose() * Js;
    const Eigen::VectorXd g = Js.transpose() * r;
    bool accepted = false;
    Eigen::VectorXd step;
    for (int tries = 0; tries < 12 && !accepted; ++tries) {
      Eigen::MatrixXd A = H;
      A.diagonal() += lambda * H.diagonal().cwiseMax(1e-12);
      step = A.ldlt().solve(g);
      Eigen::VectorXd trial = x;
      for (Eigen::Index k = 0; k < ne; ++k) trial[out.estimated[static_cast<size_t>(k)]] += scale[k] * step[k];
      const double c1 = cost(trial);
      if (std::isfinite(c1) && c1 <= c0) {
        x = trial;
        c0 = c1;
        lambda = std::max(lambda / 10, 1e-9);
        accepted = true;
      } else {
        lambda *= 10;
      }
    }
    if (!accepted || step.norm() < options.step_tolerance) {
      out.converged = true;
      break;
    }
  }
  if (!out.converged) out.message = "maximum iterations reached";
  const int rows = static_cast<int>(r.size());
  out.cost_per_row = c0 / std::max(1, rows);
  for (size_t s = 0; s < pr.starts.size(); ++s) out.params.push_back(setupParams(m, x, s));
  return out;
}

}  // namespace cellcal
