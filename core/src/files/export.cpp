#include "cellcal/core/files/export.hpp"

#include <cstdio>
#include <random>
#include <sstream>

#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"

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

std::vector<Eigen::VectorXd> spreadConfigurations(const RobotModel& model, int n) {
  std::mt19937_64 rng(20261206);
  std::vector<Eigen::VectorXd> out;
  for (int k = 0; k < n; ++k) {
    Eigen::VectorXd q(model.numJoints());
    for (int j = 0; j < model.numJoints(); ++j) {
      const auto js = static_cast<size_t>(j);
      const double lo = std::max(model.limits[js].lower_rad, -kPi), hi = std::min(model.limits[js].upper_rad, kPi);
      q[j] = std::uniform_real_distribution<double>(lo, hi)(rng);
    }
    out.push_back(q);
  }
  return out;
}

Tool0Change tool0Change(const RobotModel& model, const Eigen::VectorXd& nominal_params, const Eigen::VectorXd& params,
                        const Pose& tip_correction, const std::vector<Eigen::VectorXd>& q_rad) {
  if (q_rad.size() < 3) throw std::invalid_argument("tool0Change: at least 3 configurations");
  if (nominal_params.size() != model.numParams() || params.size() != model.numParams())
    throw std::invalid_argument("tool0Change: parameters not of the model");
  // base_link -> tool0: the frames at identity (as the test of an exported URDF reads it back).
  Eigen::VectorXd exported = params, nominal = nominal_params;
  for (Eigen::VectorXd* p : {&exported, &nominal}) {
    p->segment<6>(model.baseParam(FrameParam::kX)).setZero();
    p->segment<6>(model.toolParam(FrameParam::kX)).setZero();
  }
  KinematicsData data(model);
  Tool0Change c;
  c.configurations = static_cast<int>(q_rad.size());
  std::vector<Eigen::Vector3d> a, b;
  for (const auto& q : q_rad) {
    const Pose n = forwardKinematics(model, data, nominal, q) * tip_correction;
    const Pose e = forwardKinematics(model, data, exported, q) * tip_correction;
    const Eigen::Vector3d d = e.translation() - n.translation();
    const double angle = logSO3(n.linear().transpose() * e.linear()).norm();
    c.mean_mm += d.norm() * 1e3;
    c.max_mm = std::max(c.max_mm, d.norm() * 1e3);
    c.mean_deg += radToDeg(angle);
    c.max_deg = std::max(c.max_deg, radToDeg(angle));
    c.mean_offset_mm += d * 1e3;
    a.push_back(n.translation());
    b.push_back(e.translation());
  }
  const double k = static_cast<double>(q_rad.size());
  c.mean_mm /= k;
  c.mean_deg /= k;
  c.mean_offset_mm /= k;
  // The best rigid motion: R a + t ~ b.
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  rigidFit(a, b, R, t);
  c.rigid_deg = radToDeg(logSO3(R).norm());
  c.rigid_mm = t.norm() * 1e3;
  for (size_t i = 0; i < a.size(); ++i) c.beyond_rigid_mean_mm += (R * a[i] + t - b[i]).norm() * 1e3 / k;
  // About joint 1's axis (z of DH frame 0, the mount's): the plane's Procrustes angle.
  const Pose mount = poseFromXyzRpy(model.mount[0], model.mount[1], model.mount[2], model.mount[3], model.mount[4],
                                    model.mount[5]);
  const Eigen::Vector3d axis = mount.linear().col(2), origin = mount.translation();
  const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - axis * axis.transpose();
  double sin_sum = 0, cos_sum = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const Eigen::Vector3d u = P * (a[i] - origin), v = P * (b[i] - origin);
    sin_sum += axis.dot(u.cross(v));
    cos_sum += u.dot(v);
  }
  c.yaw_about_joint1_deg = radToDeg(std::atan2(sin_sum, cos_sum));
  return c;
}

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
    // Its size is not in the data: they see the target's place on the flange and the flange's calibration only
    // together (identifiability.hpp, frameGauge). What they see is the target's calibrated place, said.
    const Eigen::Matrix<double, 6, 1> v = p.segment<6>(m.toolParam(FrameParam::kX));
    char buf[200];
    std::snprintf(buf, sizeof buf, "%.4f, %.4f, %.4f mm, %.4f, %.4f, %.4f deg", v[0] * 1e3, v[1] * 1e3, v[2] * 1e3,
                  radToDeg(v[3]), radToDeg(v[4]), radToDeg(v[5]));
    e.not_carried.push_back("what the target's frame absorbed of the robot (joint " + std::to_string(m.numJoints()) +
                            "'s flange-side parameters), of a size these data cannot tell from the target's own place: "
                            "the target's calibrated place on the tip link is " + buf +
                            "; give its nominal place with --target-in-flange to carry the difference into tool0");
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
  e.tool0_change = tool0Change(m, u.model.nominal, p, e.tip_correction, spreadConfigurations(m, kTool0ChangeConfigurations));
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
                                       &e.not_carried_beyond_joint6_m, &e.not_carried_beyond_joint6_rad,
                                       &e.tip_not_carried);
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

Eigen::VectorXd writtenParams(const RobotModel& m, const Eigen::VectorXd& p, const RobotExport& e,
                              const ExportOptions& o) {
  const int t = m.toolParam(FrameParam::kX);
  const Pose target = o.target_in_flange ? *o.target_in_flange : frameOf(p, t);
  Eigen::VectorXd w = p;
  w.segment<6>(t) = xyzRpyFromPose(e.tip_correction * e.tip_not_carried * target);
  return w;
}

}  // namespace cellcal
