// What a tracker measures of the target on the flange: its whole pose (6D: a 6D probe such as a T-Mac) or its
// position only (3D: a reflector). Decides the rows of an observation and what inverse kinematics must reach.
#pragma once

namespace cellcal {

enum class MeasurementKind { kPose6D, kPosition3D };

}  // namespace cellcal
