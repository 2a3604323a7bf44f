// The cell file (docs/cell-file.md): the shipped cells load, errors name line and field, units and extensions are
// checked.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include <random>

#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;
const std::string kCell = std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml";

TEST(CellFile, ShippedCellLoadsWithItsRobotAndRegistration) {
  const CellConfig c = loadCellConfig(kCell);
  ASSERT_EQ(c.robots.size(), 1u);
  const CellRobot& r = c.robots[0];
  EXPECT_EQ(r.robot_id, "tx60");
  EXPECT_EQ(r.model.name, "staubli_tx60");
  EXPECT_NEAR(r.model.nominal[r.model.baseParam(FrameParam::kX)], 2.2, 1e-12);  // from the cell, not the robot file
  EXPECT_NEAR(r.model.nominal[r.model.toolParam(FrameParam::kZ)], 0.06, 1e-12);
  EXPECT_TRUE(fs::path(c.dds.profiles_file).is_absolute());
  EXPECT_TRUE(fs::exists(c.dds.profiles_file)) << c.dds.profiles_file;
  EXPECT_NEAR(c.engine.max_pairing_skew_s, 0.05, 1e-12);
  EXPECT_NEAR(c.compensation.max_correction_m, 5e-3, 1e-12);
}

TEST(CellFile, ExampleCellsLoad) {
  int n = 0;
  for (const auto& f : fs::directory_iterator(std::string(CELLCAL_CONFIG_DIR) + "/examples")) {
    if (f.path().extension() != ".yaml") continue;  // the example's robot program (CSV) beside them
    const CellConfig c = loadCellConfig(f.path().string());
    EXPECT_FALSE(c.robots.empty()) << f.path();
    ++n;
  }
  EXPECT_GE(n, 2);
}

