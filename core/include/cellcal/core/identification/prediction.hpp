// How far a fitted model can be trusted at a configuration: the predicted 1-sigma error of the target position, and
// the parameters the identification rows leave unexcited (extrapolation).
//
// The prediction covers every parameter the model could get wrong, not only the estimated ones: each canonical
// kinematic parameter (but those the frames stand for, frameGauge: the frames' columns are theirs) and each extension
// parameter starts with a prior (lengths and angles as plausible for a robot
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
#include <utility>
#include <vector>

#include "cellcal/core/identification/diagnosis.hpp"
#include "cellcal/core/identification/identifiability.hpp"
#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

// A joint's error beyond the range of the data a model was fitted on: 1 sigma sigma_at_1_rad * d^growth (rad), d the
// angle by which q_rad[joint] lies outside [lower_rad, upper_rad] (rad; 0 inside: there the posterior holds), at most
// checked_rad when that is > 0. What an extension of that joint (a periodic term, a scale, a stiffness fitted on part
// of the joint's range) may do beyond it that its posterior does not say (extensionTransfer).
//
// checked_rad is how far beyond the range the region folds judged the extensions' predictions (0: nowhere, e.g. too
// few rows at an end of the range). Within it the sigma above is measured (0 where the predictions held). Farther, an
// extension's form has never been put to the test: a periodic term standing for an error that grows, fitted on the
// whole range, can be right at every fold and many times its predicted error there. judged() is false there; the
// sigma is held at its value at checked_rad, and the caller says the configuration is extrapolated (the campaign's
// prediction check counts it, compensation refuses to call its correction known).
// How far x lies outside [lower, upper] (0 inside), and the further error sigma_at_1 * d^growth at that distance d,
// held at its value at `checked` when that is > 0 (0 inside or without a sigma): BeyondRange's and DriverRange's.
double distanceBeyond(double x, double lower, double upper);
double sigmaBeyond(double sigma_at_1, int growth, double d, double checked);

struct BeyondRange {
  int joint = 0;
  double lower_rad = 0, upper_rad = 0;
  double sigma_at_1_rad = 0;
  int growth = 0;  // 0: a constant error beyond the range, 1: growing linearly with d, 2: with d^2
  double checked_rad = 0;
  // Stretches inside [lower_rad, upper_rad] that no row of the data reached (rangeGaps: a grid at one tool
  // orientation leaves a wrist joint's angles in clusters): sorted, disjoint, strictly inside the range. An angle in
  // one lies as far from the data as from the gap's nearer edge, d, and is judged as beyond the range: the folds
  // judged the extensions up to checked_rad from their data at the range's ends, not in between.
  std::vector<std::pair<double, double>> gaps_rad;
  double beyondRad(double q_rad) const;  // d: beyond [lower_rad, upper_rad], or into a gap
  bool inGap(double q_rad) const;        // within the range, in one of gaps_rad
  double sigmaRad(double q_rad) const;
  bool judged(double q_rad) const;       // d <= checked_rad
  const char* growthText() const;        // "", " per rad beyond", " per rad^2 beyond": the unit sigma is read in
  std::string rangeText() const;         // "[-20.0, 90.0] deg"
  std::string gapsText() const;          // "", " (no data in [10.0, 45.0] deg)", " (no data in [10.0, 45.0] and [60.0, 70.0] deg)"
  bool IsValid(int num_joints, std::string* error) const;
};
// The stretches wider than min_width between consecutive values of x (in any order): BeyondRange::gaps_rad.
std::vector<std::pair<double, double>> rangeGaps(std::vector<double> x, double min_width);
// The share of a joint's range over the data that a gap must exceed to be kept (extensionTransfer): narrower ones are
// finer than the quarters of the range the region folds judge by.
constexpr double kBeyondGapShare = 0.05;
// The first range whose joint at q_rad lies farther beyond it than it was judged; nullptr where all were judged.
const BeyondRange* firstUnjudged(const std::vector<BeyondRange>& ranges, const Eigen::VectorXd& q_rad);
// The first range whose joint at q lies beyond its data (past its ends or in one of its gaps), judged there or not;
// nullptr where every joint lies within its range's data.
const BeyondRange* firstBeyond(const std::vector<BeyondRange>& ranges, const Eigen::VectorXd& q_rad);
// "joint 2 at 131.0 deg lies 41.0 deg beyond [-20.0, 90.0] deg, the range its model extensions were fitted on; they
// were judged up to 12.0 deg beyond it" (in a gap: "joint 4 at -88.0 deg lies 31.0 deg inside [-209.0, -57.0] deg, a
// stretch of [-267.0, 267.0] deg, the range its model extensions were fitted on, that its data never reached; they
// were judged up to 25.8 deg from their data"): what firstUnjudged found, for a message.
std::string unjudgedText(const BeyondRange& range, double q_rad);

