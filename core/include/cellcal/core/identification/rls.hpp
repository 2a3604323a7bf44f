// Recursive least squares for kinematic calibration, as in the paper:
//   x_{k+1} = x_k + P_{k+1} a (b - a^T x_k),  P updated by Sherman-Morrison (block form: one pose = 3 or 6 rows).
//
// RlsEstimator is the linear algebra: rows A (r x m, whitened) and targets b (r). Gain K = P A^T (lambda I + A P A^T)^-1,
// x += K (b - A x), P = (P - K A P) / lambda. lambda = 1 is the paper's (all data weighted equally); lambda < 1
// forgets old data geometrically, and then each diagonal entry of P is bounded by `max_covariance_diag`
// (the inflation 1/lambda is cut so no entry exceeds its bound) so unexcited directions cannot wind up.
// addProcessNoise() adds Q to P between measurement groups: a random-walk prior toward the previous estimate.
//
// RlsCalibrator applies it to the nonlinear kinematic model: each pose is linearized at the current estimate
// (innovation = measured - model(x_k), A = whitened pose Jacobian), which equals the linear form above for a
// linear model.
//
// With a model extension (model_extension.hpp, e.g. the joint compliance `cellcal diagnose` names) the state also holds
// the extension's parameters, after the kinematic ones: x = [params[estimated]; extension[estimated_extension]], and a
// pose's rows are [J_i(:, estimated), (J_i B_i)(:, estimated_extension)] at params + B_i e, with B_i from the pose's
// joint angles and Drivers (thermal driver, play state). Drift process noise acts on the kinematic part only.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/identification/observation.hpp"

namespace cellcal {

struct RlsOptions {
  double forgetting = 1.0;            // lambda in (0, 1]
  Eigen::VectorXd max_covariance_diag;  // empty: no bound; else one entry per state (used when lambda < 1)
  bool IsValid(int state_size, std::string* error) const;
};

class RlsEstimator {
 public:
  RlsEstimator(Eigen::VectorXd x0, Eigen::MatrixXd P0, RlsOptions options = {});
  // Batch start as in the paper: P0 = (A0^T A0)^-1, x0 = least-squares solution of A0 x = b0.
  static RlsEstimator fromInitialBatch(const Eigen::MatrixXd& A0, const Eigen::VectorXd& b0, RlsOptions options = {});

  // One measurement block: b = A x + noise (noise whitened to unit variance).
  void update(const Eigen::Ref<const Eigen::MatrixXd>& A, const Eigen::Ref<const Eigen::VectorXd>& b);
  // Same with the innovation (b - A x) computed by the caller (nonlinear models).
  void updateWithInnovation(const Eigen::Ref<const Eigen::MatrixXd>& A,
                            const Eigen::Ref<const Eigen::VectorXd>& innovation);
  void addProcessNoise(const Eigen::VectorXd& q_diag);
  void addProcessNoise(const Eigen::MatrixXd& Q);  // symmetric, state size
  // P += scale Q (Q symmetric, state size; scale >= 0): the same noise shape scaled by the time since the last update.
  // With tracked variances, the tracked form of Q is computed once per distinct Q.
  void addScaledProcessNoise(const Eigen::MatrixXd& Q, double scale);

  // Tracked variances: for the rows g_i of G (k x state size), v_i = g_i P g_i^T, kept current through every change
  // of P (the rank-r downdate of an update, the forgetting's inflation, process noise) at O(k n r) per update instead
  // of O(k n^2) for G P G^T, and computed from P again every 64th update (the downdates' rounding would otherwise
  // stay). Exact up to rounding (the tests check it against G P G^T after long random sequences).
  // Replaces any earlier tracking; v is computed from P here.
  void trackVariances(const Eigen::MatrixXd& G);
  // Replaces G.rows() tracked rows from `first` on (same width), their variances computed afresh: for rows that change
  // now and then (a configuration replaced), at the cost of those rows instead of all.
  void retrackRows(Eigen::Index first, const Eigen::MatrixXd& G);
  const Eigen::MatrixXd& trackedRows() const { return track_G_; }    // 0 x 0 when nothing is tracked
  const Eigen::VectorXd& trackedVariances() const { return track_v_; }