std::string errorOf(const std::string& yaml) {
  try {
    parseCellConfig(yaml, "cell.yaml", CELLCAL_CONFIG_DIR);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

TEST(CellFile, ErrorsNameLineAndField) {
  const std::string robot = "robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml }\n";
  EXPECT_EQ(errorOf(robot + "engine:\n  mode: sometimes\n"),
            "cell.yaml:4:9: engine.mode: expected continuous or periodic, got 'sometimes'");
  EXPECT_NE(errorOf(robot + "engine:\n  max_skew_ms: 3\n").find("cell.yaml:4:3: engine.max_skew_ms: unknown key"),
            std::string::npos);
  EXPECT_NE(errorOf(robot + "dds: { domain_id: 300 }\n").find("dds.domain_id: must be in [0, 232]"), std::string::npos);
  EXPECT_NE(errorOf("robots:\n  - { robot_id: a, target_id: t, robot_file: robots/nope.yaml }\n")
                .find("robots[0].robot_file: "),
            std::string::npos);
  EXPECT_NE(errorOf(robot + "  - { robot_id: a, target_id: u, robot_file: robots/ur10.yaml }\n").find("used twice"),
            std::string::npos);
  EXPECT_NE(errorOf(robot + "compensation: { max_correction_mm: -1 }\n").find("compensation.max_correction_mm: must be > "),
            std::string::npos);
  EXPECT_NE(errorOf("dds: {}\n").find("missing required key 'robots'"), std::string::npos);
  // calibration_file: a calibrated robot file of the same robot, not a plain robot file nor another robot's.
  EXPECT_NE(errorOf("robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml,\n"
                    "      calibration_file: robots/ur10.yaml }\n")
                .find("cell.yaml:3:25: robots[0].calibration_file: " + std::string(CELLCAL_CONFIG_DIR) +
                      "/robots/ur10.yaml has no calibration section"),
            std::string::npos)
      << errorOf("robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml,\n"
                 "      calibration_file: robots/ur10.yaml }\n");
  EXPECT_NE(errorOf("robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml, calibration_file: "
                    "robots/none.yaml }\n")
                .find("robots[0].calibration_file: "),
            std::string::npos);
}

// calibration_file of another robot with the same joint layout (a UR10's calibration in a TX60's cell) is refused,
// naming the robots; so is one whose joints lie further from robot_file's drawing than a calibration moves them.
// A calibration of the robot itself (its joints moved by up to 1 mm and 0.1 deg) loads.
TEST(CellFile, ACalibrationFileOfAnotherRobotIsRefused) {
  const std::uint64_t seed = test::testSeed();
  const fs::path dir = fs::temp_directory_path() / ("cellcal_cellfile_" + std::to_string(seed));
  fs::create_directories(dir);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto calibrated = [&](const RobotModel& m, const std::string& file) {
    RobotCalibration cal;
    cal.provenance = {{"date_utc", "2026-11-30T08:00:00Z"}};
    saveRobotFile((dir / file).string(), m, &cal, "test");
    return (dir / file).string();
  };
  auto cell = [](const std::string& robot_file, const std::string& calibration_file) {
    return "robots:\n  - { robot_id: a, target_id: t, robot_file: " + robot_file + ",\n      calibration_file: " +
           calibration_file + " }\n";
  };
  const RobotModel ur10 = test::robot("ur10"), tx60 = test::robot("staubli_tx60");
  const std::string other = errorOf(cell("robots/staubli_tx60.yaml", calibrated(ur10, "ur10_cal.yaml")));
  EXPECT_NE(other.find("robots[0].calibration_file: "), std::string::npos) << other;
  EXPECT_NE(other.find("is not a calibration of robot_file"), std::string::npos) << other;
  EXPECT_NE(other.find("its robot is 'ur10', robot_file's 'staubli_tx60'"), std::string::npos) << other;
  RobotModel near = tx60, far = tx60;
  for (int j = 0; j < tx60.numJoints(); ++j) {
    near.nominal[tx60.jointParam(j, JointParam::kA)] += 1e-3 * u(rng);
    near.nominal[tx60.jointParam(j, JointParam::kThetaOffset)] += 0.1 * kPi / 180 * u(rng);
  }
  const int moved = tx60.jointParam(static_cast<int>(rng() % 6), JointParam::kA);
  far.nominal[moved] += (u(rng) < 0 ? -1 : 1) * 0.05;
  EXPECT_EQ(errorOf(cell("robots/staubli_tx60.yaml", calibrated(near, "near.yaml"))), "");
  const std::string far_why = errorOf(cell("robots/staubli_tx60.yaml", calibrated(far, "far.yaml")));
  EXPECT_NE(far_why.find("its " + tx60.paramNameHuman(moved) + " is "), std::string::npos) << far_why;
  fs::remove_all(dir);
}

// A registration drawn at random (tracker 0.5-5 m from the base, target 10-300 mm off the flange, any rotation) loads;
// the same numbers in metres in the _mm fields are refused naming the field and line. A base aligned with the tracker
// frame (within 1 mm, no rotation) and a tool not known yet (0) load.
TEST(CellFile, MetresInTheRegistrationAreCalledOut) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Vector3d rpy_deg;
  auto frame = [&](const Eigen::Vector3d& p_mm) {
    std::ostringstream o;
    o << std::setprecision(10) << "{ x_mm: " << p_mm.x() << ", y_mm: " << p_mm.y() << ", z_mm: " << p_mm.z()
      << ", roll_deg: " << rpy_deg.x() << ", pitch_deg: " << rpy_deg.y() << ", yaw_deg: " << rpy_deg.z() << " }";
    return o.str();
  };
  auto cell = [&](const Eigen::Vector3d& base_mm, const Eigen::Vector3d& tool_mm) {
    return "robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml,\n      base_in_tracker: " +
           frame(base_mm) + ",\n      tool_in_flange: " + frame(tool_mm) + " }\n";
  };
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d dir_b = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
    const Eigen::Vector3d dir_t = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
    const Eigen::Vector3d base_mm = dir_b * (500 + 4500 * (0.5 + 0.5 * u(rng)));
    const Eigen::Vector3d tool_mm = dir_t * (10 + 290 * (0.5 + 0.5 * u(rng)));
    rpy_deg = Eigen::Vector3d(180 * u(rng), 90 * u(rng), 180 * u(rng));
    EXPECT_EQ(errorOf(cell(base_mm, tool_mm)), "") << base_mm.transpose() << " / " << tool_mm.transpose();
    const std::string base_err = errorOf(cell(base_mm / 1000, tool_mm));
    EXPECT_NE(base_err.find("cell.yaml:3:24: robots[0].base_in_tracker: "), std::string::npos) << base_err;
    EXPECT_NE(base_err.find("metres written where millimetres are expected"), std::string::npos) << base_err;
    const std::string tool_err = errorOf(cell(base_mm, tool_mm / 1000));
    EXPECT_NE(tool_err.find("cell.yaml:4:23: robots[0].tool_in_flange: "), std::string::npos) << tool_err;
    EXPECT_EQ(errorOf(cell(base_mm, Eigen::Vector3d::Zero())), "");  // tool not known yet
    rpy_deg = Eigen::Vector3d(0.5 * u(rng), 0.5 * u(rng), 0.5 * u(rng));
    EXPECT_EQ(errorOf(cell(dir_b * 0.5 * (0.5 + 0.5 * u(rng)), tool_mm)), "");  // tracker frame aligned to the base
  }
}

