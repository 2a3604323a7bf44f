// Model diagnosis: fit the geometric model, look at what it leaves, test each physical cause of
// model_extension.hpp as an extension (fitExtended, extended_fit.hpp), and choose by held-out error; say what is
// still left.
//
//   ExtendedFit f = fitExtended(model, start, ident, ident_drivers, {Cause::kBacklash, 2});   // extended_fit.hpp
//   DiagnosisResult d = diagnose(model, start, {ident, ident_drivers, verify, verify_drivers, has_thermal});
//
// Gross errors: the selection runs on every row, then the model it chose screens for them (outliers.hpp: a robust fit
// of that model on the identification rows, the verification rows against it); where that flags rows the selection
// runs again without them, until the flags repeat (three selections at the most). Flagged rows take no part in fits
// or scores.
// Choice, by forward selection of up to max_causes causes: every applicable (cause, joint) is fitted on the
// identification rows together with the geometric parameters and any causes already chosen (warm-started from the
// model so far) and scored on the verification rows by the mean squared position error times
// (1 + penalty_per_param * k / identification residual rows), k = extension parameters estimated. The best-scoring
// candidate is added only if it beats the model so far on the verification rows by more than min_gain (relative mean
// squared error) and by more than min_z standard errors of the paired per-row difference of squared errors. Among the
// candidates that pass, a simpler one (fewer parameters) is preferred unless the better-scoring one beats it by
// parsimony_z standard errors (two causes that explain the data equally well: the one with fewer parameters is
// named). Noise alone thus yields `none`. Thermal drift is also tried on the lengths alone (joint -1): a joint is named
// only when its zero drift is needed.
// Regions: the causes chosen are then checked where their data never were (region_check, RegionCheck): each, in the
// order chosen, with the causes kept before it, fitted on part of the rows kept (identification and verification
// together) and judged on rows beyond them (past either end of its joint's range, or the other half of the
// workspace) against the model without it. A cause that makes the error there worse (it fits the rows it saw, not the
// robot: a cyclic term fitted on part of a joint's range can be off by millimetres beyond it) is left out, with every
// cause chosen after it (they were chosen beside it), and named.
// Verdict: the residual the final model leaves on the verification rows is tested for structure against each driver
// the file has (residualStructure): a cause is reported as the explanation only when nothing is left; otherwise
// "partly explained by ...; structure left against <driver> (N %)".
#pragma once

#include <Eigen/Core>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/identification/outliers.hpp"

