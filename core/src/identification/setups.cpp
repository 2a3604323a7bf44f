#include "cellcal/core/identification/setups.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <optional>
#include <cmath>
#include <stdexcept>

#include "calibration_internal.hpp"
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
  if (!extensions.empty()) {
    if (drivers.size() != observations.size()) return fail("with extensions: one driver list per set-up");
    for (size_t s = 0; s < drivers.size(); ++s)
      if (drivers[s].size() != observations[s].size())
        return fail("set-up " + std::to_string(s + 1) + ": one driver per observation");
    for (const Extension& e : extensions) {
      if (followsThermalDriver(e.cause) && e.time_constant_h == 0)
        for (const auto& d : drivers)
          for (const auto& x : d)
            if (x.thermal_is_time)
              return fail(extensionSpec(e) + ": on a time driver its warm-up time constant is searched per fit; "
                          "several set-ups take it only with a temperature column");
    }
  }
  return identifiability.IsValid(error);
}

namespace {

// The state (common parameter vector, then 12 frame parameters per further set-up, then the extension parameters,
// starting at 0) from per-set-up vectors, and back.
Eigen::VectorXd stateOf(const RobotModel& m, const std::vector<Eigen::VectorXd>& p, int n_ext) {
  const int np = m.numParams(), f = m.baseParam(FrameParam::kX);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(np + 12 * static_cast<int>(p.size() - 1) + n_ext);
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

// The extension basis of every row, with the geometry of its set-up's start, as fitExtended takes it: fixed during the
// fit, so computed once (empty without extensions).
// A backlash's basis is the play state, which depends on its width: taken at `widths` (the extension parameters the
// basis is evaluated at; zero: the direction the joint last moved).
using Bases = std::vector<std::vector<Eigen::MatrixXd>>;
Bases basesAtStart(const SetupsProblem& pr, const Eigen::VectorXd& widths) {
  Bases b(pr.observations.size());
  if (pr.extensions.empty()) return b;
  for (size_t s = 0; s < pr.observations.size(); ++s)
    for (size_t i = 0; i < pr.observations[s].size(); ++i)
      b[s].push_back(extensionBasis(*pr.model, pr.starts[s], pr.extensions, pr.observations[s][i].q_rad,
                                    pr.drivers[s][i], widths));
  return b;
}

// The rows of a set-up whose play state is known for every backlash joint (playStateUnknown).
std::vector<int> rowsWithKnownPlay(const std::vector<Extension>& extensions, const std::vector<Drivers>& drivers) {
  std::vector<int> rows;
  for (size_t i = 0; i < drivers.size(); ++i)
    if (!playStateUnknown(extensions, drivers[i])) rows.push_back(static_cast<int>(i));
  return rows;
}

// Stacked whitened residual and state Jacobian over every set-up's rows.
void stack(const SetupsProblem& pr, const Bases& bases, const Eigen::VectorXd& x, Eigen::VectorXd& r,
           Eigen::MatrixXd* J) {
  const RobotModel& m = *pr.model;
  const auto& obs = pr.observations;
  const int np = m.numParams(), f = m.baseParam(FrameParam::kX);
  const int n_ext = numExtensionParams(m, pr.extensions);
  const int ext0 = static_cast<int>(x.size()) - n_ext;
  const Eigen::VectorXd e = x.tail(n_ext);
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
    for (size_t i = 0; i < obs[s].size(); ++i) {
      const Observation& o = obs[s][i];
      const Eigen::MatrixXd* B = n_ext ? &bases[s][i] : nullptr;
      const int k = whitenedResidual(m, data, B ? Eigen::VectorXd(p + *B * e) : p, o, ri, J ? &Ji : nullptr);
      r.segment(row, k) = ri.head(k);
      if (J) {
        J->block(row, 0, k, f) = Ji.topLeftCorner(k, f);
        const int fc = s == 0 ? f : np + 12 * static_cast<int>(s - 1);
        J->block(row, fc, k, 12) = Ji.block(0, f, k, 12);
        if (B) J->block(row, ext0, k, n_ext) = Ji * *B;
      }
      row += k;
    }
  }
}

}  // namespace

