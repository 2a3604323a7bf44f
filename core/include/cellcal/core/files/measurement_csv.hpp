// Measurement file, CSV v1 (docs/measurement-csv.md): one row per measured pose.
//   - Lines starting with '#' before the header are comments; then one header row of column names.
//   - Comma separated, '.' decimals.
//   - Required: q1_deg..qN_deg (or q1_rad..qN_rad), x_mm, y_mm, z_mm (target position in the tracker frame),
//     N = joints of the robot file.
//   - Optional: qw, qx, qy, qz (target orientation in the tracker frame; all four empty = position-only row),
//     stamp_s, group (integer), temperature_c, payload_kg, sigma_position_mm and sigma_orientation_deg (the reading's
//     own 1-sigma per axis, as a tracker reports it: the row's weight in every fit, instead of the command line's
//     --sigma-*), setup, pose (the ISO 9283 test pose the row visits, e.g. P1) and cycle (its cycle, an integer).
//     Unknown columns are reported once and ignored.
//   - Row order is the order the robot visited the poses.
// Bad rows (missing required cell, non-number, non-unit quaternion, joint outside limits) throw ConfigError
// "<file>:<line>:<column>: <column name>: <message>"; with skip_bad_rows they become counted warnings and the row
// is left out (the rows already read are kept).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/files/robot_yaml.hpp"

namespace cellcal {

struct MeasurementRow {
  int line = 0;                                   // 1-based line in the file
  Eigen::VectorXd q_rad;
  Eigen::Vector3d position_m = Eigen::Vector3d::Zero();
  std::optional<Eigen::Quaterniond> orientation;  // unit; absent for a position-only row
  std::optional<double> stamp_s, temperature_c, payload_kg;
  std::optional<double> sigma_position_m, sigma_orientation_rad;  // the reading's own 1 sigma per axis (> 0)
  std::optional<long long> group;
  // The tracker (or target) placement the row was measured in (column `setup`, any label up to 64 characters:
  // "A", "tracker-north"); rows of one label share a base and a tool frame (`cellcal calibrate`, setups.hpp).
  std::optional<std::string> setup;
  // The test pose the row visits (column `pose`, a label up to 64 characters: "P1".."P5" in an ISO 9283 test) and the
  // cycle of that visit (column `cycle`, an integer): rows of one pose are its cycles (accuracy/iso9283.hpp).
  std::optional<std::string> pose;
  std::optional<long long> cycle;
};

struct MeasurementFile {
  std::string source;
  std::vector<MeasurementRow> rows;
  std::vector<std::string> ignored_columns;       // unknown columns (reported once)
  std::vector<std::string> warnings;              // one per skipped row, with file:line:column
  int skipped_rows = 0;
};

struct MeasurementCsvOptions {
  bool skip_bad_rows = false;
  // A robot program rather than measurements: the joint columns (and pose, cycle) only; x_mm, y_mm, z_mm and the
  // orientation are not read (`cellcal plan iso9283` writes such files; simulation.program_csv runs them).
  bool joints_only = false;
  double quaternion_tolerance = 1e-6;             // | |q| - 1 | above this: not a unit quaternion
};

MeasurementFile readMeasurementCsv(const std::string& path, const RobotModel& robot,
                                   const MeasurementCsvOptions& options = {});
MeasurementFile parseMeasurementCsv(const std::string& text, const std::string& source, const RobotModel& robot,
                                    const MeasurementCsvOptions& options = {});

// Writes CSV v1 (q*_rad, x_mm.., qw.. when oriented, stamp_s, group, temperature_c, payload_kg, sigmas, setup, pose,
// cycle when present), the comment's lines first as '#' lines.
void writeMeasurementCsv(std::ostream& out, const MeasurementFile& file, int joints, const std::string& comment);

// The drivers of the model extensions of every row, in visiting order (driversFromSequence of the rows' joints,
// temperatures and stamps).
DriverTable driversOf(const MeasurementFile& file);

// The observation of a row (6D if it has an orientation and kind allows, else 3D), with the row's own sigmas where it
// has them, else the ones given.
Observation toObservation(const MeasurementRow& row, MeasurementKind kind, double sigma_position_m,
                          double sigma_orientation_rad);

}  // namespace cellcal
