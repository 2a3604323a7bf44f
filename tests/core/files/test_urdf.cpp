// URDF in and out (core/files/urdf.hpp), judged by KDL (Debian's liborocos-kdl with kdl_parser), which shares no code
// with cellcal's kinematics: every arm of ../shared/robots/ros-industrial as cellcal's model gives KDL's tip pose on
// random configurations within the limits, through the robot file too; an export of the model, uncalibrated and with
// every joint's parameters perturbed and the tip moved, gives KDL on the exported file the model's poses; bad URDFs
// are refused naming the file and the element.
#include <gtest/gtest.h>

#include <kdl/chainfksolverpos_recursive.hpp>
#include <kdl/tree.hpp>
#include <kdl_parser/kdl_parser.hpp>
#include <tinyxml.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include "cellcal/core/files/export.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/urdf.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/controller_check.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;

const fs::path kArms = fs::path(CELLCAL_CONFIG_DIR) / "../../shared/robots/ros-industrial";

std::vector<fs::path> arms() {
  std::vector<fs::path> out;
  if (!fs::is_directory(kArms)) return out;
  for (const auto& e : fs::recursive_directory_iterator(kArms))
    if (e.path().extension() == ".urdf") out.push_back(e.path());
  std::sort(out.begin(), out.end());
  return out;
}

std::string readText(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// KDL's pose of `tip` relative to `base` at q (the chain's joints in order).
struct KdlChain {
  KDL::Chain chain;
  std::unique_ptr<KDL::ChainFkSolverPos_recursive> fk;
  KdlChain(const std::string& xml, const std::string& base, const std::string& tip) {
    KDL::Tree tree;
    EXPECT_TRUE(kdl_parser::treeFromString(xml, tree));
    EXPECT_TRUE(tree.getChain(base, tip, chain)) << base << " -> " << tip;
    fk = std::make_unique<KDL::ChainFkSolverPos_recursive>(chain);
  }
  Pose at(const Eigen::VectorXd& q) const {
    KDL::JntArray j(chain.getNrOfJoints());
    for (unsigned i = 0; i < chain.getNrOfJoints(); ++i) j(i) = q[i];
    KDL::Frame f;
    fk->JntToCart(j, f);
    Pose T = Pose::Identity();
    for (int r = 0; r < 3; ++r) {
      T.translation()[r] = f.p(r);
      for (int c = 0; c < 3; ++c) T.linear()(r, c) = f.M(r, c);
    }
    return T;
  }
};

Eigen::VectorXd randomQ(const RobotModel& m, std::mt19937_64& rng) {
  Eigen::VectorXd q(m.numJoints());
  for (int j = 0; j < m.numJoints(); ++j)
    q[j] = std::uniform_real_distribution<double>(m.limits[j].lower_rad, m.limits[j].upper_rad)(rng);
  return q;
}

// Largest position (m) and rotation (rad) difference of two poses.
std::pair<double, double> difference(const Pose& a, const Pose& b) {
  return {(a.translation() - b.translation()).norm(), logSO3(a.linear().transpose() * b.linear()).norm()};
}

TEST(Urdf, EveryArmGivesKdlsPoseOnRandomConfigurations) {
  const auto files = arms();
  if (files.empty()) GTEST_SKIP() << kArms << " missing";
  EXPECT_EQ(files.size(), 11u);
  std::mt19937_64 rng(test::testSeed());
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    const std::string xml = readText(f);
    const UrdfImport u = importUrdf(xml, f.string());
    const RobotModel& m = u.model;
    EXPECT_EQ(u.tip_link, "tool0");
    EXPECT_EQ(m.numJoints(), 6);
    EXPECT_EQ(static_cast<int>(m.joint_names.size()), m.numJoints());
    const KdlChain kdl(xml, u.base_link, u.tip_link);
    ASSERT_EQ(static_cast<int>(kdl.chain.getNrOfJoints()), m.numJoints());
    // Through the robot file too (the text in mm and deg, read back).
    const RobotModel back = parseRobotFile(robotFileText(m, nullptr, "test"), "back.yaml").model;
    KinematicsData data(m), data_back(back);
    double worst_m = 0, worst_rad = 0, worst_back = 0;
    for (int k = 0; k < 1000; ++k) {
      const Eigen::VectorXd q = randomQ(m, rng);
      const Pose ref = kdl.at(q);
      const auto [dp, dr] = difference(forwardKinematics(m, data, m.nominal, q), ref);
      worst_m = std::max(worst_m, dp);
      worst_rad = std::max(worst_rad, dr);
      worst_back = std::max(worst_back, difference(forwardKinematics(back, data_back, back.nominal, q), ref).first);
    }
    std::printf("  %-28s %s; worst |p - KDL| %.2g m, rotation %.2g rad (robot file: %.2g m)\n",
                f.filename().c_str(), u.notes[1].c_str(), worst_m, worst_rad, worst_back);
    EXPECT_LT(worst_m, 1e-9);
    EXPECT_LT(worst_rad, 1e-9);
    EXPECT_LT(worst_back, 1e-9);
  }
}

// Export: the nominal model gives back poses equal to the file's; a calibrated one (every joint's canonical parameters
// moved 0.1-0.5 mm / 0.01-0.05 deg, the tip moved by a random small transform) gives KDL on the exported file the
// model's poses, with the tip correction; only joint origins changed (the other lines of the file as they were).
TEST(Urdf, AnExportedModelGivesKdlTheModelsPoses) {
  const auto files = arms();
  if (files.empty()) GTEST_SKIP() << kArms << " missing";
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto signedIn = [&](double lo, double hi) { return (u01(rng) < 0.5 ? -1 : 1) * (lo + (hi - lo) * u01(rng)); };
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    const std::string xml = readText(f);
    const UrdfImport u = importUrdf(xml, f.string());
    const RobotModel& m = u.model;
    for (int calibrated = 0; calibrated < 2; ++calibrated) {
      Eigen::VectorXd p = m.nominal;
      Pose tip = Pose::Identity();
      if (calibrated) {
        for (int i : m.canonicalParams())
          if (i < 5 * m.numJoints()) p[i] += m.isLength(i) ? signedIn(1e-4, 5e-4) : degToRad(signedIn(0.01, 0.05));
        tip = poseFromXyzRpy(signedIn(1e-4, 5e-4), signedIn(1e-4, 5e-4), signedIn(1e-4, 5e-4), degToRad(signedIn(0.01, 0.05)),
                             degToRad(signedIn(0.01, 0.05)), degToRad(signedIn(0.01, 0.05)));
      }
      const std::string out = exportUrdf(xml, f.string(), u, p, tip);
      const KdlChain kdl(out, u.base_link, u.tip_link);
      KinematicsData data(m);
      double worst_m = 0, worst_rad = 0;
      for (int k = 0; k < 300; ++k) {
        const Eigen::VectorXd q = randomQ(m, rng);
        const auto [dp, dr] = difference(forwardKinematics(m, data, p, q) * tip, kdl.at(q));
        worst_m = std::max(worst_m, dp);
        worst_rad = std::max(worst_rad, dr);
      }
      EXPECT_LT(worst_m, 1e-9) << (calibrated ? "calibrated" : "nominal");
      EXPECT_LT(worst_rad, 1e-9) << (calibrated ? "calibrated" : "nominal");
      // Only <origin> lines of the chain's joints differ.
      std::istringstream a(xml), b(out);
      std::string la, lb;
      int changed = 0, other = 0;
      while (std::getline(a, la) && std::getline(b, lb))
        if (la != lb) (lb.find("<origin") != std::string::npos ? changed : other)++;
      EXPECT_EQ(other, 0) << "lines other than joint origins changed";
      EXPECT_LE(changed, static_cast<int>(u.chain_joints.size()));
      // The export reads back as the same structure.
      EXPECT_EQ(importUrdf(out, "exported.urdf").model.numJoints(), m.numJoints());
    }
  }
}