namespace {

// With backlash, rows of an unknown play state do not take part (as in fitExtended): the problem without them, and
// how many each set-up left out; nullopt when every row's play state is known.
std::optional<std::pair<SetupsProblem, std::vector<int>>> withKnownPlay(const SetupsProblem& pr) {
  SetupsProblem kept = pr;
  std::vector<int> left_out(pr.observations.size(), 0);
  bool any = false;
  for (size_t s = 0; s < pr.observations.size(); ++s) {
    const std::vector<int> rows = rowsWithKnownPlay(pr.extensions, pr.drivers[s]);
    left_out[s] = static_cast<int>(pr.observations[s].size() - rows.size());
    if (left_out[s] == 0) continue;
    any = true;
    if (rows.size() < 4)
      throw std::invalid_argument("fitSetups: set-up " + std::to_string(s + 1) +
                                  ": fewer than 4 rows with a known backlash play state");
    kept.observations[s] = subset(pr.observations[s], rows);
    kept.drivers[s] = subset(pr.drivers[s], rows);
  }
  if (!any) return std::nullopt;
  return std::make_pair(std::move(kept), std::move(left_out));
}

// The state's columns in the order they are taken as identifiable: every set-up's tool first, then the kinematic
// parameters in the model's priority, further set-ups' bases, the extension parameters last (ext0: the first
// extension column, n: the state's size).
std::vector<int> columnOrder(const SetupsProblem& pr, Eigen::Index ext0, Eigen::Index n) {
  const RobotModel& m = *pr.model;
  const int np = m.numParams();
  std::vector<int> order;
  const auto& cand = pr.identifiability.candidates.empty() ? m.canonicalParams() : pr.identifiability.candidates;
  const int f = m.baseParam(FrameParam::kX), tool0 = m.toolParam(FrameParam::kX);
  const auto is_tool = [&](int kinematic) { return kinematic >= tool0 && kinematic < tool0 + 6; };
  const auto candidate = [&](int kinematic) { return std::count(cand.begin(), cand.end(), kinematic) > 0; };
  const auto further = [&](bool tool) {  // further set-ups' frame columns whose parameter of set-up 0 is a candidate
    for (Eigen::Index c = np; c < ext0; ++c) {
      const int same = f + static_cast<int>((c - np) % 12);
      if (is_tool(same) == tool && candidate(same)) order.push_back(static_cast<int>(c));
    }
  };
  const std::vector<int> priority = identificationPriority(m);
  for (int c : priority)
    if (is_tool(c) && candidate(c)) order.push_back(c);
  further(true);
  for (int c : priority)
    if (c >= f && !is_tool(c) && candidate(c)) order.push_back(c);
  further(false);
  for (int c : priority)
    if (c < f && candidate(c)) order.push_back(c);
  for (Eigen::Index c = ext0; c < n; ++c) order.push_back(static_cast<int>(c));  // extension columns last
  return order;
}

}  // namespace

