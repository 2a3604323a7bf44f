#include "cellcal/lab/paper_experiment.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/pose_selection.hpp"
#include "cellcal/core/identification/rls.hpp"

namespace cellcal {

bool PaperExperimentConfig::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (groups < 1) return fail("groups must be >= 1");
  if (identification_poses < 1 || identification_poses >= poses_per_group)
    return fail("identification_poses must be in [1, poses_per_group)");
  for (int n : sweep_poses)
    if (n < 1 || n > identification_poses) return fail("sweep pose counts must be in [1, identification_poses]");
  for (int n : continuous_poses)
    if (n < 1 || n > identification_poses) return fail("continuous pose counts must be in [1, identification_poses]");
  if (!(prior_sigma_length_m > 0 && prior_sigma_angle_rad > 0)) return fail("prior sigmas must be > 0");
  if (!(forgetting > 0 && forgetting <= 1)) return fail("forgetting must be in (0, 1]");
  if (selection_candidates < 0) return fail("selection_candidates must be >= 0");
  return true;
}

namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

struct Group {
  double t_h = 0;
  std::vector<Observation> ident, verify;
  double noise_floor_m = 0;
  Eigen::VectorXd truth;  // the simulated robot's parameters at t_h (for the figures only)
};

// Each joint's zero as the estimated parameters carry it (MaintenanceGroup::joint_offsets_rad).
struct ZeroCarriers {
  Eigen::MatrixXd T;             // absorption map over the structurally identifiable set
  std::vector<int> kept;         // its rows' parameters
  std::vector<Eigen::Index> row;  // per joint: the row that carries its zero
  std::vector<double> coef;      // per joint: that row's coefficient for the zero

  ZeroCarriers(const RobotModel& model, const Eigen::VectorXd& p0, MeasurementKind kind) {
    const auto rep = structuralIdentifiability(model, p0, kind);
    T = rep.absorption;
    kept = rep.identifiable;
    for (int j = 0; j < model.numJoints(); ++j) {
      Eigen::Index r = 0;
      T.col(model.jointParam(j, JointParam::kThetaOffset)).cwiseAbs().maxCoeff(&r);
      row.push_back(r);
      coef.push_back(T(r, model.jointParam(j, JointParam::kThetaOffset)));
    }
  }
  std::string name(const RobotModel& model, int j) const {
    const int carrier = kept[static_cast<size_t>(row[static_cast<size_t>(j)])];
    std::string n = "joint " + std::to_string(j + 1);
    if (carrier != model.jointParam(j, JointParam::kThetaOffset)) n += " (as " + model.paramName(carrier) + ")";
    return n;
  }
  // The estimate's change since p0, per joint.
  Eigen::VectorXd estimate(const Eigen::VectorXd& params, const Eigen::VectorXd& p0) const {
    Eigen::VectorXd out(static_cast<Eigen::Index>(row.size()));
    for (size_t j = 0; j < row.size(); ++j) {
      const int k = kept[static_cast<size_t>(row[j])];
      out[static_cast<Eigen::Index>(j)] = coef[j] != 0 ? (params[k] - p0[k]) / coef[j] : 0.0;
    }
    return out;
  }
  // The truth's change since p0 in the same parametrization.
  Eigen::VectorXd truth(const Eigen::VectorXd& truth, const Eigen::VectorXd& p0) const {
    const Eigen::VectorXd mapped = T * (truth - p0);
    Eigen::VectorXd out(static_cast<Eigen::Index>(row.size()));
    for (size_t j = 0; j < row.size(); ++j) out[static_cast<Eigen::Index>(j)] = coef[j] != 0 ? mapped[row[j]] / coef[j] : 0.0;
    return out;
  }
};

std::vector<Observation> firstN(const std::vector<Observation>& v, int n) {
  return {v.begin(), v.begin() + std::min<size_t>(n, v.size())};
}

void summarize(MaintenanceRun& run) {
  int n = 0;
  for (const auto& g : run.groups) {
    if (g.group == 0) continue;
    ++n;
    run.ident_before_m += g.ident_before_m;
    run.ident_after_m += g.ident_after_m;
    run.verify_before_m += g.verify_before_m;
    run.verify_after_m += g.verify_after_m;
    run.worst_verify_to_floor = std::max(run.worst_verify_to_floor, g.verify_after_m / g.noise_floor_m);
  }
  if (n == 0) return;
  run.ident_before_m /= n;
  run.ident_after_m /= n;
  run.verify_before_m /= n;
  run.verify_after_m /= n;
}

}  // namespace

