// cellcal_bench: Google Benchmark figures for the core algorithms on the simulated Staubli TX60 (6D poses).
//   build/bin/cellcal_bench
#include <benchmark/benchmark.h>

#include <filesystem>
#include <unistd.h>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/engine/state_file.hpp"
#include "cellcal/core/engine/state_journal.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/identification/rls.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace {
using namespace cellcal;

struct Fixture {
  RobotModel robot = loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml");
  SimulatedCell cell{robot, SimulationConfig{}};
  std::vector<Observation> obs;
  Fixture() {
    std::mt19937_64 rng(7);
    for (const auto& q : cell.randomConfigurations(200, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  }
  std::vector<Observation> first(int n) const { return {obs.begin(), obs.begin() + n}; }
};
const Fixture& fx() {
  static const Fixture f;
  return f;
}

void BM_ForwardKinematics(benchmark::State& state) {
  const auto& f = fx();
  KinematicsData data(f.cell.model());
  size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(forwardKinematics(f.cell.model(), data, f.cell.nominalParams(), f.obs[i++ % 200].q_rad));
  }
}
BENCHMARK(BM_ForwardKinematics);

void BM_PoseErrorJacobian(benchmark::State& state) {
  // FK + whitened 6-row residual + Jacobian over all 42 parameters: the per-pose linearization.
  const auto& f = fx();
  KinematicsData data(f.cell.model());
  Eigen::Matrix<double, 6, 1> r;
  Eigen::MatrixXd J(6, f.cell.model().numParams());
  size_t i = 0;
  for (auto _ : state) {
    whitenedResidual(f.cell.model(), data, f.cell.nominalParams(), f.obs[i++ % 200], r, &J);
    benchmark::DoNotOptimize(J.data());
  }
}
BENCHMARK(BM_PoseErrorJacobian);

void BM_RlsUpdate(benchmark::State& state) {
  // One 6-row block update of a 30-state RLS (the identifiable TX60 set), without the linearization.
  const auto& f = fx();
  const auto ident = structuralIdentifiability(f.cell.model(), f.cell.nominalParams(), MeasurementKind::kPose6D);
  const int m = ident.rank;
  std::vector<Eigen::MatrixXd> A;
  std::vector<Eigen::VectorXd> b;
  KinematicsData data(f.cell.model());
  for (const auto& o : f.obs) {
    Eigen::Matrix<double, 6, 1> r;
    Eigen::MatrixXd J;
    whitenedResidual(f.cell.model(), data, f.cell.nominalParams(), o, r, &J);
    Eigen::MatrixXd Ar(6, m);
    for (int k = 0; k < m; ++k) Ar.col(k) = J.col(ident.identifiable[k]);
    A.push_back(Ar);
    b.push_back(r);
  }
  RlsEstimator rls(Eigen::VectorXd::Zero(m), Eigen::MatrixXd::Identity(m, m) * 1e-6);
  size_t i = 0;
  for (auto _ : state) {
    rls.updateWithInnovation(A[i % 200], b[i % 200]);
    ++i;
    benchmark::DoNotOptimize(rls.x().data());
  }
  state.counters["states"] = m;
}
BENCHMARK(BM_RlsUpdate);

void BM_RlsPose(benchmark::State& state) {
  // What the engine pays per tracker pose: linearization at the current estimate + update.
  const auto& f = fx();
  const auto prior = diagonalPrior(f.cell.model(), f.cell.nominalParams(), f.cell.model().canonicalParams(), 1e-3,
                                   degToRad(0.1));
  RlsCalibrator rls(f.cell.model(), f.cell.nominalParams(), prior, MeasurementKind::kPose6D);
  size_t i = 0;
  for (auto _ : state) benchmark::DoNotOptimize(rls.addObservation(f.obs[i++ % 200]));
}
BENCHMARK(BM_RlsPose);

void BM_BatchLeastSquares(benchmark::State& state) {
  const auto& f = fx();
  CalibrationProblem p{&f.cell.model(), f.cell.nominalParams(), f.first(static_cast<int>(state.range(0))),
                       std::nullopt, {}, {}};
  for (auto _ : state) benchmark::DoNotOptimize(solveGaussNewton(p).params.data());
}
BENCHMARK(BM_BatchLeastSquares)->Arg(50)->Unit(benchmark::kMillisecond);

void BM_LevenbergMarquardt(benchmark::State& state) {
  const auto& f = fx();
  CalibrationProblem p{&f.cell.model(), f.cell.nominalParams(), f.first(static_cast<int>(state.range(0))),
                       std::nullopt, {}, {}};
  for (auto _ : state) benchmark::DoNotOptimize(solveLevenbergMarquardt(p).params.data());
}
BENCHMARK(BM_LevenbergMarquardt)->Arg(50)->Unit(benchmark::kMillisecond);

void BM_InverseKinematics(benchmark::State& state) {
  // 6D IK on the true (perturbed) model, seeded with a nearby joint solution, as compensation does. Targets are
  // reachable poses of that model (an out-of-reach answer near the workspace boundary costs up to ~2 ms: all restarts).
  const auto& f = fx();
  const Eigen::VectorXd truth = f.cell.trueParams(0.0);
  std::vector<Pose> targets;
  for (const auto& o : f.obs) {
    Eigen::VectorXd q = o.q_rad;
    q.array() += 0.01;
    targets.push_back(forwardKinematics(f.cell.model(), truth, q));
  }
  size_t i = 0;
  for (auto _ : state) {
    const size_t k = i++ % 200;
    benchmark::DoNotOptimize(solveInverseKinematics(f.cell.model(), truth, targets[k], f.obs[k].q_rad).q_rad.data());
  }
}
BENCHMARK(BM_InverseKinematics)->Unit(benchmark::kMicrosecond);

// One target through the compensation, as the compensation publisher answers it: the identified model (the truth,
// with the covariance of an RLS estimate over 50 poses for the predicted-error guard) solved from the controller's
// joints, the nominal model's pose of the answer, the correction and its bound. Beside BM_InverseKinematics: what the
// compensation adds around the solve (issue #36: within 4x in the process).
void BM_Compensate(benchmark::State& state) {
  const auto& f = fx();
  const RobotModel& m = f.cell.model();
  const Eigen::VectorXd truth = f.cell.trueParams(0.0);
  RlsCalibrator rls(m, m.nominal, diagonalPrior(m, m.nominal, m.canonicalParams(), 1e-3, 1.7e-3),
                    MeasurementKind::kPose6D);
  for (int k = 0; k < 50; ++k) rls.addObservation(f.obs[static_cast<size_t>(k)]);
  const IdentifiedModel identified(CalibratedModel::geometric(truth, rls.estimated(), rls.covariance()));
  std::vector<Pose> targets;
  for (const auto& o : f.obs) targets.push_back(forwardKinematics(m, m.nominal, o.q_rad));
  const CompensationSettings settings;
  size_t i = 0, applied = 0;
  for (auto _ : state) {
    const size_t k = i++ % 200;
    const CompensationResult r = compensate(m, identified, targets[k], f.obs[k].q_rad, settings);
    applied += r.applied;
    benchmark::DoNotOptimize(r.q_rad.data());
  }
  state.counters["applied"] = static_cast<double>(applied) / static_cast<double>(i);
}
BENCHMARK(BM_Compensate)->Unit(benchmark::kMicrosecond);

// `cellcal calibrate` on N poses without knowing where the robot stands: registration of base and tool, then
// Gauss-Newton over every identifiable parameter, as `cellcal calibrate` does (issue target: 400 poses < 100 ms).
void BM_CalibrateGeometric(benchmark::State& state) {
  const auto n = static_cast<int>(state.range(0));
  SimulationConfig sc;
  SimulatedCell cell(fx().robot, sc);
  std::mt19937_64 rng(11);
  std::vector<Observation> obs;
  for (const auto& q : cell.randomConfigurations(n, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  Eigen::VectorXd start = cell.model().nominal;
  start.tail<12>().setZero();
  for (auto _ : state) {
    const RegistrationResult reg = registerFrames(cell.model(), start, obs);
    CalibrationProblem p{&cell.model(), reg.params, obs, std::nullopt, {}, {}};
    benchmark::DoNotOptimize(solveGaussNewton(p).params.data());
  }
}
BENCHMARK(BM_CalibrateGeometric)->Arg(400)->Unit(benchmark::kMillisecond);

// `cellcal diagnose` without file I/O: n poses in visiting order (half identify, half verify) over 4 h with
// temperatures, registration, the geometric fit and every applicable (cause, joint) candidate (31 on a 6R arm).
void BM_Diagnose(benchmark::State& state) {
  const auto n = static_cast<int>(state.range(0));
  SimulationConfig sc;
  SimulatedCell cell(fx().robot, sc);
  std::mt19937_64 rng(12);
  const auto qs = cell.randomConfigurations(n, rng);
  DiagnosisData data;
  std::vector<std::optional<double>> temperature, stamp;
  std::vector<Observation> all;
  for (int i = 0; i < n; ++i) {
    const double t_h = 4.0 * i / n;
    all.push_back(cell.measure(qs[i], t_h, rng));
    temperature.push_back(cell.temperatureC(t_h));
    stamp.push_back(t_h * 3600);
  }
  const DriverTable d = driversFromSequence(qs, temperature, stamp);
  for (int i = 0; i < n; ++i) {
    (i % 2 ? data.verification : data.identification).push_back(all[i]);
    (i % 2 ? data.verification_drivers : data.identification_drivers).push_back(d.rows[i]);
  }
  data.has_thermal = true;
  Eigen::VectorXd start = cell.model().nominal;
  start.tail<12>().setZero();
  for (auto _ : state) {
    const RegistrationResult reg = registerFrames(cell.model(), start, data.identification);
    benchmark::DoNotOptimize(diagnose(cell.model(), reg.params, data).candidates.size());
  }
}
BENCHMARK(BM_Diagnose)->Arg(400)->Unit(benchmark::kMillisecond);

// One tracker reading through the engine: pairing, linearization, RLS update, statistics, and (Arg 1) the atomic
// state-file replacement the engine's host does after every change, (Arg 2) plus its fsync. Arg 0 keeps the state in
// memory only. Side by side: the cost of durability per pose.
void BM_EnginePose(benchmark::State& state) {
  const int mode = static_cast<int>(state.range(0));
  CellConfig cell = loadCellConfig(std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml");
  const auto dir = std::filesystem::temp_directory_path() / ("cellcal_bench_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  cell.engine.state_dir = dir.string();
  const CellRobot& robot = cell.robots[0];
  CalibrationEngine engine(robot, cell.engine, 1.0);
  const std::string file = stateFilePath(cell.engine.state_dir, robot.robot_id);
  DurableState snapshot(file, {Durability::kSnapshot}), journal(file, {Durability::kJournal});
  SimulatedCell sim(robot.model, SimulationConfig{});
  std::mt19937_64 rng(3);
  const auto qs = sim.randomConfigurations(64, rng);
  std::int64_t t = 1'700'000'000'000'000'000;
  std::uint64_t seq = 0;
  size_t k = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const Eigen::VectorXd& q = qs[k++ % qs.size()];
    const Observation o = sim.measure(q, 0.0, rng);
    TrackerSample s;
    s.stamp_ns = t += 10'000'000;
    s.sequence = ++seq;
    s.position_m = o.measured_in_tracker.translation();
    const Eigen::Quaterniond qn(o.measured_in_tracker.linear());
    s.orientation_xyzw = {qn.x(), qn.y(), qn.z(), qn.w()};
    engine.onJointState({t, seq, q, true}, t);
    state.ResumeTiming();
    engine.onTrackerSample(s, t);
    engine.process(t);
    if (mode == 1 || mode == 2) snapshot.save(engine.exportState());
    if (mode == 2) syncStateFile(file);
    if (mode == 3 || mode == 4) {
      journal.save(engine.exportState());
      if (journal.compactionDue()) journal.compact(engine.exportState());
    }
    if (mode == 4) syncStateFile(journal.journalPath());
  }
  std::filesystem::remove_all(dir);
}
// One pose through the engine (pairing, RLS update) and the state kept as the engine process keeps it before
// publishing: 0 in memory only; 1 the JSON snapshot replaced per pose (engine.durability: snapshot), 2 with its fsync;
// 3 a journal record appended per pose (engine.durability: journal, compaction included), 4 with its fsync. The
// fsyncs run off the latency path in the engine process; they are here for the disk's cost.
BENCHMARK(BM_EnginePose)->Arg(0)->Arg(1)->Arg(2)->Arg(3)->Arg(4)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
