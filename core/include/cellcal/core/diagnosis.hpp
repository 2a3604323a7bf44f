// Model diagnosis: fit the geometric model, look at what it leaves, test each physical cause of
// model_extension.hpp as an extension, and choose by held-out error.
//
//   ExtendedFit f = fitExtended(model, start, ident, ident_drivers, {Cause::kBacklash, 2});   // one extension
//   DiagnosisResult d = diagnose(model, start, {ident, ident_drivers, verify, verify_drivers, has_thermal});
//
// Choice: every applicable (cause, joint) is fitted on the identification rows together with the geometric
// parameters (warm-started from the geometric fit) and scored on the verification rows by the mean squared position
// error times (1 + penalty_per_param * k / identification residual rows), k = extension parameters estimated.
// The best-scoring candidate is chosen only if it beats the geometric model on the verification rows by more than
// min_gain (relative mean squared error) and by more than min_z standard errors of the paired per-row difference
// of squared errors; otherwise the cause is `none`. Noise alone thus yields `none`. Among the candidates that pass,
// a simpler one (fewer parameters) is preferred unless the better-scoring one beats it by parsimony_z standard errors
// (two causes that explain the data equally well: the one with fewer parameters is named).
// Thermal drift is also tried on the lengths alone (joint -1, `joints` empty): a joint is named only when its zero
// drift is needed.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <string>
#include <vector>

#include "cellcal/core/calibration.hpp"
#include "cellcal/core/model_extension.hpp"
#include "cellcal/core/observation.hpp"

namespace cellcal {

struct ExtendedFit {
  std::vector<Extension> extensions;      // in the order of their parameters; empty: the geometric model
  Extension extension() const { return extensions.empty() ? Extension{} : extensions.front(); }  // the (first) one
  bool converged = false;
  int iterations = 0;
  std::string message;
  Eigen::VectorXd params;                 // kinematic parameters, full vector, SI
  Eigen::VectorXd extension_params;       // numExtensionParams(model, extension)
  std::vector<int> estimated;             // kinematic parameters estimated
  std::vector<int> estimated_extension;   // extension parameters estimated (others held at 0: not identifiable)
  std::vector<std::string> extension_names;
  // Rows the fit left out: with a backlash, those where its joint had not moved yet (play state unknown).
  int rows_left_out = 0;
  // Covariance (SI) of the estimated parameters at the solution, (A^T A)^-1 of the whitened Jacobian: rows/cols are
  // `estimated` then `estimated_extension`, in those orders. It assumes the readings' sigmas: scale it by the
  // residual's ratio to them when the model leaves more than noise.
  Eigen::MatrixXd covariance;
  int numEstimatedExtension() const { return static_cast<int>(estimated_extension.size()); }
  // 1-sigma of kinematic parameter i / extension parameter k (NaN when not estimated).
  double paramStddev(int i) const;
  double extensionStddev(int k) const;
};

// Gauss-Newton on the geometric parameters identifiable from `obs` plus the extension's parameters (those the data
// separate from the geometric ones; extension columns have the lowest priority). `start`: full kinematic vector.
// `drivers`: one per observation. With a backlash, rows where its joint has not moved yet are left out of the fit
// (`rows_left_out`); they are still predicted (play state 0, the middle of the gap) by errorStats and the like.
// `warm_start` (optional): kinematic parameters to start from instead (e.g. a geometric fit); `start` still decides
// which parameters are candidates and what the held ones are.
ExtendedFit fitExtended(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                        const std::vector<Drivers>& drivers, const Extension& extension,
                        const SolverOptions& solver = {}, const IdentifiabilityOptions& identifiability = {},
                        const Eigen::VectorXd* warm_start = nullptr);

// Several extensions at once (e.g. backlash on joint 2 and compliance on joint 3): their parameters are concatenated.
ExtendedFit fitExtended(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                        const std::vector<Drivers>& drivers, const std::vector<Extension>& extensions,
                        const SolverOptions& solver = {}, const IdentifiabilityOptions& identifiability = {},
                        const Eigen::VectorXd* warm_start = nullptr);

// measured - model position (m) of each observation under a fit.
std::vector<Eigen::Vector3d> positionResiduals(const RobotModel& model, const ExtendedFit& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers);

struct ErrorStats {
  int rows = 0, oriented = 0;
  double mean_mm = 0, rms_mm = 0, max_mm = 0;     // position
  double mean_deg = 0, rms_deg = 0, max_deg = 0;  // orientation (6D rows only)
};
ErrorStats errorStats(const RobotModel& model, const ExtendedFit& fit, const std::vector<Observation>& obs,
                      const std::vector<Drivers>& drivers);
// The same figures accumulated one observation and predicted pose at a time.
class ErrorStatsAccumulator {
 public:
  void add(const Observation& obs, const Pose& predicted);
  ErrorStats stats() const;

 private:
  ErrorStats sums_;
};

struct DiagnosisData {
  std::vector<Observation> identification, verification;
  std::vector<Drivers> identification_drivers, verification_drivers;
  bool has_thermal = false;
  std::string thermal_source;  // for reports: "temperature_c" or "stamp_s"
};

struct DiagnosisOptions {
  std::vector<Cause> causes = extensionCauses();
  double penalty_per_param = 2.0;
  double min_gain = 0.03;    // relative reduction of the verification mean squared error
  double min_z = 4.0;        // standard errors of the paired difference
  double parsimony_z = 2.0;  // a candidate with more parameters must beat a simpler significant one by this much
  SolverOptions solver;
  IdentifiabilityOptions identifiability;
  // Called after the geometric fit and after each candidate fit: (fits done, fits in all). Empty: none. For progress
  // bars on large files; runs on the caller's thread.
  std::function<void(int done, int total)> progress;
  bool IsValid(std::string* error) const;
};

struct CandidateResult {
  ExtendedFit fit;
  ErrorStats identification, verification;
  double verify_mse_m2 = 0;  // mean squared position error on the verification rows
  double score = 0;          // verify_mse_m2 * (1 + penalty * k / rows)
  double z = 0;              // paired improvement over the geometric model, in standard errors
};

// How much of the held-out position residual one driver explains: adjusted R^2 of a least-squares fit of the three
// residual components on the driver's regressors (angles: sin, cos, sin 2x, cos 2x; torques and thermal: x, x^2;
// direction: x; workspace: the 9 quadratic terms of the target position in the robot base frame).
struct DriverStructure {
  std::string driver;  // "q2", "gravity_torque_2", "thermal", "direction_3", "workspace"
  double r2_adjusted = 0;
};
std::vector<DriverStructure> residualStructure(const RobotModel& model, const ExtendedFit& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                               bool has_thermal);

struct DiagnosisResult {
  CandidateResult geometric;
  std::vector<CandidateResult> candidates;  // best score first
  int chosen = -1;                          // index into candidates; -1: cause none
  Cause cause = Cause::kNone;
  std::vector<int> joints;                  // 0-based joints the cause acts on
  double gain_pct = 0;                      // verification mean position error, geometric -> chosen
  std::vector<DriverStructure> structure_before, structure_after;  // strongest first
  double noise_rms_mm = 0;                  // expected from the readings' sigmas (verification rows)
  double unexplained_rms_mm = 0;            // sqrt(max(0, chosen verify RMS^2 - noise RMS^2))
  double solve_time_s = 0;
  const CandidateResult& best() const { return chosen >= 0 ? candidates[chosen] : geometric; }
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

DiagnosisResult diagnose(const RobotModel& model, const Eigen::VectorXd& start, const DiagnosisData& data,
                         const DiagnosisOptions& options = {});

}  // namespace cellcal
