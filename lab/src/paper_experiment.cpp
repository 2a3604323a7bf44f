#include "cellcal/lab/paper_experiment.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <random>

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

// The experiment's measured groups and what every method is judged with; one method per table row family.
class Experiment {
 public:
  Experiment(const RobotModel& nominal, const PaperExperimentConfig& cfg, const ProgressFn& progress)
      : cfg_(cfg), progress_(progress), cell_(nominal, cfg.sim), model_(cell_.model()), p0_(cell_.nominalParams()),
        zeros_(model_, p0_, cfg.kind), drift_(cfg.drift.sigmas(model_)),
        prior0_(diagonalPrior(model_, p0_, model_.canonicalParams(), cfg.prior_sigma_length_m, cfg.prior_sigma_angle_rad)),
        total_steps_(static_cast<int>(cfg.sweep_poses.size()) + 3 + 4 * static_cast<int>(cfg.continuous_poses.size()) + 1) {}

  PaperExperimentResult run() {
    measure();
    for (int j = 0; j < model_.numJoints(); ++j) out_.joint_zero_names.push_back(zeros_.name(model_, j));
    sweep();
    std::vector<std::pair<std::string, int>> schedules = {{"periodic", cfg_.identification_poses}};
    for (int k : cfg_.continuous_poses) schedules.emplace_back("continuous", k);
    for (const auto& [mode, k] : schedules) {
      rls(mode, k);
      if (mode == "continuous") rlsChoosingPoses(mode, k);
      lmFreshPoses(mode, k);
      lmWithPrior(mode, k);
    }
    rlsForgetting();
    out_.rls_time_per_pose_s = rls_poses_ ? rls_time_s_ / rls_poses_ : 0.0;
    return out_;
  }

 private:
  using Chooser = std::function<std::vector<Observation>(int group, int k)>;
  using Update = std::function<void(int group, const std::vector<Observation>&)>;
  using Params = std::function<const Eigen::VectorXd&()>;

  void tick(const std::string& what) {
    if (progress_) progress_(what, ++step_, total_steps_);
  }

  // Measurements: the code under test sees only these and the nominal model.
  void measure() {
    std::mt19937_64 rng(cfg_.sim.seed * 7919 + 17);
    groups_.resize(static_cast<size_t>(cfg_.groups));
    std::vector<double> floor_all;
    for (int g = 0; g < cfg_.groups; ++g) {
      Group& G = groups_[static_cast<size_t>(g)];
      G.t_h = g * cfg_.hours_between_groups;
      const auto qs = cell_.randomConfigurations(cfg_.poses_per_group, rng);
      G.truth = cell_.trueParams(G.t_h);
      for (int i = 0; i < cfg_.poses_per_group; ++i) {
        Observation o = cell_.measure(qs[static_cast<size_t>(i)], G.t_h, rng, cfg_.kind);
        (i < cfg_.identification_poses ? G.ident : G.verify).push_back(o);
      }
      const auto fl = positionErrors(model_, G.truth, G.verify);
      G.noise_floor_m = mean(fl);
      floor_all.insert(floor_all.end(), fl.begin(), fl.end());
    }
    out_.noise_floor_m = mean(floor_all);
    out_.true_error_nominal_m = mean(positionErrors(model_, p0_, groups_[0].verify));
  }

  // Table 2: pose-number sweep (RLS, group 0).
  void sweep() {
    for (int n : cfg_.sweep_poses) {
      RlsCalibrator rls(model_, p0_, prior0_, cfg_.kind);
      const auto used = firstN(groups_[0].ident, n);
      for (const auto& o : used) rls.addObservation(o);
      out_.sweep.push_back({n, mean(positionErrors(model_, rls.params(), used)),
                            mean(positionErrors(model_, rls.params(), groups_[0].verify))});
      tick("pose sweep");
    }
  }

  static MaintenanceRun newRun(const std::string& mode, const std::string& algorithm, int updated_poses) {
    MaintenanceRun run;
    run.mode = mode;
    run.algorithm = algorithm;
    run.updated_poses = updated_poses;
    return run;
  }