// write() (export.hpp) of a calibrated model -- every joint moved, a tracker frame 1.5-4 m away turned at random, a
// target on the flange -- into the arm's URDF with the registered base as a link: KDL from that link to the tip, then
// the target's nominal place, gives the model's pose in the tracker frame to 1e-9. The DH table reads back as the
// parameters; what the formats cannot carry (extensions; the target's frame without its nominal place; the mount and
// flange in a DH table) is said; another arm's URDF is refused naming both files.
TEST(Urdf, WriteExportsTheCalibratedModelWithItsBaseTargetAndWhatItCannotCarry) {
  const auto files = arms();
  if (files.empty()) GTEST_SKIP() << kArms << " missing";
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto randomPose = [&](double reach_m) {
    Pose T = Pose::Identity();
    T.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
    T.translation() = reach_m * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    return T;
  };
  for (int draw = 0; draw < 4; ++draw) {
    const fs::path f = files[rng() % files.size()];
    SCOPED_TRACE(f.filename().string());
    const std::string xml = readText(f);
    const UrdfImport u = importUrdf(xml, f.string());
    const RobotModel& m = u.model;
    CalibratedModel c = CalibratedModel::geometric(m.nominal);
    for (int i : m.canonicalParams()) {
      if (i < 5 * m.numJoints()) c.params[i] += m.isLength(i) ? 3e-4 * g(rng) : degToRad(0.03 * g(rng));
      c.estimated.push_back(i);
    }
    const Pose base = randomPose(1.5 + 2.5 * u01(rng)), target_nominal = randomPose(0.15 * u01(rng));
    const Pose target_calibrated = target_nominal * poseFromXyzRpy(3e-4 * g(rng), 3e-4 * g(rng), 3e-4 * g(rng),
                                                                   degToRad(0.03 * g(rng)), degToRad(0.03 * g(rng)),
                                                                   degToRad(0.03 * g(rng)));
    c.params.segment<6>(m.baseParam(FrameParam::kX)) = xyzRpyFromPose(base);
    c.params.segment<6>(m.toolParam(FrameParam::kX)) = xyzRpyFromPose(target_calibrated);
    ExportOptions o;
    o.nominal_urdf_xml = xml;
    o.nominal_urdf_source = f.string();
    o.target_in_flange = target_nominal;
    o.base_frame_link = "tracker";
    o.model_source = "calibrated.yaml";
    const RobotExport e = write(m, c, ExportFormat::kUrdf, o);
    EXPECT_TRUE(e.not_carried.empty()) << e.not_carried.front();
    const KdlChain kdl(e.text, "tracker", u.tip_link);
    KinematicsData data(m);
    double worst_m = 0, worst_rad = 0;
    for (int k = 0; k < 100; ++k) {
      const Eigen::VectorXd q = randomQ(m, rng);
      const auto [dp, dr] = difference(forwardKinematics(m, data, c.params, q), kdl.at(q) * target_nominal);
      worst_m = std::max(worst_m, dp);
      worst_rad = std::max(worst_rad, dr);
    }
    EXPECT_LT(worst_m, 1e-9);
    EXPECT_LT(worst_rad, 1e-9);

    // The DH table: one row per joint, each value the parameter's in mm and deg.
    CalibratedModel extended = c;
    for (Cause cause : extensionCauses())
      if (extended.extensions.empty() && applicable(m, Extension{cause, 1}, true)) extended.extensions.push_back({cause, 1});
    extended.extension_params = Eigen::VectorXd::Zero(numExtensionParams(m, extended.extensions));
    const RobotExport dh = write(m, extended, ExportFormat::kDhTable, ExportOptions{});
    std::istringstream lines(dh.text);
    std::string line;
    ASSERT_TRUE(std::getline(lines, line));
    EXPECT_EQ(line, "joint,name,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,parallel_to_next,lower_deg,upper_deg");
    int j = 0;
    for (; std::getline(lines, line); ++j) {
      std::vector<std::string> cells;
      std::stringstream cs(line);
      for (std::string cell; std::getline(cs, cell, ',');) cells.push_back(cell);
      ASSERT_EQ(cells.size(), 10u) << line;
      EXPECT_EQ(std::stoi(cells[0]), j + 1);
      const JointParam kinds[] = {JointParam::kThetaOffset, JointParam::kD, JointParam::kA, JointParam::kAlpha,
                                  JointParam::kBeta};
      for (int k = 0; k < 5; ++k) {
        const int i = m.jointParam(j, kinds[k]);
        const double si = c.params[i], human = m.isLength(i) ? si * 1e3 : radToDeg(si);
        EXPECT_NEAR(std::stod(cells[static_cast<size_t>(2 + k)]), human, 1e-9 * (1 + std::abs(human))) << line;
      }
      EXPECT_EQ(cells[7], m.parallel_to_next[static_cast<size_t>(j)] ? "true" : "false");
    }
    EXPECT_EQ(j, m.numJoints());
    // What it cannot carry: the extensions first, the target's frame (no nominal place given), the mount and flange.
    ASSERT_FALSE(dh.not_carried.empty());
    EXPECT_EQ(dh.not_carried.front().rfind("the model extensions (", 0), 0u) << dh.not_carried.front();
    EXPECT_NE(dh.not_carried[1].find("what the target's frame absorbed"), std::string::npos) << dh.not_carried[1];
    EXPECT_EQ(dh.not_carried.size() == 3, m.hasMount() || m.hasFlange());

    // Another arm's URDF.
    const fs::path other = files[(std::find(files.begin(), files.end(), f) - files.begin() + 1) % files.size()];
    ExportOptions wrong = o;
    wrong.nominal_urdf_xml = readText(other);
    wrong.nominal_urdf_source = other.string();
    try {
      write(m, c, ExportFormat::kUrdf, wrong);
      ADD_FAILURE() << other << " accepted";
    } catch (const ConfigError& err) {
      const std::string what = err.what();
      EXPECT_NE(what.find(other.string() + ": not the description calibrated.yaml was calibrated from"), std::string::npos)
          << what;
    }
  }
}

