#include "cellcal/core/files/urdf.hpp"

#include <tinyxml.h>
#include <urdf_parser/urdf_parser.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>


namespace cellcal {
namespace {

Pose toPose(const urdf::Pose& p) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(p.position.x, p.position.y, p.position.z);
  T.linear() = Eigen::Quaterniond(p.rotation.w, p.rotation.x, p.rotation.y, p.rotation.z).normalized().toRotationMatrix();
  return T;
}

Eigen::Matrix3d rotZ(double a) { return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix(); }
Eigen::Matrix3d rotX(double a) { return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()).toRotationMatrix(); }
Eigen::Matrix3d rotY(double a) { return Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()).toRotationMatrix(); }

// x, y, z, roll, pitch, yaw of T (URDF's rpy: R = Rz(yaw) Ry(pitch) Rx(roll)), composing back to T to rounding even
// at a pitch of +-90 deg (a flange turned a quarter turn, as UR's): pitch by atan2 (asin loses half the digits there),
// roll from the last row, yaw from what the two leave, so the three agree with each other.
Eigen::Matrix<double, 6, 1> xyzRpy(const Pose& T) {
  const Eigen::Matrix3d& R = T.linear();
  Eigen::Matrix<double, 6, 1> v;
  v.head<3>() = T.translation();
  v[4] = std::atan2(-R(2, 0), std::hypot(R(0, 0), R(1, 0)));
  v[3] = std::atan2(R(2, 1), R(2, 2));
  const Eigen::Matrix3d M = R * (rotY(v[4]) * rotX(v[3])).transpose();
  v[5] = std::atan2(M(1, 0), M(0, 0));
  return v;
}

// The signed angle about `axis` (unit) from a to b (both perpendicular to it).
double angleAbout(const Eigen::Vector3d& axis, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).dot(axis), a.dot(b));
}

// A_j without the joint's own rotation: Rz(theta_offset) Tz(d) Tx(a) Rx(alpha) Ry(beta).
Pose linkRest(const RobotModel& m, const Eigen::VectorXd& p, int j) {
  auto v = [&](JointParam k) { return p[m.jointParam(j, k)]; };
  Pose A = Pose::Identity();
  A.linear() = rotZ(v(JointParam::kThetaOffset));
  A.translation() = A.linear() * Eigen::Vector3d(v(JointParam::kA), 0, v(JointParam::kD));
  A.linear() = A.linear() * rotX(v(JointParam::kAlpha)) * rotY(v(JointParam::kBeta));
  return A;
}

Pose frameFromXyzRpy(const Eigen::Matrix<double, 6, 1>& v) { return poseFromXyzRpy(v[0], v[1], v[2], v[3], v[4], v[5]); }

// The 1-based line of `element` in the file (TinyXML's row), for messages.
std::string at(const std::string& source, const TiXmlElement* e) {
  return source + ":" + std::to_string(e ? e->Row() : 0);
}

struct Parsed {
  TiXmlDocument doc;
  urdf::ModelInterfaceSharedPtr model;
  std::map<std::string, const TiXmlElement*> joint_elements, link_elements;
};

// The links and joints form one tree: every joint names a parent and a child link that exist, no link is the child of
// two joints, exactly one link is no joint's child (the root) and every link hangs from it. Checked on the XML before
// liburdfdom builds its tree, so that the error names the element and its line (liburdfdom says only "two root links"
// on stderr), and because liburdfdom 3.0 leaks the tree it half built when it refuses one (seen by the fuzzer).
void checkTree(const Parsed& p, const std::string& source) {
  std::map<std::string, std::string> parent_of;  // child link -> parent link
  for (const auto& [name, e] : p.joint_elements) {
    const std::string where = at(source, e) + ": <joint name=\"" + name + "\">: ";
    std::string ends[2];
    const char* tags[2] = {"parent", "child"};
    for (int k = 0; k < 2; ++k) {
      const TiXmlElement* t = e->FirstChildElement(tags[k]);
      const char* link = t ? t->Attribute("link") : nullptr;
      if (!link) throw ConfigError(where + "no <" + std::string(tags[k]) + " link=\"...\"/>");
      if (!p.link_elements.count(link))
        throw ConfigError(where + "<" + std::string(tags[k]) + " link=\"" + link + "\">: no such <link>");
      ends[k] = link;
    }
    if (!parent_of.emplace(ends[1], ends[0]).second)
      throw ConfigError(where + "link " + ends[1] + " is already the child of another joint (a link has one parent)");
  }
  std::vector<std::string> roots;
  for (const auto& [name, e] : p.link_elements)
    if (!parent_of.count(name)) roots.push_back(name);
  if (roots.size() != 1) {
    std::string names;
    for (const auto& r : roots) names += (names.empty() ? "" : ", ") + r;
    throw ConfigError(at(source, p.doc.RootElement()) + ": <robot>: " +
                      (roots.empty() ? std::string("no root link (the joints form a loop)")
                                     : std::to_string(roots.size()) + " root links (" + names +
                                           "): every link but one must be a joint's child"));
  }
  for (const auto& [name, e] : p.link_elements) {  // each link reaches the root within as many steps as there are links
    std::string l = name;
    for (size_t steps = 0; l != roots.front(); ++steps) {
      if (steps > p.link_elements.size())
        throw ConfigError(at(source, e) + ": <link name=\"" + name + "\">: its joints form a loop, not a tree");
      l = parent_of.at(l);
    }
  }
}