PaperExperimentResult runPaperExperiment(const RobotModel& nominal, const PaperExperimentConfig& cfg,
                                         const ProgressFn& progress) {
  std::string err;
  if (!cfg.IsValid(&err)) throw std::invalid_argument("PaperExperimentConfig: " + err);
  SimulatedCell cell(nominal, cfg.sim);
  const RobotModel& model = cell.model();
  const Eigen::VectorXd& p0 = cell.nominalParams();
  std::mt19937_64 rng(cfg.sim.seed * 7919 + 17);

  // Measurements: the code under test sees only these and the nominal model.
  std::vector<Group> groups(cfg.groups);
  PaperExperimentResult out;
  std::vector<double> floor_all;
  for (int g = 0; g < cfg.groups; ++g) {
    Group& G = groups[g];
    G.t_h = g * cfg.hours_between_groups;
    const auto qs = cell.randomConfigurations(cfg.poses_per_group, rng);
    const Eigen::VectorXd truth = cell.trueParams(G.t_h);
    G.truth = truth;
    for (int i = 0; i < cfg.poses_per_group; ++i) {
      Observation o = cell.measure(qs[i], G.t_h, rng, cfg.kind);
      if (i < cfg.identification_poses) {
        G.ident.push_back(o);
      } else {
        G.verify.push_back(o);
      }
    }
    const auto fl = positionErrors(model, truth, G.verify);
    G.noise_floor_m = mean(fl);
    floor_all.insert(floor_all.end(), fl.begin(), fl.end());
  }
  out.noise_floor_m = mean(floor_all);
  out.true_error_nominal_m = mean(positionErrors(model, p0, groups[0].verify));

  const std::vector<int> all = model.canonicalParams();
  const ZeroCarriers zeros(model, p0, cfg.kind);
  for (int j = 0; j < model.numJoints(); ++j) out.joint_zero_names.push_back(zeros.name(model, j));
  const Eigen::VectorXd drift = cfg.drift.sigmas(model);
  const GaussianPrior prior0 = diagonalPrior(model, p0, all, cfg.prior_sigma_length_m, cfg.prior_sigma_angle_rad);
  const int total_steps =
      static_cast<int>(cfg.sweep_poses.size()) + 3 + 4 * static_cast<int>(cfg.continuous_poses.size()) + 1;
  int step = 0;
  auto tick = [&](const std::string& what) {
    if (progress) progress(what, ++step, total_steps);
  };

  // ---- Table 2: pose-number sweep (RLS, group 0). ----
  for (int n : cfg.sweep_poses) {
    RlsCalibrator rls(model, p0, prior0, cfg.kind);
    const auto used = firstN(groups[0].ident, n);
    for (const auto& o : used) rls.addObservation(o);
    out.sweep.push_back({n, mean(positionErrors(model, rls.params(), used)),
                         mean(positionErrors(model, rls.params(), groups[0].verify))});
    tick("pose sweep");
  }

  // ---- Table 4: accuracy maintenance. ----
  // One generic loop; `update` moves the estimate with the poses of one group.
  using Chooser = std::function<std::vector<Observation>(int group, int k)>;
  const Chooser first_k = [&](int g, int k) { return firstN(groups[g].ident, k); };
  auto newRun = [](const std::string& mode, const std::string& algorithm, int updated_poses) {
    MaintenanceRun run;
    run.mode = mode;
    run.algorithm = algorithm;
    run.updated_poses = updated_poses;
    return run;
  };
  auto run_maintenance = [&](MaintenanceRun run, int per_group,
                             const std::function<void(int group, const std::vector<Observation>&)>& update,
                             const std::function<const Eigen::VectorXd&()>& params, const Chooser& choose) {
    for (int g = 0; g < cfg.groups; ++g) {
      const int k = g == 0 ? cfg.identification_poses : per_group;
      const auto used = choose(g, k);
      MaintenanceGroup mg;
      mg.group = g;
      mg.t_h = groups[g].t_h;
      mg.poses_used = k;
      mg.noise_floor_m = groups[g].noise_floor_m;
      mg.ident_before_m = mean(positionErrors(model, params(), used));
      mg.verify_before_m = mean(positionErrors(model, params(), groups[g].verify));
      const auto t0 = Clock::now();
      update(g, used);
      mg.update_time_s = since(t0);
      mg.ident_after_m = mean(positionErrors(model, params(), used));
      mg.verify_after_m = mean(positionErrors(model, params(), groups[g].verify));
      mg.joint_offsets_rad = zeros.estimate(params(), p0);
      mg.true_joint_offsets_rad = zeros.truth(groups[g].truth, p0);
      run.groups.push_back(mg);
    }
    summarize(run);
    out.maintenance.push_back(run);
    tick(run.mode + " " + run.algorithm);
  };

  std::vector<std::pair<std::string, int>> schedules = {{"periodic", cfg.identification_poses}};
  for (int k : cfg.continuous_poses) schedules.emplace_back("continuous", k);

  double rls_time = 0;
  int rls_poses = 0;
  for (const auto& schedule : schedules) {
    const auto& mode = schedule.first;  // not a structured binding: lambdas below capture it (C++17, clang)
    const auto& k = schedule.second;
    // RLS: prior at group 0, process noise between groups (a random walk toward the previous estimate).
    {
      RlsCalibrator rls(model, p0, prior0, cfg.kind);
      MaintenanceRun run = newRun(mode, "rls", k);
      run_maintenance(
          run, k,
          [&](int g, const std::vector<Observation>& used) {
            if (g > 0) rls.addProcessNoise(drift, cfg.kind);
            const auto t0 = Clock::now();
            for (const auto& o : used) rls.addObservation(o);
            rls_time += since(t0);
            rls_poses += static_cast<int>(used.size());
          },
          [&]() -> const Eigen::VectorXd& { return rls.params(); }, first_k);
    }
    // RLS that chooses which K poses to measure (continuous mode only): predict, choose, update.
    if (mode == "continuous") {
      RlsCalibrator rls(model, p0, prior0, cfg.kind);
      std::mt19937_64 select_rng(cfg.sim.seed * 104729 + static_cast<std::uint64_t>(k));
      PoseSelectionOptions sel;
      sel.kind = cfg.kind;
      sel.sigma_position_m = std::hypot(
          cfg.sim.tracker.sigmaPosition(model.nominal.segment<3>(model.baseParam(FrameParam::kX)).norm()),
          cfg.sim.repeatability_m / 2);
      sel.sigma_orientation_rad = cfg.sim.tracker.sigmaOrientation();
      MaintenanceRun run = newRun(mode, "rls", k);
      run.pose_selection = "i-optimal";
      const Chooser choose = [&](int g, int count) {
        if (g == 0) return firstN(groups[g].ident, count);
        rls.addProcessNoise(drift, cfg.kind);
        std::vector<Eigen::VectorXd> qs;
        if (cfg.selection_candidates > 0) {
          qs = cell.randomConfigurations(cfg.selection_candidates, select_rng);
        } else {
          for (const auto& o : groups[g].ident) qs.push_back(o.q_rad);
        }
        std::vector<Observation> used;
        for (int i : selectInformativePoses(model, rls.params(), rls.estimated(), rls.covariance(), qs, count, sel))
          // The tracker measures the chosen configurations.
          used.push_back(cfg.selection_candidates > 0 ? cell.measure(qs[i], groups[g].t_h, select_rng, cfg.kind)
                                                      : groups[g].ident[i]);
        return used;
      };
      run_maintenance(
          run, k, [&](int, const std::vector<Observation>& used) { for (const auto& o : used) rls.addObservation(o); },
          [&]() -> const Eigen::VectorXd& { return rls.params(); }, choose);
    }
    // LM as in the paper: warm start from the previous estimate, fresh poses only.
    {
      Eigen::VectorXd params = p0;
      MaintenanceRun run = newRun(mode, "lm", k);
      run_maintenance(
          run, k,
          [&](int g, const std::vector<Observation>& used) {
            CalibrationProblem p{&model, params, used, std::nullopt, {}, {}};
            const auto r = solveLevenbergMarquardt(p);
            if (g == 0 && mode == "periodic") out.lm_time_50_s = r.solve_time_s;
            params = r.params;
          },
          [&]() -> const Eigen::VectorXd& { return params; }, first_k);
    }
    // LM done like RLS: the same prior (previous estimate and covariance plus process noise).
    {
      Eigen::VectorXd params = p0;
      GaussianPrior prior = prior0;
      MaintenanceRun run = newRun(mode, "lm", k);
      run.prior = true;
      run_maintenance(
          run, k,
          [&](int g, const std::vector<Observation>& used) {
            if (g > 0) {  // as RlsCalibrator::addProcessNoise: with the drift of the parameters they stand for
              const Eigen::MatrixXd T = structuralAbsorption(model, params, cfg.kind, prior.indices);
              prior.covariance += T * drift.cwiseAbs2().asDiagonal() * T.transpose();
            }
            CalibrationProblem p{&model, params, used, prior, {}, {}};
            const auto r = solveLevenbergMarquardt(p);
            params = r.params;
            prior.mean = r.params;
            prior.indices = r.estimated;
            prior.covariance = r.covariance;
          },
          [&]() -> const Eigen::VectorXd& { return params; }, first_k);
    }
  }
  // RLS with forgetting instead of process noise (continuous, smallest K), P bounded by the prior variance.
  {
    const int k = cfg.continuous_poses.empty() ? cfg.identification_poses : cfg.continuous_poses.front();
    RlsCalibratorOptions opts;
    opts.rls.forgetting = cfg.forgetting;
    RlsCalibrator probe(model, p0, prior0, cfg.kind);
    opts.rls.max_covariance_diag = probe.covariance().diagonal();
    RlsCalibrator rls(model, p0, prior0, cfg.kind, opts);
    MaintenanceRun run = newRun("continuous", "rls", k);
    run.forgetting = cfg.forgetting;
    run_maintenance(
        run, k, [&](int, const std::vector<Observation>& used) { for (const auto& o : used) rls.addObservation(o); },
        [&]() -> const Eigen::VectorXd& { return rls.params(); }, first_k);
  }
  out.rls_time_per_pose_s = rls_poses ? rls_time / rls_poses : 0.0;
  return out;
}

}  // namespace cellcal