// Arms no vendor made: 3 to 7 revolute joints, each origin moved up to 0.3 m and turned by quarter turns or at random,
// axes along a signed coordinate axis or in any direction, fixed joints between them, neighbouring axes parallel or
// 0.1-0.5 deg off parallel (Hayati's side of the 1 deg tolerance), a flange and tool0 at random. Imported, each gives
// KDL's tool0 on random configurations to 1e-9; exported with every joint moved (and the tip), KDL on the export gives
// the model's poses to 1e-9.
std::string randomArm(std::mt19937_64& rng, int* joints_out) {
  std::uniform_real_distribution<double> u(-1.0, 1.0), u01(0.0, 1.0);
  const int n = 3 + static_cast<int>(rng() % 5);
  *joints_out = n;
  std::ostringstream o;
  o.precision(17);
  o << "<?xml version=\"1.0\"?>\n<robot name=\"random_arm\">\n  <link name=\"base_link\"/>\n";
  std::string parent = "base_link";
  int links = 0;
  auto link = [&]() {
    const std::string name = "link" + std::to_string(++links);
    o << "  <link name=\"" << name << "\"><inertial><origin xyz=\"" << 0.1 * u(rng) << " " << 0.1 * u(rng) << " "
      << 0.1 * u(rng) << "\" rpy=\"0 0 0\"/><mass value=\"" << 1 + 5 * u01(rng)
      << "\"/><inertia ixx=\"1\" ixy=\"0\" ixz=\"0\" iyy=\"1\" iyz=\"0\" izz=\"1\"/></inertial></link>\n";
    return name;
  };
  auto rpy = [&](bool quarter) {
    std::ostringstream r;
    r.precision(17);
    for (int k = 0; k < 3; ++k)
      r << (k ? " " : "") << (quarter ? 1.5707963267948966 * static_cast<double>(static_cast<int>(rng() % 4) - 1) : 3 * u(rng));
    return r.str();
  };
  Eigen::Vector3d previous_axis = Eigen::Vector3d::UnitZ();
  for (int j = 1; j <= n; ++j) {
    const bool fixed_before = u01(rng) < 0.3;
    if (fixed_before) {  // a fixed joint before this one
      const std::string child = link();
      o << "  <joint name=\"fixed" << j << "\" type=\"fixed\"><parent link=\"" << parent << "\"/><child link=\"" << child
        << "\"/><origin xyz=\"" << 0.2 * u(rng) << " 0 " << 0.2 * u(rng) << "\" rpy=\"" << rpy(u01(rng) < 0.5) << "\"/></joint>\n";
      parent = child;
    }
    const std::string child = link();
    Eigen::Vector3d axis;
    std::string origin_rpy;
    const bool parallel = j > 1 && !fixed_before && u01(rng) < 0.4;
    if (parallel) {
      // Parallel to the previous axis in this frame (no turn, no fixed joint between): exactly, or 0.1-0.5 deg off.
      origin_rpy = "0 0 0";
      axis = previous_axis;
      if (u01(rng) < 0.5) {
        const Eigen::Vector3d off = axis.unitOrthogonal();
        axis = Eigen::AngleAxisd((0.1 + 0.4 * u01(rng)) * M_PI / 180, off) * axis;
      }
    } else {
      origin_rpy = rpy(u01(rng) < 0.6);
      if (u01(rng) < 0.6) {
        axis = Eigen::Vector3d::Zero();
        axis[static_cast<int>(rng() % 3)] = u01(rng) < 0.5 ? -1 : 1;
      } else {
        axis = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
      }
    }
    previous_axis = axis;
    o << "  <joint name=\"joint" << j << "\" type=\"revolute\"><parent link=\"" << parent << "\"/><child link=\"" << child
      << "\"/><origin xyz=\"" << 0.3 * u(rng) << " " << 0.3 * u(rng) << " " << 0.3 * u(rng) << "\" rpy=\"" << origin_rpy
      << "\"/><axis xyz=\"" << axis.x() << " " << axis.y() << " " << axis.z() << "\"/><limit lower=\"" << -2.5 - u01(rng)
      << "\" upper=\"" << 2.5 + u01(rng) << "\" effort=\"1\" velocity=\"1\"/></joint>\n";
    parent = child;
  }
  o << "  <link name=\"flange\"/>\n  <joint name=\"to_flange\" type=\"fixed\"><parent link=\"" << parent
    << "\"/><child link=\"flange\"/><origin xyz=\"" << 0.1 * u(rng) << " " << 0.1 * u(rng) << " " << 0.1 * u(rng)
    << "\" rpy=\"" << rpy(u01(rng) < 0.5) << "\"/></joint>\n  <link name=\"tool0\"/>\n"
    << "  <joint name=\"to_tool0\" type=\"fixed\"><parent link=\"flange\"/><child link=\"tool0\"/><origin xyz=\"0 0 "
    << 0.05 * u01(rng) << "\" rpy=\"" << rpy(true) << "\"/></joint>\n</robot>\n";
  return o.str();
}

TEST(Urdf, RandomArmsOfThreeToSevenJointsGiveKdlsPoseAndExportBack) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto signedIn = [&](double lo, double hi) { return (u01(rng) < 0.5 ? -1 : 1) * (lo + (hi - lo) * u01(rng)); };
  double worst_import = 0, worst_export = 0;
  int parallel = 0, by_joints[8] = {0};
  for (int arm_k = 0; arm_k < 60; ++arm_k) {
    int n = 0;
    const std::string xml = randomArm(rng, &n);
    SCOPED_TRACE("arm " + std::to_string(arm_k) + ":\n" + xml);
    const UrdfImport u = importUrdf(xml, "random_arm.urdf");
    const RobotModel& m = u.model;
    ASSERT_EQ(m.numJoints(), n);
    ++by_joints[n];
    for (bool b : m.parallel_to_next) parallel += b;
    const KdlChain kdl(xml, u.base_link, u.tip_link);
    KinematicsData data(m);
    Eigen::VectorXd p = m.nominal;
    for (int i : m.canonicalParams())
      if (i < 5 * n) p[i] += m.isLength(i) ? signedIn(1e-4, 5e-4) : degToRad(signedIn(0.01, 0.05));
    const Pose tip = poseFromXyzRpy(signedIn(1e-4, 5e-4), signedIn(1e-4, 5e-4), signedIn(1e-4, 5e-4),
                                    degToRad(signedIn(0.01, 0.05)), degToRad(signedIn(0.01, 0.05)), degToRad(signedIn(0.01, 0.05)));
    const KdlChain exported(exportUrdf(xml, "random_arm.urdf", u, p, tip), u.base_link, u.tip_link);
    for (int k = 0; k < 100; ++k) {
      const Eigen::VectorXd q = randomQ(m, rng);
      const auto [dp, dr] = difference(forwardKinematics(m, data, m.nominal, q), kdl.at(q));
      worst_import = std::max({worst_import, dp, dr});
      const auto [ep, er] = difference(forwardKinematics(m, data, p, q) * tip, exported.at(q));
      worst_export = std::max({worst_export, ep, er});
    }
    ASSERT_LT(worst_import, 1e-9);
    ASSERT_LT(worst_export, 1e-9);
  }
  std::printf("  60 random arms (%d, %d, %d, %d, %d of 3..7 joints; %d parallel neighbours): worst |model - KDL| %.2g, "
              "export %.2g (m or rad)\n",
              by_joints[3], by_joints[4], by_joints[5], by_joints[6], by_joints[7], parallel, worst_import, worst_export);
}

