#include "cellcal/core/identification/rls.hpp"

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace cellcal {

bool RlsOptions::IsValid(int state_size, std::string* error) const {
  auto fail = [&](const char* m) {
    if (error) *error = m;
    return false;
  };
  if (!(forgetting > 0 && forgetting <= 1)) return fail("forgetting must be in (0, 1]");
  if (max_covariance_diag.size() != 0 &&
      (max_covariance_diag.size() != state_size || !(max_covariance_diag.array() > 0).all()))
    return fail("max_covariance_diag must be empty or one positive entry per state");
  return true;
}

RlsEstimator::RlsEstimator(Eigen::VectorXd x0, Eigen::MatrixXd P0, RlsOptions options)
    : x_(std::move(x0)), P_(std::move(P0)), options_(std::move(options)) {
  std::string err;
  if (P_.rows() != x_.size() || P_.cols() != x_.size()) throw std::invalid_argument("RlsEstimator: P0 size mismatch");
  if (!options_.IsValid(static_cast<int>(x_.size()), &err)) throw std::invalid_argument("RlsOptions: " + err);
}

RlsEstimator RlsEstimator::fromInitialBatch(const Eigen::MatrixXd& A0, const Eigen::VectorXd& b0, RlsOptions options) {
  if (A0.rows() < A0.cols()) throw std::invalid_argument("RlsEstimator::fromInitialBatch: fewer rows than states");
  const Eigen::MatrixXd H = A0.transpose() * A0;
  Eigen::LDLT<Eigen::MatrixXd> ldlt(H);
  if (ldlt.info() != Eigen::Success || ldlt.rcond() < 1e-15)
    throw std::invalid_argument("RlsEstimator::fromInitialBatch: A0 is rank deficient");
  Eigen::VectorXd x0 = A0.colPivHouseholderQr().solve(b0);
  Eigen::MatrixXd P0 = ldlt.solve(Eigen::MatrixXd::Identity(H.rows(), H.cols()));
  return RlsEstimator(std::move(x0), std::move(P0), std::move(options));
}

void RlsEstimator::update(const Eigen::Ref<const Eigen::MatrixXd>& A, const Eigen::Ref<const Eigen::VectorXd>& b) {
  updateWithInnovation(A, b - A * x_);
}

void RlsEstimator::updateWithInnovation(const Eigen::Ref<const Eigen::MatrixXd>& A,
                                        const Eigen::Ref<const Eigen::VectorXd>& innovation) {
  const double lambda = options_.forgetting;
  PA_.noalias() = P_.selfadjointView<Eigen::Lower>() * A.transpose();  // m x r
  S_.noalias() = A * PA_;                                               // r x r
  S_.diagonal().array() += lambda;
  Eigen::LLT<Eigen::MatrixXd> llt(S_);
  // x += P A^T S^-1 nu
  const Eigen::VectorXd s_inv_nu = llt.solve(innovation);
  last_nis_ = innovation.dot(s_inv_nu);
  x_.noalias() += PA_ * s_inv_nu;
  // P -= (P A^T L^-T)(P A^T L^-T)^T  (symmetric rank-r downdate, lower triangle only)
  llt.matrixU().solveInPlace<Eigen::OnTheRight>(PA_);
  P_.selfadjointView<Eigen::Lower>().rankUpdate(PA_, -1.0);
  if (track_G_.rows() > 0) {  // g (P - W W^T) g^T = v - |g W|^2
    track_GW_.noalias() = track_G_ * PA_;
    // A downdate subtracts nearly equal numbers once the estimate converges: the rounding of each stays in v. Every
    // kTrackRefresh updates v is computed from P again (amortized: 1/64 of G P G^T per update), and at once after a
    // downdate that removes all but kTrackCancel of a variance (the first poses from a wide prior: v falls by up to
    // ten orders of magnitude, and its rounding with it would stay relative to the old v).
    bool cancelled = false;
    for (Eigen::Index i = 0; i < track_v_.size(); ++i) {
      const double left = track_v_[i] - track_GW_.row(i).squaredNorm();
      cancelled = cancelled || left < kTrackCancel * track_v_[i];
      track_v_[i] = left;
    }
    if (++track_updates_ % kTrackRefresh == 0 || cancelled) track_refresh_due_ = true;
  }
  if (lambda < 1.0) {
    double inflate = 1.0 / lambda;
    if (options_.max_covariance_diag.size())
      for (Eigen::Index i = 0; i < P_.rows(); ++i)
        inflate = std::min(inflate, options_.max_covariance_diag[i] / P_(i, i));
    if (inflate > 1.0) {
      P_.triangularView<Eigen::Lower>() *= inflate;
      track_v_ *= inflate;
    }
  }
  P_.triangularView<Eigen::StrictlyUpper>() = P_.transpose();
  if (track_refresh_due_) {
    track_v_ = trackedForm(P_);
    track_refresh_due_ = false;
  }
}

void RlsEstimator::addProcessNoise(const Eigen::VectorXd& q_diag) {
  P_.diagonal() += q_diag;
  if (track_G_.rows() > 0) track_v_.noalias() += track_G_.cwiseAbs2() * q_diag;
}

void RlsEstimator::addProcessNoise(const Eigen::MatrixXd& Q) {
  if (Q.rows() != P_.rows() || Q.cols() != P_.cols()) throw std::invalid_argument("RlsEstimator: Q size mismatch");
  const Eigen::MatrixXd Qs = 0.5 * (Q + Q.transpose());
  P_ += Qs;
  if (track_G_.rows() > 0) track_v_ += trackedForm(Qs);
}

void RlsEstimator::addScaledProcessNoise(const Eigen::MatrixXd& Q, double scale) {
  if (Q.rows() != P_.rows() || Q.cols() != P_.cols()) throw std::invalid_argument("RlsEstimator: Q size mismatch");
  if (!(scale >= 0)) throw std::invalid_argument("RlsEstimator: negative process noise scale");
  P_.noalias() += scale * Q;
  if (track_G_.rows() == 0) return;
  if (track_Q_.rows() != Q.rows() || track_Q_.cols() != Q.cols() || track_Q_ != Q) {
    track_Q_ = Q;
    track_Qv_ = trackedForm(Q);
  }
  track_v_ += scale * track_Qv_;
}

void RlsEstimator::restore(const Checkpoint& c) {
  if (c.x.size() != x_.size() || c.v.size() != track_v_.size())
    throw std::invalid_argument("RlsEstimator::restore: a checkpoint of another estimator");
  x_ = c.x;
  P_ = c.P;
  track_v_ = c.v;
  track_updates_ = c.updates;
  last_nis_ = c.nis;
}

Eigen::VectorXd RlsEstimator::trackedForm(const Eigen::MatrixXd& M) const {
  return (track_G_ * M).cwiseProduct(track_G_).rowwise().sum();
}

void RlsEstimator::trackVariances(const Eigen::MatrixXd& G) {
  if (G.cols() != P_.rows()) throw std::invalid_argument("RlsEstimator::trackVariances: G has the wrong width");
  track_G_ = G;
  track_v_ = trackedForm(P_);
  track_Q_.resize(0, 0);
  track_Qv_.resize(0);
}

void RlsEstimator::retrackRows(Eigen::Index first, const Eigen::MatrixXd& G) {
  if (G.cols() != P_.rows() || first < 0 || first + G.rows() > track_G_.rows())
    throw std::invalid_argument("RlsEstimator::retrackRows: rows outside the tracked ones, or the wrong width");
  track_G_.middleRows(first, G.rows()) = G;
  track_v_.segment(first, G.rows()) = (G * P_).cwiseProduct(G).rowwise().sum();
  if (track_Qv_.size() == track_G_.rows())
    track_Qv_.segment(first, G.rows()) = (G * track_Q_).cwiseProduct(G).rowwise().sum();
}

namespace {

Eigen::VectorXd select(const Eigen::VectorXd& full, const std::vector<int>& idx) {
  Eigen::VectorXd out(idx.size());
  for (size_t k = 0; k < idx.size(); ++k) out[k] = full[idx[k]];
  return out;
}
}  // namespace

RlsCalibrator::RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params, const GaussianPrior& prior,
                             MeasurementKind kind, RlsCalibratorOptions options)
    : RlsCalibrator(model, params, structuralIdentifiability(model, params, kind, options.identifiability), prior,
                    options) {}

