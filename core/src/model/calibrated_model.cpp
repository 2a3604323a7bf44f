#include "cellcal/core/model/calibrated_model.hpp"

#include <algorithm>
#include <cmath>
#include <set>
#include <sstream>

namespace cellcal {

CalibratedModel CalibratedModel::geometric(const Eigen::VectorXd& params, const std::vector<int>& estimated,
                                           const Eigen::MatrixXd& covariance) {
  CalibratedModel m;
  m.params = params;
  m.extension_params = Eigen::VectorXd(0);
  m.estimated = estimated;
  m.covariance = covariance;
  return m;
}

std::vector<int> CalibratedModel::columns(const RobotModel& model) const {
  std::vector<int> c(estimated);
  for (int k : estimated_extension) c.push_back(model.numParams() + k);
  return c;
}

double CalibratedModel::paramStddev(int i) const {
  const auto it = std::find(estimated.begin(), estimated.end(), i);
  if (it == estimated.end() || covariance.rows() == 0) return std::nan("");
  const auto c = it - estimated.begin();
  return std::sqrt(covariance(c, c));
}

double CalibratedModel::extensionStddev(int k) const {
  const auto it = std::find(estimated_extension.begin(), estimated_extension.end(), k);
  if (it == estimated_extension.end() || covariance.rows() == 0) return std::nan("");
  const auto c = static_cast<Eigen::Index>(estimated.size()) + (it - estimated_extension.begin());
  return std::sqrt(covariance(c, c));
}

Eigen::MatrixXd CalibratedModel::kinematicCovariance() const {
  if (covariance.rows() == 0) return Eigen::MatrixXd();
  const auto n = static_cast<Eigen::Index>(estimated.size());
  return covariance.topLeftCorner(n, n);
}

std::string CalibratedModel::columnName(const RobotModel& model, int c) const {
  const int n = static_cast<int>(estimated.size());
  if (c < n) return model.paramName(estimated.at(static_cast<size_t>(c)));
  return extensionParamNames(model, extensions).at(static_cast<size_t>(estimated_extension.at(static_cast<size_t>(c - n))));
}

namespace {

bool fail(std::string* error, const std::string& what) {
  if (error) *error = what;
  return false;
}

// Each index in [0, size), each once; the first fault named.
bool indicesValid(const std::vector<int>& idx, Eigen::Index size, const char* field, std::string* error) {
  std::set<int> seen;
  for (size_t k = 0; k < idx.size(); ++k) {
    std::ostringstream m;
    if (idx[k] < 0 || idx[k] >= size) {
      m << field << ": entry " << k << " is " << idx[k] << ", ";
      if (size == 0) m << "but there is no such parameter";
      else m << "outside 0.." << size - 1;
    } else if (!seen.insert(idx[k]).second) {
      m << field << ": entry " << k << " is " << idx[k] << ", listed twice";
    }
    if (!m.str().empty()) return fail(error, m.str());
  }
  return true;
}

}  // namespace

bool CalibratedModel::IsValid(const RobotModel& model, std::string* error) const {
  std::ostringstream m;
  if (params.size() != model.numParams()) {
    m << "params: " << params.size() << " values for a model of " << model.numParams() << " parameters";
    return fail(error, m.str());
  }
  for (Eigen::Index i = 0; i < params.size(); ++i)
    if (!std::isfinite(params[i])) return fail(error, "params: " + model.paramName(static_cast<int>(i)) + " is not finite");
  for (const Extension& e : extensions)
    if (!applicable(model, e, /*has_thermal=*/true))
      return fail(error, "extensions: " + extensionSpec(e) + " does not apply to this robot model");
  const int n_ext = numExtensionParams(model, extensions);
  if (extension_params.size() != n_ext) {
    m << "extension_params: " << extension_params.size() << " values for extensions of " << n_ext << " parameters";
    return fail(error, m.str());
  }
  if (!extension_params.allFinite()) return fail(error, "extension_params: a value is not finite");
  if (!indicesValid(estimated, params.size(), "estimated", error)) return false;
  if (!indicesValid(estimated_extension, n_ext, "estimated_extension", error)) return false;
  if (covariance.size() == 0) return true;
  const Eigen::Index n = numEstimated();
  if (covariance.rows() != n || covariance.cols() != n) {
    m << "covariance: " << covariance.rows() << "x" << covariance.cols() << " for " << n << " estimated parameters";
    return fail(error, m.str());
  }
  if (!covariance.allFinite()) return fail(error, "covariance: a value is not finite");
  for (Eigen::Index c = 0; c < n; ++c)
    if (covariance(c, c) < 0)
      return fail(error, "covariance: the variance of " + columnName(model, static_cast<int>(c)) + " is negative");
  return true;
}

}  // namespace cellcal