// The URDF with every origin of the named joints moved: each coordinate by 0.1-0.5 mm, each of roll, pitch and yaw by
// 0.01-0.05 deg, random signs (TinyXML edits the attributes; the text's layout is TinyXML's).
std::string perturbedOrigins(const std::string& xml, const std::vector<std::string>& joints, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto signedIn = [&](double lo, double hi) { return (u01(rng) < 0.5 ? -1 : 1) * (lo + (hi - lo) * u01(rng)); };
  TiXmlDocument doc;
  doc.Parse(xml.c_str());
  for (TiXmlElement* e = doc.RootElement()->FirstChildElement("joint"); e; e = e->NextSiblingElement("joint")) {
    if (std::find(joints.begin(), joints.end(), std::string(e->Attribute("name"))) == joints.end()) continue;
    TiXmlElement* o = e->FirstChildElement("origin");
    if (!o) o = e->InsertEndChild(TiXmlElement("origin"))->ToElement();
    double xyz[3] = {0, 0, 0}, rpy[3] = {0, 0, 0};
    if (const char* a = o->Attribute("xyz")) std::sscanf(a, "%lf %lf %lf", &xyz[0], &xyz[1], &xyz[2]);
    if (const char* a = o->Attribute("rpy")) std::sscanf(a, "%lf %lf %lf", &rpy[0], &rpy[1], &rpy[2]);
    char buf[200];
    std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g", xyz[0] + signedIn(1e-4, 5e-4), xyz[1] + signedIn(1e-4, 5e-4),
                  xyz[2] + signedIn(1e-4, 5e-4));
    o->SetAttribute("xyz", buf);
    std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g", rpy[0] + degToRad(signedIn(0.01, 0.05)),
                  rpy[1] + degToRad(signedIn(0.01, 0.05)), rpy[2] + degToRad(signedIn(0.01, 0.05)));
    o->SetAttribute("rpy", buf);
  }
  TiXmlPrinter printer;
  doc.Accept(&printer);
  return printer.CStr();
}

// A tracker 1.5-4 m away, any orientation; a target up to 100 mm beside the tip's axis, 0-150 mm out.
struct Placement {
  Pose base, target;
};
Placement randomPlacement(std::mt19937_64& rng) {
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  Placement p{Pose::Identity(), Pose::Identity()};
  const Eigen::Vector3d dir = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
  p.base.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  p.base.translation() = (1.5 + 2.5 * u01(rng)) * dir;
  p.target.linear() = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
  const double side = 0.1 * u01(rng), az = 2 * kPi * u01(rng);
  p.target.translation() = Eigen::Vector3d(side * std::cos(az), side * std::sin(az), 0.15 * u01(rng));
  return p;
}

// A configuration within 80 % of each joint's range (at most +-180 deg).
Eigen::VectorXd innerConfiguration(const RobotModel& m, std::mt19937_64& rng) {
  Eigen::VectorXd q(m.numJoints());
  for (int j = 0; j < m.numJoints(); ++j)
    q[j] = std::uniform_real_distribution<double>(0.8 * std::max(m.limits[j].lower_rad, -kPi),
                                                  0.8 * std::min(m.limits[j].upper_rad, kPi))(rng);
  return q;
}

// The frame whose x, y, z, roll, pitch, yaw start at p[first].
Pose frameAt(const Eigen::VectorXd& p, int first) {
  return poseFromXyzRpy(p[first], p[first + 1], p[first + 2], p[first + 3], p[first + 4], p[first + 5]);
}

// Calibration through a URDF: a true robot made by moving every joint origin of a random one of the eleven arms,
// measured through KDL (a random tracker placement and target, points or 6D, tracker noise), calibrated from the
// nominal URDF as `calibrate --robot nominal.urdf` does (registration, Gauss-Newton), exported with the target's
// nominal place: KDL on the exported file (and the calibrated base) predicts held-out readings as well as the other
// calibration tests ask of a model against the noise floor (mean error within 1.3x the readings' own).
TEST(Urdf, ACalibrationThroughAUrdfExportsTheCalibratedArm) {
  const auto files = arms();
  if (files.empty()) GTEST_SKIP() << kArms << " missing";
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  for (int draw = 0; draw < 6; ++draw) {
    const fs::path f = files[rng() % files.size()];
    const bool six_d = rng() % 2 == 0;
    SCOPED_TRACE(f.filename().string() + (six_d ? ", 6D" : ", points"));
    const std::string xml = readText(f);
    const UrdfImport u = importUrdf(xml, f.string());
    const RobotModel& m = u.model;
    const std::string truth_xml = perturbedOrigins(xml, u.chain_joints, rng);
    const KdlChain truth(truth_xml, u.base_link, u.tip_link);
    const auto [base, target] = randomPlacement(rng);
    const double sp = 0.01e-3, so = degToRad(0.001);
    auto measure = [&](const Eigen::VectorXd& q) {
      Observation o;
      o.q_rad = q;
      o.kind = six_d ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
      o.sigma_position_m = sp;
      o.sigma_orientation_rad = so;
      const Pose T = base * truth.at(q) * target;
      o.measured_in_tracker = T;
      o.measured_in_tracker.translation() += sp * Eigen::Vector3d(g(rng), g(rng), g(rng));
      o.measured_in_tracker.linear() = expSO3(so * Eigen::Vector3d(g(rng), g(rng), g(rng))) * T.linear();
      return std::make_pair(o, T);
    };
    auto config = [&] { return innerConfiguration(m, rng); };
    std::vector<Observation> ident;
    for (int k = 0; k < 80; ++k) ident.push_back(measure(config()).first);
    const RegistrationResult reg = registerFrames(m, m.nominal, ident);
    const CalibrationResult r = solveGaussNewton(CalibrationProblem{&m, reg.params, ident, std::nullopt, {}, {}});
    EXPECT_TRUE(r.converged) << r.message;
    // The export: the target's nominal place is known (the one the readings were made with).
    const Pose tool_cal = frameAt(r.params, m.toolParam(FrameParam::kX));
    const Pose base_cal = frameAt(r.params, m.baseParam(FrameParam::kX));
    const std::string exported = exportUrdf(xml, f.string(), u, r.params, tool_cal * target.inverse());
    const KdlChain calibrated(exported, u.base_link, u.tip_link), nominal(xml, u.base_link, u.tip_link);
    double floor = 0, after = 0, before = 0;
    const int held_out = 100;
    for (int k = 0; k < held_out; ++k) {
      const auto [o, T] = measure(config());
      const Eigen::Vector3d p = o.measured_in_tracker.translation();
      floor += (T.translation() - p).norm() / held_out;
      after += ((base_cal * calibrated.at(o.q_rad) * target).translation() - p).norm() / held_out;
      before += ((base_cal * nominal.at(o.q_rad) * target).translation() - p).norm() / held_out;
    }
    std::printf("  %-22s %-6s KDL on the exported URDF: held-out %.4f mm (nominal URDF %.4f mm, readings' noise %.4f mm)\n",
                f.filename().c_str(), six_d ? "6D" : "points", after * 1e3, before * 1e3, floor * 1e3);
    EXPECT_LT(after, 1.3 * floor) << "nominal " << before * 1e3 << " mm";
    EXPECT_GT(before, 5 * floor);  // the moved origins are far above the noise
  }
}