RlsCalibrator::RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params,
                             const IdentifiabilityReport& structural, const GaussianPrior& prior,
                             const RlsCalibratorOptions& options)
    : model_(&model),
      params_(params),
      estimated_(structural.identifiable),
      rls_(select(params, estimated_), priorOverEstimated(prior, estimated_, structural.absorption), options.rls),
      data_(model) {}

RlsCalibrator::RlsCalibrator(const RobotModel& model, const CalibrationResult& initial, RlsCalibratorOptions options)
    : model_(&model),
      params_(initial.params),
      estimated_(initial.estimated),
      rls_(select(initial.params, initial.estimated), initial.covariance, options.rls),
      data_(model) {}

RlsCalibrator::RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                             const Eigen::MatrixXd& covariance, RlsCalibratorOptions options)
    : model_(&model), params_(params), estimated_(estimated), rls_(select(params, estimated), covariance, options.rls),
      data_(model) {}

namespace {
Eigen::VectorXd stackState(const Eigen::VectorXd& params, const std::vector<int>& estimated,
                           const Eigen::VectorXd& extension_params, const std::vector<int>& estimated_extension) {
  Eigen::VectorXd x(estimated.size() + estimated_extension.size());
  Eigen::Index c = 0;
  for (int i : estimated) x[c++] = params[i];
  for (int k : estimated_extension) x[c++] = extension_params[k];
  return x;
}
}  // namespace

