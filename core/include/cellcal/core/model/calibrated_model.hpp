// What a calibration identified of a robot, as one value: the kinematic parameters (joints, base and tool frames),
// the model extensions and their parameters, and the covariance of the parameters the data estimated. It is relative
// to a RobotModel (its layout and nominal values) and owns nothing else.
//
// Every shape of an identified model is this value plus what its producer adds: a batch fit (ExtendedFit: the
// solver's outcome), the engine's snapshot (CalibrationSnapshot: version, health, statistics), the model compensation
// uses (IdentifiedModel: a residual map) and the one a consumer received (ReceivedCalibration: version, health). So
// passing a model from one to the other is a copy of this part, never a field-by-field conversion.
//
//   CalibratedModel m = CalibratedModel::geometric(model.nominal);   // the nominal model, nothing estimated
//   std::string why;
//   if (!m.IsValid(model, &why)) throw std::invalid_argument(why);
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct CalibratedModel {
  Eigen::VectorXd params;                // kinematic parameters, full vector, SI (RobotModel layout)
  std::vector<Extension> extensions;     // in the order of their parameters; empty: the geometric model
  Eigen::VectorXd extension_params;      // SI, numExtensionParams(model, extensions), extensionParamNames order
  std::vector<int> estimated;            // kinematic parameters the data estimated (indices into params)
  std::vector<int> estimated_extension;  // extension parameters the data estimated (indices into extension_params)
  // Covariance (SI) of the estimated parameters: rows/cols are `estimated`, then `estimated_extension`, in those
  // orders (columns()). Empty: not known. A producer that sends only the kinematic block leaves estimated_extension
  // empty.
  Eigen::MatrixXd covariance;

  // The geometric model with these kinematic parameters: no extension; `estimated` and their covariance if given.
  static CalibratedModel geometric(const Eigen::VectorXd& params, const std::vector<int>& estimated = {},
                                   const Eigen::MatrixXd& covariance = Eigen::MatrixXd());

  // The covariance's columns: kinematic index i, or numParams + k for extension parameter k (RobotCalibration's
  // numbering).
  std::vector<int> columns(const RobotModel& model) const;
  int numEstimated() const { return static_cast<int>(estimated.size() + estimated_extension.size()); }
  int numEstimatedExtension() const { return static_cast<int>(estimated_extension.size()); }
  bool hasCovariance() const { return covariance.rows() > 0; }
  // 1-sigma of kinematic parameter i / extension parameter k (NaN when not estimated or no covariance).
  double paramStddev(int i) const;
  double extensionStddev(int k) const;
  // The covariance's block over the estimated kinematic parameters (estimated x estimated); empty without one.
  Eigen::MatrixXd kinematicCovariance() const;
  // The name of covariance column c: the kinematic parameter's paramName, an extension parameter's own name.
  std::string columnName(const RobotModel& model, int c) const;

  // Sizes against `model` (params, extension_params from the extensions), every extension applicable to it (ignoring
  // the thermal driver, which is the cell's), indices in range and each once, finite values, and a covariance that is
  // empty or square over numEstimated() with a finite, non-negative diagonal. The first fault, named, in *error.
  bool IsValid(const RobotModel& model, std::string* error) const;
};

// A covariance as files and messages carry it: the 1-sigmas, and the correlations (1 on the diagonal, 0 where either
// sigma is 0). covarianceOf is the inverse.
Eigen::VectorXd stddevsOf(const Eigen::MatrixXd& covariance);
Eigen::MatrixXd correlationOf(const Eigen::MatrixXd& covariance);
Eigen::MatrixXd covarianceOf(const Eigen::VectorXd& stddevs, const Eigen::MatrixXd& correlation);

// A calibrated model by parameter name, as the CalibrationState message carries it (components/convert.hpp): every
// kinematic parameter in RobotModel order, then every extension parameter; names from parameterNames (the SI unit in
// each). `values` and `stddevs` (0: not estimated) follow that order; `correlations` are those of the estimated
// parameters in that order, the upper triangle without the diagonal, row by row (n (n - 1) / 2 values). The vectors
// are cleared and filled, their capacity kept (a publisher reuses them).
std::vector<std::string> parameterNames(const RobotModel& model, const std::vector<Extension>& extensions);
void parametersByName(const RobotModel& model, const CalibratedModel& m, std::vector<double>& values,
                      std::vector<double>& stddevs, std::vector<double>& correlations);
// The inverse, for parameters named in any order: a kinematic parameter left out keeps its nominal value, every
// extension parameter must be given. The estimated parameters are those with a stddev > 0, with their covariance when
// `correlations` is not empty (else none is estimated). nullopt with the first fault in *error, naming the field
// ("unknown parameter 'x'", "parameter_correlations: 20 values, expected 21 for 7 parameters with a stddev", ...).
std::optional<CalibratedModel> modelFromParameters(const RobotModel& model, const std::vector<Extension>& extensions,
                                                   const std::vector<std::string>& names,
                                                   const std::vector<double>& values,
                                                   const std::vector<double>& stddevs,
                                                   const std::vector<double>& correlations, std::string* error);

}  // namespace cellcal
