// A robot from its URDF (parsed with liburdfdom), as cellcal's modified-DH model, and a calibrated model back into
// the URDF it came from.
//
// Import: the chain from the base link (the root, or `base_link`) to the tip link (`tool0`, or `tip_link`, else the
// one leaf the revolute joints lead to), 3 to 7 revolute joints; fixed joints anywhere in it. At q = 0 every joint is
// an axis line in the base link's frame (its origin and its axis, any direction and sign). DH frame 0 has z along
// joint 1's axis, its origin where that axis passes closest to the base link's origin, x as close to the base link's
// x as z allows; each next frame follows the common normal of two neighbouring axes (classic DH: Rz(theta) Tz(d)
// Tx(a) Rx(alpha)); where they are parallel within `parallel_tolerance_rad` the joint is parallel_to_next (Hayati:
// d = 0, the small angle in alpha and beta). The last frame has z along the last axis, its origin at the tip's foot
// on it, x as close to the tip's x as z allows. What is left between the base link and DH frame 0, and between DH
// frame n and the tip, is the model's mount and flange (RobotModel: fixed, never identified), so base_in_tracker and
// tool_in_flange keep their meaning (the base link in the tracker frame, the target on the tip link). Joint names and
// limits are carried; each link's mass and centre of mass are the sum over the links rigidly attached to it (fixed
// joints) up to the next revolute joint, in its DH frame; gravity is -z of the base link (9.81 m/s^2).
// Forward kinematics of the model equal the URDF's (tests: KDL on the ROS-Industrial arms, to 1e-9 m and rad).
//
// Bad input throws ConfigError naming the file and the element: malformed XML (with its line), a missing link, a
// joint of another type (prismatic, continuous, floating, planar) in the chain, a zero axis, fewer than 3 or more than
// 7 revolute joints, a tip that is not unique.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

struct UrdfImportOptions {
  std::string base_link;  // empty: the root link
  std::string tip_link;   // empty: tool0 if the base reaches it, else the one leaf the revolute joints lead to
  double parallel_tolerance_rad = 1.0 * 3.14159265358979323846 / 180.0;
};

struct UrdfImport {
  RobotModel model;  // base_in_tracker and tool_in_flange zero
  std::string robot_name, base_link, tip_link;
  // Every joint from the base link to the tip, fixed ones too, in order; the revolute ones' indices into it.
  std::vector<std::string> chain_joints;
  std::vector<int> revolute;
  // Per revolute joint k: its child link's frame in DH frame k-1 turned by Rz(q_k) (q_k = 0): what an export keeps
  // constant (the link's visuals, collisions and inertials stay where they are on the body).
  std::vector<Pose> link_in_dh;
  // The choices made, for the robot file's header and `robot import`: frames, parallel joints, masses.
  std::vector<std::string> notes;
};

UrdfImport importUrdf(const std::string& xml, const std::string& source, const UrdfImportOptions& options = {});
UrdfImport importUrdfFile(const std::string& path, const UrdfImportOptions& options = {});

// True for a path that names a URDF (".urdf", any case).
bool isUrdfPath(const std::string& path);

// The URDF a robot file came from and the options that give its chain: the file itself when it is a .urdf, else the
// robot file's source section (`cellcal robot import`: urdf, base_link, tip_link; a relative path is taken as written,
// then from the robot file's folder). nullopt, with the reason in *why, when the robot file names none or it is gone.
struct UrdfOrigin {
  std::string path;
  UrdfImportOptions options;
};
std::optional<UrdfOrigin> urdfOriginOf(const std::string& robot_file_path,
                                       const std::vector<std::pair<std::string, std::string>>& source, std::string* why);

// What makes `model` (a robot file's, calibrated or not) another robot than the description `u` was imported from:
// the number of joints, their names (when the model has them), which are parallel, the mount or the flange, or a
// joint's d, a or alpha more than 20 mm / 5 deg apart. Empty when it is of this description.
std::string urdfMismatch(const UrdfImport& u, const RobotModel& model);

// The URDF text of `nominal_xml` (the file `nominal` was imported from) with only the origins of the chain's joints
// changed so that its forward kinematics from the base link to the tip are `params`' (of nominal.model's structure:
// joint-zero offsets folded into the origins) with the tip moved by `tip_correction` (the tip's true place relative
// to where the chain puts it: what the target's frame absorbed of the robot). The revolute joints' origins carry the
// joints; the first fixed joint after the last revolute joint carries the last joint's and the tip correction (an
// error when there is none). Everything else (visuals, collisions, limits, inertials, other elements, formatting) is
// kept as it was. Throws ConfigError naming the element when nominal_xml does not hold the chain.
std::string exportUrdf(const std::string& nominal_xml, const std::string& source, const UrdfImport& nominal,
                       const Eigen::VectorXd& params, const Pose& tip_correction);

// Universal Robots' `kinematics:` YAML (ur_calibration writes it, ur_robot_driver reads it through
// kinematics_params_file; ur_description composes its six revolute joints' origins from it: shoulder, upper_arm,
// forearm, wrist_1, wrist_2, wrist_3, each x y z roll pitch yaw) of the same calibration as exportUrdf. The fixed
// joints after wrist_3 are ur_description's own: of what exportUrdf puts into the first of them, the part that commutes
// with joint 6 (a turn about its axis, a shift along it) goes into wrist_3, the rest is not carried (*rest_m, *rest_rad:
// its size; *tip_not_carried: what it does at the tip, so that the tip ur_description composes from the file is the
// calibrated tip times *tip_not_carried). `hash`: the controller's calibration hash ("" written as empty).
std::string exportUrKinematics(const std::string& nominal_xml, const std::string& source, const UrdfImport& nominal,
                               const Eigen::VectorXd& params, const Pose& tip_correction, const std::string& hash,
                               double* rest_m, double* rest_rad, Pose* tip_not_carried = nullptr);

// The <origin> of joint `name` in `xml` (identity when it has none). ConfigError when there is no such joint.
Pose urdfJointOrigin(const std::string& xml, const std::string& source, const std::string& name);

}  // namespace cellcal
