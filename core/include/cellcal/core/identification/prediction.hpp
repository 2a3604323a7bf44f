// How far a fitted model can be trusted at a configuration: the predicted 1-sigma error of the target position, and
// the parameters the identification rows leave unexcited (extrapolation).
//
// The prediction covers every parameter the model could get wrong, not only the estimated ones: each canonical
// kinematic parameter and each extension parameter starts with a prior (lengths and angles as plausible for a robot
// that has not been calibrated; extension parameters from extensionPriorSigma), and the identification rows' whitened
// Jacobian at the fit turns it into a posterior
//     C = D (D^T J^T J D / s^2 + I)^-1 D,      D = diag(prior sigmas),
// with s^2 the a-posteriori variance factor of the fit (residual sum of squares over its degrees of freedom; 1 when
// the readings' sigmas are right and the model leaves nothing but noise), one for the position rows and one for the
// orientation rows (J^T J / s^2 is their sum). A direction the identification rows do not
// excite keeps its prior width, so a configuration that moves along it gets a large predicted error: the model is
// extrapolating there. The actual held-out error compared with sqrt(sigma_model^2 + reading noise) says whether the
// covariance can be trusted (their ratio's RMS is 1 when it can).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct PredictionOptions {
  double prior_length_m = kPlausibleLengthM;            // 1 sigma of a length no one calibrated
  double prior_angle_rad = kPlausibleAngleRad;
  double extension_joint_error_rad = 0.05 * 3.14159265358979323846 / 180;  // extensionPriorSigma's RMS joint error
  bool IsValid(std::string* error) const;
};

struct PredictionModel {
  std::vector<int> columns;      // kinematic index, or numParams() + k for extension parameter k
  Eigen::VectorXd prior_sigma;   // per column, SI
  Eigen::MatrixXd covariance;    // posterior over `columns`, SI (variance factor applied)
  double variance_factor = 1.0;              // s^2 of every row together
  double variance_factor_position = 1.0;     // s^2 of the position rows: the one that scales the readings' position noise
  double variance_factor_orientation = 1.0;  // s^2 of the orientation rows (1 without 6D rows)
  int rows = 0, estimated = 0;   // whitened rows of the identification data; parameters the fit estimated
};

// By how much a fit's whitened residuals exceed the readings' sigmas, position rows and orientation rows apart (a
// model error, or a tracker that understates one kind of noise, shows in millimetres and in degrees by different
// amounts): each kind's residual sum of squares over its share of the degrees of freedom, rows - `estimated` split in
// proportion to the rows. 1 for a kind without rows (or without degrees of freedom).
struct VarianceFactors {
  double position = 1.0, orientation = 1.0;
};
VarianceFactors residualVarianceFactors(const RobotModel& model, const ExtendedFit& fit,
                                        const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                        int estimated);

// The posterior of `fit` on its identification rows (those it was fitted on, gross errors left out).
PredictionModel predictionModel(const RobotModel& model, const ExtendedFit& fit, const std::vector<Observation>& obs,
                                const std::vector<Drivers>& drivers, const PredictionOptions& options = {});

// The prediction of a calibrated model carried to another set-up, its frames registered again on `obs` at `fit`
// (calibrate --frames-only). `carried` is the model's prediction from the campaign that identified it (a robot file's
// calibration section: its columns and covariance are used; without one, the priors:
// predictionModel with no rows). `frames` are the frame columns the new rows determine (conditionalCovariance). The
// new frames absorb part of the carried model's error dm on these rows: with A the whitened Jacobian of `obs`,
//     frame error  df = -K dm + e,   K = (A_f^T A_f)^-1 A_f^T A_m,   e ~ N(0, N^-1 (A_f^T Σ A_f) N^-1),
// N = A_f^T A_f, Σ the variance of the whitened rows: `noise`, the factors by which these rows' sigmas understate what
// the frames leave of them, position rows and orientation rows apart (residualVarianceFactors of the frames' fit with
// the frames estimated; with one factor s^2 for every row, e ~ N(0, s^2 N^-1)). They are the new rows' own: a
// campaign's factor scales the campaign's sigmas, and another file's rows may carry other sigmas (per-reading ones, or
// a default). They are also the result's variance factors, by which the readings' noise is scaled beside it. The
// position error at q is J_m(q) dm + J_f(q) df, so the result is a PredictionModel over the carried columns other
// than `frames`, then `frames`, with the joint covariance [S, -S K^T; -K S, K S K^T + cov(e)] (S the carried
// covariance of the others): predictedPositionSigma gives that error's 1 sigma. An error the new frames take up
// entirely (a base offset) predicts nothing; one they cannot (a link length) predicts what it does at q less what the frames took on these rows.
// The error the model makes only on this set-up (a cause it does not hold that acts differently here) is not in it:
// the ratio of actual to predicted on held-out rows says so.
PredictionModel carriedPrediction(const RobotModel& model, const ExtendedFit& fit, const PredictionModel& carried,
                                  const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                  const std::vector<int>& frames, const VarianceFactors& noise);

// Predicted 1-sigma error (m) of the target position at q: sqrt of the trace of its 3x3 covariance (the RMS of the
// 3D position error the model makes there, reading noise not included).
double predictedPositionSigma(const RobotModel& model, const ExtendedFit& fit, const PredictionModel& prediction,
                              const Eigen::VectorXd& q_rad, const Drivers& drivers);

// Predicted 1-sigma position error (m) of a kinematic estimate at q: sqrt(trace(J P J^T)) over the position rows,
// J the pose Jacobian's columns `estimated` at `params`, P their covariance. Infinite where it is not finite (a
// covariance gone bad is never read as a small error). The engine's hold bound and compensation's guard use it.
double kinematicPositionSigma(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params,
                              const std::vector<int>& estimated, const Eigen::MatrixXd& covariance,
                              const Eigen::VectorXd& q_rad);

// Excitation deficits: parameters the identification rows barely move while other rows of the same data move them
// strongly. Estimating one would extrapolate: its value would rest on rows where it hardly acts and then decide the
// prediction where it acts most (e.g. a gravity moment of link 4 near zero on every identification pose and 9.81 N m
// on one held-out upright pose). Column c of the whitened Jacobian [J, J B] is measured per row (the norm of its
// entries in that observation's 3 or 6 rows): its RMS over the identification rows against its largest value on the
// `other` rows. A canonical kinematic or extension parameter whose RMS there is below `ratio` times that largest value
// is a deficit (IdentifiabilityOptions::held takes their columns; ExcitationDeficit in diagnosis.hpp). `other` empty:
// none.
std::vector<ExcitationDeficit> excitationDeficits(const RobotModel& model, const Eigen::VectorXd& params,
                                                  const std::vector<Extension>& extensions,
                                                  const std::vector<Observation>& identification,
                                                  const std::vector<Drivers>& identification_drivers,
                                                  const std::vector<Observation>& other,
                                                  const std::vector<Drivers>& other_drivers, double ratio = 0.1);
// "joint4.compliance_link4_mass_rad_per_Nm_kg: excited 31x less on the identification rows (RMS 0.05) than on
// another row (9.8)".
std::string deficitText(const ExcitationDeficit& d);
std::vector<int> heldColumns(const std::vector<ExcitationDeficit>& deficits);

}  // namespace cellcal
