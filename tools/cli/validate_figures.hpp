// `cellcal validate --figures`: what it draws of a robot's calibrations over a recording.
#pragma once

#include <string>
#include <vector>

#include "cellcal/components/convert.hpp"

namespace cellcal::cli {

// Figures of one robot's calibrations over a recording (gnuplot, PNG): <robot>_accuracy.png, the a-priori
// verification error (each pose predicted by the calibration before it) and the a-posteriori residual against the
// cell time of the reading (stamps times the cell file's time_compression: a simulated cell's hours, not the seconds
// it ran); <robot>_joint_drift.png, each joint's zero offset as identified, minus its nominal value, for the joints
// whose zero the calibrations estimate (the others are held: named in the title, not drawn as flat lines). A version
// without a reading of its own (v1 of an engine started from a calibration file) has no time and is not drawn.
void writeRecordingFigures(const std::string& dir, const std::string& robot, const RobotModel& model,
                           const std::vector<components::ReceivedCalibration>& all, double time_compression);

}  // namespace cellcal::cli
