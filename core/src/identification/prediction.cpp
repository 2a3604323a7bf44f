#include "cellcal/core/identification/prediction.hpp"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace cellcal {
namespace {

// Whitened Jacobian rows of one observation with respect to [kinematic parameters, extension parameters].
int jacobianRows(const RobotModel& model, KinematicsData& data, const CalibratedModel& fit, const Observation& obs,
                 const Drivers& drivers, Eigen::VectorXd* r, Eigen::MatrixXd& J) {
  const int np = model.numParams();
  const int k = static_cast<int>(fit.extension_params.size());
  Eigen::MatrixXd B;
  Eigen::VectorXd p = fit.params;
  if (k > 0) {
    B = extensionBasis(model, fit.params, fit.extensions, obs.q_rad, drivers, fit.extension_params);
    p += B * fit.extension_params;
  }
  Eigen::Matrix<double, 6, 1> ri;
  Eigen::MatrixXd Ji;
  const int rows = whitenedResidual(model, data, p, obs, ri, &Ji);
  J.resize(rows, np + k);
  J.leftCols(np) = Ji.topRows(rows);
  if (k > 0) J.rightCols(k) = Ji.topRows(rows) * B;
  if (r) *r = ri.head(rows);
  return rows;
}

// Each kind's residual sum of squares over its share of rows - estimated (residualVarianceFactors).
VarianceFactors factorsOf(double rss_p, int rows_p, double rss_o, int rows_o, int estimated) {
  const int rows = rows_p + rows_o;
  auto factor = [&](double rss, int kind_rows) {
    const double dof = kind_rows - estimated * static_cast<double>(kind_rows) / std::max(rows, 1);
    return kind_rows > 0 && dof > 0 ? std::max(rss / dof, 1e-12) : 1.0;
  };
  return {factor(rss_p, rows_p), factor(rss_o, rows_o)};
}

}  // namespace

bool PredictionOptions::IsValid(std::string* error) const {
  if (!(prior_length_m > 0) || !(prior_angle_rad > 0) || !(extension_joint_error_rad > 0)) {
    if (error) *error = "prior_length_m, prior_angle_rad and extension_joint_error_rad must be > 0";
    return false;
  }
  return true;
}

VarianceFactors residualVarianceFactors(const RobotModel& model, const CalibratedModel& fit,
                                        const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                        int estimated) {
  if (obs.size() != drivers.size()) throw std::invalid_argument("residualVarianceFactors: one Drivers entry per observation");
  KinematicsData data(model);
  Eigen::MatrixXd J;
  Eigen::VectorXd r;
  double rss_p = 0, rss_o = 0;
  int rows_p = 0, rows_o = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    const int rows = jacobianRows(model, data, fit, obs[i], drivers[i], &r, J);
    rss_p += r.head(3).squaredNorm();
    rows_p += 3;
    if (rows == 6) {
      rss_o += r.tail(3).squaredNorm();
      rows_o += 3;
    }
  }
  return factorsOf(rss_p, rows_p, rss_o, rows_o, estimated);
}