RlsCalibrator::RlsCalibrator(const RobotModel& model, const Eigen::VectorXd& params, const std::vector<int>& estimated,
                             const std::vector<Extension>& extensions, const Eigen::VectorXd& extension_params,
                             const std::vector<int>& estimated_extension, const Eigen::MatrixXd& covariance,
                             RlsCalibratorOptions options)
    : model_(&model),
      params_(params),
      estimated_(estimated),
      extensions_(extensions),
      extension_params_(extension_params),
      estimated_extension_(estimated_extension),
      rls_(stackState(params, estimated, extension_params, estimated_extension), covariance, options.rls),
      data_(model) {
  if (extension_params_.size() != numExtensionParams(model, extensions_))
    throw std::invalid_argument("RlsCalibrator: extension parameters do not match the extensions");
}

RlsCalibrator::RlsCalibrator(const RobotModel& model, const CalibratedModel& initial, RlsCalibratorOptions options)
    : model_(&model),
      params_(initial.params),
      estimated_(initial.estimated),
      extensions_(initial.extensions),
      extension_params_(initial.extension_params),
      estimated_extension_(initial.estimated_extension),
      rls_(stackState(initial.params, initial.estimated, initial.extension_params, initial.estimated_extension),
           initial.covariance, options.rls),
      data_(model) {}

Eigen::VectorXd RlsCalibrator::rowParams(const Eigen::VectorXd& q_rad, const Drivers* drivers) {
  if (extensions_.empty()) {
    B_.resize(0, 0);
    return params_;
  }
  if (!drivers) throw std::invalid_argument("RlsCalibrator: an extended model needs the pose's Drivers");
  B_ = extensionBasis(*model_, params_, extensions_, q_rad, *drivers, extension_params_);
  return params_ + B_ * extension_params_;
}

int RlsCalibrator::linearize(const Observation& obs, const Drivers* drivers) {
  if (drivers == nullptr && estimated_extension_.empty() && lin_obs_ == &obs && lin_q_ == obs.q_rad &&
      lin_measured_ == obs.measured_in_tracker.matrix())
    return lin_rows_;
  lin_obs_ = nullptr;
  const int rows = linearizeAnew(obs, drivers);
  if (drivers == nullptr && estimated_extension_.empty()) {
    lin_obs_ = &obs;
    lin_q_ = obs.q_rad;
    lin_measured_ = obs.measured_in_tracker.matrix();
    lin_rows_ = rows;
  }
  return rows;
}

int RlsCalibrator::linearizeAnew(const Observation& obs, const Drivers* drivers) {
  const Eigen::VectorXd p = rowParams(obs.q_rad, drivers);
  const int rows = whitenedResidual(*model_, data_, p, obs, r_, &J_);
  const auto ne = static_cast<Eigen::Index>(estimated_.size());
  A_.resize(rows, ne + static_cast<Eigen::Index>(estimated_extension_.size()));
  for (Eigen::Index k = 0; k < ne; ++k) A_.col(k) = J_.col(estimated_[k]).head(rows);
  if (!estimated_extension_.empty()) {
    const Eigen::MatrixXd JB = J_.topRows(rows) * B_;
    for (size_t k = 0; k < estimated_extension_.size(); ++k) A_.col(ne + k) = JB.col(estimated_extension_[k]);
  }
  return rows;
}