  std::vector<Observation> firstK(int g, int k) const { return firstN(groups_[static_cast<size_t>(g)].ident, k); }

  // Table 4, accuracy maintenance: one generic loop; `update` moves the estimate with the poses of one group.
  void maintain(MaintenanceRun run, int per_group, const Update& update, const Params& params, const Chooser& choose) {
    for (int g = 0; g < cfg_.groups; ++g) {
      const Group& G = groups_[static_cast<size_t>(g)];
      const int k = g == 0 ? cfg_.identification_poses : per_group;
      const auto used = choose(g, k);
      MaintenanceGroup mg;
      mg.group = g;
      mg.t_h = G.t_h;
      mg.poses_used = k;
      mg.noise_floor_m = G.noise_floor_m;
      mg.ident_before_m = mean(positionErrors(model_, params(), used));
      mg.verify_before_m = mean(positionErrors(model_, params(), G.verify));
      const auto t0 = Clock::now();
      update(g, used);
      mg.update_time_s = since(t0);
      mg.ident_after_m = mean(positionErrors(model_, params(), used));
      mg.verify_after_m = mean(positionErrors(model_, params(), G.verify));
      mg.joint_offsets_rad = zeros_.estimate(params(), p0_);
      mg.true_joint_offsets_rad = zeros_.truth(G.truth, p0_);
      run.groups.push_back(mg);
    }
    summarize(run);
    out_.maintenance.push_back(run);
    tick(run.mode + " " + run.algorithm);
  }

  Chooser firstKChooser() const {
    return [this](int g, int k) { return firstK(g, k); };
  }

  // RLS: prior at group 0, process noise between groups (a random walk toward the previous estimate).
  void rls(const std::string& mode, int k) {
    RlsCalibrator rls(model_, p0_, prior0_, cfg_.kind);
    maintain(
        newRun(mode, "rls", k), k,
        [&](int g, const std::vector<Observation>& used) {
          if (g > 0) rls.addProcessNoise(drift_, cfg_.kind);
          const auto t0 = Clock::now();
          for (const auto& o : used) rls.addObservation(o);
          rls_time_s_ += since(t0);
          rls_poses_ += static_cast<int>(used.size());
        },
        [&]() -> const Eigen::VectorXd& { return rls.params(); }, firstKChooser());
  }

  // RLS that chooses which K poses to measure (continuous mode only): predict, choose, update.
  void rlsChoosingPoses(const std::string& mode, int k) {
    RlsCalibrator rls(model_, p0_, prior0_, cfg_.kind);
    std::mt19937_64 select_rng(cfg_.sim.seed * 104729 + static_cast<std::uint64_t>(k));
    PoseSelectionOptions sel;
    sel.kind = cfg_.kind;
    sel.sigma_position_m =
        std::hypot(cfg_.sim.tracker.sigmaPosition(model_.nominal.segment<3>(model_.baseParam(FrameParam::kX)).norm()),
                   cfg_.sim.repeatability_m / 2);
    sel.sigma_orientation_rad = cfg_.sim.tracker.sigmaOrientation();
    MaintenanceRun run = newRun(mode, "rls", k);
    run.pose_selection = "i-optimal";
    const Chooser choose = [&](int g, int count) {
      const Group& G = groups_[static_cast<size_t>(g)];
      if (g == 0) return firstN(G.ident, count);
      rls.addProcessNoise(drift_, cfg_.kind);
      std::vector<Eigen::VectorXd> qs;
      if (cfg_.selection_candidates > 0) {
        qs = cell_.randomConfigurations(cfg_.selection_candidates, select_rng);
      } else {
        for (const auto& o : G.ident) qs.push_back(o.q_rad);
      }
      std::vector<Observation> used;
      for (int i : selectInformativePoses(model_, rls.params(), rls.estimated(), rls.covariance(), qs, count, sel))
        // The tracker measures the chosen configurations.
        used.push_back(cfg_.selection_candidates > 0 ? cell_.measure(qs[static_cast<size_t>(i)], G.t_h, select_rng, cfg_.kind)
                                                     : G.ident[static_cast<size_t>(i)]);
      return used;
    };
    maintain(
        run, k, [&](int, const std::vector<Observation>& used) { for (const auto& o : used) rls.addObservation(o); },
        [&]() -> const Eigen::VectorXd& { return rls.params(); }, choose);
  }