PredictionModel predictionModel(const RobotModel& model, const CalibratedModel& fit, const std::vector<Observation>& obs,
                                const std::vector<Drivers>& drivers, const PredictionOptions& options) {
  std::string err;
  if (!options.IsValid(&err)) throw std::invalid_argument("PredictionOptions: " + err);
  if (obs.size() != drivers.size()) throw std::invalid_argument("predictionModel: one Drivers entry per observation");
  const int np = model.numParams();
  const int k = static_cast<int>(fit.extension_params.size());
  PredictionModel pm;
  std::vector<double> prior;
  // What the frames stand for (frameGauge) is theirs: its prior would only split the frames' pinned sum in two.
  const std::vector<int> gauge = frameGauge(model, fit.params);
  for (int c : model.canonicalParams()) {
    if (std::binary_search(gauge.begin(), gauge.end(), c)) continue;
    pm.columns.push_back(c);
    prior.push_back(model.isLength(c) ? options.prior_length_m : options.prior_angle_rad);
  }
  if (k > 0) {
    const Eigen::VectorXd ext_prior =
        extensionPriorSigma(model, fit.params, fit.extensions, options.extension_joint_error_rad);
    for (int e = 0; e < k; ++e)
      if (ext_prior[e] > 0) {
        pm.columns.push_back(np + e);
        prior.push_back(ext_prior[e]);
      }
  }
  const auto n = static_cast<Eigen::Index>(pm.columns.size());
  pm.prior_sigma = Eigen::Map<const Eigen::VectorXd>(prior.data(), n);
  // Normal matrices of the scaled columns (D^T J^T J D), position rows and orientation rows apart: each gets its own
  // variance factor (a model error shows in millimetres and in degrees by different amounts than the readings' sigmas
  // say), from its residual sum of squares over its share of the degrees of freedom.
  Eigen::MatrixXd Np = Eigen::MatrixXd::Zero(n, n), No = Eigen::MatrixXd::Zero(n, n);
  KinematicsData data(model);
  Eigen::MatrixXd J, Js(6, n);
  Eigen::VectorXd r;
  double rss_p = 0, rss_o = 0;
  int rows_p = 0, rows_o = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    const int rows = jacobianRows(model, data, fit, obs[i], drivers[i], &r, J);
    for (Eigen::Index c = 0; c < n; ++c) Js.col(c).head(rows) = J.col(pm.columns[c]) * pm.prior_sigma[c];
    Np.noalias() += Js.topRows(3).transpose() * Js.topRows(3);
    rss_p += r.head(3).squaredNorm();
    rows_p += 3;
    if (rows == 6) {
      No.noalias() += Js.middleRows(3, 3).transpose() * Js.middleRows(3, 3);
      rss_o += r.tail(3).squaredNorm();
      rows_o += 3;
    }
  }
  pm.rows = rows_p + rows_o;
  pm.estimated = static_cast<int>(fit.estimated.size() + fit.estimated_extension.size());
  const VarianceFactors vf = factorsOf(rss_p, rows_p, rss_o, rows_o, pm.estimated);
  pm.variance_factor_position = vf.position;
  pm.variance_factor_orientation = vf.orientation;
  pm.variance_factor = rows_o > 0 ? (rss_p + rss_o) / std::max(1.0, pm.rows - static_cast<double>(pm.estimated))
                                  : pm.variance_factor_position;
  const Eigen::MatrixXd A = Np / pm.variance_factor_position + No / pm.variance_factor_orientation +
                            Eigen::MatrixXd::Identity(n, n);
  const Eigen::MatrixXd inv = A.ldlt().solve(Eigen::MatrixXd::Identity(n, n));
  pm.covariance = pm.prior_sigma.asDiagonal() * inv * pm.prior_sigma.asDiagonal();
  return pm;
}

