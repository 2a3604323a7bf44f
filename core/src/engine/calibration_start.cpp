#include "cellcal/core/engine/calibration_start.hpp"

#include <cmath>
#include <map>
#include <string>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/rls.hpp"
#include "cellcal/core/identification/statistics.hpp"

namespace cellcal {

CalibrationStart calibrationStart(const RobotModel& m, const RobotFile& file, const std::vector<Extension>& exts,
                                  double prior_length_m, double prior_angle_rad, MeasurementKind measurement) {
  const RobotCalibration& cal = *file.calibration;
  CalibrationStart out;
  CalibratedModel& c = out.model;
  // The estimate: the file's kinematics and frames (the campaign's registration; a tracker moved since shows as poses
  // beyond the outlier gate, and the engine then says to re-register).
  c.params = file.model.nominal;
  c.extensions = exts;
  // The state the engine estimates when it starts from nominal, and its uncalibrated prior widths.
  const GaussianPrior prior = diagonalPrior(m, c.params, m.canonicalParams(), prior_length_m, prior_angle_rad);
  const RlsCalibrator plain(m, c.params, prior, measurement);
  c.estimated = plain.estimated();
  const Eigen::VectorXd ext_sigma = extensionPriorSigma(m, c.params, exts, prior_angle_rad);
  for (Eigen::Index k = 0; k < ext_sigma.size(); ++k)
    if (ext_sigma[k] > 0) c.estimated_extension.push_back(static_cast<int>(k));
  const auto ne = static_cast<Eigen::Index>(c.estimated.size());
  const Eigen::Index n = c.numEstimated();
  const std::vector<std::string> ext_names = extensionParamNames(m, exts);
  std::vector<std::string> names;
  out.prior_sd.resize(n);
  for (Eigen::Index k = 0; k < ne; ++k) {
    names.push_back(m.paramName(c.estimated[static_cast<size_t>(k)]));
    out.prior_sd[k] = std::sqrt(plain.covariance()(k, k));
  }
  for (size_t k = 0; k < c.estimated_extension.size(); ++k) {
    names.push_back(ext_names[static_cast<size_t>(c.estimated_extension[k])]);
    out.prior_sd[ne + static_cast<Eigen::Index>(k)] = ext_sigma[c.estimated_extension[k]];
  }
  // Each state entry's column in the file (-1: the file does not cover it).
  std::map<std::string, int> file_column;
  for (size_t j = 0; j < cal.columns.size(); ++j) file_column[cal.columnName(file.model, cal.columns[j])] = static_cast<int>(j);
  std::vector<int> e_rows, e_cols;
  for (Eigen::Index k = 0; k < n; ++k) {
    const auto it = file_column.find(names[static_cast<size_t>(k)]);
    if (it == file_column.end()) continue;
    e_rows.push_back(static_cast<int>(k));
    e_cols.push_back(it->second);
  }
  out.covered = static_cast<int>(e_rows.size());
  // The covariance of the covered entries given every other column of the file; the others keep their prior.
  const Eigen::MatrixXd Pee = conditionalGaussianCovariance(cal.covariance, e_cols);
  c.covariance = out.prior_sd.array().square().matrix().asDiagonal();
  for (size_t a = 0; a < e_rows.size(); ++a)
    for (size_t b = 0; b < e_rows.size(); ++b)
      c.covariance(e_rows[a], e_rows[b]) = Pee(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
  // The extension values the file fitted (same names); the others start at zero, no effect.
  c.extension_params = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(ext_names.size()));
  const std::vector<std::string> file_ext_names = extensionParamNames(file.model, cal.extensions);
  for (size_t k = 0; k < ext_names.size(); ++k)
    for (size_t j = 0; j < file_ext_names.size(); ++j)
      if (ext_names[k] == file_ext_names[j])
        c.extension_params[static_cast<Eigen::Index>(k)] = cal.extension_params[static_cast<Eigen::Index>(j)];
  out.capped = capVariances(c.covariance, out.prior_sd);
  return out;
}

int capVariances(Eigen::MatrixXd& P, const Eigen::VectorXd& sd) {
  int capped = 0;
  for (Eigen::Index k = 0; k < P.rows() && k < sd.size(); ++k)
    if (P(k, k) > sd[k] * sd[k]) {
      const double f = sd[k] / std::sqrt(P(k, k));
      P.row(k) *= f;
      P.col(k) *= f;
      ++capped;
    }
  return capped;
}

}  // namespace cellcal