// A true arm for the convention test, twice. `identifiable`: the nominal arm with every joint parameter moved (0.1-0.5
// mm, 0.01-0.05 deg) but those the frames stand for on the base side (frameGauge: joint 1's offset about and along its
// axis), and the tip moved likewise, written by exportUrdf (itself checked against KDL above). `with_gauge`: the same
// arm with what no data tell from the base moved too: the first revolute joint's origin moved before it anywhere and
// after it along and about its axis. base_move: the constant transform that stands for that (FK_with_gauge(q) =
// base_move FK_identifiable(q)).
struct MovedChain {
  std::string identifiable, with_gauge;
  Pose base_move = Pose::Identity();
};

MovedChain movedChain(const std::string& xml, const std::string& source, const UrdfImport& u, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto signedIn = [&](double lo, double hi) { return (u01(rng) < 0.5 ? -1 : 1) * (lo + (hi - lo) * u01(rng)); };
  auto small = [&] {
    return poseFromXyzRpy(signedIn(1e-4, 5e-4), signedIn(1e-4, 5e-4), signedIn(1e-4, 5e-4),
                          degToRad(signedIn(0.01, 0.05)), degToRad(signedIn(0.01, 0.05)), degToRad(signedIn(0.01, 0.05)));
  };
  const RobotModel& m = u.model;
  Eigen::VectorXd p = m.nominal;
  const std::vector<int> base_side = {m.jointParam(0, JointParam::kThetaOffset), m.jointParam(0, JointParam::kD)};
  for (int i : m.canonicalParams())
    if (i < 5 * m.numJoints() && std::find(base_side.begin(), base_side.end(), i) == base_side.end())
      p[i] += m.isLength(i) ? signedIn(1e-4, 5e-4) : degToRad(signedIn(0.01, 0.05));
  MovedChain out;
  out.identifiable = exportUrdf(xml, source, u, p, small());
  // The gauge: the first revolute joint's origin O becomes D O G, G along and about its axis (in its own frame).
  TiXmlDocument doc;
  doc.Parse(out.identifiable.c_str());
  std::map<std::string, TiXmlElement*> joints;
  for (TiXmlElement* e = doc.RootElement()->FirstChildElement("joint"); e; e = e->NextSiblingElement("joint"))
    joints[e->Attribute("name")] = e;
  const size_t first = static_cast<size_t>(u.revolute.front());
  TiXmlElement* j1 = joints.at(u.chain_joints[first]);
  Eigen::Vector3d axis(1, 0, 0);
  if (TiXmlElement* a = j1->FirstChildElement("axis")) std::sscanf(a->Attribute("xyz"), "%lf %lf %lf", &axis[0], &axis[1], &axis[2]);
  axis.normalize();
  auto originOf = [](TiXmlElement* e) {
    double xyz[3] = {0, 0, 0}, rpy[3] = {0, 0, 0};
    if (TiXmlElement* o = e->FirstChildElement("origin")) {
      if (const char* a = o->Attribute("xyz")) std::sscanf(a, "%lf %lf %lf", &xyz[0], &xyz[1], &xyz[2]);
      if (const char* a = o->Attribute("rpy")) std::sscanf(a, "%lf %lf %lf", &rpy[0], &rpy[1], &rpy[2]);
    }
    return poseFromXyzRpy(xyz[0], xyz[1], xyz[2], rpy[0], rpy[1], rpy[2]);
  };
  Pose before = Pose::Identity();  // base_link -> the first revolute joint's parent link
  for (size_t k = 0; k < first; ++k) before = before * originOf(joints.at(u.chain_joints[k]));
  const Pose O = originOf(j1), D = small();
  Pose G = Pose::Identity();
  G.linear() = expSO3(axis * degToRad(signedIn(0.01, 0.05)));
  G.translation() = axis * signedIn(1e-4, 5e-4);
  const Pose moved = D * O * G;
  const Eigen::Matrix<double, 6, 1> v = xyzRpyFromPose(moved);
  TiXmlElement* o = j1->FirstChildElement("origin");
  if (!o) o = j1->InsertEndChild(TiXmlElement("origin"))->ToElement();
  char buf[200];
  std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g", v[0], v[1], v[2]);
  o->SetAttribute("xyz", buf);
  std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g", v[3], v[4], v[5]);
  o->SetAttribute("rpy", buf);
  out.base_move = before * moved * O.inverse() * before.inverse();
  TiXmlPrinter printer;
  doc.Accept(&printer);
  out.with_gauge = printer.CStr();
  return out;
}