PredictionModel carriedPrediction(const RobotModel& model, const CalibratedModel& fit, const PredictionModel& carried,
                                  const std::vector<Observation>& obs, const std::vector<Drivers>& drivers,
                                  const std::vector<int>& frames, const VarianceFactors& noise) {
  if (obs.size() != drivers.size()) throw std::invalid_argument("carriedPrediction: one Drivers entry per observation");
  for (double f : {noise.position, noise.orientation})
    if (!(f >= 0) || !std::isfinite(f)) throw std::invalid_argument("carriedPrediction: variance factors must be finite and >= 0");
  const auto nc = static_cast<Eigen::Index>(carried.columns.size());
  if (carried.covariance.rows() != nc || carried.covariance.cols() != nc)
    throw std::invalid_argument("carriedPrediction: the carried covariance does not match its columns");
  const int ncols = model.numParams() + static_cast<int>(fit.extension_params.size());
  for (int c : carried.columns)
    if (c < 0 || c >= ncols) throw std::invalid_argument("carriedPrediction: carried column " + std::to_string(c) + " out of range");
  for (int c : frames)
    if (c < 0 || c >= model.numParams()) throw std::invalid_argument("carriedPrediction: frame column out of range");
  std::vector<Eigen::Index> m_at;  // positions in `carried` of the columns the new frames do not replace
  for (Eigen::Index k = 0; k < nc; ++k)
    if (!std::count(frames.begin(), frames.end(), carried.columns[static_cast<size_t>(k)])) m_at.push_back(k);
  const auto nm = static_cast<Eigen::Index>(m_at.size()), nf = static_cast<Eigen::Index>(frames.size());
  Eigen::MatrixXd S(nm, nm);
  for (Eigen::Index i = 0; i < nm; ++i)
    for (Eigen::Index j = 0; j < nm; ++j) S(i, j) = carried.covariance(m_at[i], m_at[j]);
  // Normal equations of the frames on these rows, and their coupling to the carried columns.
  // Nfs: A_f^T Σ A_f, the frames' normal matrix with each kind of row scaled by its variance factor.
  Eigen::MatrixXd Nff = Eigen::MatrixXd::Zero(nf, nf), Nfm = Eigen::MatrixXd::Zero(nf, nm), Nfs = Nff;
  KinematicsData data(model);
  Eigen::MatrixXd J, Af, Am;
  int rows_total = 0, rows_o = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    const int rows = jacobianRows(model, data, fit, obs[i], drivers[i], nullptr, J);
    rows_total += rows;
    Af.resize(rows, nf);
    Am.resize(rows, nm);
    for (Eigen::Index c = 0; c < nf; ++c) Af.col(c) = J.col(frames[static_cast<size_t>(c)]);
    for (Eigen::Index c = 0; c < nm; ++c) Am.col(c) = J.col(carried.columns[static_cast<size_t>(m_at[c])]);
    Nff.noalias() += Af.transpose() * Af;
    Nfm.noalias() += Af.transpose() * Am;
    Nfs.noalias() += noise.position * Af.topRows(3).transpose() * Af.topRows(3);
    if (rows == 6) {
      Nfs.noalias() += noise.orientation * Af.bottomRows(3).transpose() * Af.bottomRows(3);
      rows_o += 3;
    }
  }
  const auto ldlt = Nff.ldlt();
  const Eigen::MatrixXd Nff_inv = ldlt.solve(Eigen::MatrixXd::Identity(nf, nf));
  const Eigen::MatrixXd K = ldlt.solve(Nfm);
  PredictionModel pm;
  pm.covariance.resize(nm + nf, nm + nf);
  pm.covariance.topLeftCorner(nm, nm) = S;
  pm.covariance.bottomLeftCorner(nf, nm) = -K * S;
  pm.covariance.topRightCorner(nm, nf) = -S * K.transpose();
  pm.covariance.bottomRightCorner(nf, nf) = K * S * K.transpose() + Nff_inv * Nfs * Nff_inv;
  pm.prior_sigma.resize(nm + nf);
  for (Eigen::Index k = 0; k < nm; ++k) {
    pm.columns.push_back(carried.columns[static_cast<size_t>(m_at[k])]);
    pm.prior_sigma[k] = carried.prior_sigma.size() == nc ? carried.prior_sigma[m_at[k]] : std::sqrt(S(k, k));
  }
  for (Eigen::Index k = 0; k < nf; ++k) {
    pm.columns.push_back(frames[static_cast<size_t>(k)]);
    pm.prior_sigma[nm + k] = std::sqrt(std::max(0.0, pm.covariance(nm + k, nm + k)));
  }
  pm.variance_factor_position = noise.position;
  pm.variance_factor_orientation = noise.orientation;
  const double rows_p = rows_total - rows_o;
  pm.variance_factor = rows_total > 0 ? (noise.position * rows_p + noise.orientation * rows_o) / rows_total : noise.position;
  pm.rows = rows_total;
  pm.estimated = static_cast<int>(nf);
  pm.beyond = carried.beyond;
  pm.beyond_drivers = carried.beyond_drivers;
  return pm;
}

double predictedPositionSigma(const RobotModel& model, const CalibratedModel& fit, const PredictionModel& prediction,
                              const Eigen::VectorXd& q_rad, const Drivers& drivers) {
  Observation o;
  o.q_rad = q_rad;
  o.kind = MeasurementKind::kPosition3D;
  o.sigma_position_m = 1.0;  // unwhitened: position rows in metres
  KinematicsData data(model);
  Eigen::MatrixXd J;
  jacobianRows(model, data, fit, o, drivers, nullptr, J);
  const auto n = static_cast<Eigen::Index>(prediction.columns.size());
  Eigen::MatrixXd Jp(3, n);
  for (Eigen::Index c = 0; c < n; ++c) Jp.col(c) = J.col(prediction.columns[c]);
  const double var = (Jp * prediction.covariance * Jp.transpose()).trace() +
                    beyondPositionVariance(model, J.leftCols(model.numParams()), prediction.beyond, q_rad) +
                    driverRangeVariance(model, fit.params, prediction.beyond_drivers, q_rad, drivers);
  return std::sqrt(std::max(0.0, var));
}

double beyondPositionVariance(const RobotModel& model, const Eigen::Ref<const Eigen::MatrixXd>& J,
                              const std::vector<BeyondRange>& ranges, const Eigen::VectorXd& q_rad) {
  double var = 0;
  for (const BeyondRange& b : ranges) {  // a joint error: the position moves as with the joint's offset
    const double s = b.sigmaRad(q_rad[b.joint]);
    if (s > 0) var += s * s * J.col(model.jointParam(b.joint, JointParam::kThetaOffset)).head<3>().squaredNorm();
  }
  return var;
}

