// Vendor interop on loopback: a Cyclone DDS participant (tests/interop/cyclone_peer.c, C code idlc made from cellcal's
// own IDL) publishes a simulated robot's joint states and tracker readings and then asks for targets; cellcal's engine
// and compensation publisher (Fast DDS processes) calibrate from them and answer. The Cyclone side counts the
// CalibrationState and CompensatedTarget samples it receives. Settings: docs/interop.md.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <random>

#include "cell/cell_test_support.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/core/files/urdf.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

// Cyclone DDS on loopback: the 127.0.0.1 interface, no multicast (lo has none), unicast discovery to 127.0.0.1.
const char* kCycloneLoopback =
    "<CycloneDDS><Domain id=\"any\"><General><Interfaces><NetworkInterface address=\"127.0.0.1\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>40</MaxAutoParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery>"
    "</Domain></CycloneDDS>";

// The cell's robot as the simulator plays it (hidden errors from the seed).
SimulatedCell simulatedRobot(const CellConfig& cell, std::uint64_t seed) {
  SimulationSettings settings;
  settings.seed = seed;
  return makeSimulatedCell(cell.robots[0], settings, 0);
}

// A tracker reading as a peer input line (cyclone_peer.c's T line).
void trackerLine(std::ostream& in, std::int64_t t_ms, const Observation& reading) {
  const msg::TrackerPose r = components::toTrackerPose("tx60_target", 0, 0, reading);
  in << "T " << t_ms * 1000000 << " tx60_target " << (r.has_orientation() ? 1 : 0) << std::setprecision(17);
  for (double v : r.position_m()) in << ' ' << v;
  for (double v : r.orientation_xyzw()) in << ' ' << v;
  for (double v : r.covariance()) in << ' ' << v;
  in << '\n';
}

// A stand-still per configuration after the first, 100 ms apart: a move, two settled joint states, the tracker
// reading, two more (J and T lines).
void standStillLines(std::ostream& in, const SimulatedCell& sim, std::mt19937_64& rng, const std::vector<Eigen::VectorXd>& qs) {
  auto joints = [&](std::int64_t t_ms, const Eigen::VectorXd& q, bool settled) {
    in << "J " << t_ms * 1000000 << " tx60 " << (settled ? 1 : 0) << ' ' << q.size();
    for (int i = 0; i < q.size(); ++i) in << ' ' << std::setprecision(17) << q[i];
    in << '\n';
  };
  for (size_t k = 0; k + 1 < qs.size(); ++k) {
    const std::int64_t t = 100LL * static_cast<std::int64_t>(k);
    joints(t, qs[k] + 0.5 * (qs[k + 1] - qs[k]), false);
    joints(t + 40, qs[k + 1], true);
    joints(t + 50, qs[k + 1], true);
    trackerLine(in, t + 55, sim.measure(qs[k + 1], 0.0, rng));
    joints(t + 60, qs[k + 1], true);
    joints(t + 70, qs[k + 1], true);
  }
}

// `targets` targets the nominal model reaches, 50 ms apart from t_ms, the controller's joints for each as the solver's
// seed (P lines).
void targetLines(std::ostream& in, const SimulatedCell& sim, std::mt19937_64& rng, std::int64_t t_ms, int targets) {
  KinematicsData kd(sim.model());
  for (const auto& q : sim.randomConfigurations(targets, rng)) {
    msg::TargetPose tp;
    components::fromPose(forwardKinematics(sim.model(), kd, sim.nominalParams(), q), tp.position_m(), tp.orientation_xyzw());
    in << "P " << t_ms * 1000000 << " tx60" << std::setprecision(17);
    for (double v : tp.position_m()) in << ' ' << v;
    for (double v : tp.orientation_xyzw()) in << ' ' << v;
    in << ' ' << q.size();
    for (int i = 0; i < q.size(); ++i) in << ' ' << q[i];
    in << '\n';
    t_ms += 50;
  }
}

