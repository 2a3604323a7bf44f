// Registration: first estimates of base_in_tracker and tool_in_flange from measurements, when the cell does not
// know where the robot stands in the tracker frame (e.g. the ipa UR10 data). Rigid point-set fit (Kabsch) of the
// nominal flange positions to the measured target positions, alternated with a linear solve of the target offset on
// the flange; then the tool orientation from 6D readings (chordal mean). The kinematic parameters are not touched:
// the result is the starting point of a calibration, and "before" figures of a calibration use it.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/identification/observation.hpp"
#include "cellcal/core/model/model_extension.hpp"
#include "cellcal/core/model/robot_model.hpp"

namespace cellcal {

struct RegistrationResult {
  Eigen::VectorXd params;            // `initial` with the base and tool frames replaced
  double rms_position_m = 0;         // residual of the registered nominal model over the observations
  int iterations = 0;
  // Set when the positions lie on a line (its direction in the tracker frame): the base's turn about it is not in
  // the data; the registration turns the base by the smallest rotation that lays the robot's line onto the tracker's.
  std::optional<Eigen::Vector3d> line_direction;
};

// The rotation R and translation t minimizing sum |R a_i + t - b_i|^2 (Kabsch; a proper rotation). When the points
// are (nearly) collinear the turn about their line is not in them: with `line`, R is the smallest rotation that lays
// a's line onto b's (in the same sense) and *line is b's direction; without, std::invalid_argument.
void rigidFit(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b, Eigen::Matrix3d& R,
              Eigen::Vector3d& t, Eigen::Vector3d* line = nullptr);

// Needs >= 4 observations; flange positions on a line are registered as rigidFit says (line_direction set).
RegistrationResult registerFrames(const RobotModel& model, const Eigen::VectorXd& initial,
                                  const std::vector<Observation>& observations, int iterations = 10);

// Base and tool frames of a calibrated model on new readings ("the tracker was moved"): Gauss-Newton on the 12 frame
// parameters (those the readings excite) with the kinematics and the model extensions held, starting from `params`
// (e.g. registerFrames on the calibrated kinematics). `drivers`: one per observation (extensions only). `held`: frame
// parameters kept at their value in `params` (e.g. a tool frame the readings cannot tell from the base).
RegistrationResult refineFrames(const RobotModel& model, const Eigen::VectorXd& params,
                                const std::vector<Extension>& extensions, const Eigen::VectorXd& extension_params,
                                const std::vector<Observation>& observations, const std::vector<Drivers>& drivers,
                                int iterations = 20, const std::vector<int>& held = {});

// Where rows of two tracker (or target) placements meet in one file, in visiting order. A single registration of
// rows from two set-ups leaves residuals of the size of the move (hundreds of mm); registered apart, each side fits to
// the robot's own error (mm). Tries every split that leaves both sides `min_rows` rows (coarse steps, then every row
// around the best) and returns the one whose two registrations leave the least total squared residual, when the
// single registration's RMS is more than `ratio` times that split's; nullopt otherwise (or too few rows).
struct SetupChange {
  int first_row = -1;              // first observation of the second set-up
  double rms_single_m = 0;         // one registration over all rows
  double rms_first_m = 0, rms_second_m = 0;  // each side registered on its own
};
std::optional<SetupChange> findSetupChange(const RobotModel& model, const Eigen::VectorXd& initial,
                                           const std::vector<Observation>& observations, double ratio = 10,
                                           int min_rows = 8);

// Frame parameters (x, y, z, roll, pitch, yaw) of a pose, inverse of poseFromXyzRpy (T = Trans Rz Ry Rx).
Eigen::Matrix<double, 6, 1> xyzRpyFromPose(const Pose& T);

}  // namespace cellcal
