// Reader of the ipa-robot-accuracy UR10 series (../shared/datasets/ipa-robot-accuracy, Landgraf et al. 2021):
// ';'-separated, decimal commas, joints in rad (shoulder_pan_joint .. wrist_3_joint), T-Mac position in the tracker
// frame (measurement_x/y/z, mm) and orientation as intrinsic X-Y-Z Euler angles in degrees (measurement_rx/ry/rz),
// ambient temperature (measurement_temperature, deg C), Timestamp YYYYMMDDhhmmss (damaged in Series B: then
// no stamps, only the row order). Converted to measurement rows (CSV v1, measurement_csv.hpp).
#pragma once

#include <ostream>
#include <string>

#include "cellcal/core/files/measurement_csv.hpp"

namespace cellcal {

// Rows whose cells are unusable throw ConfigError "<file>:<line>:<column>: <column>: <message>".
// `notes` (optional) says what was read (rows, stamps usable or not, time span, temperature range).
MeasurementFile readIpaSeries(const std::string& path, const RobotModel& robot, std::string* notes = nullptr);

}  // namespace cellcal
