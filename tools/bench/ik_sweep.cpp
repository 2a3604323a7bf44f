// cellcal_ik_sweep: the inverse-kinematics test (tests/core/test_inverse_kinematics.cpp) over thousands of random
// seeds, for both robots, and the same near the wrist singularity. Prints the failure rates; exits 1 if a target of
// the test's own distribution failed. Run by `make bench`.
//   build/bin/cellcal_ik_sweep [--seeds N] [--first-seed S]
//
// Distributions (a simulated robot with random geometric errors, 1 h warm; 20 targets per seed):
//   test      configurations uniform in 80 % of the joint limits, the solver seeded 0.1 rad (1 sigma per joint) off
//   wrist     the same with joint 5 within 0.05 rad of the wrist singularity, seeded 0.2 rad off
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>

#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace {
using namespace cellcal;

struct Sweep {
  long targets = 0, failed = 0, iterations = 0;
  double seconds = 0, worst_position_m = 0;
  std::uint64_t first_failing_seed = 0;
};

Sweep run(const RobotModel& nominal, std::uint64_t first_seed, int seeds, bool near_wrist_singularity) {
  Sweep s;
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < seeds; ++k) {
    SimulationConfig sc;
    sc.seed = first_seed + static_cast<std::uint64_t>(k);
    const SimulatedCell cell(nominal, sc);
    const Eigen::VectorXd params = cell.trueParams(1.0);
    std::mt19937_64 rng(sc.seed);
    std::normal_distribution<double> g(0.0, near_wrist_singularity ? 0.2 : 0.1);
    std::uniform_real_distribution<double> wrist(-0.05, 0.05);
    for (Eigen::VectorXd q : cell.randomConfigurations(20, rng)) {
      if (near_wrist_singularity) q[4] = wrist(rng);
      const Pose target = forwardKinematics(cell.model(), params, q);
      Eigen::VectorXd seed = q;
      for (int j = 0; j < seed.size(); ++j) seed[j] += g(rng);
      const IkResult r = solveInverseKinematics(cell.model(), params, target, seed);
      ++s.targets;
      s.iterations += r.iterations;
      if (!r.ok()) {
        if (s.failed++ == 0) s.first_failing_seed = sc.seed;
        s.worst_position_m = std::max(s.worst_position_m, r.position_error_m);
      }
    }
  }
  s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = 2000;
  std::uint64_t first = (static_cast<std::uint64_t>(std::random_device{}()) << 32) ^ std::random_device{}();
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--seeds") && i + 1 < argc) {
      seeds = std::atoi(argv[++i]);
    } else if (!std::strcmp(argv[i], "--first-seed") && i + 1 < argc) {
      first = std::strtoull(argv[++i], nullptr, 10);
    } else {
      std::fprintf(stderr, "usage: cellcal_ik_sweep [--seeds N] [--first-seed S]\n");
      return 2;
    }
  }
  std::printf("cellcal_ik_sweep: %d seeds x 20 targets per robot and distribution, seeds %llu..%llu\n", seeds,
              static_cast<unsigned long long>(first), static_cast<unsigned long long>(first + seeds - 1));
  std::printf("%-14s %-6s %9s %7s %10s %12s %10s  %s\n", "robot", "dist", "targets", "failed", "rate", "us/solve",
              "iter/solve", "worst miss / first failing seed");
  bool test_failed = false;
  for (const char* name : {"staubli_tx60", "ur10"}) {
    const RobotModel m = loadRobotModel(std::string(CELLCAL_CONFIG_DIR) + "/robots/" + name + ".yaml");
    for (bool wrist : {false, true}) {
      const Sweep s = run(m, first, seeds, wrist);
      char worst[96] = "";
      if (s.failed)
        std::snprintf(worst, sizeof worst, "%.3g um / CELLCAL_TEST_SEED=%llu", s.worst_position_m * 1e6,
                      static_cast<unsigned long long>(s.first_failing_seed));
      std::printf("%-14s %-6s %9ld %7ld %10.2e %12.1f %10.1f  %s\n", name, wrist ? "wrist" : "test", s.targets, s.failed,
                  static_cast<double>(s.failed) / static_cast<double>(s.targets), s.seconds / s.targets * 1e6,
                  static_cast<double>(s.iterations) / static_cast<double>(s.targets), worst);
      test_failed = test_failed || (!wrist && s.failed > 0);
    }
  }
  return test_failed ? 1 : 0;
}
