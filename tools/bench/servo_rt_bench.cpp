// cellcal_servo_rt_bench: the controller-side compensator's cost per cycle (RealtimeCompensator::correct) beside the
// inverse kinematics it is built on (solveInverseKinematics as BM_InverseKinematics runs it), measured side by side in
// one run: blocks of each, interleaved, each call timed on the steady clock. Run by `make bench`.
//   build/bin/cellcal_servo_rt_bench [--calls N] [--json FILE]
//
// The stream: the simulated Staubli TX60 (its true robot the calibration), a 500 Hz joint path through random
// configurations, a new calibration version (with the covariance of an RLS estimate over 50 poses) every 100,000
// cycles, blended in over 2 s (1,000 cycles answered by two versions). Prints the percentiles and the ratios, the
// largest forward-kinematics evaluation count of a cycle against its bound, and exits 1 when correct()'s p50 exceeds
// 3x the inverse kinematics' or its p99.9 10x.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/rls.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/servo/realtime_compensator.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace {
using namespace cellcal;
using Clock = std::chrono::steady_clock;

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  const auto k = static_cast<size_t>(std::min<double>(static_cast<double>(v.size()) - 1, p * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}
}  // namespace

int main(int argc, char** argv) {
  long calls = 1'000'000;
  std::string json;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--calls") && i + 1 < argc) calls = std::atol(argv[++i]);
    else if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json = argv[++i];
    else {
      std::fprintf(stderr, "usage: cellcal_servo_rt_bench [--calls N] [--json FILE]\n");
      return 2;
    }
  }
  const RobotModel robot = loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/staubli_tx60.yaml");
  const SimulatedCell cell(robot, SimulationConfig{});
  const RobotModel& m = cell.model();
  std::mt19937_64 rng(7);
  std::vector<Observation> obs;
  for (const auto& q : cell.randomConfigurations(50, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  RlsCalibrator rls(m, m.nominal, diagonalPrior(m, m.nominal, m.canonicalParams(), 1e-3, 1.7e-3),
                    MeasurementKind::kPose6D);
  for (const Observation& o : obs) rls.addObservation(o);
  const Eigen::VectorXd truth = cell.trueParams(0.0);
  auto version = [&](std::uint64_t id) {  // the truth, each version's joint zeros moved by up to 0.01 deg
    Eigen::VectorXd p = truth;
    std::uniform_real_distribution<double> u(-1, 1);
    for (int j = 0; j < m.numJoints(); ++j) p[m.jointParam(j, JointParam::kThetaOffset)] += degToRad(0.01 * u(rng));
    std::string why;
    auto v = ServoVersion::prepare(m, id, IdentifiedModel(CalibratedModel::geometric(p, rls.estimated(), rls.covariance())),
                                   &why);
    if (!v) std::fprintf(stderr, "%s\n", why.c_str());
    return v;
  };
  // The path: random configurations 1 s apart at 500 Hz, joined smoothly.
  const auto ends = cell.randomConfigurations(64, rng);
  std::vector<Eigen::VectorXd> path;
  for (size_t e = 0; e + 1 < ends.size(); ++e)
    for (int k = 0; k < 500; ++k) path.push_back(ends[e] + (0.5 - 0.5 * std::cos(kPi * k / 500.0)) * (ends[e + 1] - ends[e]));
  // The inverse kinematics' targets, as BM_InverseKinematics: the truth's pose 0.01 rad from the seed.
  std::vector<Pose> targets;
  for (const Observation& o : obs) {
    Eigen::VectorXd q = o.q_rad;
    q.array() += 0.01;
    targets.push_back(forwardKinematics(m, truth, q));
  }

  RealtimeSettings settings;
  RealtimeCompensator rt(m, settings);
  rt.publish(version(1));
  std::vector<double> correct_us, ik_us;
  correct_us.reserve(static_cast<size_t>(calls));
  ik_us.reserve(static_cast<size_t>(calls / 10));
  long applied = 0, held = 0, versions = 1, blending = 0;
  int worst_evaluations = 0;
  std::vector<long> outcomes(kNumCompensationOutcomes, 0);
  std::vector<long> evaluations_applied(RealtimeCompensator::evaluationBound(settings) + 1, 0);
  constexpr long kBlock = 1000;
  for (long done = 0; done < calls;) {
    for (long k = 0; k < kBlock && done < calls; ++k, ++done) {  // a block of cycles
      if (done > 0 && done % 100'000 == 0) rt.publish(version(static_cast<std::uint64_t>(++versions)));
      const Eigen::VectorXd& q = path[static_cast<size_t>(done) % path.size()];
      const auto t0 = Clock::now();
      const RealtimeAnswer a = rt.correct(done * 2'000'000LL, q.data(), static_cast<int>(q.size()));
      const auto t1 = Clock::now();
      correct_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
      applied += a.status == ServoStatus::kApplied;
      held += a.status == ServoStatus::kHeld;
      blending += a.weight < 1;
      worst_evaluations = std::max(worst_evaluations, a.ik_evaluations);
      ++outcomes[static_cast<size_t>(a.outcome)];
      if (a.status == ServoStatus::kApplied && a.weight == 1) ++evaluations_applied[static_cast<size_t>(a.ik_evaluations)];
    }
    for (long k = 0; k < kBlock / 10; ++k) {  // beside it, a tenth as many inverse kinematics
      const size_t i = static_cast<size_t>(ik_us.size()) % targets.size();
      const auto t0 = Clock::now();
      const IkResult r = solveInverseKinematics(m, truth, targets[i], obs[i].q_rad);
      const auto t1 = Clock::now();
      if (r.q_rad.size() == 0) return 3;
      ik_us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    }
  }
  const double c50 = percentile(correct_us, 0.5), c99 = percentile(correct_us, 0.99),
               c999 = percentile(correct_us, 0.999), cmax = *std::max_element(correct_us.begin(), correct_us.end());
  const double i50 = percentile(ik_us, 0.5);
  const int bound = RealtimeCompensator::evaluationBound(settings);
  std::printf("correct(): %ld calls (%ld applied, %ld held, %ld blending in a version or back after a refusal; %ld versions): p50 %.2f us, "
              "p99 %.2f us, p99.9 %.2f us, max %.1f us\n",
              calls, applied, held, blending, versions, c50, c99, c999, cmax);
  std::printf("inverse kinematics beside it: %zu calls, p50 %.2f us\n", ik_us.size(), i50);
  std::printf("ratios to the inverse kinematics' p50: correct() p50 %.2fx (target <= 3), p99.9 %.2fx (target <= 10)\n",
              c50 / i50, c999 / i50);
  std::printf("forward-kinematics evaluations in one cycle: at most %d seen, bounded by %d (2 x (3 + 2 x "
              "max_ik_evaluations %d))\n",
              worst_evaluations, bound, settings.max_ik_evaluations);
  std::printf("outcomes:");
  for (int o = 0; o < kNumCompensationOutcomes; ++o)
    if (outcomes[static_cast<size_t>(o)] > 0)
      std::printf(" %s %ld", outcomeName(static_cast<CompensationOutcome>(o)), outcomes[static_cast<size_t>(o)]);
  std::printf("\nevaluations of a cycle answered by one version:");
  for (size_t e = 0; e < evaluations_applied.size(); ++e)
    if (evaluations_applied[e] > 0) std::printf(" %zu:%ld", e, evaluations_applied[e]);
  std::printf("\n");
  if (!json.empty()) {
    std::ofstream out(json);
    out << "{\"calls\": " << calls << ", \"applied\": " << applied << ", \"held\": " << held
        << ", \"blending\": " << blending << ", \"versions\": " << versions << ", \"correct_us\": {\"p50\": " << c50
        << ", \"p99\": " << c99 << ", \"p999\": " << c999 << ", \"max\": " << cmax << "}, \"ik_us\": {\"p50\": " << i50
        << "}, \"evaluations\": {\"max_seen\": " << worst_evaluations << ", \"bound\": " << bound << "}}\n";
  }
  return c50 <= 3 * i50 && c999 <= 10 * i50 ? 0 : 1;
}