// Where `text` stops being UTF-8 text: the offset of the first NUL byte or the first byte that does not begin a
// well-formed UTF-8 sequence within the text (a stray continuation byte, an overlong form, a surrogate, a sequence cut
// short by the end or by another byte), with why in *what; npos where all of it is.
size_t firstNonText(const std::string& text, std::string* what) {
  const auto* b = reinterpret_cast<const unsigned char*>(text.data());
  const size_t n = text.size();
  for (size_t i = 0; i < n;) {
    const unsigned char c = b[i];
    if (c == 0) {
      *what = "a NUL byte (not a text file)";
      return i;
    }
    if (c < 0x80) {
      ++i;
      continue;
    }
    const int len = c >= 0xC2 && c <= 0xDF ? 2 : c >= 0xE0 && c <= 0xEF ? 3 : c >= 0xF0 && c <= 0xF4 ? 4 : 0;
    // The second byte's range: narrower after E0 (overlong), ED (surrogates), F0 (overlong) and F4 (above U+10FFFF).
    const unsigned char lo = c == 0xE0 ? 0xA0 : c == 0xF0 ? 0x90 : 0x80;
    const unsigned char hi = c == 0xED ? 0x9F : c == 0xF4 ? 0x8F : 0xBF;
    bool ok = len > 0 && i + static_cast<size_t>(len) <= n && b[i + 1] >= lo && b[i + 1] <= hi;
    for (int k = 2; ok && k < len; ++k) ok = b[i + static_cast<size_t>(k)] >= 0x80 && b[i + static_cast<size_t>(k)] <= 0xBF;
    if (!ok) {
      char t[96];
      std::snprintf(t, sizeof t, "byte 0x%02X is not UTF-8%s", c,
                    len > 0 && i + static_cast<size_t>(len) > n ? " (a character cut short by the end of the file)" : "");
      *what = t;
      return i;
    }
    i += static_cast<size_t>(len);
  }
  return std::string::npos;
}

void parse(const std::string& xml, const std::string& source, Parsed& p) {
  // TinyXML and liburdfdom read a multi-byte character whole from its first byte: one cut short at the end of the text
  // reads past it. Only UTF-8 text is handed to them, named where it is not.
  std::string what;
  if (const size_t bad = firstNonText(xml, &what); bad != std::string::npos) {
    size_t line = 1, line_start = 0;  // the column counts bytes from the line's start
    for (size_t k = 0; k < bad; ++k)
      if (xml[k] == '\n') ++line, line_start = k + 1;
    throw ConfigError(source + ":" + std::to_string(line) + ":" + std::to_string(bad - line_start + 1) + ": " + what +
                      ": a URDF is UTF-8 text (save it as UTF-8)");
  }
  p.doc.Parse(xml.c_str(), nullptr, TIXML_ENCODING_UTF8);
  if (p.doc.Error())
    throw ConfigError(source + ":" + std::to_string(p.doc.ErrorRow()) + ":" + std::to_string(p.doc.ErrorCol()) +
                      ": not well-formed XML: " + p.doc.ErrorDesc());
  const TiXmlElement* robot = p.doc.RootElement();
  if (!robot || std::string(robot->Value()) != "robot")
    throw ConfigError(at(source, robot) + ": <robot>: the document's root element is not <robot> (not a URDF)");
  for (const TiXmlElement* e = robot->FirstChildElement(); e; e = e->NextSiblingElement()) {
    const char* name = e->Attribute("name");
    if (!name) continue;
    if (std::string(e->Value()) == "joint") p.joint_elements[name] = e;
    if (std::string(e->Value()) == "link") p.link_elements[name] = e;
  }
  checkTree(p, source);
  try {
    p.model = urdf::parseURDF(xml);
  } catch (const std::exception& e) {
    throw ConfigError(source + ": liburdfdom: " + e.what());
  }
  if (!p.model)
    throw ConfigError(source + ": liburdfdom refused the URDF (a joint naming a missing link, two roots, a loop, or an "
                               "attribute it cannot read; its own message is on stderr)");
}

struct ChainJoint {
  urdf::JointConstSharedPtr joint;
  const TiXmlElement* element = nullptr;
};

// The links below the base link.
struct Tree {
  const urdf::ModelInterface& model;
  urdf::LinkConstSharedPtr base;
  // Is `l` below the base? The path from the base to it, joints in base-to-tip order.
  bool pathFromBase(urdf::LinkConstSharedPtr l, std::vector<urdf::JointConstSharedPtr>* joints) const {
    std::vector<urdf::JointConstSharedPtr> up;
    while (l && l->name != base->name) {
      if (!l->parent_joint) return false;
      up.push_back(l->parent_joint);
      l = model.getLink(l->parent_joint->parent_link_name);
    }
    if (!l) return false;
    if (joints) joints->assign(up.rbegin(), up.rend());
    return true;
  }
};