// What the data cannot see stays at nominal in an export, on the eleven arms through KDL: a true arm moved only in
// what the data tell from the base and the target (movedChain), measured at a random tracker placement with a target
// beside the flange (points or 6D), calibrated from its nominal URDF (registration, Gauss-Newton) and exported with
// the target's nominal place: KDL's base_link -> tool0 on the exported file is the true arm's, with no rigid re-fit,
// within a few times the readings' noise. The same arm with joint 1's origin moved anywhere and the next joint along
// and about joint 1's axis (what no data tell from the base) exports the same chain, and the calibrated base carries
// the move.
TEST(Urdf, AnExportMovesTool0OnlyByWhatTheDataTellFromTheBase) {
  const auto files = arms();
  if (files.empty()) GTEST_SKIP() << kArms << " missing";
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  for (int draw = 0; draw < 4; ++draw) {
    const fs::path f = files[rng() % files.size()];
    const bool six_d = rng() % 2 == 0;
    SCOPED_TRACE(f.filename().string() + (six_d ? ", 6D" : ", points"));
    const std::string xml = readText(f);
    const UrdfImport u = importUrdf(xml, f.string());
    const RobotModel& m = u.model;
    const MovedChain truth = movedChain(xml, f.string(), u, rng);
    const KdlChain identifiable(truth.identifiable, u.base_link, u.tip_link);
    const auto [base, target] = randomPlacement(rng);
    const double sp = 0.01e-3, so = degToRad(0.001);
    auto config = [&] { return innerConfiguration(m, rng); };
    std::vector<Eigen::VectorXd> qs;
    for (int k = 0; k < 80; ++k) qs.push_back(config());
    double noise_mean = 0;
    std::vector<Eigen::Vector3d> noise;
    std::vector<Eigen::Vector3d> turn;
    for (size_t k = 0; k < qs.size(); ++k) {
      noise.push_back(sp * Eigen::Vector3d(g(rng), g(rng), g(rng)));
      turn.push_back(so * Eigen::Vector3d(g(rng), g(rng), g(rng)));
      noise_mean += noise.back().norm() / static_cast<double>(qs.size());
    }
    Pose exported_base[2];
    for (int with_gauge = 0; with_gauge < 2; ++with_gauge) {
      SCOPED_TRACE(with_gauge ? "joint 1 moved too" : "identifiable moves only");
      const KdlChain truth_chain(with_gauge ? truth.with_gauge : truth.identifiable, u.base_link, u.tip_link);
      std::vector<Observation> ident;
      for (size_t k = 0; k < qs.size(); ++k) {  // the same readings' noise for both arms
        Observation o;
        o.q_rad = qs[k];
        o.kind = six_d ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
        o.sigma_position_m = sp;
        o.sigma_orientation_rad = so;
        const Pose T = base * truth_chain.at(qs[k]) * target;
        o.measured_in_tracker = T;
        o.measured_in_tracker.translation() += noise[k];
        o.measured_in_tracker.linear() = expSO3(turn[k]) * T.linear();
        ident.push_back(o);
      }
      const RegistrationResult reg = registerFrames(m, m.nominal, ident);
      const CalibrationResult r = solveGaussNewton(CalibrationProblem{&m, reg.params, ident, std::nullopt, {}, {}});
      EXPECT_TRUE(r.converged) << r.message;
      const Pose tool_cal = frameAt(r.params, m.toolParam(FrameParam::kX));
      exported_base[with_gauge] = frameAt(r.params, m.baseParam(FrameParam::kX));
      const KdlChain exported(exportUrdf(xml, f.string(), u, r.params, tool_cal * target.inverse()), u.base_link,
                              u.tip_link);
      const KdlChain nominal(xml, u.base_link, u.tip_link);
      double mean = 0, worst = 0, worst_deg = 0, nominal_mean = 0;
      const int n = 100;
      for (int k = 0; k < n; ++k) {
        const Eigen::VectorXd q = config();
        // 6D: tool0 itself; points: the target (the tool frame's turn is not seen, so neither is tool0's place).
        const Pose seen = six_d ? Pose::Identity() : target;
        const Pose e = exported.at(q) * seen, t = identifiable.at(q) * seen;
        const double d = (e.translation() - t.translation()).norm();
        mean += d / n;
        worst = std::max(worst, d);
        if (six_d) worst_deg = std::max(worst_deg, radToDeg(logSO3(e.linear().transpose() * t.linear()).norm()));
        nominal_mean += ((nominal.at(q) * seen).translation() - t.translation()).norm() / n;
      }
      std::printf("  %-22s %-6s %-17s KDL base_link -> %s on the export against the true arm's: %.4f mm mean (max "
                  "%.4f, %.5f deg; the nominal URDF %.4f mm; readings' noise %.4f mm)\n",
                  f.filename().c_str(), six_d ? "6D" : "points", with_gauge ? "joint 1 moved too" : "identifiable only",
                  six_d ? "tool0" : "the target", mean * 1e3, worst * 1e3, worst_deg, nominal_mean * 1e3,
                  noise_mean * 1e3);
      EXPECT_LT(mean, noise_mean);
      EXPECT_LT(worst_deg, 0.002);
      EXPECT_GT(nominal_mean, 10 * noise_mean);  // the arm did move, far above the noise
    }
    // The base carries what no data tell from it: the calibrated base moved by the chain's move.
    const Pose expected = exported_base[0] * truth.base_move;
    const double dp = (exported_base[1].translation() - expected.translation()).norm();
    const double dr = logSO3(exported_base[1].linear().transpose() * expected.linear()).norm();
    const double moved_p = truth.base_move.translation().norm(), moved_r = logSO3(truth.base_move.linear()).norm();
    std::printf("  the base carries the move of %.4f mm and %.4f deg to %.5f mm and %.5f deg\n", moved_p * 1e3,
                radToDeg(moved_r), dp * 1e3, radToDeg(dr));
    EXPECT_LT(dp, 0.1 * moved_p);
    EXPECT_LT(dr, 0.1 * moved_r);
  }
}

// `robot check` (controller_check.hpp) against KDL: a controller that loaded a URDF reports its tool pose at its joints
// (KDL base_link -> tip of that URDF, rounded to 1 um and 1e-9 of its quaternion as a controller prints it). A random
// arm of the eleven, calibrated through its URDF and exported (exportUrdf, the tip as the chain puts it): a controller
// running the exported file matches the calibrated model and not the nominal one, a controller running the nominal
// URDF the other way round. Where they differ, the parameters fitted to the controller's poses explain them (what
// they leave is under the rounding) and the largest named is the calibration's own change of it, to 1 %.
TEST(Urdf, ControllerCheckTellsWhichUrdfAControllerRuns) {
  const auto files = arms();
  if (files.empty()) GTEST_SKIP() << kArms << " missing";
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g(0.0, 1.0);
  for (int draw = 0; draw < 4; ++draw) {
    const fs::path f = files[rng() % files.size()];
    SCOPED_TRACE(f.filename().string());
    const std::string xml = readText(f);
    const UrdfImport u = importUrdf(xml, f.string());
    const RobotModel& m = u.model;
    const KdlChain truth(perturbedOrigins(xml, u.chain_joints, rng), u.base_link, u.tip_link);
    const auto [base, target] = randomPlacement(rng);
    std::vector<Observation> ident;
    for (int k = 0; k < 80; ++k) {
      Observation o;
      o.q_rad = innerConfiguration(m, rng);
      o.kind = MeasurementKind::kPose6D;
      o.sigma_position_m = 0.01e-3;
      o.sigma_orientation_rad = degToRad(0.001);
      o.measured_in_tracker = base * truth.at(o.q_rad) * target;
      o.measured_in_tracker.translation() += o.sigma_position_m * Eigen::Vector3d(g(rng), g(rng), g(rng));
      ident.push_back(o);
    }
    const CalibrationResult r =
        solveGaussNewton(CalibrationProblem{&m, registerFrames(m, m.nominal, ident).params, ident, std::nullopt, {}, {}});
    ASSERT_TRUE(r.converged) << r.message;
    const std::string exported = exportUrdf(xml, f.string(), u, r.params, Pose::Identity());
    const KdlChain controllers[2] = {KdlChain(exported, u.base_link, u.tip_link), KdlChain(xml, u.base_link, u.tip_link)};
    const Eigen::VectorXd models[2] = {r.params, m.nominal};
    std::vector<Eigen::VectorXd> qs;
    for (int k = 0; k < 40; ++k) qs.push_back(innerConfiguration(m, rng));
    for (int c = 0; c < 2; ++c) {
      std::vector<Observation> readings;
      for (const auto& q : qs) {
        Observation o;
        o.q_rad = q;
        o.kind = MeasurementKind::kPose6D;
        const Pose T = controllers[c].at(q);
        Eigen::Quaterniond qt(T.linear());
        for (int i = 0; i < 4; ++i) qt.coeffs()[i] = std::round(qt.coeffs()[i] * 1e9) / 1e9;
        o.measured_in_tracker = Pose::Identity();
        o.measured_in_tracker.linear() = qt.normalized().toRotationMatrix();
        for (int i = 0; i < 3; ++i) o.measured_in_tracker.translation()[i] = std::round(T.translation()[i] * 1e6) / 1e6;
        readings.push_back(o);
      }
      for (int k = 0; k < 2; ++k) {
        const ControllerCheck check = checkController(m, models[k], readings, ControllerCheckOptions{});
        SCOPED_TRACE(std::string(c == 0 ? "controller on the export" : "controller on the nominal URDF") +
                     (k == 0 ? ", the calibrated model" : ", the nominal model"));
        EXPECT_EQ(check.matches, c == k) << "max " << check.max_mm << " mm, " << check.max_deg << " deg";
        if (c == k) {
          EXPECT_LT(check.max_mm, 1e-3);
          continue;
        }
        EXPECT_GT(check.max_mm, 0.05);
        ASSERT_FALSE(check.explained_by.empty());
        EXPECT_LT(check.left_mean_mm, 2e-3);
        const auto [param, change] = check.explained_by.front();
        const double calibrated = models[c][param] - models[k][param];
        std::printf("  %-22s %s: %.4f mm mean, named first %s %+.6g (the calibration's %+.6g), %.5f mm left\n",
                    f.filename().c_str(), c == 0 ? "export vs nominal model" : "nominal URDF vs calibrated model",
                    check.mean_mm, m.paramName(param).c_str(), change, calibrated, check.left_mean_mm);
        EXPECT_NEAR(change, calibrated, 0.01 * std::abs(calibrated)) << m.paramName(param);
      }
    }
  }
}