CalibratedModel RlsCalibrator::model() const {
  CalibratedModel m;
  m.params = params_;
  m.extensions = extensions_;
  m.extension_params = extension_params_;
  m.estimated = estimated_;
  m.estimated_extension = estimated_extension_;
  m.covariance = rls_.P();
  return m;
}

void RlsCalibrator::save(Checkpoint& c) const {
  rls_.save(c.rls);
  c.params = params_;
  c.extension_params = extension_params_;
}

void RlsCalibrator::restore(const Checkpoint& c) {
  lin_obs_ = nullptr;
  rls_.restore(c.rls);
  params_ = c.params;
  extension_params_ = c.extension_params;
}

void RlsCalibrator::writeBack() {
  lin_obs_ = nullptr;  // the parameters move: a linearization at the old ones is stale
  const auto ne = estimated_.size();
  for (size_t k = 0; k < ne; ++k) params_[estimated_[k]] = rls_.x()[k];
  for (size_t k = 0; k < estimated_extension_.size(); ++k) extension_params_[estimated_extension_[k]] = rls_.x()[ne + k];
}

double RlsCalibrator::normalizedInnovation(const Observation& obs, const Drivers* drivers) {
  const int rows = linearize(obs, drivers);
  // S = A P A^T + I (at most 6 x 6: no heap), P A^T into a workspace.
  gate_PA_.noalias() = rls_.P().selfadjointView<Eigen::Lower>() * A_.transpose();
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 6, 6> S(rows, rows);
  S.noalias() = A_ * gate_PA_;
  S.diagonal().array() += 1.0;
  const Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 6, 1> r = r_.head(rows);
  return r.dot(S.ldlt().solve(r));
}

double RlsCalibrator::addObservation(const Observation& obs, const Drivers* drivers) {
  const int rows = linearize(obs, drivers);
  rls_.updateWithInnovation(A_, r_.head(rows));
  writeBack();
  return rls_.lastNormalizedInnovation();
}

Pose RlsCalibrator::predict(const Eigen::VectorXd& q_rad, const Drivers* drivers) {
  return forwardKinematics(*model_, data_, rowParams(q_rad, drivers), q_rad);
}

void RlsCalibrator::addProcessNoise(const Eigen::VectorXd& sigma_full, MeasurementKind kind, double variance_scale) {
  if (sigma_full.size() != model_->numParams()) throw std::invalid_argument("RlsCalibrator: sigma has the wrong size");
  const auto ne = static_cast<Eigen::Index>(estimated_.size());
  if (drift_map_.rows() != ne || drift_kind_ != kind) {
    // At the nominal parameters, not the current estimate: a state resumed from a file adds the same noise as the
    // run that saved it.
    drift_map_ = structuralAbsorption(*model_, model_->nominal, kind, estimated_);
    drift_kind_ = kind;
    noise_sigma_.resize(0);
  }
  if (noise_sigma_.size() != sigma_full.size() || noise_sigma_ != sigma_full || noise_Q_.rows() != rls_.x().size()) {
    noise_Q_ = Eigen::MatrixXd::Zero(rls_.x().size(), rls_.x().size());
    noise_Q_.topLeftCorner(ne, ne) = drift_map_ * sigma_full.cwiseAbs2().asDiagonal() * drift_map_.transpose();
    noise_Q_ = 0.5 * (noise_Q_ + noise_Q_.transpose()).eval();
    noise_sigma_ = sigma_full;
  }
  rls_.addScaledProcessNoise(noise_Q_, variance_scale);
}

Eigen::VectorXd DriftModel::sigmas(const RobotModel& model) const {
  Eigen::VectorXd s(model.numParams());
  const int n = model.numJoints();
  for (int i = 0; i < model.numParams(); ++i) {
    if (i >= 5 * n) {
      s[i] = model.isLength(i) ? frame_length_m : frame_angle_rad;
    } else if (i % 5 == static_cast<int>(JointParam::kThetaOffset)) {
      s[i] = joint_offset_rad;
    } else {
      s[i] = model.isLength(i) ? joint_length_m : axis_angle_rad;
    }
  }
  return s;
}

GaussianPrior RlsCalibrator::asPrior() const {
  GaussianPrior p;
  p.mean = params_;
  p.indices = estimated_;
  const auto ne = static_cast<Eigen::Index>(estimated_.size());
  p.covariance = rls_.P().topLeftCorner(ne, ne);
  return p;
}

}  // namespace cellcal