// Without tip_link or a tool0 below the base: the one leaf the most movable joints lead to.
urdf::LinkConstSharedPtr deepestLeaf(const Tree& tree, const std::string& where) {
  const urdf::LinkConstSharedPtr& base = tree.base;
  std::vector<urdf::LinkConstSharedPtr> leaves;
  std::vector<urdf::LinkConstSharedPtr> todo = {base};
  while (!todo.empty()) {
    const auto l = todo.back();
    todo.pop_back();
    if (l->child_links.empty()) leaves.push_back(l);
    for (const auto& c : l->child_links) todo.push_back(c);
  }
  std::vector<urdf::LinkConstSharedPtr> deepest;
  size_t most = 0;
  for (const auto& l : leaves) {
    std::vector<urdf::JointConstSharedPtr> js;
    tree.pathFromBase(l, &js);
    const size_t revolute = std::count_if(js.begin(), js.end(), [](const auto& j) { return j->type != urdf::Joint::FIXED; });
    if (revolute > most) {
      most = revolute;
      deepest = {l};
    } else if (revolute == most && revolute > 0) {
      deepest.push_back(l);
    }
  }
  if (deepest.size() != 1) {
    std::string names;
    for (const auto& l : deepest) names += (names.empty() ? "" : ", ") + l->name;
    throw ConfigError(where + ": no tool0 and " +
                      (deepest.empty() ? std::string("no movable chain below ") + base->name
                                       : "the chain branches to " + names) +
                      ": name the tip with --tip-link");
  }
  return deepest.front();
}

// The tip: tip_link, else tool0 below the base, else the one leaf the most movable joints lead to.
urdf::LinkConstSharedPtr findTip(const Tree& tree, const Parsed& parsed, const std::string& source,
                                 const UrdfImportOptions& options) {
  const TiXmlElement* robot = parsed.doc.RootElement();
  if (!options.tip_link.empty()) {
    urdf::LinkConstSharedPtr tip = tree.model.getLink(options.tip_link);
    if (!tip) throw ConfigError(at(source, robot) + ": --tip-link " + options.tip_link + ": no such <link>");
    if (!tree.pathFromBase(tip, nullptr)) {
      const auto it = parsed.link_elements.find(tip->name);
      throw ConfigError(at(source, it == parsed.link_elements.end() ? robot : it->second) + ": <link name=\"" +
                        tip->name + "\">: not below the base link " + tree.base->name);
    }
    return tip;
  }
  if (urdf::LinkConstSharedPtr t = tree.model.getLink("tool0"); t && tree.pathFromBase(t, nullptr)) return t;
  return deepestLeaf(tree, at(source, robot));
}

// The chain's joints from the base to the tip, each revolute (with limits and an axis) or fixed; out gets their names
// and which are revolute.
std::vector<ChainJoint> chainOf(const std::vector<urdf::JointConstSharedPtr>& path, const Parsed& parsed,
                                const std::string& source, UrdfImport& out) {
  const TiXmlElement* robot = parsed.doc.RootElement();
  std::vector<ChainJoint> chain;
  for (const auto& j : path) {
    const auto it = parsed.joint_elements.find(j->name);
    ChainJoint c{j, it == parsed.joint_elements.end() ? robot : it->second};
    const std::string where = at(source, c.element) + ": <joint name=\"" + j->name + "\">: ";
    if (j->type == urdf::Joint::CONTINUOUS)
      throw ConfigError(where + "type continuous in the chain: a calibrated arm needs joint limits (make it revolute "
                                "with its limits)");
    if (j->type != urdf::Joint::REVOLUTE && j->type != urdf::Joint::FIXED)
      throw ConfigError(where + "a joint that is neither revolute nor fixed in the chain (prismatic, floating or planar)");
    if (j->type == urdf::Joint::REVOLUTE) {
      const Eigen::Vector3d a(j->axis.x, j->axis.y, j->axis.z);
      if (!(a.norm() > 1e-9)) throw ConfigError(where + "<axis> is zero");
      if (!j->limits) throw ConfigError(where + "a revolute joint without <limit>");
      if (!(j->limits->lower < j->limits->upper))
        throw ConfigError(where + "<limit> lower " + std::to_string(j->limits->lower) + " is not below upper " +
                          std::to_string(j->limits->upper));
    }
    chain.push_back(c);
    out.chain_joints.push_back(j->name);
    if (j->type == urdf::Joint::REVOLUTE) out.revolute.push_back(static_cast<int>(chain.size()) - 1);
  }
  return chain;
}

