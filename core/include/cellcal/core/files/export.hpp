// A calibrated model written for the robot stack: write(model, calibrated, format, options) -> RobotExport, the
// file's text and what the format could not carry. `cellcal robot export` writes it and prints the rest.
//
// Formats (ExportFormat):
//   urdf           the nominal URDF (options.nominal_urdf_xml, the description the robot file was imported from)
//                  with only the chain's joint origins calibrated (urdf.hpp: exportUrdf); the registered base, if
//                  asked, as a fixed joint from options.base_frame_link;
//   ur-kinematics  Universal Robots' `kinematics:` YAML for ur_robot_driver (urdf.hpp: exportUrKinematics);
//   dh-table       the calibrated modified-DH table as CSV, one row per joint (dh_rows: the same values).
// None carries model extensions, covariance or a residual map: a calibrated model with extensions exports its
// geometric part, and says so in not_carried.
//
//   const RobotFile rf = loadRobotFile("cal.yaml");
//   ExportOptions o;
//   o.nominal_urdf_xml = text_of("ur10.urdf");
//   o.nominal_urdf_source = "ur10.urdf";
//   const RobotExport e = write(rf.model, calibratedModel(rf), ExportFormat::kUrdf, o);
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "cellcal/core/files/urdf.hpp"
#include "cellcal/core/model/calibrated_model.hpp"
#include "cellcal/core/model/robot_model.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {

enum class ExportFormat { kUrdf, kUrKinematics, kDhTable };
const char* exportFormatName(ExportFormat f);  // "urdf", "ur-kinematics", "dh-table"
std::optional<ExportFormat> exportFormatFromName(const std::string& name);

struct ExportOptions {
  // urdf and ur-kinematics: the nominal description's text, its path (for messages) and the chain the robot file was
  // imported with. The calibrated model must be of it (urdfMismatch); else write() throws ConfigError.
  std::string nominal_urdf_xml, nominal_urdf_source;
  UrdfImportOptions chain;
  // The target's nominal place on the flange: with it, what the calibrated tool frame absorbed of the robot (the last
  // joint's flange-side parameters) moves the tip; without it, that part is not carried (said when the model is a
  // calibration: it has estimated parameters).
  std::optional<Pose> target_in_flange;
  std::string base_frame_link;  // urdf: the registered base as a fixed joint from a link of this name (empty: none)
  std::string ur_hash;          // ur-kinematics: the controller's calibration hash (empty: written empty, said)
  std::string header;           // ur-kinematics: comment lines at the top (each prefixed "# ")
  std::string model_source;     // the calibrated model's file, for messages (empty: "the model")
};

struct DhRow {
  int joint = 0;  // 1-based
  std::string name;
  double theta_offset_deg = 0, d_mm = 0, a_mm = 0, alpha_deg = 0, beta_deg = 0;
  bool parallel_to_next = false;
  double lower_deg = 0, upper_deg = 0;
};

// How the exported base_link -> tool0 differs from the nominal description's over configurations: what a consumer of
// the export sees change (the nominal with the tip correction's frame at tool0 too, so only the chain counts), and the
// part of it a rigid motion of base_link explains. A calibration's chain moves only by what the data tell from the
// base and the target (identifiability.hpp, frameGauge), so that rigid part stays small; a large one is a base or a
// mount moved into the chain, which a world frame fixed to base_link would see as an error.
struct Tool0Change {
  int configurations = 0;
  double mean_mm = 0, max_mm = 0, mean_deg = 0, max_deg = 0;  // |position| and rotation angle of the difference
  Eigen::Vector3d mean_offset_mm = Eigen::Vector3d::Zero();   // the positions' mean difference, in base_link
  // The rigid motion of base_link that best maps the nominal tool0 positions onto the exported ones (least squares):
  // its angle and its translation; what is left of the positions' difference after it (mean).
  double rigid_deg = 0, rigid_mm = 0, beyond_rigid_mean_mm = 0;
  // The turn about joint 1's axis alone that best maps them (signed, right-handed about the axis): a base yaw moved
  // into the chain shows here.
  double yaw_about_joint1_deg = 0;
};
// `nominal`, `params`: the nominal description's parameters and the calibrated ones, in model's layout (their base and
// tool frames are not used); q_rad: the configurations (at least 3).
Tool0Change tool0Change(const RobotModel& model, const Eigen::VectorXd& nominal, const Eigen::VectorXd& params,
                        const Pose& tip_correction, const std::vector<Eigen::VectorXd>& q_rad);
// n configurations spread within the joint limits (each joint within [-180, 180] deg), drawn with a fixed seed: the
// same for every call.
std::vector<Eigen::VectorXd> spreadConfigurations(const RobotModel& model, int n);
constexpr int kTool0ChangeConfigurations = 300;

struct RobotExport {
  std::string text;                      // the file
  std::vector<std::string> not_carried;  // what the format cannot carry, one sentence each
  Pose tip_correction = Pose::Identity();  // the tip's move from its nominal place (identity without target_in_flange)
  // ur-kinematics: the flange's calibration beyond joint 6's turn and shift, not carried (0 for other formats), and
  // what it does at the tip: the file's tip is the calibrated tip times tip_not_carried (identity for other formats).
  double not_carried_beyond_joint6_m = 0, not_carried_beyond_joint6_rad = 0;
  Pose tip_not_carried = Pose::Identity();
  std::vector<DhRow> dh_rows;            // dh-table: the rows of `text`
  // urdf and ur-kinematics: against the nominal URDF, over spreadConfigurations(model, kTool0ChangeConfigurations);
  // dh-table: none (configurations 0), there is no nominal description.
  Tool0Change tool0_change;
};

// `model`: the robot's structure (its joints, limits, mount and flange); `calibrated`: the parameters to write
// (calibrated.params in model's layout, e.g. calibratedModel(robot file)). Throws ConfigError when the options do not
// fit the format (no nominal URDF for urdf, a URDF of another robot, no </robot>).
RobotExport write(const RobotModel& model, const CalibratedModel& calibrated, ExportFormat format,
                  const ExportOptions& options);

// The parameters a consumer of the written file computes with, in the calibration's frames: the file's chain, the
// calibrated base, and the target at its nominal place (options.target_in_flange) on the file's tip, or without it at
// its calibrated place: `params` with the tool frame moved by what the format did not carry at the tip. Their
// positions at the calibration's rows are the file's own held-out figures.
Eigen::VectorXd writtenParams(const RobotModel& model, const Eigen::VectorXd& params, const RobotExport& written,
                              const ExportOptions& options);

}  // namespace cellcal
