// Whether a robot controller computes its tool pose with a given kinematic model: the poses the controller itself
// reports (UR's tool0_controller, a KUKA's $POS_ACT, a ROS tf of the controller's frame) at its joint angles, against
// the model's forward kinematics at the same angles. A controller running the model gives its poses to its own
// rounding; one running another model (the nominal one, another calibration) differs by what the two models differ,
// and a least-squares fit of the model's kinematic parameters to the controller's poses names the parameters that
// explain the difference.
//
//   ControllerCheckOptions o;
//   o.base_in_controller = poseFromXyzRpy(0, 0, 0, 0, 0, kPi);  // UR: `base` is base_link turned half a turn
//   const ControllerCheck c = checkController(model, model.nominal, readings, o);
//   if (!c.matches) ... c.explained_by ...
#pragma once

#include <Eigen/Core>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

struct ControllerCheckOptions {
  // The controller reports T = base_in_controller * mount * chain(q) * flange * tool_in_flange: the pose of its tool
  // in its own base frame (base_in_controller: the model's base link in that frame; tool_in_flange: the tool it
  // reports, on the model's tip link).
  Pose base_in_controller = Pose::Identity();
  Pose tool_in_flange = Pose::Identity();
  // A controller runs the model when every reading lies within these of the model's pose (its own rounding).
  double tolerance_mm = 0.01, tolerance_deg = 0.001;
  bool IsValid(std::string* error) const;
};

struct ControllerCheck {
  int rows = 0, oriented = 0;
  double mean_mm = 0, max_mm = 0, mean_deg = 0, max_deg = 0;  // controller's pose against the model's
  int worst_row = -1;                                          // the row of max_mm
  bool matches = false;                                        // max_mm <= tolerance_mm and max_deg <= tolerance_deg
  // The kinematic parameters (base and tool frames held as given) fitted to the controller's poses from the model:
  // each estimated one that moved, with its change (SI), largest first in plausible deviations (plausibleDeviation);
  // what the fitted model leaves of the difference (mean, mm). Empty when the model matches.
  std::vector<std::pair<int, double>> explained_by;
  double left_mean_mm = 0;
  bool fit_converged = false;
};

// `params`: the model's parameters (model.numParams(); its base and tool frames are replaced by the options').
// `readings`: the controller's joint angles and its reported tool pose (kPose6D) or position (kPosition3D) in its base
// frame. Throws std::invalid_argument on invalid options, mismatched sizes or no readings.
ControllerCheck checkController(const RobotModel& model, const Eigen::VectorXd& params,
                                const std::vector<Observation>& readings, const ControllerCheckOptions& options);

}  // namespace cellcal