// The DH model of the axes (each revolute joint's point and direction at q = 0 in the base link's frame) up to the
// tip: m's nominal parameters and parallel joints; the DH frames 0..n at q = 0; parallel_joints the (1-based) joints
// whose axis is parallel to the next.
std::vector<Pose> fitDh(const std::vector<Eigen::Vector3d>& axis_point, const std::vector<Eigen::Vector3d>& axis_dir,
                        const Pose& tip_pose, double parallel_tolerance_rad, RobotModel& m,
                        std::vector<int>* parallel_joints_out) {
  const int n = m.numJoints();
  // DH frame 0.
  std::vector<Pose> dh(static_cast<size_t>(n) + 1, Pose::Identity());
  {
    const Eigen::Vector3d z = axis_dir[0], p = axis_point[0];
    const Eigen::Vector3d o = p + (Eigen::Vector3d::Zero() - p).dot(z) * z;
    Eigen::Vector3d x = Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitX().dot(z) * z;
    if (x.norm() < 1e-6) x = Eigen::Vector3d::UnitY() - Eigen::Vector3d::UnitY().dot(z) * z;
    x.normalize();
    dh[0].linear() << x, z.cross(x), z;
    dh[0].translation() = o;
  }
  std::vector<int>& parallel_joints = *parallel_joints_out;
  for (int j = 0; j < n; ++j) {
    const Pose& F = dh[static_cast<size_t>(j)];
    const Eigen::Vector3d O = F.translation(), z = F.linear().col(2), x_prev = F.linear().col(0);
    double theta = 0, d = 0, a = 0, alpha = 0, beta = 0;
    Pose next = Pose::Identity();
    if (j + 1 == n) {
      // The last frame: z along the axis, the origin at the tip's foot on it, x as close to the tip's x as z allows.
      d = (tip_pose.translation() - O).dot(z);
      Eigen::Vector3d x = tip_pose.linear().col(0) - tip_pose.linear().col(0).dot(z) * z;
      if (x.norm() < 1e-6) x = tip_pose.linear().col(1) - tip_pose.linear().col(1).dot(z) * z;
      x.normalize();
      theta = angleAbout(z, x_prev, x);
      next.linear() << x, z.cross(x), z;
      next.translation() = O + d * z;
    } else {
      const Eigen::Vector3d u2 = axis_dir[static_cast<size_t>(j) + 1], p2 = axis_point[static_cast<size_t>(j) + 1];
      const double sine = z.cross(u2).norm();
      if (sine < std::sin(parallel_tolerance_rad)) {
        // Parallel (within the tolerance): Hayati, d = 0. The next origin is where the next axis crosses the plane
        // through this origin normal to this axis; alpha and beta turn z onto the next axis.
        m.parallel_to_next[static_cast<size_t>(j)] = true;
        parallel_joints.push_back(j + 1);
        const double t = (O - p2).dot(z) / u2.dot(z);
        const Eigen::Vector3d P = p2 + t * u2, v = P - O;
        Eigen::Vector3d x = x_prev;
        if (v.norm() > 1e-12) x = v.normalized();
        if (x.dot(x_prev) < 0) x = -x;
        a = v.dot(x);
        theta = angleAbout(z, x_prev, x);
        Eigen::Matrix3d R = F.linear() * rotZ(theta);
        const Eigen::Vector3d u = R.transpose() * u2;
        beta = std::asin(std::clamp(u.x(), -1.0, 1.0));
        alpha = std::atan2(-u.y(), u.z());
        next.linear() = R * rotX(alpha) * rotY(beta);
        next.translation() = O + a * R.col(0);
      } else {
        // Classic DH along the common normal of the two axes.
        const Eigen::Vector3d w0 = O - p2;
        const double b = z.dot(u2), dd = z.dot(w0), e = u2.dot(w0), den = 1 - b * b;
        const double s1 = (b * e - dd) / den, s2 = (e - b * dd) / den;
        const Eigen::Vector3d c1 = O + s1 * z, c2 = p2 + s2 * u2;
        Eigen::Vector3d x = (c2 - c1).norm() > 1e-12 ? Eigen::Vector3d((c2 - c1).normalized()) : Eigen::Vector3d(z.cross(u2).normalized());
        if (x.dot(x_prev) < 0) x = -x;
        theta = angleAbout(z, x_prev, x);
        d = (c1 - O).dot(z);
        a = (c2 - c1).dot(x);
        alpha = angleAbout(x, z, u2);
        next.linear() << x, u2.cross(x), u2;
        next.translation() = c2;
      }
    }
    // Round-off of the geometry (1e-17 m, 1e-16 rad) is no length or angle: zero (the robot file then reads as the
    // drawing it is).
    auto clean = [](double v) { return std::abs(v) < 1e-12 ? 0.0 : v; };
    m.nominal[m.jointParam(j, JointParam::kThetaOffset)] = clean(theta);
    m.nominal[m.jointParam(j, JointParam::kD)] = clean(d);
    m.nominal[m.jointParam(j, JointParam::kA)] = clean(a);
    m.nominal[m.jointParam(j, JointParam::kAlpha)] = clean(alpha);
    m.nominal[m.jointParam(j, JointParam::kBeta)] = clean(beta);
    // The frame as the model composes it (rounding aside the same as `next`).
    dh[static_cast<size_t>(j) + 1] = F * linkRest(m, m.nominal, j);
    (void)next;
  }
  return dh;
}