// The ROS 2 joint names (docs/ros2.md): one per joint of the robot file, none empty or twice, each fault named with
// its line and field.
TEST(CellFile, Ros2JointNamesAreOnePerJoint) {
  auto cell = [](const std::string& names) {
    return "robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml,\n      ros2_joint_names: " + names +
           " }\n";
  };
  const std::string ur = "[shoulder_pan_joint, shoulder_lift_joint, elbow_joint, wrist_1_joint, wrist_2_joint, wrist_3_joint]";
  const CellConfig ok = parseCellConfig(cell(ur), "cell.yaml", CELLCAL_CONFIG_DIR);
  ASSERT_EQ(ok.robots[0].ros2_joint_names.size(), 6u);
  EXPECT_EQ(ok.robots[0].ros2_joint_names[2], "elbow_joint");
  EXPECT_TRUE(parseCellConfig("robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml }\n", "cell.yaml",
                              CELLCAL_CONFIG_DIR)
                  .robots[0]
                  .ros2_joint_names.empty());
  EXPECT_NE(errorOf(cell("[a, b, c]")).find("cell.yaml:3:25: robots[0].ros2_joint_names: expected a list of 6 joint names"),
            std::string::npos)
      << errorOf(cell("[a, b, c]"));
  EXPECT_NE(errorOf(cell("[a, b, c, d, e, a]")).find("robots[0].ros2_joint_names[5]: 'a' named twice"),
            std::string::npos);
  EXPECT_NE(errorOf(cell("[a, b, c, d, e, '']")).find("robots[0].ros2_joint_names[5]: expected a non-empty string"),
            std::string::npos);
  EXPECT_NE(errorOf(cell("elbow_joint")).find("robots[0].ros2_joint_names"), std::string::npos);
}

