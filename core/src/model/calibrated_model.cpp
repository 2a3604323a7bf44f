#include "cellcal/core/model/calibrated_model.hpp"

#include <algorithm>
#include <cmath>
#include <map>
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

Eigen::VectorXd stddevsOf(const Eigen::MatrixXd& covariance) {
  return covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
}

Eigen::MatrixXd correlationOf(const Eigen::MatrixXd& covariance) {
  const Eigen::VectorXd sd = stddevsOf(covariance);
  const Eigen::Index n = covariance.rows();
  Eigen::MatrixXd r(n, n);
  for (Eigen::Index i = 0; i < n; ++i)
    for (Eigen::Index j = 0; j < n; ++j)
      r(i, j) = i == j ? 1.0 : (sd[i] > 0 && sd[j] > 0 ? covariance(i, j) / (sd[i] * sd[j]) : 0.0);
  return r;
}

Eigen::MatrixXd covarianceOf(const Eigen::VectorXd& stddevs, const Eigen::MatrixXd& correlation) {
  return stddevs.asDiagonal() * correlation * stddevs.asDiagonal();
}

std::vector<std::string> parameterNames(const RobotModel& model, const std::vector<Extension>& extensions) {
  std::vector<std::string> names;
  for (int i = 0; i < model.numParams(); ++i) names.push_back(model.paramName(i));
  for (auto& n : extensionParamNames(model, extensions)) names.push_back(std::move(n));
  return names;
}

void parametersByName(const RobotModel& model, const CalibratedModel& m, std::vector<double>& values,
                      std::vector<double>& stddevs, std::vector<double>& correlations) {
  const int np = model.numParams();
  values.clear();
  stddevs.clear();
  correlations.clear();
  values.insert(values.end(), m.params.data(), m.params.data() + np);
  values.insert(values.end(), m.extension_params.data(), m.extension_params.data() + m.extension_params.size());
  stddevs.assign(values.size(), 0.0);
  // (place in the name order, covariance column) of each estimated parameter, in the name order.
  std::vector<std::pair<int, Eigen::Index>> order;
  const std::vector<int> columns = m.columns(model);
  for (size_t c = 0; c < columns.size(); ++c) order.emplace_back(columns[c], static_cast<Eigen::Index>(c));
  std::sort(order.begin(), order.end());
  for (const auto& [place, c] : order) stddevs[static_cast<size_t>(place)] = std::sqrt(std::max(0.0, m.covariance(c, c)));
  correlations.reserve(order.size() * (order.size() - 1) / 2);  // 0 for no order: 0 * anything
  for (size_t a = 0; a < order.size(); ++a)
    for (size_t b = a + 1; b < order.size(); ++b) {
      const Eigen::Index i = order[a].second, j = order[b].second;
      const double d = std::sqrt(std::max(0.0, m.covariance(i, i)) * std::max(0.0, m.covariance(j, j)));
      correlations.push_back(d > 0 ? m.covariance(i, j) / d : 0.0);
    }
}

std::optional<CalibratedModel> modelFromParameters(const RobotModel& model, const std::vector<Extension>& extensions,
                                                   const std::vector<std::string>& names,
                                                   const std::vector<double>& values,
                                                   const std::vector<double>& stddevs,
                                                   const std::vector<double>& correlations, std::string* error) {
  auto refuse = [&](const std::string& e) -> std::optional<CalibratedModel> {
    if (error) *error = e;
    return std::nullopt;
  };
  const int np = model.numParams();
  std::map<std::string, int> index;  // name -> place in the name order
  int next = 0;
  for (const auto& n : parameterNames(model, extensions)) index[n] = next++;
  Eigen::VectorXd all(next);
  all << model.nominal, Eigen::VectorXd::Zero(next - np);
  std::vector<bool> given(static_cast<size_t>(next), false);
  if (values.size() != names.size()) return refuse("parameter_names and parameter_values differ in length");
  std::vector<int> place_of(names.size());
  for (size_t k = 0; k < names.size(); ++k) {
    const auto it = index.find(names[k]);
    if (it == index.end()) return refuse("unknown parameter '" + names[k] + "'");
    if (!std::isfinite(values[k])) return refuse("parameter '" + names[k] + "' is not finite");
    all[it->second] = values[k];
    given[static_cast<size_t>(it->second)] = true;
    place_of[k] = it->second;
  }
  // An extension's parameters must all be there (a missing one would silently mean "no effect").
  for (const auto& [n, place] : index)
    if (place >= np && !given[static_cast<size_t>(place)]) return refuse("extension parameter '" + n + "' missing");
  CalibratedModel m;
  m.params = all.head(np);
  m.extensions = extensions;
  m.extension_params = all.tail(next - np);
  if (stddevs.size() != names.size()) return refuse("parameter_names and parameter_stddevs differ in length");
  std::vector<int> with_sd;  // places in the name order of the parameters with a stddev, in the order given
  std::vector<double> sd;
  for (size_t k = 0; k < stddevs.size(); ++k) {
    const double v = stddevs[k];
    if (!(v >= 0) || !std::isfinite(v)) return refuse("parameter_stddevs[" + std::to_string(k) + "] is not a stddev");
    if (v > 0) {
      with_sd.push_back(place_of[k]);
      sd.push_back(v);
    }
  }
  const size_t n = with_sd.size();
  if (correlations.empty()) return m;
  if (correlations.size() != n * (n - 1) / 2)
    return refuse("parameter_correlations: " + std::to_string(correlations.size()) + " values, expected " +
                  std::to_string(n * (n - 1) / 2) + " for " + std::to_string(n) + " parameters with a stddev");
  Eigen::MatrixXd C(static_cast<Eigen::Index>(n), static_cast<Eigen::Index>(n));
  size_t c = 0;
  for (size_t a = 0; a < n; ++a) {
    const auto ia = static_cast<Eigen::Index>(a);
    C(ia, ia) = sd[a] * sd[a];
    for (size_t b = a + 1; b < n; ++b) {
      const double rho = correlations[c++];
      if (!(std::abs(rho) <= 1.0 + 1e-9)) return refuse("parameter_correlations: " + std::to_string(rho) + " is not a correlation");
      const auto ib = static_cast<Eigen::Index>(b);
      C(ia, ib) = C(ib, ia) = rho * sd[a] * sd[b];
    }
  }
  // The covariance's columns in CalibratedModel's order: the kinematic ones by index, then the extension ones.
  std::vector<Eigen::Index> at(n);
  for (size_t k = 0; k < n; ++k) at[k] = static_cast<Eigen::Index>(k);
  std::sort(at.begin(), at.end(), [&](Eigen::Index a, Eigen::Index b) {
    return with_sd[static_cast<size_t>(a)] < with_sd[static_cast<size_t>(b)];
  });
  for (const Eigen::Index k : at) {
    const int place = with_sd[static_cast<size_t>(k)];
    (place < np ? m.estimated : m.estimated_extension).push_back(place < np ? place : place - np);
  }
  m.covariance = C(at, at);
  return m;
}

}  // namespace cellcal