// Masses: each body (the links rigidly attached after revolute joint k, up to the next revolute joint or the tip and
// beyond it through fixed joints), its centre of mass in DH frame k. m.links is set when the URDF has any mass; the
// total is returned.
double linkMasses(const Tree& tree, const std::vector<ChainJoint>& chain, const std::vector<int>& revolute,
                  const std::vector<Pose>& dh, RobotModel& m) {
  const urdf::ModelInterface& model = tree.model;
  const urdf::LinkConstSharedPtr& base = tree.base;
  const int n = m.numJoints();
  std::map<std::string, Pose> link_pose;  // at q = 0, in the base link's frame
  {
    std::vector<std::pair<urdf::LinkConstSharedPtr, Pose>> todo = {{base, Pose::Identity()}};
    while (!todo.empty()) {
      auto [l, P] = todo.back();
      todo.pop_back();
      link_pose[l->name] = P;
      for (const auto& cj : l->child_joints)
        if (auto c = model.getLink(cj->child_link_name)) todo.push_back({c, P * toPose(cj->parent_to_joint_origin_transform)});
    }
  }
  double total = 0;
  std::vector<LinkInertia> links(static_cast<size_t>(n));
  std::string mass_note;
  for (int k = 0; k < n; ++k) {
    const auto& rj = chain[static_cast<size_t>(revolute[static_cast<size_t>(k)])].joint;
    double mass = 0;
    Eigen::Vector3d moment = Eigen::Vector3d::Zero();
    std::vector<urdf::LinkConstSharedPtr> todo = {model.getLink(rj->child_link_name)};
    while (!todo.empty()) {
      const auto l = todo.back();
      todo.pop_back();
      if (!l) continue;
      if (l->inertial && l->inertial->mass > 0) {
        mass += l->inertial->mass;
        moment += l->inertial->mass * (link_pose[l->name] * toPose(l->inertial->origin).translation());
      }
      for (const auto& cj : l->child_joints)
        if (cj->type == urdf::Joint::FIXED) todo.push_back(model.getLink(cj->child_link_name));
    }
    links[static_cast<size_t>(k)].mass_kg = mass;
    if (mass > 0)
      links[static_cast<size_t>(k)].com_m = (dh[static_cast<size_t>(k) + 1].inverse() * (moment / mass)).unaryExpr([](double v) {
        return std::abs(v) < 1e-12 ? 0.0 : v;
      });
    total += mass;
  }
  if (total > 0) m.links = links;
  return total;
}

// What was chosen, in words.
std::vector<std::string> importNotes(const RobotModel& m, const std::string& base, const std::string& tip,
                                     size_t chain_joints, const std::vector<int>& parallel_joints, double total_mass) {
  const int n = m.numJoints();
  std::vector<std::string> notes;
  auto list = [](const std::vector<int>& v) {
    std::string s;
    for (int x : v) s += (s.empty() ? "" : ", ") + std::to_string(x);
    return s;
  };
  notes.push_back("chain " + base + " -> " + tip + ": " + std::to_string(chain_joints) + " joints, " +
                      std::to_string(n) + " revolute (" + [&] {
                        std::string s;
                        for (const auto& name : m.joint_names) s += (s.empty() ? "" : ", ") + name;
                        return s;
                      }() + ")");
  notes.push_back(parallel_joints.empty()
                          ? std::string("no neighbouring axes parallel: classic DH throughout")
                          : "joint" + std::string(parallel_joints.size() > 1 ? "s " : " ") + list(parallel_joints) +
                                ": axis parallel to the next (Hayati: d = 0, beta)");
  const bool mounted = m.mount.norm() > 1e-12, flanged = m.flange.norm() > 1e-12;
  notes.push_back(std::string("mount (") + base + " -> DH frame 0): " +
                      (mounted ? "kept as a fixed transform (joint 1's axis is not " + base + "'s z through its origin)"
                               : "identity"));
  notes.push_back(std::string("flange (DH frame ") + std::to_string(n) + " -> " + tip + "): " +
                      (flanged ? "kept as a fixed transform" : "identity"));
  notes.push_back(total_mass > 0 ? "link masses from the URDF's inertials: " + [&] {
    std::ostringstream o;
    o.precision(4);
    for (int k = 0; k < n; ++k) o << (k ? ", " : "") << m.links[static_cast<size_t>(k)].mass_kg;
    return o.str();
  }() + " kg" : std::string("no link masses in the URDF (gravity-dependent extensions need them)"));
  return notes;
}

}  // namespace

bool isUrdfPath(const std::string& path) {
  if (path.size() < 5) return false;
  std::string ext = path.substr(path.size() - 5);
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".urdf";
}

std::optional<UrdfOrigin> urdfOriginOf(const std::string& robot_file_path,
                                       const std::vector<std::pair<std::string, std::string>>& source, std::string* why) {
  namespace fs = std::filesystem;
  UrdfOrigin o;
  if (isUrdfPath(robot_file_path)) {
    o.path = robot_file_path;
    return o;
  }
  for (const auto& [k, v] : source) {
    if (k == "urdf") o.path = v;
    if (k == "base_link") o.options.base_link = v;
    if (k == "tip_link") o.options.tip_link = v;
  }
  if (o.path.empty()) {
    if (why) *why = robot_file_path + " names no URDF (no source.urdf: it was not made by `cellcal robot import`)";
    return std::nullopt;
  }
  std::error_code ec;
  if (!fs::exists(o.path, ec) && fs::path(o.path).is_relative()) {
    const fs::path beside = fs::path(robot_file_path).parent_path() / o.path;
    if (fs::exists(beside, ec)) o.path = beside.string();
  }
  if (!fs::exists(o.path, ec)) {
    if (why) *why = robot_file_path + ": its source URDF " + o.path + " is not there";
    return std::nullopt;
  }
  return o;
}