// Universal Robots' kinematics YAML, composed the way ur_description composes it (a plain reference written from its
// xacro: base_link -> base_link_inertia turned by pi about z, each joint's origin from its kinematics entry then the
// joint's turn about z, wrist_3 -> flange and flange -> tool0 fixed): the calibrated model's poses to 1e-9 m when the
// calibration moved joint 6 only about and along its axis; more than that (its a and alpha) is said, not carried.
TEST(Urdf, AUrKinematicsFileComposesAsUrDescriptionDoesToTheCalibratedModel) {
  const fs::path f = kArms / "universal_robots" / (std::mt19937_64(test::testSeed())() % 2 ? "ur10.urdf" : "ur5.urdf");
  if (!fs::exists(f)) GTEST_SKIP() << f << " missing";
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  auto signedIn = [&](double lo, double hi) { return (u01(rng) < 0.5 ? -1 : 1) * (lo + (hi - lo) * u01(rng)); };
  const std::string xml = readText(f);
  const UrdfImport u = importUrdf(xml, f.string());
  const RobotModel& m = u.model;
  Eigen::VectorXd p = m.nominal;
  for (int i : m.canonicalParams()) {
    if (i >= 5 * m.numJoints()) continue;
    const bool flange_side = i / 5 == 5 && (i % 5 == 2 || i % 5 == 3);  // joint 6's a and alpha
    if (!flange_side) p[i] += m.isLength(i) ? signedIn(1e-4, 5e-4) : degToRad(signedIn(0.01, 0.05));
  }
  auto compose = [&](const std::string& yaml, const Eigen::VectorXd& q) {
    const YAML::Node k = YAML::Load(yaml)["kinematics"];
    Pose T = poseFromXyzRpy(0, 0, 0, 0, 0, kPi);
    const char* names[] = {"shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3"};
    for (int j = 0; j < 6; ++j) {
      const YAML::Node e = k[names[j]];
      T = T * poseFromXyzRpy(e["x"].as<double>(), e["y"].as<double>(), e["z"].as<double>(), e["roll"].as<double>(),
                             e["pitch"].as<double>(), e["yaw"].as<double>());
      T.linear() = T.linear() * Eigen::AngleAxisd(q[j], Eigen::Vector3d::UnitZ()).toRotationMatrix();
    }
    return T * poseFromXyzRpy(0, 0, 0, 0, -kPi / 2, -kPi / 2) * poseFromXyzRpy(0, 0, 0, kPi / 2, 0, kPi / 2);
  };
  double rest_m = 1, rest_rad = 1;
  const std::string yaml = exportUrKinematics(xml, f.string(), u, p, Pose::Identity(), "calib_123", &rest_m, &rest_rad);
  EXPECT_LT(rest_m, 1e-12);
  EXPECT_LT(rest_rad, 1e-12);
  EXPECT_EQ(YAML::Load(yaml)["kinematics"]["hash"].as<std::string>(), "calib_123");
  KinematicsData data(m);
  double worst = 0;
  for (int k = 0; k < 300; ++k) {
    const Eigen::VectorXd q = randomQ(m, rng);
    const auto [dp, dr] = difference(compose(yaml, q), forwardKinematics(m, data, p, q));
    worst = std::max({worst, dp, dr});
  }
  std::printf("  %s: the composed kinematics file against the calibrated model: worst %.2g (m or rad)\n",
              f.filename().c_str(), worst);
  EXPECT_LT(worst, 1e-9);
  // Joint 6's a and alpha moved too: not carried, said with its size, and what it does at the tip is the composed
  // file's tip against the calibrated one.
  p[m.jointParam(5, JointParam::kA)] += 3e-4;
  p[m.jointParam(5, JointParam::kAlpha)] += degToRad(0.02);
  Pose not_carried;
  const std::string lossy = exportUrKinematics(xml, f.string(), u, p, Pose::Identity(), "", &rest_m, &rest_rad,
                                               &not_carried);
  EXPECT_GT(rest_m, 1e-4);
  EXPECT_NEAR(radToDeg(rest_rad), 0.02, 1e-3);
  double worst_loss = 0, worst_rest = 0;
  for (int k = 0; k < 300; ++k) {
    const Eigen::VectorXd q = randomQ(m, rng);
    const Pose calibrated = forwardKinematics(m, data, p, q);
    const auto [dp, dr] = difference(compose(lossy, q), calibrated * not_carried);
    worst_loss = std::max({worst_loss, dp, dr});
    worst_rest = std::max(worst_rest, difference(compose(lossy, q), calibrated).first);
  }
  std::printf("  with joint 6's a and alpha moved: the composed file against the calibrated model times what is not "
              "carried: worst %.2g; against the calibrated model alone %.3g mm\n", worst_loss, worst_rest * 1e3);
  EXPECT_LT(worst_loss, 1e-9);
  EXPECT_NEAR(worst_rest, not_carried.translation().norm(), 1e-9);
  // Through write(), with a registered base and the target's nominal place given: writtenParams is the model of the
  // file as ur_description composes it, with the calibration's base and the target at its nominal place.
  const auto [base, target] = randomPlacement(rng);
  Eigen::VectorXd cal = p;
  cal.segment<6>(m.baseParam(FrameParam::kX)) = xyzRpyFromPose(base);
  cal.segment<6>(m.toolParam(FrameParam::kX)) = xyzRpyFromPose(target);
  ExportOptions o;
  o.nominal_urdf_xml = xml;
  o.nominal_urdf_source = f.string();
  const Pose target_nominal = target * poseFromXyzRpy(2e-4, -1e-4, 3e-4, degToRad(0.02), 0, degToRad(-0.01));
  o.target_in_flange = target_nominal;
  const RobotExport e = write(m, CalibratedModel::geometric(cal), ExportFormat::kUrKinematics, o);
  const Eigen::VectorXd w = writtenParams(m, cal, e, o);
  double worst_written = 0;
  for (int k = 0; k < 100; ++k) {
    const Eigen::VectorXd q = randomQ(m, rng);
    const auto [dp, dr] = difference(forwardKinematics(m, data, w, q), base * compose(e.text, q) * target_nominal);
    worst_written = std::max({worst_written, dp, dr});
  }
  std::printf("  the written file's own model against the file composed, in the calibration's frames: worst %.2g\n",
              worst_written);
  EXPECT_LT(worst_written, 1e-9);
}

