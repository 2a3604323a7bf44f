// A calibration campaign, whole: the rows of one or several set-ups (campaign_input.hpp) -> the fit (geometric, named
// causes, or the causes `diagnose` names; or only the frames of a calibrated robot file), the error figures before
// and after on both row sets with their gross errors, the predicted error and whether the actual one agrees, what the
// extensions do beyond their data, the residual map, the verdict, and the calibration a robot file saves.
// `cellcal calibrate` is this plus printing; a program linking cellcal::core calibrates a measurement file with it.
//
//   CampaignProblem p;  p.setups = {prepareCampaignInput(...)};  p.model = CampaignModel::kAuto;
//   const CampaignReport r = calibrateCampaign(p);  // r.exitCode(): 0 deploy, 3 not converged, 4 not usable
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/campaign/campaign_input.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/identification/residual_map.hpp"
#include "cellcal/core/identification/setups.hpp"

namespace cellcal {

enum class CampaignModel {
  kGeometric,  // the kinematic parameters and frames
  kAuto,       // the causes `diagnose` names on the identification rows (with several set-ups: the same in each)
  kNamed,      // CampaignProblem::extensions
};
enum class CampaignSolver { kGaussNewton, kLevenbergMarquardt };  // Levenberg-Marquardt: geometric, one set-up

struct CampaignProblem {
  std::vector<CampaignInput> setups;  // one, or several set-ups of one robot: one model, frames per set-up
  CampaignModel model = CampaignModel::kGeometric;
  std::vector<Extension> extensions;  // kNamed
  CampaignSolver solver = CampaignSolver::kGaussNewton;
  // Rank tolerance and plausible ranges (prior_sigma over the kinematic parameters; empty: rank alone decides).
  IdentifiabilityOptions identifiability;
  OutlierOptions outliers;
  // Hold (and name) a parameter whose excitation on the identification rows is below this fraction of its largest on
  // a verification row; 0: off.
  double excitation_ratio = DiagnosisOptions{}.excitation_ratio;
  bool region_check = true;  // kAuto: each cause fitted on one half of the workspace and judged on the other
  // Keep the first set-up's robot file kinematics and extensions; register only the base and tool frames. Where the
  // file's extensions do not transfer to these rows, its geometric calibration is used unless keep_extensions.
  bool frames_only = false, keep_extensions = false;
  // Learn what the model leaves at the identification rows (residual_map.hpp) and judge it on the verification rows.
  bool residual_map = false;
  ResidualMapOptions residual_map_options;
  // First in the saved calibration's provenance (the caller's: date, tool, files, their hashes).
  std::vector<std::pair<std::string, std::string>> provenance;
  // Long work (diagnose: tens of fits) reports `done` of `total` under a stage name; may be empty.
  std::function<void(const std::string& stage, int done, int total)> progress;
  // At least one set-up with rows; one robot (same joints) in every set-up; kNamed with extensions; frames_only and
  // the Levenberg-Marquardt solver with one set-up and a geometric model.
  bool IsValid(std::string* why) const;
};

// Before (the start: nominal kinematics, registered frames) and after on both row sets; the verification rows
// without their gross errors (judged against the calibrated model); the gross errors of both.
struct CampaignErrors {
  ErrorStats identification_before, identification_after, verification_before, verification_after;
  ErrorStats verification_kept_before, verification_kept_after, identification_kept_after;
  OutlierScreen identification_outliers, verification_outliers;
};

// The predicted model error (prediction.hpp) on the rows kept, and whether the actual errors agree: RMS of actual /
// sqrt(predicted^2 + 3 s^2 sigma_reading^2) over the verification rows.
struct PredictionCheck {
  double identification_rms_mm = 0, identification_max_mm = 0, verification_rms_mm = 0, verification_max_mm = 0;
  double ratio_rms = 0;
  int extrapolated = 0;    // verification rows predicted more than 3x the largest identification row
  // verification rows farther beyond a joint's range, or an extension driver's, than its folds judged (firstUnjudged)
  int beyond_checked = 0;
};

// The residual map judged on the verification rows: the held-out mean with the map where it applies against without
// it on the same rows, and over every row.
struct ResidualMapCheck {
  double fit_time_s = 0;
  int verification_rows = 0;       // judged: the verification rows without their gross errors
  int verification_rows_near = 0;  // of them, within the map's reach
  double near_mean_with_mm = 0, near_mean_without_mm = 0, near_sigma_mean_mm = 0;
  double all_mean_with_mm = 0, all_mean_without_mm = 0;
};

// Several set-ups: one per set-up.
struct SetupReport {
  CampaignErrors errors;
  int rows_left_out_backlash = 0;
  Eigen::VectorXd frames;  // the set-up's 12 base and tool frame parameters (SI), as the fit has them
};

struct CampaignReport {
  bool several_setups = false;
  std::string model_label;  // "geometric", "joint_compliance:2", "the robot file's (...), frames only", ...
  bool converged = false;
  int iterations = 0;
  size_t estimated = 0;     // parameters estimated
  std::string message;      // the solver's, when it did not converge
  double solve_s = 0;
  std::string unusable;     // why the result cannot be used; empty: it can
  bool frames_only = false; // the problem's: the robot file's model with new frames (no baseline to beat)
  // The calibration --save-robot writes (robot file kinematics `saved_params`), complete only when exitCode() is 0.
  RobotCalibration calibration;
  Eigen::VectorXd saved_params;
  int exitCode() const { return !converged ? 3 : !unusable.empty() ? 4 : 0; }

