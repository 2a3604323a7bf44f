// What campaign.cpp and campaign_setups.cpp share; not installed.
#pragma once

#include <string>

#include "cellcal/core/campaign/campaign.hpp"

namespace cellcal::internal {

// `diagnose` on a set-up's rows with the campaign's identifiability, gross-error, excitation and region settings; its
// progress reported under `stage`.
DiagnosisResult diagnoseForAuto(const CampaignProblem& problem, const CampaignInput& setup, const std::string& stage);

// The errors of `before` and `after` on a set-up's rows; the verification rows screened against `after`.
CampaignErrors campaignErrors(const RobotModel& robot, const ExtendedFit& before, const ExtendedFit& after,
                              const DiagnosisData& data, const OutlierScreen& identification_outliers,
                              const OutlierOptions& outliers);

CampaignReport calibrateSetups(const CampaignProblem& problem);

}  // namespace cellcal::internal