TEST(Interop, CycloneDdsFeedsTheEngineAndReceivesCalibrationsAndCompensatedTargets) {
  const std::string dir = testDir();
  const int domain = domainForTest();
  const std::uint64_t seed = testSeed();
  // Fast DDS 2.9's TypeInformation is refused by Cyclone DDS 0.10: the cell does not send it.
  const std::string cfg = writeCell(dir, domain, seed, {{"tx60", "tx60_target"}}, "", "", ", type_information: false");
  const CellConfig cell = loadCellConfig(cfg);

  // The inputs: 40 stand-stills of a simulated robot (hidden errors from the seed), each a move, two settled joint
  // states, the tracker reading, two more; then 20 targets the nominal model reaches, with those joints as the seed.
  std::mt19937_64 rng(seed);
  const SimulatedCell sim = simulatedRobot(cell, seed);
  const int poses = 40, targets = 20;
  const auto qs = sim.randomConfigurations(poses + 1, rng);
  std::ofstream in(dir + "/inputs.txt");
  standStillLines(in, sim, rng, qs);
  targetLines(in, sim, rng, 100LL * poses + 1000, targets);  // 1 s after the last reading: calibrated by then
  in.close();

  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet", "--stats-json", dir + "/engine.json"});
  Process compensation(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg});
  std::ofstream(dir + "/cyclone.xml") << kCycloneLoopback;
  ::setenv("CYCLONEDDS_URI", ("file://" + dir + "/cyclone.xml").c_str(), 1);
  Process peer(dir, "cyclone_peer", {"cyclone_peer", std::to_string(domain), dir + "/inputs.txt", "2", dir + "/peer.json"});
  ASSERT_EQ(peer.wait(60), 0) << peer.log() << engine.log() << compensation.log();
  EXPECT_EQ(engine.stop(SIGINT), 0) << engine.log();
  EXPECT_EQ(compensation.stop(SIGINT), 0) << compensation.log();
  const auto p = readJson(dir + "/peer.json");
  const auto e = readJson(dir + "/engine.json");
  ASSERT_FALSE(p.is_discarded()) << peer.log();
  ASSERT_FALSE(e.is_discarded()) << engine.log();
  EXPECT_EQ(p["published"]["tracker_pose"], poses);
  EXPECT_EQ(p["published"]["target_pose"], targets);
  // Cyclone -> Fast DDS: the engine took the readings (best effort on loopback: at most a couple lost) and calibrated.
  const int tracker_rx = e["topics"]["cellcal/tracker_pose"]["received"];
  EXPECT_GE(tracker_rx, poses - 2) << e.dump();
  EXPECT_GE(e["topics"]["cellcal/joint_state"]["received"].get<int>(), 5 * (poses - 2));
  // Fast DDS -> Cyclone: the calibrations, up to the last one, and an answer to every target.
  EXPECT_GE(p["received"]["max_version"].get<int>(), tracker_rx - 2) << p.dump();
  EXPECT_GT(p["received"]["calibration_state"].get<int>(), 0);
  EXPECT_EQ(p["received"]["compensated_target"], targets) << p.dump();
  // Answers made with the calibration the engine computed from Cyclone's samples (a target may still be refused on
  // its own: beyond the correction bound or the joint limits).
  EXPECT_GE(p["received"]["applied"].get<int>(), targets / 2) << p.dump();
  std::printf("  Cyclone DDS peer: sent %d readings and %d targets; the engine (Fast DDS) received %d and published up "
              "to v%d; the peer received %d CalibrationState and %d CompensatedTarget (%d applied)\n",
              poses, targets, tracker_rx, p["received"]["max_version"].get<int>(),
              p["received"]["calibration_state"].get<int>(), p["received"]["compensated_target"].get<int>(),
              p["received"]["applied"].get<int>());
}

