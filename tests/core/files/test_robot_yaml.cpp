#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

const char* kValid = R"(name: two_link
joints:
  - { theta_offset_deg: 0, d_mm: 100, a_mm: 0, alpha_deg: -90, beta_deg: 0, parallel_to_next: false, limits_deg: [-180, 180] }
  - { theta_offset_deg: 0, d_mm: 0, a_mm: 300, alpha_deg: 0, parallel_to_next: false, limits_deg: [-90, 90] }
base_in_tracker: { x_mm: 1000, y_mm: 0, z_mm: 0, roll_deg: 0, pitch_deg: 0, yaw_deg: 90 }
tool_in_flange:  { x_mm: 0, y_mm: 0, z_mm: 50, roll_deg: 0, pitch_deg: 0, yaw_deg: 0 }
)";

std::string errorOf(const std::string& text) {
  try {
    parseRobotModel(text, "<test>");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

std::string replace(std::string s, const std::string& from, const std::string& to) {
  const auto pos = s.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  return s.replace(pos, from.size(), to);
}

TEST(RobotYaml, ParsesUnitsIntoSi) {
  const RobotModel m = parseRobotModel(kValid, "<test>");
  EXPECT_EQ(m.name, "two_link");
  ASSERT_EQ(m.numJoints(), 2);
  EXPECT_DOUBLE_EQ(m.nominal[m.jointParam(0, JointParam::kD)], 0.1);
  EXPECT_DOUBLE_EQ(m.nominal[m.jointParam(1, JointParam::kA)], 0.3);
  EXPECT_NEAR(m.nominal[m.jointParam(0, JointParam::kAlpha)], -kPi / 2, 1e-15);
  EXPECT_NEAR(m.nominal[m.baseParam(FrameParam::kYaw)], kPi / 2, 1e-15);
  EXPECT_DOUBLE_EQ(m.nominal[m.toolParam(FrameParam::kZ)], 0.05);
  EXPECT_NEAR(m.limits[1].upper_rad, kPi / 2, 1e-15);
}

TEST(RobotYaml, ShippedTx60HasFlangeAtDatasheetPosition) {
  const RobotModel m = test::robot("staubli_tx60");
  ASSERT_EQ(m.numJoints(), 6);
  EXPECT_TRUE(m.parallel_to_next[1]);
  const Pose T = forwardKinematics(m, m.nominal, Eigen::VectorXd::Zero(6));
  EXPECT_NEAR(T.translation().x(), 0.0, 1e-12);
  EXPECT_NEAR(T.translation().y(), 0.020, 1e-12);
  EXPECT_NEAR(T.translation().z(), 0.670, 1e-12);
}

TEST(RobotYaml, ShippedUr10MatchesPublishedDh) {
  const RobotModel m = test::robot("ur10");
  ASSERT_EQ(m.numJoints(), 6);
  EXPECT_TRUE(m.parallel_to_next[1]);
  EXPECT_TRUE(m.parallel_to_next[2]);
  EXPECT_FALSE(m.parallel_to_next[3]);
  // UR10 at q = 0 (standard DH): flange at x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
  const Pose T = forwardKinematics(m, m.nominal, Eigen::VectorXd::Zero(6));
  EXPECT_NEAR(T.translation().x(), -1.1843, 1e-9);
  EXPECT_NEAR(T.translation().y(), -0.256141, 1e-9);
  EXPECT_NEAR(T.translation().z(), 0.0116, 1e-9);
}

TEST(RobotYaml, UnknownTopLevelKeyNamesKeyAndLine) {
  const std::string e = errorOf(replace(kValid, "base_in_tracker", "colour: red\nbase_in_tracker"));
  EXPECT_NE(e.find("<test>:5:"), std::string::npos) << e;
  EXPECT_NE(e.find("colour"), std::string::npos) << e;
  EXPECT_NE(e.find("unknown key"), std::string::npos) << e;
}

TEST(RobotYaml, UnknownJointKeyNamesFieldAndLine) {
  const std::string e = errorOf(replace(kValid, "a_mm: 300", "a_mm: 300, a_m: 0.3"));
  EXPECT_NE(e.find("<test>:4:"), std::string::npos) << e;
  EXPECT_NE(e.find("joints[1].a_m"), std::string::npos) << e;
}

// Found by tools/fuzz.sh: a list used as a key threw yaml-cpp's bare "bad conversion" without the file.
TEST(RobotYaml, AListAsAKeyIsAnErrorNamingFileAndLine) {
  const std::string e = errorOf(replace(kValid, "a_mm: 300", "a_mm: 300, [1, 2]"));
  EXPECT_NE(e.find("<test>:4:"), std::string::npos) << e;
  EXPECT_NE(e.find("plain key"), std::string::npos) << e;
}

TEST(RobotYaml, MetresInMillimetreFieldsAreCalledOut) {
  const std::string metres = replace(replace(kValid, "a_mm: 300", "a_mm: 0.3"), "d_mm: 100", "d_mm: 0.1");
  const std::string e = errorOf(metres);
  EXPECT_NE(e.find("metres written where millimetres are expected"), std::string::npos) << e << "\n" << metres;
}

// One length of a shipped robot's drawing written in metres (a nonzero a or d drawn at random, divided by 1000), or one
// right angle written in radians, is refused naming the joint's field and its line; the drawing itself loads.
TEST(RobotYaml, OneLengthInMetresOrOneAngleInRadiansIsCalledOut) {
  std::mt19937_64 rng(test::testSeed());
  for (const char* name : {"staubli_tx60", "ur10"}) {
    const RobotModel m = test::robot(name);
    EXPECT_EQ(errorOf(robotFileText(m, nullptr, "")), "");
    std::vector<int> lengths, right_angles;
    for (int j = 0; j < m.numJoints(); ++j) {
      for (JointParam p : {JointParam::kD, JointParam::kA})
        if (m.nominal[m.jointParam(j, p)] != 0) lengths.push_back(m.jointParam(j, p));
      if (std::abs(m.nominal[m.jointParam(j, JointParam::kAlpha)]) > 1) right_angles.push_back(m.jointParam(j, JointParam::kAlpha));
    }
    ASSERT_FALSE(lengths.empty());
    ASSERT_FALSE(right_angles.empty());
    const int i = lengths[rng() % lengths.size()], k = right_angles[rng() % right_angles.size()];
    const int joint = i / 5;
    RobotModel metres = m;
    metres.nominal[i] /= 1000;
    const std::string e = errorOf(robotFileText(metres, nullptr, ""));
    const std::string field = "joints[" + std::to_string(joint) + "]." + (m.isLength(i) && i % 5 == 1 ? "d_mm" : "a_mm");
    EXPECT_NE(e.find("<test>:" + std::to_string(3 + joint) + ":"), std::string::npos) << e;
    EXPECT_NE(e.find(field + ": "), std::string::npos) << e;
    EXPECT_NE(e.find("metres written where millimetres are expected"), std::string::npos) << e;
    RobotModel radians = m;
    radians.nominal[k] = degToRad(radians.nominal[k]);  // 90 deg written as 1.5708
    const std::string r = errorOf(robotFileText(radians, nullptr, ""));
    EXPECT_NE(r.find("joints[" + std::to_string(k / 5) + "].alpha_deg: "), std::string::npos) << r;
    EXPECT_NE(r.find("written in radians"), std::string::npos) << r;
  }
}

TEST(RobotYaml, MissingKeyIsNamed) {
  const std::string e = errorOf(replace(kValid, "d_mm: 0, a_mm: 300", "a_mm: 300"));
  EXPECT_NE(e.find("joints[1].d_mm"), std::string::npos) << e;
  EXPECT_NE(e.find("missing"), std::string::npos) << e;
  EXPECT_NE(errorOf(replace(kValid, "name: two_link\n", "")).find("name"), std::string::npos);
}

TEST(RobotYaml, WrongTypesAndNonFiniteValuesAreRejected) {
  EXPECT_NE(errorOf(replace(kValid, "a_mm: 300", "a_mm: abc")).find("joints[1].a_mm: expected a number"),
            std::string::npos);
  EXPECT_NE(errorOf(replace(kValid, "a_mm: 300", "a_mm: .nan")).find("must be finite"), std::string::npos);
  EXPECT_NE(errorOf(replace(kValid, "parallel_to_next: false, limits_deg: [-90", "parallel_to_next: maybe, limits_deg: [-90"))
                .find("parallel_to_next"),
            std::string::npos);
  EXPECT_NE(errorOf(replace(kValid, "[-90, 90]", "[90, -90]")).find("lower < upper"), std::string::npos);
  EXPECT_NE(errorOf(replace(kValid, "[-90, 90]", "[-90]")).find("limits_deg"), std::string::npos);
}

TEST(RobotYaml, ParallelJointMustUseBetaNotD) {
  const std::string three = replace(kValid, "  - { theta_offset_deg: 0, d_mm: 0, a_mm: 300",
                                    "  - { theta_offset_deg: 0, d_mm: 5, a_mm: 300, alpha_deg: 0, parallel_to_next: "
                                    "true, limits_deg: [-90, 90] }\n  - { theta_offset_deg: 0, d_mm: 0, a_mm: 300");
  const std::string e = errorOf(three);
  EXPECT_NE(e.find("joints[1].d_mm"), std::string::npos) << e;
  EXPECT_NE(e.find("parallel_to_next"), std::string::npos) << e;
  EXPECT_NE(errorOf(replace(kValid, "beta_deg: 0, parallel_to_next: false", "beta_deg: 1, parallel_to_next: false"))
                .find("beta"),
            std::string::npos);
}

TEST(RobotYaml, DuplicatedKeyAndSyntaxErrorsAreReported) {
  const std::string dup = errorOf(replace(kValid, "name: two_link", "name: two_link\nname: other"));
  EXPECT_FALSE(dup.empty());
  const std::string syn = errorOf(replace(kValid, "joints:", "joints: [\n"));
  EXPECT_NE(syn.find("<test>:"), std::string::npos) << syn;
}

TEST(RobotYaml, MissingOrEmptyFileIsAClearError) {
  try {
    loadRobotModel("/nonexistent/robot.yaml");
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/robot.yaml"), std::string::npos);
  }
  EXPECT_NE(errorOf("").find("<test>"), std::string::npos);
}

// A file that cannot be a robot or cell file is refused by name without reading it all: larger than 1 MiB (a valid
// file padded with comments to a random size), or a device that never ends (/dev/zero).
TEST(RobotYaml, HugeFilesAndEndlessDevicesAreRefused) {
  std::mt19937_64 rng(test::testSeed());
  const std::string dir = ::testing::TempDir();
  const std::string big = dir + "/big_robot.yaml";
  {
    std::ofstream out(big);
    out << kValid;
    const std::size_t pad = (1u << 20) + std::uniform_int_distribution<std::size_t>(1, 50u << 20)(rng);
    const std::string line = "# " + std::string(77, 'x') + "\n";
    for (std::size_t n = 0; n < pad; n += line.size()) out << line;
  }
  for (const std::string& path : {big, std::string("/dev/zero")}) {
    try {
      loadRobotModel(path);
      ADD_FAILURE() << path << " was accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(path + ": more than 1 MiB"), std::string::npos) << e.what();
    }
    try {
      loadCellConfig(path);
      ADD_FAILURE() << path << " was accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(path + ": more than 1 MiB; a cell file"), std::string::npos) << e.what();
    }
  }
  std::filesystem::remove(big);
}

TEST(RobotYaml, LinksNeedOneEntryPerJoint) {
  const std::string e = errorOf(std::string(kValid) + "links:\n  - { mass_kg: 1, com_mm: [0, 0, 0] }\n");
  EXPECT_NE(e.find("links"), std::string::npos) << e;
  const RobotModel m = parseRobotModel(std::string(kValid) + "links:\n  - { mass_kg: 1, com_mm: [0, 0, 10] }\n"
                                       "  - { mass_kg: 2, com_mm: [-150, 0, 0] }\n", "<test>");
  ASSERT_EQ(m.links.size(), 2u);
  EXPECT_DOUBLE_EQ(m.links[1].com_m.x(), -0.15);
}

}  // namespace
}  // namespace cellcal