std::vector<double> estimatePositionSigmas(const RobotModel& model, const CalibratedModel& fit,
                                           const std::vector<Observation>& fitted,
                                           const std::vector<Drivers>& fitted_drivers,
                                           const std::vector<Observation>& at, const std::vector<Drivers>& at_drivers) {
  if (at.size() != at_drivers.size()) throw std::invalid_argument("estimatePositionSigmas: one Drivers entry per row");
  std::vector<double> sigma(at.size(), 0.0);
  if (!fit.hasCovariance()) return sigma;
  PredictionModel pm;
  pm.columns = fit.columns(model);
  pm.covariance =
      fit.covariance * residualVarianceFactors(model, fit, fitted, fitted_drivers, fit.numEstimated()).position;
  for (size_t i = 0; i < at.size(); ++i) sigma[i] = predictedPositionSigma(model, fit, pm, at[i].q_rad, at_drivers[i]);
  return sigma;
}

double kinematicPositionSigma(const RobotModel& model, KinematicsData& data, const Eigen::VectorXd& params,
                              const std::vector<int>& estimated, const Eigen::MatrixXd& covariance,
                              const Eigen::VectorXd& q_rad) {
  Eigen::MatrixXd J(6, model.numParams());
  forwardKinematics(model, data, params, q_rad);
  computePoseJacobian(model, data, J);
  const auto n = static_cast<Eigen::Index>(estimated.size());
  Eigen::MatrixXd Js(3, n);
  for (Eigen::Index k = 0; k < n; ++k) Js.col(k) = J.col(estimated[static_cast<size_t>(k)]).head<3>();
  const double var = (Js * covariance.topLeftCorner(n, n) * Js.transpose()).trace();
  return std::isfinite(var) ? std::sqrt(std::max(0.0, var)) : std::numeric_limits<double>::infinity();
}

std::vector<ExcitationDeficit> excitationDeficits(const RobotModel& model, const Eigen::VectorXd& params,
                                                  const std::vector<Extension>& extensions,
                                                  const std::vector<Observation>& identification,
                                                  const std::vector<Drivers>& identification_drivers,
                                                  const std::vector<Observation>& other,
                                                  const std::vector<Drivers>& other_drivers, double ratio) {
  if (identification.size() != identification_drivers.size() || other.size() != other_drivers.size())
    throw std::invalid_argument("excitationDeficits: one Drivers entry per observation");
  if (identification.empty() || other.empty()) return {};
  ExtendedFit at;
  at.params = params;
  at.extensions = extensions;
  at.extension_params = Eigen::VectorXd::Zero(numExtensionParams(model, extensions));
  const int np = model.numParams();
  std::vector<int> columns = model.canonicalParams();
  for (int e = 0; e < at.extension_params.size(); ++e) columns.push_back(np + e);
  const std::vector<std::string> ext_names = extensionParamNames(model, extensions);
  KinematicsData data(model);
  Eigen::MatrixXd J;
  std::vector<double> sum_sq(columns.size(), 0.0), most(columns.size(), 0.0);
  for (size_t i = 0; i < identification.size(); ++i) {
    jacobianRows(model, data, at, identification[i], identification_drivers[i], nullptr, J);
    for (size_t c = 0; c < columns.size(); ++c) sum_sq[c] += J.col(columns[c]).squaredNorm();
  }
  for (size_t i = 0; i < other.size(); ++i) {
    jacobianRows(model, data, at, other[i], other_drivers[i], nullptr, J);
    for (size_t c = 0; c < columns.size(); ++c) most[c] = std::max(most[c], J.col(columns[c]).norm());
  }
  std::vector<ExcitationDeficit> out;
  constexpr double kNumericalFloor = 1e-9;
  const double largest = most.empty() ? 0.0 : *std::max_element(most.begin(), most.end());
  for (size_t c = 0; c < columns.size(); ++c) {
    const double rms = std::sqrt(sum_sq[c] / static_cast<double>(identification.size()));
    // A column no row excites beyond rounding (a regressor column that never acts here) is structurally
    // unidentifiable, not a deficit: the identifiable-set choice leaves it out.
    if (most[c] > kNumericalFloor * largest && rms < ratio * most[c]) {
      const int col = columns[c];
      out.push_back({col, col < np ? model.paramName(col) : ext_names[static_cast<size_t>(col - np)], rms, most[c]});
    }
  }
  return out;
}

std::string deficitText(const ExcitationDeficit& d) {
  std::ostringstream s;
  s.precision(2);
  s << d.name << ": excited ";
  if (d.identification_rms > 0) s << std::fixed << d.elsewhere_max / d.identification_rms << "x less";
  else s << "not at all";
  s.unsetf(std::ios::fixed);
  s << " on the identification rows (RMS " << d.identification_rms << ") than on another row (" << d.elsewhere_max
    << "): held at its start value";
  return s.str();
}

std::vector<int> heldColumns(const std::vector<ExcitationDeficit>& deficits) {
  std::vector<int> held;
  for (const auto& d : deficits) held.push_back(d.column);
  return held;
}

}  // namespace cellcal
