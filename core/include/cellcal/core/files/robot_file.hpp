// A calibrated robot file: a robot file (docs/robot-file.md) whose joints, base_in_tracker and tool_in_flange hold
// the identified kinematics, plus a `calibration:` section with what a calibration adds: the model extensions and
// their parameters, the covariance of the parameters (every one a prediction depends on, with a flag for those the
// data estimated: prediction.hpp can be rebuilt from it), and where it came from. `cellcal calibrate --save-robot`
// writes it; every command that takes --robot reads it (loadRobotModel reads the kinematics and checks the section).
// Round trip: the predictions of a saved and reloaded model agree to rounding (1e-15 relative).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/identification/residual_map.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct RobotCalibration {
  std::vector<Extension> extensions;     // in the order of their parameters
  Eigen::VectorXd extension_params;      // SI (the units their names say), numExtensionParams(model, extensions)
  // The parameters the covariance covers: kinematic index, or numParams() + k for extension parameter k.
  std::vector<int> columns;
  std::vector<bool> estimated;           // per column: estimated by the calibration (else its prior width)
  Eigen::MatrixXd covariance;            // SI, over `columns`
  double variance_factor_position = 1;   // of the fit (prediction.hpp): scales the readings' position noise
  // Where it came from, in order: date_utc, data_file, data_sha256, rows, split, verification figures, ...
  std::vector<std::pair<std::string, std::string>> provenance;
  // What the model leaves, learnt at the calibration's identification rows (calibrate --residual-map): measured minus
  // model target position in the tracker frame of this calibration's registration. Key residual_map.
  std::optional<ResidualMap> residual_map;
  // The geometric calibration of the same campaign (every kinematic parameter and frame, SI; no extensions), kept
  // beside an extended model so that a new set-up can judge the extensions against it (calibrate --frames-only).
  // Empty: none. Key geometric_parameters.
  Eigen::VectorXd geometric_params;
  // The kinematics the calibration started from (the robot file's before it was calibrated; SI, every parameter, the
  // frames as they were), so that a new set-up can judge the calibration against them (calibrate --frames-only).
  // Empty: not known. Key nominal_parameters.
  Eigen::VectorXd nominal_params;
  // What the extensions may do beyond the joint ranges of the campaign's data (extensionTransfer, prediction.hpp):
  // predictions carried to other rows (calibrate --frames-only) include it, and how far beyond each range the folds
  // judged it: farther, compensation calls the extensions' correction unknown (compensation.hpp). One entry per joint
  // with extensions (sigma 0 where the folds' predictions held); empty without extensions. Key beyond_data.
  std::vector<BeyondRange> beyond_data;
  // The same for the extensions no joint bounds, over their drivers' ranges (DriverRange: link deflection's gravity
  // across its link, a thermal drift's driver). Key beyond_drivers.
  std::vector<DriverRange> beyond_drivers;
  std::string provenanceValue(const std::string& key) const;  // "" when absent
  // provenance date_utc ("YYYY-MM-DDTHH:MM:SSZ") as ns since the epoch; nullopt when absent or malformed.
  std::optional<std::int64_t> dateUtcNs() const;
  // Name of a column: the kinematic parameter's paramName (SI unit), an extension parameter's own name.
  std::string columnName(const RobotModel& model, int column) const;
  bool IsValid(const RobotModel& model, std::string* error) const;
};

struct RobotFile {
  RobotModel model;
  std::optional<RobotCalibration> calibration;
  // Where the robot description came from (`cellcal robot import`: urdf, sha256, base_link, tip_link, ...); empty for
  // a file written by hand.
  std::vector<std::pair<std::string, std::string>> source;
};

// The calibration section of a fit and its prediction model (prediction.hpp): the fit's extensions and their values,
// the prediction's covariance over every parameter a prediction depends on, flagged estimated where the fit estimated
// it. Provenance is the caller's to fill.
RobotCalibration robotCalibration(const RobotModel& model, const CalibratedModel& fit, const PredictionModel& prediction);

// The file's model as a calibrated model (calibrated_model.hpp): its kinematics and frames (model.nominal), the
// extensions and their values, and the columns the calibration estimated with their covariance given the columns kept
// at their prior width (conditionalGaussianCovariance: held at their values, as a fit holds them and as the engine
// starts from the file; their marginal would carry the prior width they share with the estimated columns they are
// confounded with, which cancels in every position). Without a calibration section: the geometric model of its values,
// nothing estimated.
CalibratedModel calibratedModel(const RobotFile& file);

// Throws ConfigError "<file>:<line>:<column>: <field>: <message>" on bad input (as loadRobotModel).
RobotFile loadRobotFile(const std::string& path);
RobotFile parseRobotFile(const std::string& yaml_text, const std::string& source);

// The file's text: `header` as comment lines, then the model (mm, deg) and the calibration section if given.
// `source`, when given: the file's source section.
std::string robotFileText(const RobotModel& model, const RobotCalibration* calibration, const std::string& header,
                          const std::vector<std::pair<std::string, std::string>>* source = nullptr);
// Writes robotFileText to path through a temporary file and rename. Throws std::runtime_error naming the path.
void saveRobotFile(const std::string& path, const RobotModel& model, const RobotCalibration* calibration,
                   const std::string& header,
                   const std::vector<std::pair<std::string, std::string>>* source = nullptr);

}  // namespace cellcal
