// Uses the installed cellcal::core as the README's "Using the core library" does: a robot file from the installed
// configuration, a batch calibration of simulated poses, then RLS pose by pose; and a measurement file (CSV v1) it
// writes calibrated as `cellcal calibrate` does (campaign.hpp). Exit 0 only when the calibrated model is far closer to
// the simulated truth than the nominal one, and the campaign's verdict is to deploy a model that beats the start.
#include <cstdio>
#include <fstream>
#include <random>

#include "cellcal/core/campaign/campaign.hpp"
#include "cellcal/core/files/measurement_csv.hpp"

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
  if (!r.converged || !(calibrated < nominal / 10)) return 1;

  // A measurement file of 60 poses, calibrated as a campaign.
  {
    std::ofstream csv("consumer_campaign.csv");
    csv << "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n";
    csv.precision(12);
    for (const auto& q : cell.randomConfigurations(60, rng)) {
      const cellcal::Observation o = cell.measure(q, 0.0, rng);
      for (int j = 0; j < 6; ++j) csv << q[j] * 180 / cellcal::kPi << ",";
      const Eigen::Vector3d p = o.measured_in_tracker.translation() * 1e3;
      csv << p.x() << "," << p.y() << "," << p.z() << "\n";
    }
  }
  cellcal::RobotFile rf;
  rf.model = robot;
  cellcal::CampaignProblem campaign;
  campaign.setups = {cellcal::prepareCampaignInput(
      "consumer_campaign.csv", rf, cellcal::readMeasurementCsv("consumer_campaign.csv", robot), cellcal::InputOptions{})};
  const cellcal::CampaignReport report = cellcal::calibrateCampaign(campaign);
  const auto& e = report.errors;
  std::printf("consumer: campaign of %zu rows: held-out mean %.4f mm before -> %.4f mm after, exit code %d\n%s\n",
              campaign.setups[0].file.rows.size(), e.verification_kept_before.mean_mm, e.verification_kept_after.mean_mm,
              report.exitCode(), cellcal::recommendationText(report).c_str());
  return report.exitCode() == 0 && e.verification_kept_after.mean_mm < e.verification_kept_before.mean_mm / 5 ? 0 : 1;
}