std::string urdfMismatch(const UrdfImport& u, const RobotModel& m) {
  auto num = [](double v) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.4g", v);
    return std::string(buf);
  };
  if (u.model.numJoints() != m.numJoints())
    return std::to_string(m.numJoints()) + " joints against " + std::to_string(u.model.numJoints());
  if (!m.joint_names.empty() && m.joint_names != u.model.joint_names) return "other joint names";
  if (u.model.parallel_to_next != m.parallel_to_next) return "other parallel joints";
  if ((u.model.mount - m.mount).cwiseAbs().maxCoeff() > 1e-9 || (u.model.flange - m.flange).cwiseAbs().maxCoeff() > 1e-9)
    return "another mount or flange";
  for (int j = 0; j < m.numJoints(); ++j)
    for (JointParam p : {JointParam::kD, JointParam::kA, JointParam::kAlpha}) {
      const int i = m.jointParam(j, p);
      if (std::abs(m.nominal[i] - u.model.nominal[i]) > (m.isLength(i) ? 0.02 : 5 * 3.14159265358979323846 / 180))
        return m.paramNameHuman(i) + " " + num(m.toHuman(i, m.nominal[i])) + " against the URDF's " +
               num(m.toHuman(i, u.model.nominal[i]));
    }
  return "";
}

UrdfImport importUrdf(const std::string& xml, const std::string& source, const UrdfImportOptions& options) {
  Parsed parsed;
  parse(xml, source, parsed);
  const urdf::ModelInterface& model = *parsed.model;
  const TiXmlElement* robot = parsed.doc.RootElement();
  UrdfImport out;
  out.robot_name = model.getName();
  urdf::LinkConstSharedPtr base = options.base_link.empty() ? model.getRoot() : model.getLink(options.base_link);
  if (!base) throw ConfigError(at(source, robot) + ": --base-link " + options.base_link + ": no such <link>");
  const Tree tree{model, base};
  const urdf::LinkConstSharedPtr tip = findTip(tree, parsed, source, options);
  out.base_link = base->name;
  out.tip_link = tip->name;
  std::vector<urdf::JointConstSharedPtr> path;
  tree.pathFromBase(tip, &path);
  const std::vector<ChainJoint> chain = chainOf(path, parsed, source, out);
  const int n = static_cast<int>(out.revolute.size());
  if (n < 3 || n > 7)
    throw ConfigError(at(source, robot) + ": the chain from " + base->name + " to " + tip->name + " has " +
                      std::to_string(n) + " revolute joints: cellcal takes arms of 3 to 7");

  // The chain at q = 0 in the base link's frame: each revolute joint's frame (origin and axis) and the tip.
  std::vector<Pose> joint_frame(chain.size());  // the child link's frame of each chain joint at q = 0
  std::vector<Eigen::Vector3d> axis_point, axis_dir;
  Pose W = Pose::Identity();
  for (size_t k = 0; k < chain.size(); ++k) {
    W = W * toPose(chain[k].joint->parent_to_joint_origin_transform);
    joint_frame[k] = W;
    if (chain[k].joint->type == urdf::Joint::REVOLUTE) {
      const auto& a = chain[k].joint->axis;
      axis_point.push_back(W.translation());
      axis_dir.push_back((W.linear() * Eigen::Vector3d(a.x, a.y, a.z)).normalized());
    }
  }
  const Pose tip_pose = W;

  RobotModel& m = out.model;
  m.name = out.robot_name.empty() ? tip->name : out.robot_name;
  m.parallel_to_next.assign(static_cast<size_t>(n), false);
  m.nominal = Eigen::VectorXd::Zero(5 * n + 12);
  for (int i : out.revolute) {
    const auto& j = chain[static_cast<size_t>(i)].joint;
    m.limits.push_back({j->limits->lower, j->limits->upper});
    m.joint_names.push_back(j->name);
  }
  std::vector<int> parallel_joints;
  const std::vector<Pose> dh = fitDh(axis_point, axis_dir, tip_pose, options.parallel_tolerance_rad, m, &parallel_joints);
  m.mount = xyzRpy(dh[0]).unaryExpr([](double v) { return std::abs(v) < 1e-12 ? 0.0 : v; });
  m.flange = xyzRpy(dh[static_cast<size_t>(n)].inverse() * tip_pose).unaryExpr([](double v) {
    return std::abs(v) < 1e-12 ? 0.0 : v;
  });
  // Each revolute joint's child link frame in DH frame k-1 at q = 0 (the export keeps it).
  for (int k = 0; k < n; ++k)
    out.link_in_dh.push_back(dh[static_cast<size_t>(k)].inverse() * joint_frame[static_cast<size_t>(out.revolute[static_cast<size_t>(k)])]);
  const double total = linkMasses(tree, chain, out.revolute, dh, m);
  m.gravity_in_base_mps2 = dh[0].linear().transpose() * Eigen::Vector3d(0, 0, -9.81);
  std::string err;
  if (!m.IsValid(&err)) throw ConfigError(source + ": the converted model: " + err);

  out.notes = importNotes(m, base->name, tip->name, chain.size(), parallel_joints, total);
  return out;
}