SetupsFit fitSetups(const SetupsProblem& pr, const SolverOptions& options) {
  std::string err;
  if (!pr.IsValid(&err)) throw std::invalid_argument("fitSetups: " + err);
  if (hasBacklash(pr.extensions))
    if (auto known = withKnownPlay(pr)) {
      SetupsFit fit = fitSetups(known->first, options);
      fit.rows_left_out = known->second;
      return fit;
    }
  const RobotModel& m = *pr.model;
  const int n_ext = numExtensionParams(m, pr.extensions);
  Eigen::VectorXd x = stateOf(m, pr.starts, n_ext);
  const auto n = x.size();
  const Eigen::Index ext0 = n - n_ext;
  // Identifiable columns of the stacked Jacobian at the start, in the model's priority: every set-up's tool first,
  // then every set-up's base, then the joints. The tools first: a common change at the flange (joint 6's flange-side parameters)
  // is then what is held, as in a single set-up, and each set-up's tool takes it exactly, whatever its size. Holding
  // a further set-up's tool instead leaves the rotations about the flange to reach the held value, which for a target
  // near the flange axis takes a rotation of radians that Levenberg-Marquardt crawls along
  // (CELLCAL_TEST_SEED=829672055: joint 6's offset at -1.1 rad after 200 iterations). Then every set-up's base, then
  // the joints: what the frames stand for (frameGauge: joint 1's offset along and about its axis) is held in the
  // kinematic chain and the bases carry it, as in a single set-up.
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  Eigen::VectorXd widths = Eigen::VectorXd::Zero(n_ext);  // the extension parameters the bases are evaluated at
  Bases bases = basesAtStart(pr, widths);
  stack(pr, bases, x, r, &J);
  const std::vector<int> order = columnOrder(pr, ext0, n);
  const int f = m.baseParam(FrameParam::kX);
  SetupsFit out;
  out.estimated = independentColumns(J, order, internal::withExtensionRanges(pr.identifiability, m, pr.starts.front(), pr.extensions, ext0));
  for (int c : out.estimated) {
    if (c < f) out.estimated_kinematic.push_back(c);
    if (c >= ext0) out.estimated_extension.push_back(c - static_cast<int>(ext0));
  }
  std::sort(out.estimated_kinematic.begin(), out.estimated_kinematic.end());
  std::sort(out.estimated_extension.begin(), out.estimated_extension.end());
  const auto ne = static_cast<Eigen::Index>(out.estimated.size());
  auto cost = [&](const Eigen::VectorXd& state) {
    Eigen::VectorXd rr;
    stack(pr, bases, state, rr, nullptr);
    return rr.squaredNorm();
  };
  double c0 = r.squaredNorm();
  // Levenberg-Marquardt from x on the current bases, columns scaled; adds its iterations to out.iterations.
  auto solve = [&] {
    double lambda = 1e-3;
    out.converged = false;
    int iteration = 1;
    for (; iteration <= options.max_iterations; ++iteration) {
      stack(pr, bases, x, r, &J);
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
    out.iterations += iteration;
  };
  solve();
  // A backlash basis depends on its own width: re-evaluated at the fitted width and solved again until the width
  // settles (the fixed point fitExtended iterates to).
  for (int pass = 0; pass < 8 && hasBacklash(pr.extensions); ++pass) {
    const Eigen::VectorXd e = x.tail(n_ext);
    const Eigen::VectorXd moved = e.cwiseAbs() - widths.cwiseAbs();
    if ((moved.array().abs() <= 1e-3 * e.array().abs() + 1e-12).all()) break;
    widths = e;
    bases = basesAtStart(pr, widths);
    c0 = cost(x);
    solve();
  }
  if (!out.converged) out.message = "maximum iterations reached";
  const int rows = static_cast<int>(r.size());
  out.cost_per_row = c0 / std::max(1, rows);
  for (size_t s = 0; s < pr.starts.size(); ++s) out.params.push_back(setupParams(m, x, s));
  out.extension_params = x.tail(n_ext);
  return out;
}

ExtendedFit setupFit(const SetupsProblem& pr, const SetupsFit& fit, size_t s) {
  ExtendedFit f;
  f.extensions = pr.extensions;
  f.params = fit.params.at(s);
  f.extension_params = fit.extension_params;
  f.extension_names = extensionParamNames(*pr.model, pr.extensions);
  f.converged = fit.converged;
  f.iterations = fit.iterations;
  f.rows_left_out = fit.rows_left_out.empty() ? 0 : fit.rows_left_out.at(s);
  return f;
}

SetupsFit fitSetupsRobust(const SetupsProblem& pr, const SolverOptions& solver, const OutlierOptions& outliers,
                          std::vector<OutlierScreen>* screens) {
  std::string err;
  if (!outliers.IsValid(&err)) throw std::invalid_argument(err);
  const size_t n_setups = pr.observations.size();
  auto driversOf = [&](const SetupsProblem& p, size_t s) {
    return p.drivers.size() == n_setups ? p.drivers[s] : std::vector<Drivers>(p.observations[s].size());
  };
  auto screen = [&](const SetupsFit& fit) {
    std::vector<OutlierScreen> sc;
    for (size_t s = 0; s < n_setups; ++s)
      sc.push_back(screenRows(*pr.model, setupFit(pr, fit, s), pr.observations[s], driversOf(pr, s), outliers));
    return sc;
  };
  auto flaggedOf = [](const std::vector<OutlierScreen>& sc) {
    std::vector<std::vector<int>> f;
    for (const auto& x : sc) f.push_back(x.rows);
    return f;
  };
  SetupsFit fit = fitSetups(pr, solver);
  std::vector<OutlierScreen> sc = screen(fit);
  std::vector<std::vector<int>> used(n_setups);
  for (int round = 0; outliers.enabled && round < outliers.max_rounds && flaggedOf(sc) != used; ++round) {
    bool too_many = false;
    for (size_t s = 0; s < n_setups; ++s)
      too_many = too_many || 2 * sc[s].rows.size() > pr.observations[s].size();
    if (too_many) break;
    used = flaggedOf(sc);
    SetupsProblem kept = pr;
    for (size_t s = 0; s < n_setups; ++s) {
      const std::vector<int> rows = keptRows(static_cast<int>(pr.observations[s].size()), used[s]);
      kept.observations[s] = subset(pr.observations[s], rows);
      if (!kept.drivers.empty()) kept.drivers[s] = subset(pr.drivers[s], rows);
    }
    fit = fitSetups(kept, solver);
    sc = screen(fit);
  }
  if (screens) *screens = std::move(sc);
  return fit;
}

}  // namespace cellcal