// The same for an extension that no joint's angle bounds (link deflection: the gravity across its link; thermal drift
// and frame drift: the thermal driver): the range of its driver over the data it was fitted on (CauseModel::rangeValue,
// in the unit rangeLabel names) and a further position error (m, 1 sigma) of sigma_at_1_m * d^growth beyond it, d the
// driver's distance beyond [lower, upper] in its unit, held at its value at the end's checked distance (how far
// beyond that end the folds judged it; 0: nowhere). Farther the extension's form was never put to the test, as for a
// BeyondRange: judged() is false there and the caller says the configuration is extrapolated. Each end keeps its own
// distance (a driver may be bounded at one end, as the gravity across a link is at 1 g, and seen far at the other).
struct DriverRange {
  Extension extension;            // whose driver (its time constant sets a warm-up driver's value)
  std::string label;              // rangeLabel: "gravity across link 2 (g)"
  double lower = 0, upper = 0;    // the driver's range over the data, in its unit
  double sigma_at_1_m = 0;
  int growth = 0;                 // 0, 1 or 2 as BeyondRange's
  double checked_below = 0, checked_above = 0;  // driver unit
  double beyond(double x) const;  // d
  double checked(double x) const; // the checked distance of the end x lies beyond (0 within the range)
  double sigmaM(double x) const;
  bool judged(double x) const;    // d <= checked(x)
  std::string quantity() const;   // the label without its unit: "gravity across link 2"
  std::string unit() const;       // the label's unit: "g"
  std::string growthText() const; // "", " per g beyond", " per g^2 beyond": the unit sigma is read in
  // "gravity across link 2 [0.3, 0.92] g": the range, to 3 significant digits.
  std::string rangeText() const;
  // "judged up to 0.09 g below it and 0.015 g above it" ("not below it", "not judged beyond it").
  std::string judgedText() const;
  // The driver at q (CauseModel::rangeValue of the extension at the kinematic parameters `params`).
  double value(const RobotModel& model, const Eigen::VectorXd& params, const Eigen::VectorXd& q_rad,
               const Drivers& drivers) const;
  bool IsValid(const RobotModel& model, std::string* error) const;
};
// The first driver range whose driver at q lies farther beyond it than it was judged, with that driver's value in
// *x; nullptr where all were judged.
const DriverRange* firstUnjudged(const RobotModel& model, const Eigen::VectorXd& params,
                                 const std::vector<DriverRange>& ranges, const Eigen::VectorXd& q_rad,
                                 const Drivers& drivers, double* x);
// The first driver range whose driver at q lies beyond it, judged there or not, with that driver's value in *x.
const DriverRange* firstBeyond(const RobotModel& model, const Eigen::VectorXd& params,
                               const std::vector<DriverRange>& ranges, const Eigen::VectorXd& q_rad,
                               const Drivers& drivers, double* x);
// "gravity across link 2 at 0.95 g lies 0.2 g beyond [0.3, 0.75] g, the range link_deflection link 2 was fitted on;
// it was judged up to 0.1 g beyond it".
std::string unjudgedText(const DriverRange& range, double x);
// The position variance (m^2) the driver ranges add at q: the sum of sigmaM(value)^2.
double driverRangeVariance(const RobotModel& model, const Eigen::VectorXd& params,
                           const std::vector<DriverRange>& ranges, const Eigen::VectorXd& q_rad, const Drivers& drivers);

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
  // Errors beyond the data's joint ranges (extensionTransfer), added to the parameters' in predictedPositionSigma:
  // sum over them of sigmaRad(q)^2 |dp/dq_joint|^2. carriedPrediction keeps the carried model's.
  std::vector<BeyondRange> beyond;
  // And beyond the ranges of the drivers of extensions no joint bounds: sum of DriverRange::sigmaM^2.
  std::vector<DriverRange> beyond_drivers;
};

// By how much a fit's whitened residuals exceed the readings' sigmas, position rows and orientation rows apart (a
// model error, or a tracker that understates one kind of noise, shows in millimetres and in degrees by different
// amounts): each kind's residual sum of squares over its share of the degrees of freedom, rows - `estimated` split in
// proportion to the rows. 1 for a kind without rows (or without degrees of freedom).
struct VarianceFactors {
  double position = 1.0, orientation = 1.0;
};
VarianceFactors residualVarianceFactors(const RobotModel& model, const CalibratedModel& fit,
                                        const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                        int estimated);