// dds.discovery: static peers or a Discovery Server, each fault named with its field.
TEST(CellFile, DiscoveryWithoutMulticastIsChecked) {
  const std::string robot = "robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml }\n";
  auto cell = [&](const std::string& d) { return "dds: { discovery: " + d + " }\n" + robot; };
  const CellConfig peers = parseCellConfig(cell("{ peers: [10.0.0.1, 192.168.1.20] }"), "cell.yaml", CELLCAL_CONFIG_DIR);
  EXPECT_EQ(peers.dds.discovery_peers, (std::vector<std::string>{"10.0.0.1", "192.168.1.20"}));
  EXPECT_EQ(peers.dds.discovery_server_port, 0);
  const CellConfig server =
      parseCellConfig(cell("{ server: \"10.0.0.3:11811\", server_id: 2 }"), "cell.yaml", CELLCAL_CONFIG_DIR);
  EXPECT_EQ(server.dds.discovery_server_address, "10.0.0.3");
  EXPECT_EQ(server.dds.discovery_server_port, 11811);
  EXPECT_EQ(server.dds.discovery_server_id, 2);
  EXPECT_TRUE(parseCellConfig(robot, "cell.yaml", CELLCAL_CONFIG_DIR).dds.discovery_peers.empty());
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"{ peers: [10.0.0] }", "dds.discovery.peers[0]: expected an IPv4 address"},
      {"{ peers: [10.0.0.256] }", "dds.discovery.peers[0]: expected an IPv4 address"},
      {"{ peers: [] }", "dds.discovery.peers: expected a non-empty list"},
      {"{ server: 10.0.0.3 }", "dds.discovery.server: expected address:port"},
      {"{ server: \"10.0.0.3:0\" }", "dds.discovery.server: port '0' not in 1..65535"},
      {"{ server: \"10.0.0.3:11811\", server_id: 300 }", "dds.discovery.server_id: "},
      {"{ server_id: 1 }", "dds.discovery.server_id: only with server"},
      {"{ peers: [10.0.0.1], server: \"10.0.0.3:11811\" }", "give peers or a server, not both"},
      {"{ multicast: false }", "dds.discovery.multicast: unknown key"},
  };
  for (const auto& [text, expect] : bad)
    EXPECT_NE(errorOf(cell(text)).find(expect), std::string::npos) << text << ": " << errorOf(cell(text));
}

TEST(CellFile, ExtensionsAndHiddenEffectsAreChecked) {
  auto cell = [](const std::string& ext, const std::string& sim = "") {
    return "robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml, extensions: " + ext + " }\n" + sim;
  };
  const CellConfig ok = parseCellConfig(cell("[joint_compliance:2, backlash:3]"), "cell.yaml", CELLCAL_CONFIG_DIR);
  ASSERT_EQ(ok.robots[0].extensions.size(), 2u);
  EXPECT_EQ(ok.robots[0].extensions[0].cause, Cause::kJointCompliance);
  EXPECT_EQ(ok.robots[0].extensions[0].joint, 1);
  EXPECT_EQ(extensionSpec(ok.robots[0].extensions[1]), "backlash:3");
  EXPECT_NE(errorOf(cell("[joint_compliance:9]")).find("cell.yaml:2:77: robots[0].extensions[0]: 'joint_compliance:9': ur10 has joints 1..6"),
            std::string::npos) << errorOf(cell("[joint_compliance:9]"));
  EXPECT_NE(errorOf(cell("[gear_wear:2]")).find("'gear_wear' is not a cause"), std::string::npos);
  EXPECT_NE(errorOf(cell("[joint_scale]")).find("needs a joint"), std::string::npos);
  EXPECT_NE(errorOf(cell("[joint_scale:x]")).find("must be a number"), std::string::npos);
  EXPECT_NE(errorOf(cell("[thermal_drift]")).find("thermal_drift needs a temperature"), std::string::npos);
  EXPECT_NE(errorOf(cell("[backlash:2, backlash:2]")).find("listed twice"), std::string::npos);
  EXPECT_NE(errorOf(cell("joint_scale:2")).find("expected a list"), std::string::npos);
  const CellConfig hid = parseCellConfig(
      cell("[]", "simulation:\n  hidden_effect: { cause: joint_compliance, joint: 3, size_deg: -0.02 }\n"), "cell.yaml",
      CELLCAL_CONFIG_DIR);
  EXPECT_EQ(hid.simulation.effect, Cause::kJointCompliance);
  EXPECT_EQ(hid.simulation.effect_joint, 2);
  EXPECT_NEAR(hid.simulation.effect_size_rad, -0.02 * kPi / 180, 1e-15);
  EXPECT_NE(errorOf(cell("[]", "simulation:\n  hidden_effect: { cause: backlash, joint: 3, size_deg: 0.02 }\n"))
                .find("simulation.hidden_effect.cause: expected none, joint_compliance"),
            std::string::npos);
  EXPECT_NE(errorOf(cell("[]", "simulation:\n  hidden_effect: { cause: joint_scale, joint: 3 }\n")).find("size_deg"),
            std::string::npos);
  // simulation.rsi_hz: the RSI streams `cellcal cell` runs (0: none), a controller cycle of 1 ms or more.
  EXPECT_EQ(hid.simulation.rsi_hz, 0.0);
  EXPECT_EQ(parseCellConfig(cell("[]", "simulation:\n  rsi_hz: 250\n"), "cell.yaml", CELLCAL_CONFIG_DIR).simulation.rsi_hz,
            250.0);
  EXPECT_NE(errorOf(cell("[]", "simulation:\n  rsi_hz: 4000\n")).find("simulation.rsi_hz: must be <= 1000"),
            std::string::npos)
      << errorOf(cell("[]", "simulation:\n  rsi_hz: 4000\n"));
  EXPECT_NE(errorOf(cell("[]", "simulation:\n  rsi_hz: -1\n")).find("simulation.rsi_hz"), std::string::npos);
}