std::string errorOf(const std::string& xml, const UrdfImportOptions& o = {}) {
  try {
    importUrdf(xml, "arm.urdf", o);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

// A small arm: `joints` revolute joints about z, x, y in turn, each 0.2 m up, and tool0.
std::string arm(int joints, const std::string& type3 = "revolute", const std::string& axis2 = "1 0 0") {
  std::ostringstream o;
  o << "<?xml version=\"1.0\"?>\n<robot name=\"arm\">\n  <link name=\"base_link\"/>\n";
  for (int k = 1; k <= joints; ++k) {
    o << "  <link name=\"l" << k << "\"/>\n";
    o << "  <joint name=\"j" << k << "\" type=\"" << (k == 3 ? type3 : "revolute") << "\">\n"
      << "    <parent link=\"" << (k == 1 ? "base_link" : "l" + std::to_string(k - 1)) << "\"/>\n"
      << "    <child link=\"l" << k << "\"/>\n    <origin xyz=\"0 0 0.2\" rpy=\"0 0 0\"/>\n"
      << "    <axis xyz=\"" << (k == 2 ? axis2 : k % 3 == 1 ? "0 0 1" : k % 3 == 2 ? "1 0 0" : "0 1 0") << "\"/>\n"
      << "    <limit lower=\"-3\" upper=\"3\" effort=\"1\" velocity=\"1\"/>\n  </joint>\n";
  }
  o << "  <link name=\"tool0\"/>\n  <joint name=\"flange\" type=\"fixed\">\n    <parent link=\"l" << joints
    << "\"/>\n    <child link=\"tool0\"/>\n    <origin xyz=\"0 0 0.1\" rpy=\"0 0 0\"/>\n  </joint>\n</robot>\n";
  return o.str();
}

TEST(Urdf, BadInputIsRefusedNamingTheFileAndTheElement) {
  EXPECT_EQ(errorOf(arm(6)), "");
  EXPECT_NE(errorOf(arm(6).substr(0, 300)).find("arm.urdf:"), std::string::npos);
  EXPECT_NE(errorOf(arm(6).substr(0, 300)).find("not well-formed XML"), std::string::npos);
  const std::string prismatic = errorOf(arm(6, "prismatic"));
  EXPECT_NE(prismatic.find("<joint name=\"j3\">"), std::string::npos) << prismatic;
  EXPECT_NE(prismatic.find("neither revolute nor fixed"), std::string::npos) << prismatic;
  EXPECT_NE(errorOf(arm(6, "continuous")).find("type continuous"), std::string::npos);
  const std::string zero = errorOf(arm(6, "revolute", "0 0 0"));
  EXPECT_NE(zero.find("<joint name=\"j2\">"), std::string::npos) << zero;
  EXPECT_NE(zero.find("<axis> is zero"), std::string::npos) << zero;
  EXPECT_NE(errorOf(arm(2)).find("has 2 revolute joints"), std::string::npos);
  EXPECT_NE(errorOf(arm(8)).find("has 8 revolute joints"), std::string::npos);
  UrdfImportOptions o;
  o.tip_link = "nope";
  EXPECT_NE(errorOf(arm(6), o).find("--tip-link nope: no such <link>"), std::string::npos);
  // A branch and no tool0: two leaves the revolute joints lead to.
  std::string branch = arm(6);
  branch.replace(branch.find("tool0"), 5, "flange_link");
  branch.replace(branch.find("\"tool0\""), 7, "\"flange_link\"");
  branch.insert(branch.find("</robot>"),
                "  <link name=\"side\"/>\n  <joint name=\"jside\" type=\"revolute\">\n    <parent link=\"l5\"/>\n"
                "    <child link=\"side\"/>\n    <axis xyz=\"0 0 1\"/>\n"
                "    <limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/>\n  </joint>\n");
  const std::string branched = errorOf(branch);
  EXPECT_NE(branched.find("the chain branches"), std::string::npos) << branched;
  EXPECT_NE(branched.find("--tip-link"), std::string::npos) << branched;
  // The line of the element is named.
  EXPECT_EQ(prismatic.rfind("arm.urdf:", 0), 0u) << prismatic;
  // Not a tree: a joint to a missing link, two roots, a link with two parents, a loop (each named, with its line).
  std::string missing = arm(6);
  missing.replace(missing.find("<child link=\"l4\""), 16, "<child link=\"l9\"");
  const std::string missed = errorOf(missing);
  EXPECT_NE(missed.find("<joint name=\"j4\">: <child link=\"l9\">: no such <link>"), std::string::npos) << missed;
  std::string two_roots = arm(6);
  two_roots.insert(two_roots.find("</robot>"), "  <link name=\"stray\"/>\n");
  EXPECT_NE(errorOf(two_roots).find("2 root links (base_link, stray)"), std::string::npos) << errorOf(two_roots);
  std::string two_parents = arm(6);
  two_parents.replace(two_parents.find("<child link=\"l5\""), 16, "<child link=\"l4\"");
  EXPECT_NE(errorOf(two_parents).find("is already the child of another joint"), std::string::npos) << errorOf(two_parents);
  std::string loop = arm(6);
  loop.replace(loop.find("<parent link=\"base_link\""), 24, "<parent link=\"l6\"");
  EXPECT_NE(errorOf(loop).find("loop"), std::string::npos) << errorOf(loop);
  // Not UTF-8 text, named by line and column before any XML parser reads it: a character cut short by the end (the
  // XML parser read past the text's end on such a file, found by Fuzz.Parsers), a stray byte, a NUL; UTF-8 passes.
  const std::string whole = arm(6);
  const size_t line3 = whole.find('\n', whole.find('\n') + 1) + 1;
  const std::string cut = errorOf(whole.substr(0, 300) + "\xD4");
  EXPECT_NE(cut.find("cut short by the end of the file"), std::string::npos) << cut;
  EXPECT_EQ(cut.rfind("arm.urdf:", 0), 0u) << cut;
  std::string latin1 = whole;
  latin1.insert(line3 + 4, "\xE9");  // a Latin-1 e-acute, 5th byte of line 3
  EXPECT_NE(errorOf(latin1).find("arm.urdf:3:5: byte 0xE9 is not UTF-8"), std::string::npos) << errorOf(latin1);
  std::string nul = whole;
  nul.insert(line3 + 1, std::string(1, '\0'));
  EXPECT_NE(errorOf(nul).find("arm.urdf:3:2: a NUL byte"), std::string::npos) << errorOf(nul);
  std::string accented = whole;  // UTF-8 in a comment: read as before
  accented.insert(line3, "<!-- \xC3\xA9paule \xE2\x80\x94 \xF0\x9F\xA4\x96 -->\n");
  EXPECT_EQ(errorOf(accented), "");
  // An export against another robot's URDF.
  const UrdfImport six = importUrdf(arm(6), "arm.urdf");
  std::string other = arm(6);
  for (auto at = other.find("\"j"); at != std::string::npos; at = other.find("\"j", at + 3)) other.replace(at, 2, "\"k");
  try {
    exportUrdf(other, "other.urdf", six, six.model.nominal, Pose::Identity());
    ADD_FAILURE() << "exported against another robot's URDF";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("<joint name=\"j1\">: not in this URDF"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace cellcal
