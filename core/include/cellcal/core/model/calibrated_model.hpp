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

}  // namespace cellcal