  // One set-up.
  ExtendedFit before, after;               // the start; the calibrated model
  CalibrationResult geometric;             // the geometric fit beneath (empty with frames_only)
  std::vector<ExcitationDeficit> held;     // held for an excitation deficit
  std::optional<DiagnosisResult> diagnosis;                // kAuto: what diagnose found
  std::optional<CarriedComparison> carried;                // frames_only: the file's extensions against its geometry
  // frames_only, when the robot file keeps the kinematics its calibration started from: the carried model against
  // them on the same rows ('before' is then the nominal kinematics); the nominal deployed when better, unless
  // keep_extensions keeps the file's model (then unusable: exit 4).
  std::optional<NominalComparison> against_nominal;
  // frames_only: the tool frame's translation or rotation that these rows leave open beyond 1 mm or 0.1 deg in some
  // direction (one tool orientation, or nearly), held at the robot file's values, each parameter with the sigma (SI)
  // the rows would give it (infinite: none).
  std::vector<std::pair<int, double>> frames_held;
  bool nominal_deployed = false;
  bool nominalDeployed() const { return nominal_deployed; }
  std::optional<ExtensionTransfer> transfer;               // extensions: measured on region folds
  std::vector<BeyondRange> beyond;                         // what the extensions may do beyond the data (or carried)
  std::vector<DriverRange> beyond_drivers;                 // the same beyond their drivers' ranges
  CampaignErrors errors;
  double frames_variance_factor = 1;                       // frames_only: what the frames leave against the sigmas
  PredictionModel prediction;
  PredictionCheck check;
  std::vector<std::string> implausible;    // parameters moved further than a robot built to its drawing could be
  std::optional<ResidualMap> residual_map;
  ResidualMapCheck residual_map_check;

  // Several set-ups.
  std::vector<Extension> extensions;       // the robot's model, common to every set-up
  std::vector<std::string> extension_names;
  SetupsFit setups_fit;
  std::vector<SetupReport> setups;
  std::vector<std::string> held_names;     // what the rows leave open ("set-up2.base_x", kinematic names)
};

// Throws ConfigError when !problem.IsValid, or (kAuto, several set-ups) the set-ups name different models.
CampaignReport calibrateCampaign(const CampaignProblem& problem);

// The last line of a one-set-up calibration, in words: deploy this model or not (exitCode()), and why, from the report's
// figures (before/after: the held-out rows without their gross errors): "recommendation: deploy the geometric model:
// held-out mean 0.0412 mm against 0.2671 mm before (85 % better)"; "" for several set-ups.
std::string recommendationText(const CampaignReport& report);

// A column's 1 sigma in a prediction's covariance (what a robot file saves and predictions use; SI), NaN when the
// prediction does not cover it.
double savedSigma(const PredictionModel& prediction, int column);

}  // namespace cellcal
