#include "cellcal/core/files/robot_yaml.hpp"

#include <cmath>

#include <yaml-cpp/yaml.h>

#include <fstream>
#include <sstream>

#include "cellcal/core/model/se3.hpp"
#include "yaml_reader.hpp"

namespace cellcal {
namespace {

using detail::YamlReader;
void readFrame(const YamlReader& r, const YAML::Node& node, const std::string& field, RobotModel& m, int first) {
  double v[6];
  r.frame(node, field, v);
  for (int k = 0; k < 6; ++k) m.nominal[first + k] = v[k];
}

}  // namespace

RobotModel parseRobotModel(const std::string& yaml_text, const std::string& source) try {
  YamlReader r(source);
  const YAML::Node root = r.load(yaml_text);
  if (!root.IsMap()) r.fail(root, "<document>", "expected a mapping with name, joints, ...");
  r.checkKeys(root, "", {"name", "joints", "links", "gravity_in_base_mps2", "base_in_tracker", "tool_in_flange"});

  RobotModel m;
  const YAML::Node name = r.required(root, "name", "name");
  if (!name.IsScalar() || name.Scalar().empty()) r.fail(name, "name", "expected a non-empty string");
  m.name = name.Scalar();

  const YAML::Node joints = r.required(root, "joints", "joints");
  if (!joints.IsSequence() || joints.size() == 0) r.fail(joints, "joints", "expected a non-empty list of joints");
  const int n = static_cast<int>(joints.size());
  m.nominal = Eigen::VectorXd::Zero(5 * n + 12);
  for (int j = 0; j < n; ++j) {
    const YAML::Node jn = joints[j];
    const std::string f = "joints[" + std::to_string(j) + "]";
    r.requireMap(jn, f);
    r.checkKeys(jn, f,
                {"theta_offset_deg", "d_mm", "a_mm", "alpha_deg", "beta_deg", "parallel_to_next", "limits_deg"});
    auto num = [&](const char* key, bool req) -> double {
      const YAML::Node v = jn[key];
      if (!v.IsDefined() || v.IsNull()) {
        if (req) r.fail(jn, f + "." + key, std::string("missing required key '") + key + "'");
        return 0.0;
      }
      return r.number(v, f + "." + key);
    };
    m.nominal[m.jointParam(j, JointParam::kThetaOffset)] = degToRad(num("theta_offset_deg", true));
    m.nominal[m.jointParam(j, JointParam::kD)] = num("d_mm", true) * 1e-3;
    m.nominal[m.jointParam(j, JointParam::kA)] = num("a_mm", true) * 1e-3;
    m.nominal[m.jointParam(j, JointParam::kAlpha)] = degToRad(num("alpha_deg", true));
    m.nominal[m.jointParam(j, JointParam::kBeta)] = degToRad(num("beta_deg", false));
    const YAML::Node par = jn["parallel_to_next"];
    const bool parallel = par.IsDefined() && !par.IsNull() && r.boolean(par, f + ".parallel_to_next");
    m.parallel_to_next.push_back(parallel);
    if (parallel && m.nominal[m.jointParam(j, JointParam::kD)] != 0.0)
      r.fail(jn["d_mm"], f + ".d_mm", "must be 0 on a joint that is parallel_to_next (its offset goes in beta_deg)");
    if (!parallel && m.nominal[m.jointParam(j, JointParam::kBeta)] != 0.0)
      r.fail(jn["beta_deg"], f + ".beta_deg", "only a joint that is parallel_to_next may have a beta");
    const auto lim = r.vector(r.required(jn, "limits_deg", f + ".limits_deg"), f + ".limits_deg", 2);
    if (!(lim[0] < lim[1])) r.fail(jn["limits_deg"], f + ".limits_deg", "expected [lower, upper] with lower < upper");
    m.limits.push_back({degToRad(lim[0]), degToRad(lim[1])});
  }
  if (m.parallel_to_next.back())
    r.fail(joints[n - 1], "joints[" + std::to_string(n - 1) + "].parallel_to_next", "the last joint has no next joint");

  if (const YAML::Node links = root["links"]; links.IsDefined() && !links.IsNull()) {
    if (!links.IsSequence() || static_cast<int>(links.size()) != n)
      r.fail(links, "links", "expected one entry per joint (" + std::to_string(n) + ")");
    for (int j = 0; j < n; ++j) {
      const std::string f = "links[" + std::to_string(j) + "]";
      r.requireMap(links[j], f);
      r.checkKeys(links[j], f, {"mass_kg", "com_mm"});
      LinkInertia li;
      li.mass_kg = r.number(r.required(links[j], "mass_kg", f + ".mass_kg"), f + ".mass_kg");
      if (li.mass_kg < 0) r.fail(links[j]["mass_kg"], f + ".mass_kg", "must be >= 0");
      const auto c = r.vector(r.required(links[j], "com_mm", f + ".com_mm"), f + ".com_mm", 3);
      li.com_m = Eigen::Vector3d(c[0], c[1], c[2]) * 1e-3;
      m.links.push_back(li);
    }
  }
  if (const YAML::Node g = root["gravity_in_base_mps2"]; g.IsDefined() && !g.IsNull()) {
    const auto v = r.vector(g, "gravity_in_base_mps2", 3);
    m.gravity_in_base_mps2 = Eigen::Vector3d(v[0], v[1], v[2]);
  }
  if (const YAML::Node b = root["base_in_tracker"]; b.IsDefined() && !b.IsNull())
    readFrame(r, b, "base_in_tracker", m, m.baseParam(FrameParam::kX));
  if (const YAML::Node t = root["tool_in_flange"]; t.IsDefined() && !t.IsNull())
    readFrame(r, t, "tool_in_flange", m, m.toolParam(FrameParam::kX));

  // Wrong units: the smallest industrial arms reach ~300 mm; link lengths adding up to under 50 mm are metres
  // written in the _mm fields.
  double reach_m = 0;
  for (int j = 0; j < n; ++j)
    reach_m += std::abs(m.nominal[m.jointParam(j, JointParam::kA)]) + std::abs(m.nominal[m.jointParam(j, JointParam::kD)]);
  if (reach_m < 0.05)
    r.fail(joints, "joints[*].a_mm/d_mm",
           "the link lengths add up to " + std::to_string(reach_m * 1e3) +
               " mm: no robot arm is that small; metres written where millimetres are expected?");
  std::string err;
  if (!m.IsValid(&err)) throw ConfigError(source + ": " + err);
  return m;
} catch (const YAML::Exception& e) {
  // The checks above name file, line and field; a yaml-cpp error that slips past them still names the file.
  throw ConfigError(source + ": " + e.what());
}

RobotModel loadRobotModel(const std::string& path) {
  return parseRobotModel(detail::readConfigFile(path, "robot file"), path);
}

}  // namespace cellcal