// The posterior of `fit` on its identification rows (those it was fitted on, gross errors left out).
PredictionModel predictionModel(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
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
PredictionModel carriedPrediction(const RobotModel& model, const CalibratedModel& fit, const PredictionModel& carried,
                                  const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                  const std::vector<int>& frames, const VarianceFactors& noise);

// What a fit's extensions are worth where their data never were. The prediction above holds while the model's form
// does: an extension fitted on part of a joint's range (a periodic term standing for a local error, a scale or a
// stiffness for an error that grows otherwise) may act otherwise beyond it, and its posterior does not say so.
// Measured as RegionCheck folds the rows by that joint's angle (the rows beyond either end's region_joint_end
// quantile judged, the others fitted; each joint once): the whole model is fitted on the fitted rows (at most
// region_fit_rows of them; excitation deficits held as diagnose holds them) and predicts the judged ones
// (predictionModel of that fit, and the readings' noise 3 s^2 sigma_reading^2 beside it). Where the actual errors
// there exceed that (RMS of actual / sqrt(predicted^2 + noise) above 1), a BeyondRange of the joint is fitted on the
// judged rows by maximum likelihood (Gaussian position errors of that variance plus the BeyondRange's, d measured from
// the fitted rows' range): the growth (0, 1 or 2) that explains them best and its sigma. The folds' models are fitted
// on less of the range than the campaign's, and an error that grows with the range fitted (a periodic term standing
// for a curve bends away from it the farther it was made to follow it) would be understated: each fold's fitted rows
// are folded again at the same end, and where the rows of both levels are explained better with the sigma scaled by
// (fitted width / the campaign's)^p, p 1 or 2 (a likelihood ratio test at 1 %), the sigma is that carried to the
// campaign's whole width (JointTransfer::width_power). The result's ranges are the joint's over `obs`.
// An extension no joint bounds (link deflection, thermal drift, frame drift: CauseModel::rangeValue) is judged the same
// way on folds by its driver's value (DriverTransfer): the rows beyond either end's quantile of the driver judged, a
// DriverRange fitted on them with the position error itself as its unit (no joint to carry it). One whose driver is
// the same at every row (nothing to fold by) is not measured: `not_measured` names it.
struct FoldStats {
  int folds = 0, judged_rows = 0;
  // The folds of each fold's fitted rows at its end, and their judged rows: made only where the folds' rows err
  // beyond their prediction (ratio_rms_without above 1), for width_power.
  int inner_folds = 0, inner_rows = 0;
  int width_power = 0;  // 1 or 2: the sigma is the folds' carried to the whole range as width^p
  double ratio_rms_without = 0, ratio_rms_with = 0;  // on the judged rows
};
struct JointTransfer : FoldStats {
  BeyondRange beyond;  // sigma_at_1_rad 0: the folds' predictions held (or checked_rad 0: not measured)
};
struct DriverTransfer : FoldStats {
  DriverRange range;   // sigma_at_1_m 0: the folds' predictions held (or both checked 0: not measured)
};
struct ExtensionTransfer {
  std::vector<JointTransfer> joints;
  std::vector<DriverTransfer> drivers;
  std::vector<std::string> not_measured;  // extensionLabel of each extension not measured, with why
  // Every joint's: its range, the sigma measured beyond it (0 where the folds' predictions held) and how far beyond
  // it that was judged (0 for a joint not measured).
  std::vector<BeyondRange> beyond() const;
  std::vector<DriverRange> beyondDrivers() const;  // the same for every driver measured
  std::string text;                         // one line per joint and driver and a line for what was not measured
};
ExtensionTransfer extensionTransfer(const RobotModel& model, const Eigen::VectorXd& start, const CalibratedModel& fit,
                                    const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                    const DiagnosisOptions& options = {});

// The position variance (m^2) that `ranges`' joint errors add at q: the sum of sigmaRad(q)^2 |dp/dq_joint|^2, the
// position's derivative by the joint read from J, the pose Jacobian at q (6 x numParams, its theta offset column).
double beyondPositionVariance(const RobotModel& model, const Eigen::Ref<const Eigen::MatrixXd>& J,
                              const std::vector<BeyondRange>& ranges, const Eigen::VectorXd& q_rad);

// Predicted 1-sigma error (m) of the target position at q: sqrt of the trace of its 3x3 covariance (the RMS of the
// 3D position error the model makes there, reading noise not included), prediction.beyond's errors included.
double predictedPositionSigma(const RobotModel& model, const CalibratedModel& fit, const PredictionModel& prediction,
                              const Eigen::VectorXd& q_rad, const Drivers& drivers);

// Predicted 1-sigma position error (m) of a kinematic estimate at q: sqrt(trace(J P J^T)) over the position rows,
// J the pose Jacobian's columns `estimated` at `params`, P their covariance. Infinite where it is not finite (a
// covariance gone bad is never read as a small error). The engine's hold bound and compensation's guard use it.
double kinematicPositionSigma(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params,
                              const std::vector<int>& estimated, const Eigen::MatrixXd& covariance,
                              const Eigen::VectorXd& q_rad);

// The 1-sigma position error (m) `fit` makes at each of `at` from the uncertainty of the parameters it estimated,
// and from nothing else: sqrt of the trace of J C J^T over its estimated columns, C its covariance scaled by the
// position rows' variance factor on `fitted` (the rows it was fitted on: residualVarianceFactors). Columns it held add
// nothing (they are part of the model's form, as are the causes it does not hold); no prior, unlike predictionModel.
// What refits of the same rows with fresh noise would scatter by at `at` (RegionCheck takes it off each model's
// error). Zeros without a covariance.
std::vector<double> estimatePositionSigmas(const RobotModel& model, const CalibratedModel& fit,
                                           const std::vector<Observation>& fitted,
                                           const std::vector<Drivers>& fitted_drivers,
                                           const std::vector<Observation>& at, const std::vector<Drivers>& at_drivers);

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