UrdfImport importUrdfFile(const std::string& path, const UrdfImportOptions& options) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path + ": cannot open the URDF");
  std::stringstream ss;
  ss << in.rdbuf();
  return importUrdf(ss.str(), path, options);
}

namespace {

// " xyz=\"...\" rpy=\"...\"" of a transform, every figure to the last bit.
std::string originAttributes(const Pose& T) {
  const Eigen::Matrix<double, 6, 1> v = xyzRpy(T);
  char buf[256];
  std::snprintf(buf, sizeof buf, "xyz=\"%.17g %.17g %.17g\" rpy=\"%.17g %.17g %.17g\"", v[0] + 0.0, v[1] + 0.0, v[2] + 0.0,
                v[3] + 0.0, v[4] + 0.0, v[5] + 0.0);
  return buf;
}

// The byte offset in `text` where line `row` (1-based) begins.
size_t lineStart(const std::string& text, int row) {
  size_t at = 0;
  for (int r = 1; r < row && at != std::string::npos; ++r) {
    at = text.find('\n', at);
    if (at != std::string::npos) ++at;
  }
  return at == std::string::npos ? text.size() : at;
}

}  // namespace

std::string exportUrdf(const std::string& nominal_xml, const std::string& source, const UrdfImport& nominal,
                       const Eigen::VectorXd& params, const Pose& tip_correction) {
  Parsed parsed;
  parse(nominal_xml, source, parsed);
  const RobotModel& m = nominal.model;
  const int n = m.numJoints();
  if (params.size() != m.numParams())
    throw ConfigError(source + ": the calibrated model has " + std::to_string(params.size()) + " parameters, this URDF's " +
                      std::to_string(m.numParams()));
  // The chain's joints, as imported: each must still be there, of the same type.
  std::vector<urdf::JointConstSharedPtr> chain;
  for (const auto& name : nominal.chain_joints) {
    const auto j = parsed.model->getJoint(name);
    if (!j) throw ConfigError(source + ": <joint name=\"" + name + "\">: not in this URDF (another robot's?)");
    chain.push_back(j);
  }
  // Fixed joints between revolute joints: unchanged. New origins: O'_k = F_k^-1 G_(k-1)^-1 A_(k-1)^rest G_k, where
  // F_k is the fixed chain between the previous revolute joint's child link and revolute joint k's parent (for k = 1:
  // from the base link, with the mount in place of G_0^-1 A_0^rest).
  std::map<std::string, Pose> new_origin;
  auto fixedBetween = [&](int from, int to) {  // product of the chain's joint origins from..to-1 (fixed ones)
    Pose F = Pose::Identity();
    for (int k = from; k < to; ++k) F = F * toPose(chain[static_cast<size_t>(k)]->parent_to_joint_origin_transform);
    return F;
  };
  const Pose mount = frameFromXyzRpy(m.mount), flange = frameFromXyzRpy(m.flange);
  for (int k = 0; k < n; ++k) {
    const int idx = nominal.revolute[static_cast<size_t>(k)];
    const int prev = k == 0 ? 0 : nominal.revolute[static_cast<size_t>(k) - 1] + 1;
    const Pose F = fixedBetween(prev, idx);
    const Pose before = k == 0 ? mount : nominal.link_in_dh[static_cast<size_t>(k) - 1].inverse() * linkRest(m, params, k - 1);
    new_origin[chain[static_cast<size_t>(idx)]->name] = F.inverse() * before * nominal.link_in_dh[static_cast<size_t>(k)];
  }
  // The tail: the first fixed joint after the last revolute one takes the last joint's link and the tip correction.
  const int last = nominal.revolute.back();
  if (last + 1 >= static_cast<int>(chain.size()))
    throw ConfigError(source + ": <joint name=\"" + chain[static_cast<size_t>(last)]->name + "\">: the tip " +
                      nominal.tip_link + " is the last revolute joint's own link: no fixed joint after it to carry "
                      "the last joint's calibration (add a fixed joint to a flange link)");
  const Pose rest_after = fixedBetween(last + 2, static_cast<int>(chain.size()));
  new_origin[chain[static_cast<size_t>(last) + 1]->name] = nominal.link_in_dh.back().inverse() * linkRest(m, params, n - 1) *
                                                           flange * tip_correction * rest_after.inverse();
  // Text surgery: each changed joint's <origin> element, or one inserted after its start tag.
  struct Edit {
    size_t from, to;
    std::string text;
  };
  std::vector<Edit> edits;
  for (const auto& [name, T] : new_origin) {
    const auto it = parsed.joint_elements.find(name);
    if (it == parsed.joint_elements.end()) throw ConfigError(source + ": <joint name=\"" + name + "\">: not found");
    const TiXmlElement* e = it->second;
    const size_t start = nominal_xml.find("<joint", lineStart(nominal_xml, e->Row()));
    const size_t end = nominal_xml.find("</joint>", start);
    const size_t self_close = nominal_xml.find("/>", start);
    const size_t open_end = nominal_xml.find('>', start);
    if (start == std::string::npos || open_end == std::string::npos)
      throw ConfigError(at(source, e) + ": <joint name=\"" + name + "\">: cannot locate it in the text");
    const size_t close = end == std::string::npos ? self_close : end;
    size_t o = nominal_xml.find("<origin", open_end);
    if (o != std::string::npos && o < close) {
      const size_t o_end = nominal_xml.find("/>", o);
      edits.push_back({o, o_end + 2, "<origin " + originAttributes(T) + "/>"});
    } else {
      edits.push_back({open_end + 1, open_end + 1, "\n    <origin " + originAttributes(T) + "/>"});
    }
  }
  std::sort(edits.begin(), edits.end(), [](const Edit& a, const Edit& b) { return a.from > b.from; });
  std::string out = nominal_xml;
  for (const auto& e : edits) out.replace(e.from, e.to - e.from, e.text);
  return out;
}

