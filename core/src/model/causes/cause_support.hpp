// What several causes (and model_extension.cpp) compute alike: gravity in the tracker frame, the torque of a unit
// mass about a joint, the gravity across a link. Internal to core/src/model.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "cellcal/core/model/cause.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal::causes {

constexpr double kMinBeamLengthM = 0.2;  // links shorter than this are not treated as beams

inline Eigen::Vector3d gravityInTracker(const RobotModel& model, const std::vector<Pose>& F) {
  return F[0].linear() * model.gravity_in_base_mps2;
}

// Torque about joint j's axis of a unit mass at point c (tracker frame), N m per kg.
inline double unitTorque(const std::vector<Pose>& F, int j, const Eigen::Vector3d& c, const Eigen::Vector3d& g) {
  const Eigen::Vector3d z = F[j].linear().col(2), o = F[j].translation();
  return z.dot((c - o).cross(g));
}

// Gravity across link j at the frames F, in g: the part of the unit gravity vector perpendicular to the link; and the
// link's direction and far end.
struct LinkLoad {
  Eigen::Vector3d across, direction, far_end;
};
inline LinkLoad linkLoad(const RobotModel& model, const std::vector<Pose>& F, int j) {
  LinkLoad l;
  l.far_end = F[j + 1].translation();
  l.direction = (l.far_end - F[j].translation()).normalized();
  const Eigen::Vector3d g = gravityInTracker(model, F).normalized();
  l.across = g - g.dot(l.direction) * l.direction;
  return l;
}

// "joint3." for the 0-based joint 2: the prefix of a joint's parameter names.
inline std::string jointPrefix(int joint) { return "joint" + std::to_string(joint + 1) + "."; }

// A joint cause's only kinematic row: the joint's theta offset.
inline int thetaRow(const RobotModel& model, int joint) { return model.jointParam(joint, JointParam::kThetaOffset); }

// ", warm-up 1.5 h" or ", linear in time" for a fitted time constant; "" before one is fitted.
inline std::string warmUpSuffix(const Extension& ext) {
  if (!(ext.time_constant_h > 0)) return "";
  char b[64];
  if (std::isfinite(ext.time_constant_h))
    std::snprintf(b, sizeof b, ", warm-up %.2g h", ext.time_constant_h);
  else
    std::snprintf(b, sizeof b, ", linear in time");
  return b;
}

// The thermal driver's axis label.
inline std::string thermalLabel(const std::string& thermal_source) {
  return thermal_source == "temperature_c" ? "temperature - mean (K)" : "time since first row (h)";
}

}  // namespace cellcal::causes