  // What an update changes (state, covariance, tracked variances), to undo one: save before, restore after.
  struct Checkpoint {
    Eigen::VectorXd x, v;
    Eigen::MatrixXd P;
    std::uint64_t updates = 0;
    double nis = 0;
  };
  void save(Checkpoint& c) const { c = Checkpoint{x_, track_v_, P_, track_updates_, last_nis_}; }
  void restore(const Checkpoint& c);

  const Eigen::VectorXd& x() const { return x_; }
  Eigen::VectorXd& mutableX() { return x_; }
  const Eigen::MatrixXd& P() const { return P_; }
  // Normalized innovation squared of the last update: nu^T S^-1 nu (chi-square with r dof for a consistent filter).
  double lastNormalizedInnovation() const { return last_nis_; }

 private:
  Eigen::VectorXd x_;
  Eigen::MatrixXd P_;
  RlsOptions options_;
  double last_nis_ = 0;
  Eigen::MatrixXd PA_, S_;  // workspaces
  Eigen::VectorXd trackedForm(const Eigen::MatrixXd& M) const;  // diag(G M G^T) over the tracked rows G
  Eigen::MatrixXd track_G_, track_GW_, track_Q_;  // tracked rows, G W workspace, the last scaled noise shape
  Eigen::VectorXd track_v_, track_Qv_;            // tracked variances; diag(G Q G^T) of track_Q_
  static constexpr std::uint64_t kTrackRefresh = 64;
  static constexpr double kTrackCancel = 1e-2;
  std::uint64_t track_updates_ = 0;
  bool track_refresh_due_ = false;
};

// How much each kind of parameter may change between two calibration updates (1 sigma, random walk).
// Warm-up and wear move joint zeros and link lengths; axis angles and the base/tool frames barely move.
struct DriftModel {
  double joint_offset_rad = 0.02 * 3.14159265358979323846 / 180.0;  // theta offsets
  double joint_length_m = 0.05e-3;                                  // d, a
  double axis_angle_rad = 0.002 * 3.14159265358979323846 / 180.0;   // alpha, beta
  double frame_length_m = 0.01e-3;                                  // base/tool x, y, z
  double frame_angle_rad = 0.001 * 3.14159265358979323846 / 180.0;  // base/tool roll, pitch, yaw
  // sigma for every parameter of the full vector.
  Eigen::VectorXd sigmas(const RobotModel& model) const;
};

struct RlsCalibratorOptions {
  RlsOptions rls;
  IdentifiabilityOptions identifiability;
};

class RlsCalibrator {
 public:
  // Starts from `params` with a Gaussian prior over the structurally identifiable set (P0 = priorOverEstimated: the
  // prior's uncertainty of a parameter left out is carried by those that stand for it).
  RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params, const GaussianPrior& prior,
                MeasurementKind kind, RlsCalibratorOptions options = {});
  // Starts from the parameters and covariance of a batch result (the paper's P0 = (A0^T A0)^-1 when it had no prior).
  RlsCalibrator(const RobotModel& model, const CalibrationResult& initial, RlsCalibratorOptions options = {});
  // Resumes a saved estimate: full parameter vector, estimated indices, covariance over the state (the estimated
  // kinematic parameters, then the estimated extension parameters).
  RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                const Eigen::MatrixXd& covariance, RlsCalibratorOptions options = {});
  RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                const std::vector<Extension>& extensions, const Eigen::VectorXd& extension_params,
                const std::vector<int>& estimated_extension, const Eigen::MatrixXd& covariance,
                RlsCalibratorOptions options = {});

  // Starts from an extended fit (fitExtended): its parameters, estimated sets and covariance.
  RlsCalibrator(const RobotModel& model, const CalibratedModel& initial, RlsCalibratorOptions options = {});

  // Linearize at the current estimate and update. Returns the normalized innovation squared. `drivers` (the pose's
  // thermal driver and play state) is required when the state has extension parameters.
  double addObservation(const Observation& obs, const Drivers* drivers = nullptr);
  // Normalized innovation squared of `obs` against the current estimate, without updating (for outlier gating).
  double normalizedInnovation(const Observation& obs, const Drivers* drivers = nullptr);
  // The model's pose for joint angles q (with the extension evaluated at `drivers` when there is one).
  Pose predict(const Eigen::VectorXd& q_rad, const Drivers* drivers = nullptr);
  // Random-walk process noise: sigma (full parameter vector) of the change since the last update. The estimated
  // parameters also take the drift of the parameters they stand for (structuralAbsorption for `kind` at the nominal
  // parameters, computed once):
  // a joint 6 zero that drifts moves the tool yaw that stands for it.
  // `variance_scale` multiplies the noise's covariance (the hours since the last update over the drift's period): the
  // covariance of sigma_full is computed once per distinct sigma_full.
  void addProcessNoise(const Eigen::VectorXd& sigma_full, MeasurementKind kind, double variance_scale = 1.0);
  // The estimator's tracked variances (RlsEstimator::trackVariances) over the state.
  void trackVariances(const Eigen::MatrixXd& G) { rls_.trackVariances(G); }
  void retrackRows(Eigen::Index first, const Eigen::MatrixXd& G) { rls_.retrackRows(first, G); }
  // What addObservation and addProcessNoise change, to roll an update back (cheaper than a copy of the calibrator).
  struct Checkpoint {
    RlsEstimator::Checkpoint rls;
    Eigen::VectorXd params, extension_params;
  };
  void save(Checkpoint& c) const;
  void restore(const Checkpoint& c);

  const Eigen::VectorXd& params() const { return params_; }
  const std::vector<int>& estimated() const { return estimated_; }
  const Eigen::MatrixXd& covariance() const { return rls_.P(); }  // over the whole state (kinematic, then extension)
  const RlsEstimator& estimator() const { return rls_; }
  const std::vector<Extension>& extensions() const { return extensions_; }
  const Eigen::VectorXd& extensionParams() const { return extension_params_; }
  const std::vector<int>& estimatedExtension() const { return estimated_extension_; }
  // The estimate as a calibrated model (calibrated_model.hpp): the covariance over the whole state.
  CalibratedModel model() const;
  GaussianPrior asPrior() const;  // kinematic part of the estimate and covariance, e.g. for a batch solve

 private:
  RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params, const IdentifiabilityReport& structural,
                const GaussianPrior& prior, const RlsCalibratorOptions& options);
  // Whitened residual and state Jacobian of one observation into r_ / A_; returns its rows. The engine gates a pose
  // (normalizedInnovation) and then adds it: the second call for the same observation at unchanged parameters (no
  // update in between, no extension) reuses the first's.
  int linearize(const Observation& obs, const Drivers* drivers);
  int linearizeAnew(const Observation& obs, const Drivers* drivers);
  Eigen::VectorXd rowParams(const Eigen::VectorXd& q_rad, const Drivers* drivers);
  void writeBack();

  const RobotModel* model_;
  Eigen::VectorXd params_;
  std::vector<int> estimated_;
  std::vector<Extension> extensions_;
  Eigen::VectorXd extension_params_;
  std::vector<int> estimated_extension_;
  RlsEstimator rls_;
  Eigen::MatrixXd B_;
  KinematicsData data_;
  Eigen::MatrixXd J_, A_, gate_PA_;
  Eigen::Matrix<double, 6, 1> r_;
  const Observation* lin_obs_ = nullptr;  // what r_ / A_ hold (nullptr: nothing reusable)
  Eigen::VectorXd lin_q_;
  Eigen::Matrix4d lin_measured_;
  int lin_rows_ = 0;
  Eigen::MatrixXd drift_map_;  // structuralAbsorption over estimated_ at the nominal parameters, for drift_kind_
  Eigen::VectorXd noise_sigma_;  // the sigma_full whose process noise covariance (over the state) is noise_Q_
  Eigen::MatrixXd noise_Q_;
  MeasurementKind drift_kind_ = MeasurementKind::kPose6D;
};

}  // namespace cellcal