  // LM as in the paper: warm start from the previous estimate, fresh poses only.
  void lmFreshPoses(const std::string& mode, int k) {
    Eigen::VectorXd params = p0_;
    maintain(
        newRun(mode, "lm", k), k,
        [&](int g, const std::vector<Observation>& used) {
          CalibrationProblem p{&model_, params, used, std::nullopt, {}, {}};
          const auto r = solveLevenbergMarquardt(p);
          if (g == 0 && mode == "periodic") out_.lm_time_50_s = r.solve_time_s;
          params = r.params;
        },
        [&]() -> const Eigen::VectorXd& { return params; }, firstKChooser());
  }

  // LM done like RLS: the same prior (previous estimate and covariance plus process noise).
  void lmWithPrior(const std::string& mode, int k) {
    Eigen::VectorXd params = p0_;
    GaussianPrior prior = prior0_;
    MaintenanceRun run = newRun(mode, "lm", k);
    run.prior = true;
    maintain(
        run, k,
        [&](int g, const std::vector<Observation>& used) {
          if (g > 0) {  // as RlsCalibrator::addProcessNoise: with the drift of the parameters they stand for
            const Eigen::MatrixXd T = structuralAbsorption(model_, params, cfg_.kind, prior.indices);
            prior.covariance += T * drift_.cwiseAbs2().asDiagonal() * T.transpose();
          }
          CalibrationProblem p{&model_, params, used, prior, {}, {}};
          const auto r = solveLevenbergMarquardt(p);
          params = r.params;
          prior.mean = r.params;
          prior.indices = r.estimated;
          prior.covariance = r.covariance;
        },
        [&]() -> const Eigen::VectorXd& { return params; }, firstKChooser());
  }

  // RLS with forgetting instead of process noise (continuous, smallest K), P bounded by the prior variance.
  void rlsForgetting() {
    const int k = cfg_.continuous_poses.empty() ? cfg_.identification_poses : cfg_.continuous_poses.front();
    RlsCalibratorOptions opts;
    opts.rls.forgetting = cfg_.forgetting;
    RlsCalibrator probe(model_, p0_, prior0_, cfg_.kind);
    opts.rls.max_covariance_diag = probe.covariance().diagonal();
    RlsCalibrator rls(model_, p0_, prior0_, cfg_.kind, opts);
    MaintenanceRun run = newRun("continuous", "rls", k);
    run.forgetting = cfg_.forgetting;
    maintain(
        run, k, [&](int, const std::vector<Observation>& used) { for (const auto& o : used) rls.addObservation(o); },
        [&]() -> const Eigen::VectorXd& { return rls.params(); }, firstKChooser());
  }

  const PaperExperimentConfig& cfg_;
  const ProgressFn& progress_;
  SimulatedCell cell_;
  const RobotModel& model_;
  const Eigen::VectorXd& p0_;
  const ZeroCarriers zeros_;
  const Eigen::VectorXd drift_;
  const GaussianPrior prior0_;
  const int total_steps_;
  int step_ = 0;
  std::vector<Group> groups_;
  PaperExperimentResult out_;
  double rls_time_s_ = 0;
  int rls_poses_ = 0;
};

}  // namespace

PaperExperimentResult runPaperExperiment(const RobotModel& nominal, const PaperExperimentConfig& cfg,
                                         const ProgressFn& progress) {
  std::string err;
  if (!cfg.IsValid(&err)) throw std::invalid_argument("PaperExperimentConfig: " + err);
  return Experiment(nominal, cfg, progress).run();
}

}  // namespace cellcal