// engine.pose_requests and simulation.follow_pose_requests: read in the file's units, bad values named with line and
// field, following without proposals or beside a fixed program refused.
TEST(CellFile, PoseRequestsAreChecked) {
  const std::string robot = "robots:\n  - { robot_id: a, target_id: t, robot_file: robots/ur10.yaml }\n";
  const CellConfig d = parseCellConfig(robot, "cell.yaml", CELLCAL_CONFIG_DIR);
  EXPECT_EQ(d.engine.pose_requests.count, 10);
  EXPECT_FALSE(d.simulation.follow_pose_requests);
  const CellConfig c = parseCellConfig(
      robot + "engine:\n  pose_requests: { count: 4, candidates: 50, min_period_s: 2, range_mm: [500, 6000], "
              "link_radius_mm: 80, acceptance_deg: 30, sigma_position_mm: 0.02 }\nsimulation:\n  follow_pose_requests: true\n",
      "cell.yaml", CELLCAL_CONFIG_DIR);
  const PoseRequestSettings& p = c.engine.pose_requests;
  EXPECT_EQ(p.count, 4);
  EXPECT_EQ(p.candidates, 50);
  EXPECT_EQ(p.min_period_s, 2);
  EXPECT_NEAR(p.min_range_m, 0.5, 1e-15);
  EXPECT_NEAR(p.max_range_m, 6.0, 1e-15);
  EXPECT_NEAR(p.link_radius_m, 0.08, 1e-15);
  EXPECT_NEAR(p.acceptance_rad, 30 * kPi / 180, 1e-15);
  EXPECT_NEAR(p.sigma_position_m, 2e-5, 1e-18);
  EXPECT_TRUE(c.simulation.follow_pose_requests);
  EXPECT_EQ(errorOf(robot + "engine:\n  pose_requests: { count: 80 }\n"),
            "cell.yaml:4:27: engine.pose_requests.count: must be in [0, 64]");
  EXPECT_NE(errorOf(robot + "engine:\n  pose_requests: { count: 20, candidates: 10 }\n").find("more than the candidates (10)"),
            std::string::npos);
  EXPECT_NE(errorOf(robot + "engine:\n  pose_requests: { range_mm: [6000, 500] }\n")
                .find("engine.pose_requests.range_mm: expected 0 <= MIN < MAX"),
            std::string::npos);
  EXPECT_NE(errorOf(robot + "engine:\n  pose_requests: { count: 0 }\nsimulation:\n  follow_pose_requests: true\n")
                .find("simulation.follow_pose_requests: engine.pose_requests.count is 0: nothing to follow"),
            std::string::npos);
  const std::string tx60 = "robots:\n  - { robot_id: a, target_id: t, robot_file: robots/staubli_tx60.yaml }\n"
                           "simulation:\n  follow_pose_requests: true\n  program_csv: examples/iso9283_program.csv\n";
  EXPECT_NE(errorOf(tx60).find("follow the engine's proposals or run a program, not both"), std::string::npos) << errorOf(tx60);
  EXPECT_NE(errorOf(robot + "engine:\n  pose_requests: { count: 3, spread: 2 }\n").find("engine.pose_requests.spread: unknown key"),
            std::string::npos);
}

}  // namespace
}  // namespace cellcal
