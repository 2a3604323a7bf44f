// Uses the installed cellcal::core as the README's "Using the core library" does: a robot file from the installed
// configuration, a batch calibration of simulated poses, then RLS pose by pose. Exit 0 only when the calibrated model
// is far closer to the simulated truth than the nominal one.
#include <cstdio>
#include <random>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/identification/rls.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/sim/simulation.hpp"

int main() {
  const cellcal::RobotModel robot = cellcal::loadRobotModel(std::string(CELLCAL_INSTALLED_CONFIG_DIR) + "/robots/staubli_tx60.yaml");
  cellcal::SimulationConfig sc;
  sc.seed = 7;
  const cellcal::SimulatedCell cell(robot, sc);
  std::mt19937_64 rng(7);
  std::vector<cellcal::Observation> obs;
  for (const auto& q : cell.randomConfigurations(40, rng)) obs.push_back(cell.measure(q, 0.0, rng));
  cellcal::CalibrationProblem problem{&cell.model(), cell.nominalParams(), obs, std::nullopt, {}, {}};
  std::string why;
  if (!problem.IsValid(&why)) {
    std::fprintf(stderr, "consumer: %s\n", why.c_str());
    return 1;
  }
  const cellcal::CalibrationResult r = cellcal::solveLevenbergMarquardt(problem);
  cellcal::RlsCalibrator rls(cell.model(), r);
  for (const auto& q : cell.randomConfigurations(15, rng)) rls.addObservation(cell.measure(q, 0.0, rng));
  auto meanErrorMm = [&](const Eigen::VectorXd& params) {
    double s = 0;
    const auto qs = cell.randomConfigurations(50, rng);
    for (const auto& q : qs)
      s += (cellcal::forwardKinematics(cell.model(), params, q).translation() - cell.truePose(q, 0.0).translation()).norm();
    return s / static_cast<double>(qs.size()) * 1e3;
  };
  const double nominal = meanErrorMm(cell.nominalParams()), calibrated = meanErrorMm(rls.params());
  std::printf("consumer: cellcal::core from %s: converged %d, mean error %.3f mm nominal -> %.4f mm calibrated\n",
              CELLCAL_INSTALLED_CONFIG_DIR, r.converged ? 1 : 0, nominal, calibrated);
  return r.converged && calibrated < nominal / 10 ? 0 : 1;
}
