// The extended fit: Gauss-Newton on the geometric parameters together with the parameters of model extensions
// (model_extension.hpp, each cause in core/src/model/causes/), its robust form, what it leaves and its error figures.
// diagnose (diagnosis.hpp) chooses among such fits; RLS (rls.hpp), prediction (prediction.hpp), set-ups (setups.hpp)
// and the robot file (robot_file.hpp) start from or save one.
//
//   ExtendedFit f = fitExtended(model, start, ident, ident_drivers, {Cause::kBacklash, 2});   // one extension
//   ErrorStats e = errorStats(model, f, verify, verify_drivers);
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/identification/outliers.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/model_extension.hpp"

namespace cellcal {

// A batch fit's model (calibrated_model.hpp: kinematic and extension parameters, the estimated ones, their
// covariance) and the solver's outcome. The covariance, (A^T A)^-1 of the whitened Jacobian at the solution, assumes
// the readings' sigmas: scale it by the residual's ratio to them when the model leaves more than noise. Extension
// parameters the data do not separate from the geometric ones are held at 0 (not in estimated_extension).
struct ExtendedFit : CalibratedModel {
  Extension extension() const { return extensions.empty() ? Extension{} : extensions.front(); }  // the (first) one
  bool converged = false;
  int iterations = 0;
  std::string message;
  std::vector<std::string> extension_names;
  // Rows the fit left out: with a backlash, those where its joint had not moved yet (play state unknown).
  int rows_left_out = 0;
};

// A geometric solve's outcome (calibration.hpp) as a fit: no extension, its estimated set, covariance and outcome.
ExtendedFit geometricFit(const CalibrationResult& result);
// The geometric model with these kinematic parameters as a fit: nothing estimated, not a solve's outcome.
ExtendedFit geometricFit(const Eigen::VectorXd& params);

// "joint_compliance joint 2", "thermal_drift (lengths)", "thermal_drift joint 3, warm-up 1.6 h",
// "link_deflection link 3"; a model: the labels joined by " + ", "geometric" when empty.
std::string extensionLabel(const Extension& ext);
std::string modelLabel(const std::vector<Extension>& exts);

// Gauss-Newton on the geometric parameters identifiable from `obs` plus the extension's parameters (those the data
// separate from the geometric ones; extension columns have the lowest priority). `start`: full kinematic vector.
// A thermal drift on a time driver whose time constant is 0 gets one: the warm-up time constant (or a straight line)
// that leaves the least residual, searched on the model linearized at the warm start (log-spaced grid from 1/32 to 4
// times the time span, then golden section); fit.extensions carries it.
// `drivers`: one per observation. With a backlash, rows where its joint has not moved yet are left out of the fit
// (`rows_left_out`); they are still predicted (play state 0, the middle of the gap) by errorStats and the like.
// `warm_start` (optional): kinematic parameters to start from instead (e.g. a geometric fit); `start` still decides
// which parameters are candidates and what the held ones are. `warm_extension` (optional, the list overload): the
// extension parameters to start from (e.g. the linearized screen's step), else 0.
ExtendedFit fitExtended(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                        const std::vector<Drivers>& drivers, const Extension& extension,
                        const SolverOptions& solver = {}, const IdentifiabilityOptions& identifiability = {},
                        const Eigen::VectorXd* warm_start = nullptr);

// Several extensions at once (e.g. backlash on joint 2 and compliance on joint 3): their parameters are concatenated.
ExtendedFit fitExtended(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                        const std::vector<Drivers>& drivers, const std::vector<Extension>& extensions,
                        const SolverOptions& solver = {}, const IdentifiabilityOptions& identifiability = {},
                        const Eigen::VectorXd* warm_start = nullptr,
                        const Eigen::VectorXd* warm_extension = nullptr);

// fitExtended, then screening for gross errors (outliers.hpp): refit on the rows kept until the flagged set repeats.
// `screen` (optional) receives the last screening, indices into `obs`.
ExtendedFit fitExtendedRobust(const RobotModel& model, const Eigen::VectorXd& start, const std::vector<Observation>& obs,
                              const std::vector<Drivers>& drivers, const std::vector<Extension>& extensions,
                              const SolverOptions& solver, const IdentifiabilityOptions& identifiability,
                              const Eigen::VectorXd* warm_start, const OutlierOptions& outliers, OutlierScreen* screen);

// What `obs` determine of some kinematic parameters at `fit`, every other parameter and the extension parameters as
// the fit has them (e.g. the frames registered on a new set-up: calibrate --frames-only). Returns the columns of
// `columns` the rows determine (independentColumns in that priority: a tool rotation from points is not), and in
// `covariance` (A^T A)^-1 of the whitened Jacobian over them, SI, in that order. `variance_factor` (optional)
// receives r^T r / (rows - columns returned): the ratio of what the fit leaves to the readings' sigmas, by which the
// covariance is to be scaled when it is above 1.
std::vector<int> conditionalCovariance(const RobotModel& model, const CalibratedModel& fit,
                                       const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                       const std::vector<int>& columns, Eigen::MatrixXd* covariance,
                                       double* variance_factor = nullptr);

// Screening of rows a fit predicts (e.g. verification rows): their errors against the robust scale of their own.
OutlierScreen screenRows(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                         const std::vector<Drivers>& drivers, const OutlierOptions& options);

// measured - model position (m) of each observation under a fit.
std::vector<Eigen::Vector3d> positionResiduals(const RobotModel& model, const CalibratedModel& fit,
                                               const std::vector<Observation>& obs, const std::vector<Drivers>& drivers);

struct ErrorStats {
  int rows = 0, oriented = 0;
  double mean_mm = 0, rms_mm = 0, max_mm = 0;     // position
  double mean_deg = 0, rms_deg = 0, max_deg = 0;  // orientation (6D rows only)
  // The 99.7th percentile (statistics.hpp's percentile; where 3 sigma of a normal error lies): what an accuracy
  // stated "at 99.7 %" means, beside the mean and the max.
  double p997_mm = 0, p997_deg = 0;
};
ErrorStats errorStats(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                      const std::vector<Drivers>& drivers);
// The target poses `fit` predicts in the tracker frame at each observation's joints and drivers.
std::vector<Pose> predictedPoses(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                                 const std::vector<Drivers>& drivers);
// The same figures accumulated one observation and predicted pose at a time.
class ErrorStatsAccumulator {
 public:
  void add(const Observation& obs, const Pose& predicted);
  ErrorStats stats() const;

 private:
  ErrorStats sums_;
  std::vector<double> position_mm_, orientation_deg_;  // each row's, for the percentile
};

}  // namespace cellcal