namespace cellcal {

struct DiagnosisData {
  std::vector<Observation> identification, verification;
  std::vector<Drivers> identification_drivers, verification_drivers;
  bool has_thermal = false;
  std::string thermal_source;  // for reports: "temperature_c" or "stamp_s"
  // The rows' temperature where the column holds one that never changes (DriverTable): said, not used as a driver.
  std::optional<double> constant_temperature_c;
  // "temperature_c", "stamp_s (temperature_c constant at 22.40 C)", "none (temperature_c constant at 22.40 C)", "none".
  std::string thermalText() const;
};

// A split of rows by region of the workspace: the measured target positions cut at their median along the direction
// in which they spread most (their covariance's largest principal axis); true for the far half. No row of one half
// lies on the other's side of the cut. Fewer than 8 rows: every row false.
std::vector<bool> regionSplit(const std::vector<Observation>& obs);

// A chosen cause judged where its data never were (DiagnosisOptions::region_check), in two folds whose judged rows
// are pooled. For a joint's cyclic error, scale, backlash or compliance, by the angle of that joint: the rows up to
// its upper quantile (1 - region_joint_end) fitted and those beyond it judged, and the same at the lower end (a
// periodic or stiffness term fitted on part of a joint's range, carried beyond it). For other causes, by the workspace
// (regionSplit): each half fitted, the other judged.
// What is judged is the model's form, not the fold's estimate: a fold's fit has fewer rows and a narrower range than
// the campaign's, so a true cause near the noise can predict worse beyond it only because its extra parameters are
// less certain there. Each model's squared error on a judged row is taken less its fit's variance there (the
// parameters it estimated, their covariance scaled by the residual scatter it left on its rows); what is left is what
// its form gets wrong, plus the readings' noise, the same for both.
struct RegionCheck {
  Extension cause;                   // the cause judged, fitted with the causes kept before it
  std::string split;                 // "q2" (by joint 2's angle) or "workspace"
  int judged_rows[2] = {0, 0};       // observations judged in each fold
  double mean_without_mm = 0, mean_with_mm = 0;    // mean position error on the judged rows
  double sigma_without_mm = 0, sigma_with_mm = 0;  // RMS there of the position error the fits' uncertainty explains
  // Without -> with the cause, of the mean squared position error there less each fit's variance, as a share of the
  // mean squared error without it (positive: the cause helps).
  double gain_pct = 0;
  double z = 0;                      // that difference row by row, in standard errors of its mean
  bool transfers = true;             // not (gain_pct < 0 and z < -region_z)
};
// RegionCheck::split for a cause: "q<joint>" (1-based) or "workspace".
std::string regionSplitName(const Extension& cause);

// Whether a drift diagnose finds could be the base frame's rather than the robot's. A thermal drift of joint 1's zero
// is the same motion as the robot's base turning about joint 1's axis in the tracker's frame (a tracker or a base that
// creeps), and a frame drift is partly alike to any drift. With a thermal driver, diagnose fits the alternatives on
// the identification rows and judges them on the verification rows, as the forward selection judges a cause (more
// than min_z standard errors of the paired difference and more than min_gain of the mean squared error):
//   - a drift was chosen: the model with each thermal_drift replaced by frame_drift (the base frame moving with the
//     same driver, model_extension.hpp), and the model with both. Whether the drift adds to the frame drift, and the
//     frame drift to the drift, are the two nested tests (more parameters alone never decide it);
//   - no drift was chosen but structure against the thermal driver ("time" or "thermal") is left: the model with
//     frame_drift added, against the model chosen.
struct DriftCheck {
  enum class Outcome {
    kNotRun,
    kToldApart,           // the drift adds to a frame drift; a frame drift adds nothing to it
    kAlike,               // neither adds to the other: the data cannot tell them
    kFrameDriftBetter,    // a frame drift adds to the drift; the drift adds nothing to a frame drift
    kBoth,                // each adds to the other: the robot drifts and the frame moves
    kFrameDriftExplains,  // structure left: frame_drift added to the model passes the test
    kNotAFrameDrift,      // structure left: it does not
  };
  Outcome outcome = Outcome::kNotRun;
  std::vector<Extension> chosen, alternative, both;  // the models judged (with their fitted time constants)
  double mean_chosen_mm = 0, mean_alternative_mm = 0, mean_both_mm = 0;  // verification rows kept
  // Paired improvement, in standard errors, of the model with both over the frame drift alone (the drift adds) and
  // over the model chosen (the frame drift adds). Structure left: `alternative` is the model chosen with frame_drift
  // added and only z_frame is set.
  double z_drift = 0, z_frame = 0;
  std::string text;  // one sentence for the verdict and the report; empty when not run
};
const char* driftOutcomeName(DriftCheck::Outcome o);  // "not_run", "told_apart", "alike", ...

struct DiagnosisOptions {
  std::vector<Cause> causes = extensionCauses();
  double penalty_per_param = 2.0;
  double min_gain = 0.03;    // relative reduction of the verification mean squared error
  double min_z = 4.0;        // standard errors of the paired difference
  double parsimony_z = 2.0;  // a candidate with more parameters must beat a simpler significant one by this much
  int max_causes = 3;        // causes chosen together at the most (forward selection)
  double structure_alpha = 0.001;  // family-wise false alarm rate of the structure test (nominal, iid noise)
  OutlierOptions outliers;
  SolverOptions solver;
  IdentifiabilityOptions identifiability;
  // A parameter (kinematic or of a candidate extension) whose excitation on the identification rows is below this
  // fraction of its largest on a verification row is held, not estimated (excitationDeficits, prediction.hpp). 0: off.
  double excitation_ratio = 0.1;
  // Held-out max beyond this many times the identification max (or a held-out mean worse than the start model's):
  // the fit is not usable and nothing is recommended (unusableFit).
  double max_extrapolation_ratio = 3.0;
  // Each forward-selection round screens its candidates with one linearized step from the round's base fit and fits
  // in full only the best, at most this many (and any warm-up whose time constant the fit searches); 0: every
  // candidate in full.
  int screen_keep = 2;
  // ... of those whose screened score is within this fraction of the best screened score (the best always).
  double screen_margin = 0.05;
  // The screen judges at most this many identification and this many verification observations (every k-th of a
  // larger file); 0: all of them. The fits use every row.
  int screen_rows = 2000;
  // Check each chosen cause on a half of the rows its fit never saw (RegionCheck: by its joint's angle or by the
  // workspace, over the rows kept, both ways round) against the model without it: a cause whose form makes the error
  // there worse (beyond what the fits' uncertainty explains), by more than region_z standard errors of the paired
  // difference, is left out with those chosen after it.
  // Not run for a cause whose halves hold fewer than region_min_rows observations (DiagnosisResult::region_note).
  bool region_check = true;
  double region_z = 2.0;
  double region_joint_end = 0.25;  // the share of rows judged at each end of a joint's range
  int region_min_rows = 40;
  // Each half's fit takes at most this many observations (every k-th of a larger half); the judged half all of its
  // own. 0: every one.
  int region_fit_rows = 3000;
  // DriftCheck (above): needs a thermal driver; one more fit where it runs.
  bool drift_check = true;
  // Called after the geometric fit and after each candidate fit: (fits done, fits in all). Empty: none. For progress
  // bars on large files; runs on the caller's thread.
  std::function<void(int done, int total)> progress;
  bool IsValid(std::string* error) const;
};

// A parameter the identification rows leave unexcited while another row of the same data excites it (prediction.hpp).
struct ExcitationDeficit {
  int column = -1;  // kinematic index, or numParams() + k for extension parameter k
  std::string name;
  double identification_rms = 0, elsewhere_max = 0;  // whitened column norms per observation
};

struct CandidateResult {
  ExtendedFit fit;
  std::vector<ExcitationDeficit> held;      // parameters held for an excitation deficit
  ErrorStats identification, verification;  // over the rows kept (gross errors left out)
  double verify_mse_m2 = 0;  // mean squared position error on the verification rows
  double score = 0;          // verify_mse_m2 * (1 + penalty * k / rows)
  double z = 0;              // paired improvement over the geometric model, in standard errors
  // Judged by the linearized screen only (DiagnosisOptions::screen_keep): `fit` is one Gauss-Newton step from the
  // round's base, `verification` the residual that step predicts (no identification figures); never chosen.
  bool screened = false;
};

// How much structure against one driver the held-out position residual of a fit still has. The residual components
// are regressed on the driver's regressors (angles: sin, cos, sin 2x, cos 2x; torques and thermal: x, x^2; time since
// the first row: x, x^2; direction: x; workspace: the 9 quadratic terms of the target position in the robot base
// frame), beyond what the fit's own parameters could absorb (their Jacobian columns on these rows, since their
// estimation error is structured too): partial F-test. `share` is the part of the residual's variance the driver
// explains beyond the model (partial R^2); significant when p_value < alpha / the number of drivers (Bonferroni).
struct DriverStructure {
  std::string driver;  // "q2", "gravity_torque_2", "thermal", "time", "direction_3", "workspace"
  double share = 0;
  double p_value = 1;
  bool significant = false;
};
std::vector<DriverStructure> residualStructure(const RobotModel& model, const CalibratedModel& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                               bool has_thermal, double alpha = 0.001);

// The reading noise (1 sigma per axis), estimated from the data where they allow it: from rows measured at the same
// configuration (within 2e-3 rad per joint; the difference of their residuals under the fit, in which the model's
// error cancels) when they give 30 degrees of freedom or more; otherwise from the residual of `fit` on the rows it
// was fitted to, with its degrees of freedom (an upper bound: it holds whatever the model leaves).
struct NoiseEstimate {
  double sigma_position_mm = 0;
  int dof = 0;
  bool from_repeats = false;
  std::string source;  // "repeated poses (12 groups, 30 rows)" or "residual of <model> on 195 identification rows"
};
NoiseEstimate estimateNoise(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& fitted,
                            const std::vector<Drivers>& fitted_drivers, const std::vector<Observation>& predicted,
                            const std::vector<Drivers>& predicted_drivers);

// One step of the forward selection: the cause added, the model with it and what it gained over the model before.
struct SelectionStep {
  Extension added;
  CandidateResult result;   // every cause chosen so far, fitted together
  double z = 0;             // paired improvement over the model before, in standard errors
  double gain_pct = 0;      // verification mean position error, model before -> this one
  // Other causes that passed the same test in this round and that the one added does not beat by parsimony_z
  // standard errors: on these data they explain the residual about as well (e.g. a joint's compliance and the
  // deflection of the link it carries). Best first, at most 3.
  std::vector<Extension> alike;
};

enum class Verdict {
  kNoise,            // no cause, and the geometric model leaves no structure
  kNamed,            // causes named; no structure left
  kPartlyExplained,  // causes named, structure left
  kUnexplained,      // no cause, structure left: something the library does not have
  kUnusable,         // the chosen model is worse than the start on held-out rows or extrapolates: no recommendation
};

struct DiagnosisResult {
  CandidateResult geometric;
  std::vector<CandidateResult> candidates;  // each single cause against the geometric model, best score first
  std::vector<SelectionStep> selection;     // the causes chosen, in order (empty: none)
  int chosen = -1;                          // index into candidates of the first cause chosen; -1: none
  Cause cause = Cause::kNone;               // the first cause chosen
  std::vector<int> joints;                  // 0-based joints (links) of the first cause
  std::vector<Extension> causes() const;    // every cause chosen
  double gain_pct = 0;                      // verification mean position error, geometric -> final
  std::vector<DriverStructure> structure_before, structure_after;  // geometric / final model, strongest first
  Verdict verdict = Verdict::kNoise;
  const DriverStructure* structureLeft() const;  // the strongest significant structure after; null: none
  NoiseEstimate noise;
  double noise_rms_mm = 0;                  // sqrt(3) noise.sigma_position_mm: the RMS error noise alone would leave
  double unexplained_rms_mm = 0;            // sqrt(max(0, final verify RMS^2 - noise RMS^2)), outliers excluded
  // Gross errors (indices into the identification / verification rows). Every CandidateResult's figures are over the
  // rows kept; these are the geometric and the final model on every verification row, outliers included.
  OutlierScreen identification_outliers, verification_outliers;
  ErrorStats geometric_verification_all_rows, verification_all_rows;
  ErrorStats start_verification;            // the start model (nominal kinematics, registered frames), rows kept
  std::string unusable;                     // why the chosen model cannot be used (unusableFit); empty: it can
  // The region check, in the order of the selection (the causes left out included); `not_transferred`: the causes it
  // left out (the selection above no longer holds them); `region_note`: why it did not run, empty when it ran.
  std::vector<RegionCheck> region_checks;
  std::vector<Extension> not_transferred;
  std::string region_note;
  DriftCheck drift_check;
  double solve_time_s = 0;
  // The noise_scale every fit decided its parameters with: with plausible ranges (identifiability.prior_sigma), the
  // root of the variance factor of a robust geometric fit on the identification rows (at least the options' own).
  double identifiability_noise_scale = 1.0;
  const CandidateResult& best() const { return selection.empty() ? geometric : selection.back().result; }
};

// The signature of a cause in the data, for figures: per observation, the driver of the cause (x) and the residual
// expressed as the cause's own quantity (y), under the geometric fit (before) and the extended fit (after).
// Joint causes: y = apparent error of joint j (deg), the least-squares joint-angle change that explains the position
// residual; x = gravity torque on joint j (N m; without link masses, of a unit mass at the target, N m/kg), the
// thermal driver, q_j (deg), or the direction joint j last moved (+-1, spread by +-0.15 so the two groups show).
// Thermal drift of the lengths alone: y = apparent relative growth of all lengths (um/m), x = the thermal driver.
struct CauseSignature {
  std::string x_label, y_label;
  std::vector<double> x, y_before, y_after;
};
CauseSignature causeSignature(const RobotModel& model, const ExtendedFit& geometric, const ExtendedFit& extended,
                              const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                              const std::string& thermal_source);

// Why a fitted model cannot be used, or empty when it can: its held-out mean position error is worse than the start
// model's (nominal kinematics with registered frames), or its held-out max exceeds max_ratio times its identification
// max (it extrapolates: the held-out rows reach where the identification rows did not pin the model down).
std::string unusableFit(const ErrorStats& start_held_out, const ErrorStats& held_out, const ErrorStats& identification,
                        double max_ratio = 3.0);

DiagnosisResult diagnose(const RobotModel& model, const Eigen::VectorXd& start, const DiagnosisData& data,
                         const DiagnosisOptions& options = {});
// The verdict in words, from the result's values: "partly explained by joint_compliance:2; structure left against
// workspace (31 %)", with what was left out and a drift the base frame explains; "no recommendation: ..." when unusable.
std::string describeVerdict(const DiagnosisResult& result);

// The region check diagnose runs on its selection: `obs` (rows without gross errors; diagnose passes identification and
// verification together) split in two for each step's cause (RegionCheck); the causes kept before it without and with
// it, fitted on each half (warm-started from `geometric` and the steps' fits; parameters unexcited there but excited on
// the other half held) and judged on the other. Stops after the first cause that does not transfer, or before one
// whose halves hold fewer than options.region_min_rows observations (the reason in `note`).
std::vector<RegionCheck> checkRegions(const RobotModel& model, const Eigen::VectorXd& start,
                                      const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                      const ExtendedFit& geometric, const std::vector<SelectionStep>& steps,
                                      const DiagnosisOptions& options, std::string* note);

// A model carried to a new set-up (calibrate --frames-only) judged on its rows: the robot file's extended model and
// the same campaign's geometric calibration (RobotCalibration::geometric_params), each with its frames registered on
// `identification` (closed form, then refineFrames with the rest held), judged on `verification`. The extensions do
// not transfer when the geometric model is better there by more than `z_limit` standard errors of the paired per-row
// difference and `min_gain` of the mean squared position error.
struct CarriedComparison {
  ExtendedFit extended, geometric;  // frames registered on the identification rows
  double mean_extended_mm = 0, mean_geometric_mm = 0;  // verification rows
  double z = 0;                     // paired improvement of the geometric model over the extended one
  bool extensions_transfer = true;
  std::string text;                 // one sentence
};
CarriedComparison compareCarried(const RobotModel& model, const ExtendedFit& extended, const Eigen::VectorXd& geometric_params,
                                 const std::vector<Observation>& identification,
                                 const std::vector<Drivers>& identification_drivers,
                                 const std::vector<Observation>& verification,
                                 const std::vector<Drivers>& verification_drivers, double z_limit = 2.0,
                                 double min_gain = 0.03);

// A calibration carried to a new set-up judged against the kinematics it started from (RobotCalibration::
// nominal_params): the nominal kinematics with their frames registered on `identification` as the carried model's
// are, both judged on `verification` (the same rows). The nominal is better when its held-out mean is lower: the
// same data then show the calibration worse than no calibration, and it is not to be deployed.
struct NominalComparison {
  ExtendedFit nominal;                                // the nominal kinematics, frames registered
  double mean_carried_mm = 0, mean_nominal_mm = 0;    // verification rows
  double z = 0;                                       // paired improvement of the nominal over the carried model
  bool nominal_better = false;
};
NominalComparison compareWithNominal(const RobotModel& model, const ExtendedFit& carried,
                                     const Eigen::VectorXd& nominal_params,
                                     const std::vector<Observation>& identification,
                                     const std::vector<Drivers>& identification_drivers,
                                     const std::vector<Observation>& verification,
                                     const std::vector<Drivers>& verification_drivers);

// The drift check diagnose runs (DriftCheck) on its result: `identification` and `verification` are the rows kept
// (without gross errors); `best` the model chosen. kNotRun where it does not apply (no thermal driver, neither a
// drift chosen nor structure against the thermal driver left).
DriftCheck checkDrift(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& identification,
                      const std::vector<Drivers>& identification_drivers, const std::vector<Observation>& verification,
                      const std::vector<Drivers>& verification_drivers, bool has_thermal, const CandidateResult& best,
                      const DriverStructure* structure_left, const DiagnosisOptions& options);

}  // namespace cellcal
