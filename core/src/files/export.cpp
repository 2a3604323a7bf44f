#include "cellcal/core/files/export.hpp"

#include <cstdio>
#include <sstream>

#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/extended_fit.hpp"

namespace cellcal {
namespace {

Pose frameOf(const Eigen::VectorXd& p, int first) {
  return poseFromXyzRpy(p[first], p[first + 1], p[first + 2], p[first + 3], p[first + 4], p[first + 5]);
}

std::vector<DhRow> dhRows(const RobotModel& m, const Eigen::VectorXd& p) {
  std::vector<DhRow> rows;
  for (int j = 0; j < m.numJoints(); ++j) {
    auto v = [&](JointParam k) { return m.toHuman(m.jointParam(j, k), p[m.jointParam(j, k)]); };
    const auto js = static_cast<size_t>(j);
    DhRow r;
    r.joint = j + 1;
    r.name = m.joint_names.empty() ? "joint" + std::to_string(j + 1) : m.joint_names[js];
    r.theta_offset_deg = v(JointParam::kThetaOffset);
    r.d_mm = v(JointParam::kD);
    r.a_mm = v(JointParam::kA);
    r.alpha_deg = v(JointParam::kAlpha);
    r.beta_deg = v(JointParam::kBeta);
    r.parallel_to_next = m.parallel_to_next[js];
    r.lower_deg = radToDeg(m.limits[js].lower_rad);
    r.upper_deg = radToDeg(m.limits[js].upper_rad);
    rows.push_back(r);
  }
  return rows;
}

std::string dhCsv(const std::vector<DhRow>& rows) {
  std::ostringstream csv;
  csv << "joint,name,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,parallel_to_next,lower_deg,upper_deg\n";
  for (const DhRow& r : rows) {
    char buf[400];
    std::snprintf(buf, sizeof buf, "%d,%s,%.12g,%.12g,%.12g,%.12g,%.12g,%s,%.12g,%.12g\n", r.joint, r.name.c_str(),
                  r.theta_offset_deg, r.d_mm, r.a_mm, r.alpha_deg, r.beta_deg, r.parallel_to_next ? "true" : "false",
                  r.lower_deg, r.upper_deg);
    csv << buf;
  }
  return csv.str();
}

// The registered base (calibrated base_in_tracker) as a fixed joint from a new link `link` to the URDF's base link.
void addBaseFrame(std::string& xml, const std::string& source, const std::string& link, const std::string& base_link,
                  const Eigen::Matrix<double, 6, 1>& b) {
  char joint[512];
  std::snprintf(joint, sizeof joint,
                "  <link name=\"%s\"/>\n  <joint name=\"%s_to_%s\" type=\"fixed\">\n    <parent link=\"%s\"/>\n"
                "    <child link=\"%s\"/>\n    <origin xyz=\"%.17g %.17g %.17g\" rpy=\"%.17g %.17g %.17g\"/>\n  </joint>\n",
                link.c_str(), link.c_str(), base_link.c_str(), link.c_str(), base_link.c_str(), b[0], b[1], b[2], b[3],
                b[4], b[5]);
  const auto end = xml.rfind("</robot>");
  if (end == std::string::npos) throw ConfigError(source + ": no </robot>");
  xml.insert(end, joint);
}

}  // namespace

const char* exportFormatName(ExportFormat f) {
  switch (f) {
    case ExportFormat::kUrdf: return "urdf";
    case ExportFormat::kUrKinematics: return "ur-kinematics";
    case ExportFormat::kDhTable: return "dh-table";
  }
  return "?";
}

std::optional<ExportFormat> exportFormatFromName(const std::string& name) {
  for (ExportFormat f : {ExportFormat::kUrdf, ExportFormat::kUrKinematics, ExportFormat::kDhTable})
    if (name == exportFormatName(f)) return f;
  return std::nullopt;
}

RobotExport write(const RobotModel& m, const CalibratedModel& calibrated, ExportFormat format, const ExportOptions& o) {
  const Eigen::VectorXd& p = calibrated.params;
  if (p.size() != m.numParams())
    throw ConfigError("export: " + std::to_string(p.size()) + " parameters for a model of " + std::to_string(m.numParams()));
  RobotExport e;
  if (!calibrated.extensions.empty())
    e.not_carried.push_back("the model extensions (" + modelLabel(calibrated.extensions) +
                            "): only the geometric part is exported");
  // The tip's correction: where the calibrated tool frame puts the target against its nominal place on the flange.
  if (o.target_in_flange) {
    e.tip_correction = frameOf(p, m.toolParam(FrameParam::kX)) * o.target_in_flange->inverse();
  } else if (!calibrated.estimated.empty()) {
    e.not_carried.push_back("what the target's frame absorbed of the robot (joint " + std::to_string(m.numJoints()) +
                            "'s flange-side parameters): give the target's nominal place with --target-in-flange to "
                            "carry it");
  }
  if (format == ExportFormat::kDhTable) {
    e.dh_rows = dhRows(m, p);
    e.text = dhCsv(e.dh_rows);
    if (m.hasMount() || m.hasFlange())
      e.not_carried.push_back("the fixed transforms around the chain (mount, flange): a controller's DH table has "
                              "none; they are in the JSON");
    return e;
  }
  if (o.nominal_urdf_xml.empty())
    throw ConfigError(std::string("--format ") + exportFormatName(format) +
                      ": the nominal URDF (the description to calibrate) is needed");
  const UrdfImport u = importUrdf(o.nominal_urdf_xml, o.nominal_urdf_source, o.chain);
  // The calibrated model must be of this description: same joints, same fixed transforms around the chain.
  if (const std::string mismatch = urdfMismatch(u, m); !mismatch.empty())
    throw ConfigError(o.nominal_urdf_source + ": not the description " +
                      (o.model_source.empty() ? std::string("the model") : o.model_source) + " was calibrated from (" +
                      mismatch + "): nothing written");
  if (format == ExportFormat::kUrdf) {
    e.text = exportUrdf(o.nominal_urdf_xml, o.nominal_urdf_source, u, p, e.tip_correction);
    if (!o.base_frame_link.empty())
      addBaseFrame(e.text, o.nominal_urdf_source, o.base_frame_link, u.base_link, p.segment<6>(m.baseParam(FrameParam::kX)));
    return e;
  }
  std::string header;
  std::istringstream lines(o.header);
  for (std::string line; std::getline(lines, line);) header += "# " + line + "\n";
  e.text = header + exportUrKinematics(o.nominal_urdf_xml, o.nominal_urdf_source, u, p, e.tip_correction, o.ur_hash,
                                       &e.not_carried_beyond_joint6_m, &e.not_carried_beyond_joint6_rad);
  if (e.not_carried_beyond_joint6_m * 1e3 > 1e-6 || radToDeg(e.not_carried_beyond_joint6_rad) > 1e-6) {
    char buf[300];
    std::snprintf(buf, sizeof buf,
                  "%.4f mm and %.4f deg of the flange's calibration beyond joint 6's turn and shift (ur_description's "
                  "fixed joints after wrist_3 are its own)",
                  e.not_carried_beyond_joint6_m * 1e3, radToDeg(e.not_carried_beyond_joint6_rad));
    e.not_carried.push_back(buf);
  }
  if (o.ur_hash.empty())
    e.not_carried.push_back("the controller's calibration hash (--ur-hash): written empty, so the driver cannot check "
                            "the file against the robot");
  return e;
}

}  // namespace cellcal
