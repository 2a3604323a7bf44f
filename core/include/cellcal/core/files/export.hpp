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

struct RobotExport {
  std::string text;                      // the file
  std::vector<std::string> not_carried;  // what the format cannot carry, one sentence each
  Pose tip_correction = Pose::Identity();  // the tip's move from its nominal place (identity without target_in_flange)
  // ur-kinematics: the flange's calibration beyond joint 6's turn and shift, not carried (0 for other formats).
  double not_carried_beyond_joint6_m = 0, not_carried_beyond_joint6_rad = 0;
  std::vector<DhRow> dh_rows;            // dh-table: the rows of `text`
};

// `model`: the robot's structure (its joints, limits, mount and flange); `calibrated`: the parameters to write
// (calibrated.params in model's layout, e.g. calibratedModel(robot file)). Throws ConfigError when the options do not
// fit the format (no nominal URDF for urdf, a URDF of another robot, no </robot>).
RobotExport write(const RobotModel& model, const CalibratedModel& calibrated, ExportFormat format,
                  const ExportOptions& options);

}  // namespace cellcal