// A ROS 2 cell: the robot driver is a ROS 2 node publishing sensor_msgs/JointState on /joint_states, here played by
// the Cyclone DDS peer as rmw_cyclonedds puts it on the wire (topic rt/joint_states, type
// sensor_msgs::msg::dds_::JointState_, ROS 2's default QoS, names in the driver's own order with a gripper joint the
// robot file does not have, no `settled` flag). The joint-state adapter reads it with --source ros2; the compensation
// publisher answers targets on cellcal/compensated_target and also as geometry_msgs/PoseStamped on
// /cellcal/corrected_pose, which the peer reads. One sample in 40 lacks a joint: skipped and said, nothing else lost.
TEST(Interop, Ros2JointStatesInCorrectedPosesOut) {
  const std::string dir = testDir();
  const int domain = domainForTest();
  const std::uint64_t seed = testSeed();
  const std::string cfg = writeCell(dir, domain, seed, {{"tx60", "tx60_target"}}, "", "", ", type_information: false");
  const CellConfig cell = loadCellConfig(cfg);
  const std::vector<std::string> robot_joints = {"shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                                 "wrist_1_joint",      "wrist_2_joint",       "wrist_3_joint"};
  // The driver's order (alphabetical, as ros2_control's joint_state_broadcaster sends a UR's joints) and a gripper.
  const std::vector<int> wire_order = {2, -1, 1, 0, 3, 4, 5};  // index into robot_joints; -1: the gripper

  std::mt19937_64 rng(seed);
  const SimulatedCell sim = simulatedRobot(cell, seed);
  const int poses = 40, targets = 20;
  const auto qs = sim.randomConfigurations(poses + 1, rng);
  std::ofstream in(dir + "/inputs.txt");
  int ros_lines = 0, faulty = 0;
  auto joints = [&](std::int64_t t_ms, const Eigen::VectorXd& q) {
    const bool drop = ++ros_lines % 40 == 0;  // this sample lacks wrist_3_joint
    faulty += drop;
    const int n = static_cast<int>(wire_order.size()) - (drop ? 1 : 0);
    in << "R " << t_ms * 1000000 << " base_link " << n;
    for (int w : wire_order)
      if (!(drop && w == 5)) in << ' ' << (w < 0 ? "gripper_finger_joint" : robot_joints[static_cast<size_t>(w)]);
    for (int w : wire_order)
      if (!(drop && w == 5)) in << ' ' << std::setprecision(17) << (w < 0 ? 0.01 : q[w]);
    in << '\n';
  };
  for (int k = 0; k < poses; ++k) {
    const std::int64_t t = 100LL * k;
    for (int i = 0; i < 3; ++i) joints(t + 10 * i, qs[k] + (i + 1) / 3.0 * (qs[k + 1] - qs[k]));  // the move
    for (std::int64_t ms = 30; ms < 100; ms += 10) {
      joints(t + ms, qs[k + 1]);  // standing still: 70 ms, settled after 20 ms (--settle-window-s 0.02)
      if (ms == 70) {
        trackerLine(in, t + 75, sim.measure(qs[k + 1], 0.0, rng));
      }
    }
  }
  targetLines(in, sim, rng, 100LL * poses + 1000, targets);
  in.close();

  std::string names;
  for (const auto& n : robot_joints) names += (names.empty() ? "" : ",") + n;
  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet", "--stats-json", dir + "/engine.json"});
  Process compensation(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg, "--ros-pose-topic",
                                             "/cellcal/corrected_pose", "--ros-frame-id", "cell_tracker"});
  Process adapter(dir, "joint_state_adapter",
                  {"cellcal_joint_state_adapter", "--config", cfg, "--source", "ros2", "--ros-topic", "/joint_states",
                   "--ros-joint-names", names, "--settle-window-s", "0.02", "--stats-json", dir + "/adapter.json"});
  std::ofstream(dir + "/cyclone.xml") << kCycloneLoopback;
  ::setenv("CYCLONEDDS_URI", ("file://" + dir + "/cyclone.xml").c_str(), 1);
  Process peer(dir, "cyclone_peer", {"cyclone_peer", std::to_string(domain), dir + "/inputs.txt", "2", dir + "/peer.json",
                                     "rt/cellcal/corrected_pose"});
  ASSERT_EQ(peer.wait(60), 0) << peer.log() << adapter.log() << engine.log() << compensation.log();
  EXPECT_EQ(adapter.stop(SIGINT), 0) << adapter.log();
  EXPECT_EQ(engine.stop(SIGINT), 0) << engine.log();
  EXPECT_EQ(compensation.stop(SIGINT), 0) << compensation.log();
  const auto p = readJson(dir + "/peer.json");
  const auto e = readJson(dir + "/engine.json");
  const auto a = readJson(dir + "/adapter.json");
  ASSERT_FALSE(p.is_discarded()) << peer.log();
  ASSERT_FALSE(e.is_discarded()) << engine.log();
  ASSERT_FALSE(a.is_discarded()) << adapter.log();
  EXPECT_EQ(p["published"]["ros_joint_state"], ros_lines);
  // ROS 2 -> the adapter: every JointState (reliable writer, loopback), the faulty ones skipped and said.
  const int ros_rx = a["extra"]["ros2_received"];
  EXPECT_GE(ros_rx, ros_lines - 2) << a.dump();
  EXPECT_EQ(a["extra"]["ros2_skipped"].get<int>(), faulty) << a.dump();
  EXPECT_NE(adapter.log().find("no joint 'wrist_3_joint'"), std::string::npos) << adapter.log();
  EXPECT_GT(a["extra"]["settled"].get<int>(), 3 * (poses - 2)) << a.dump();
  // The engine paired the adapter's settled joint states with the tracker and calibrated.
  const int tracker_rx = e["topics"]["cellcal/tracker_pose"]["received"];
  EXPECT_GE(tracker_rx, poses - 2) << e.dump();
  EXPECT_GE(p["received"]["max_version"].get<int>(), poses - 4) << p.dump() << e.dump() << engine.log();
  // Every applied correction also came as a PoseStamped, with the same pose, in the given frame.
  EXPECT_EQ(p["received"]["compensated_target"], targets) << p.dump();
  EXPECT_GE(p["received"]["applied"].get<int>(), targets / 2) << p.dump();
  EXPECT_EQ(p["received"]["pose_stamped"], p["received"]["applied"]) << p.dump();
  EXPECT_EQ(p["received"]["last_frame_id"], "cell_tracker") << p.dump();
  EXPECT_EQ(p["received"]["pose_max_diff"].get<double>(), 0.0) << p.dump();
  std::printf("  ROS 2 peer (Cyclone DDS): %d JointState sent (%d without a joint), the adapter received %d and skipped "
              "%d; the engine published up to v%d from %d readings; %d targets, %d applied, %d PoseStamped received\n",
              ros_lines, faulty, ros_rx, a["extra"]["ros2_skipped"].get<int>(),
              p["received"]["max_version"].get<int>(), tracker_rx, targets, p["received"]["applied"].get<int>(),
              p["received"]["pose_stamped"].get<int>());
}