std::string exportUrKinematics(const std::string& nominal_xml, const std::string& source, const UrdfImport& nominal,
                               const Eigen::VectorXd& params, const Pose& tip_correction, const std::string& hash,
                               double* rest_m, double* rest_rad, Pose* tip_not_carried) {
  static const char* kNames[] = {"shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3"};
  if (nominal.model.numJoints() != 6)
    throw ConfigError(source + ": a UR arm has 6 revolute joints, this chain " + std::to_string(nominal.model.numJoints()));
  const std::string out = exportUrdf(nominal_xml, source, nominal, params, tip_correction);
  Parsed parsed;
  parse(out, source, parsed);
  const auto& chain = nominal.chain_joints;
  for (int k = 0; k < 6; ++k) {
    const auto j = parsed.model->getJoint(chain[static_cast<size_t>(nominal.revolute[static_cast<size_t>(k)])]);
    const Eigen::Vector3d axis(j->axis.x, j->axis.y, j->axis.z);
    if ((axis.normalized() - Eigen::Vector3d::UnitZ()).norm() > 1e-12)
      throw ConfigError(source + ": <joint name=\"" + j->name + "\">: its axis is not z: not a Universal Robots description");
  }
  // The exported tail's change in wrist_3's link frame (new = D * nominal), split into what commutes with joint 6 (a
  // turn about z and a shift along it: wrist_3's origin takes it) and the rest.
  const std::string tail = chain[static_cast<size_t>(nominal.revolute.back()) + 1];
  const Pose D = urdfJointOrigin(out, source, tail) * urdfJointOrigin(nominal_xml, source, tail).inverse();
  const double turn = std::atan2(D.linear()(1, 0) - D.linear()(0, 1), D.linear()(0, 0) + D.linear()(1, 1));
  Pose commuting = Pose::Identity();
  commuting.linear() = rotZ(turn);
  commuting.translation() = Eigen::Vector3d(0, 0, D.translation().z());
  const Pose rest = commuting.inverse() * D;
  if (rest_m) *rest_m = rest.translation().norm();
  if (rest_rad) *rest_rad = logSO3(rest.linear()).norm();
  // The composed tip: wrist_3 * commuting * N = (wrist_3 * D * N) * N^-1 rest^-1 N, N the nominal fixed joints from
  // wrist_3 to the tip.
  if (tip_not_carried) {
    Pose N = Pose::Identity();
    for (size_t k = static_cast<size_t>(nominal.revolute.back()) + 1; k < chain.size(); ++k)
      N = N * urdfJointOrigin(nominal_xml, source, chain[k]);
    *tip_not_carried = N.inverse() * rest.inverse() * N;
  }
  std::ostringstream y;
  y << "kinematics:\n";
  for (int k = 0; k < 6; ++k) {
    Pose origin = urdfJointOrigin(out, source, chain[static_cast<size_t>(nominal.revolute[static_cast<size_t>(k)])]);
    if (k == 5) origin = origin * commuting;
    const Eigen::Matrix<double, 6, 1> v = xyzRpy(origin);
    char buf[400];
    std::snprintf(buf, sizeof buf,
                  "  %s:\n    x: %.17g\n    y: %.17g\n    z: %.17g\n    roll: %.17g\n    pitch: %.17g\n    yaw: %.17g\n",
                  kNames[k], v[0] + 0.0, v[1] + 0.0, v[2] + 0.0, v[3] + 0.0, v[4] + 0.0, v[5] + 0.0);
    y << buf;
  }
  y << "  hash: \"" << hash << "\"\n";
  return y.str();
}

Pose urdfJointOrigin(const std::string& xml, const std::string& source, const std::string& name) {
  Parsed parsed;
  parse(xml, source, parsed);
  const auto j = parsed.model->getJoint(name);
  if (!j) throw ConfigError(source + ": <joint name=\"" + name + "\">: not in this URDF");
  return toPose(j->parent_to_joint_origin_transform);
}

}  // namespace cellcal
