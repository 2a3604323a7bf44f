// `cellcal calibrate`'s options, and what it prints and writes of a campaign's report (campaign.hpp).
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "cellcal/core/campaign/campaign.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {

struct CalibrateArgs {
  InputArgs input;
  std::string json, model = "geometric", solver = "gn";
  double rank_tolerance = IdentifiabilityOptions{}.rank_tolerance;
  double excitation_ratio = DiagnosisOptions{}.excitation_ratio;
  std::string save_robot;
  std::string report;  // --report: a folder for report.md and its figures
  bool frames_only = false;
  bool keep_extensions = false;
  bool residual_map = false, no_region_check = false;
  double residual_map_distance = ResidualMapOptions{}.max_distance;
};

// The report as text on stdout: the rows, the fit, the errors before and after with the gross errors, the
// parameters with their sigmas, the predicted error and its check, what is held; with one set-up the verdict last.
void printCampaignReport(const CalibrateArgs& a, const CampaignProblem& problem, const CampaignReport& report);
// The report as --json writes it (docs/diagnosis.md and docs/real-robots.md name its fields).
nlohmann::json campaignJson(const CalibrateArgs& a, const CampaignProblem& problem, const CampaignReport& report);
// --report DIR (one set-up): report.md with the held-out errors before and after (mean, RMS, 99.7th percentile, max),
// their histogram, along each joint and over the workspace (SVG figures drawn by gnuplot), and the parameters with
// their sigmas (calibrate_figures.cpp). Throws ConfigError for several set-ups.
void writeCalibrationReport(const std::string& dir, const CalibrateArgs& a, const CampaignProblem& problem,
                            const CampaignReport& report);

}  // namespace cellcal::cli