// A ROS 2 cell's robot_description: the cell's robot is the ROS-Industrial TX60 URDF; the compensation publisher
// (--ros-description-topic /robot_description) publishes that URDF with the calibrated joint origins after each new ok
// calibration, which the Cyclone DDS peer reads as RViz does (rt/robot_description, std_msgs::msg::dds_::String_,
// reliable, transient local). The last description is that of the last ok calibration the peer received: the same
// text as core's export of those parameters, only joint origins changed from the nominal file, and, read back as a
// robot, its tool0 carries the target where the calibration puts it. A peer that joins after the last update gets
// it at once (transient local).
TEST(Interop, Ros2RobotDescriptionFollowsTheCalibration) {
  namespace fs = std::filesystem;
  const fs::path urdf = fs::path(CELLCAL_CONFIG_DIR) / "../../shared/robots/ros-industrial/staubli/tx60.urdf";
  if (!fs::exists(urdf)) GTEST_SKIP() << urdf << " missing";
  const std::string dir = testDir();
  const int domain = domainForTest();
  const std::uint64_t seed = testSeed();
  RobotEntry robot{"tx60", "tx60_target", "../../../shared/robots/ros-industrial/staubli/tx60.urdf"};
  const std::string cfg = writeCell(dir, domain, seed, {robot}, "", "", ", type_information: false");
  const CellConfig cell = loadCellConfig(cfg);
  std::mt19937_64 rng(seed);
  const SimulatedCell sim = simulatedRobot(cell, seed);
  const int poses = 30;
  const auto qs = sim.randomConfigurations(poses + 1, rng);
  std::ofstream in(dir + "/inputs.txt");
  standStillLines(in, sim, rng, qs);
  in.close();
  std::ofstream(dir + "/nothing.txt").close();

  Process engine(dir, "engine", {"cellcal_calibration_engine", "--config", cfg, "--quiet"});
  Process compensation(dir, "compensation", {"cellcal_compensation_publisher", "--config", cfg, "--ros-description-topic",
                                             "/robot_description", "--stats-json", dir + "/compensation.json"});
  std::ofstream(dir + "/cyclone.xml") << kCycloneLoopback;
  ::setenv("CYCLONEDDS_URI", ("file://" + dir + "/cyclone.xml").c_str(), 1);
  Process peer(dir, "cyclone_peer", {"cyclone_peer", std::to_string(domain), dir + "/inputs.txt", "2", dir + "/peer.json",
                                     "-", "rt/robot_description"});
  ASSERT_EQ(peer.wait(60), 0) << peer.log() << engine.log() << compensation.log();
  Process late(dir, "late_peer", {"cyclone_peer", std::to_string(domain), dir + "/nothing.txt", "20", dir + "/late.json",
                                  "-", "rt/robot_description"});
  const auto late_start = std::chrono::steady_clock::now();
  ASSERT_EQ(late.wait(40), 0) << late.log();
  const double late_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - late_start).count();
  EXPECT_EQ(engine.stop(SIGINT), 0) << engine.log();
  EXPECT_EQ(compensation.stop(SIGINT), 0) << compensation.log();
  const auto p = readJson(dir + "/peer.json");
  const auto l = readJson(dir + "/late.json");
  const auto c = readJson(dir + "/compensation.json");
  ASSERT_FALSE(p.is_discarded()) << peer.log();
  ASSERT_FALSE(l.is_discarded()) << late.log();
  ASSERT_FALSE(c.is_discarded()) << compensation.log();
  EXPECT_NE(compensation.log().find("the calibrated URDF of"), std::string::npos) << compensation.log();
  const std::uint64_t ok_version = p["received"]["ok_version"];
  ASSERT_GE(ok_version, static_cast<std::uint64_t>(poses / 2)) << p.dump() << engine.log();
  const auto& d = c["extra"]["descriptions"]["tx60"];
  EXPECT_GE(d["published"].get<int>(), 1) << c.dump();
  EXPECT_EQ(d["failed"].get<int>(), 0) << c.dump() << compensation.log();
  EXPECT_EQ(d["last_version"].get<std::uint64_t>(), ok_version) << c.dump();
  EXPECT_GE(p["received"]["robot_description"].get<int>(), 1) << p.dump();
  const std::string got = readTextFile(dir + "/peer.json.urdf");
  ASSERT_FALSE(got.empty());
  // Named by its version; without that comment line, core's export of the calibration's parameters to the byte.
  const std::string tag = "<!-- cellcal: tx60, calibration v" + std::to_string(ok_version) + " (";
  const size_t comment = got.find(tag);
  ASSERT_NE(comment, std::string::npos) << got.substr(0, 400);
  std::string without = got;
  without.erase(comment, got.find('\n', comment) + 1 - comment);
  const std::string nominal_xml = readTextFile(urdf.string());
  const UrdfImport nominal = importUrdf(nominal_xml, urdf.string());
  const RobotModel& m = cell.robots[0].model;
  ASSERT_EQ(p["received"]["ok_values"].size(), static_cast<size_t>(m.numParams())) << p.dump();
  Eigen::VectorXd params(m.numParams());
  for (int i = 0; i < m.numParams(); ++i) params[i] = p["received"]["ok_values"][static_cast<size_t>(i)];
  auto frame = [](const Eigen::VectorXd& v, int first) {
    return poseFromXyzRpy(v[first], v[first + 1], v[first + 2], v[first + 3], v[first + 4], v[first + 5]);
  };
  const int tool = m.toolParam(FrameParam::kX), base = m.baseParam(FrameParam::kX);
  const Pose target_nominal = frame(m.nominal, tool);
  EXPECT_EQ(without, exportUrdf(nominal_xml, urdf.string(), nominal, params, frame(params, tool) * target_nominal.inverse()));
  // Only joint origins changed, and some did (it is calibrated).
  std::istringstream a(nominal_xml), b(without);
  int changed = 0, other = 0;
  for (std::string la, lb; std::getline(a, la) && std::getline(b, lb);)
    if (la != lb) (la.find("<origin") != std::string::npos && lb.find("<origin") != std::string::npos ? changed : other)++;
  EXPECT_GT(changed, 0);
  EXPECT_EQ(other, 0);
  // Read back as a robot: its tool0 with the target at its nominal place is the calibrated model's target (in the base).
  const UrdfImport back = importUrdf(got, "robot_description");
  KinematicsData kb(back.model), kc(m);
  double worst_m = 0;
  for (const auto& q : sim.randomConfigurations(200, rng)) {
    const Pose want = frame(params, base).inverse() * forwardKinematics(m, kc, params, q);
    const Pose have = forwardKinematics(back.model, kb, back.model.nominal, q) * target_nominal;
    worst_m = std::max(worst_m, (want.translation() - have.translation()).norm());
  }
  EXPECT_LT(worst_m, 1e-9);
  // A late joiner gets the last description (transient local) once it has discovered the publisher.
  EXPECT_EQ(l["received"]["robot_description"].get<int>(), 1) << l.dump();
  EXPECT_EQ(readTextFile(dir + "/late.json.urdf"), got);
  std::printf("  robot_description: %d published by the compensation publisher (last v%llu), %d received by the peer, "
              "the last with %d joint origins changed; read back, tool0 within %.2g m of the calibrated model; a late joiner had "
              "it after %.1f s\n",
              d["published"].get<int>(), static_cast<unsigned long long>(ok_version),
              p["received"]["robot_description"].get<int>(), changed, worst_m, late_s);
}

}  // namespace
}  // namespace cellcal
