// The calibration feed (components/common calibration_feed.hpp) over DDS in one process, on the loopback profile and
// a domain of its own: an engine's writer publishes CalibrationState samples as the engine does (toCalibrationState),
// the feed hands the ok ones to a RealtimeCompensator, and a controller's thread (this one) answers setpoints with
// them. Each answer is checked against the in-memory compensator given the same version directly; the rules (not ok,
// older, another robot's, not answerable) against the feed's status. The versions' errors are drawn from the test seed.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include "cellcal/components/calibration_feed.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/servo_compensation.h"
#include "cellcal/core/model/kinematics.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

using components::CalibrationFeed;
using components::FeedStatus;

int domainForTest() {
  const std::string name = test::currentTestName();
  std::uint32_t h = 2166136261u;
  for (char c : name) h = (h ^ static_cast<unsigned char>(c)) * 16777619u;
  return 1 + static_cast<int>(h % 200);
}

struct FeedFixture : ::testing::Test {
  std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng{seed};
  std::uniform_real_distribution<double> u{-1, 1};
  CellConfig cell = loadCellConfig(std::string(CELLCAL_CONFIG_DIR) + "/cell.yaml");
  void SetUp() override {
    cell.dds.domain_id = domainForTest();
    cell.dds.participant_profile = "cellcal_loopback";
  }
  const CellRobot& robot() const { return cell.robots[0]; }
  // A calibration as the engine publishes one: each joint's zero moved by up to 0.05 deg, its a by up to 0.2 mm; a
  // covariance of 2-20 um (urad) over the canonical parameters.
  CalibrationSnapshot snapshot(std::uint64_t version, Health health) {
    const RobotModel& m = robot().model;
    Eigen::VectorXd p = m.nominal;
    for (int j = 0; j < m.numJoints(); ++j) {
      p[m.jointParam(j, JointParam::kThetaOffset)] += degToRad(0.05 * u(rng));
      p[m.jointParam(j, JointParam::kA)] += 0.2e-3 * u(rng);
    }
    const std::vector<int> est = m.canonicalParams();
    const double sigma = (11 + 9 * u(rng)) * 1e-6;
    CalibrationSnapshot s;
    static_cast<CalibratedModel&>(s) = CalibratedModel::geometric(
        p, est, sigma * sigma * Eigen::MatrixXd::Identity(static_cast<Eigen::Index>(est.size()), static_cast<Eigen::Index>(est.size())));
    s.version = version;
    s.health = health;
    s.poses_used = 50;
    s.last_measurement_stamp_ns = static_cast<std::int64_t>(version) * 1'000'000'000;
    return s;
  }
  // Waits until the feed's status satisfies `done` (10 s at most: discovery on loopback takes under a second).
  template <class F>
  FeedStatus waitFor(const CalibrationFeed& feed, F&& done) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    FeedStatus s = feed.status();
    while (!done(s) && std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
      s = feed.status();
    }
    return s;
  }
};

// v1 ok is applied; v2 degraded leaves v1 answering (said: holding); v3 ok is applied; v2 again (older) is refused;
// another robot's sample is not this feed's; v4 with a model extension is refused by name and v3 keeps answering.
// After each, the controller's answers equal those of a compensator given the version in memory, bit for bit.
TEST_F(FeedFixture, OkVersionsReachTheControllersLoopAndTheRestAreRefused) {
  const RobotModel& m = robot().model;
  RealtimeSettings settings{cell.compensation, 0.0};  // switch at once: each answer is one version's
  RealtimeCompensator rt(m, settings);
  CalibrationFeed feed(cell, robot().robot_id, rt);
  components::DdsNode engine(cell, "test_engine", components::identity::kCalibrationEngine);
  auto writer = engine.writer<msg::CalibrationState>();
  std::uint64_t sequence = 0;
  auto publish = [&](const CalibrationSnapshot& s, const std::string& id = "") {
    msg::CalibrationState state = components::toCalibrationState(robot(), s, 0, ++sequence);
    if (!id.empty()) state.robot_id(id);
    writer.write(state);
  };
  // The answers of the feed's compensator against one given the version directly, over random setpoints.
  std::vector<Eigen::VectorXd> qs;
  for (int k = 0; k < 50; ++k) {
    Eigen::VectorXd q(m.numJoints());
    for (int j = 0; j < m.numJoints(); ++j)
      q[j] = 0.5 * (m.limits[j].lower_rad + m.limits[j].upper_rad) + 0.4 * u(rng) * (m.limits[j].upper_rad - m.limits[j].lower_rad) / 2;
    qs.push_back(q);
  }
  std::int64_t t = 0;
  auto sameAnswers = [&](const CalibrationSnapshot& s) {
    RealtimeCompensator direct(m, settings);
    std::string why;
    direct.publish(ServoVersion::prepare(m, s.version, IdentifiedModel(s), &why));
    int applied = 0;
    for (const Eigen::VectorXd& q : qs) {
      t += 4'000'000;
      const RealtimeAnswer a = rt.correct(t, q.data(), static_cast<int>(q.size()));
      const RealtimeAnswer b = direct.correct(t, q.data(), static_cast<int>(q.size()));
      EXPECT_EQ(a.version, s.version);
      if (a.status != b.status || a.q_rad != b.q_rad) return false;
      applied += a.status == ServoStatus::kApplied;
    }
    return applied > 0;
  };

  const CalibrationSnapshot v1 = snapshot(1, Health::kOk);
  // TRANSIENT_LOCAL: the feed gets v1 even if it was published before the reader matched.
  publish(v1);
  FeedStatus s = waitFor(feed, [](const FeedStatus& f) { return f.applied_version == 1; });
  ASSERT_EQ(s.applied_version, 1u) << components::describe(s);
  EXPECT_TRUE(sameAnswers(v1));

  publish(snapshot(2, Health::kDegraded));
  s = waitFor(feed, [](const FeedStatus& f) { return f.received_version == 2; });
  EXPECT_TRUE(s.holding);
  EXPECT_EQ(s.applied_version, 1u);
  EXPECT_NE(components::describe(s).find("applying v1; holding it: v2 degraded"), std::string::npos)
      << components::describe(s);
  EXPECT_TRUE(sameAnswers(v1));

  const CalibrationSnapshot v3 = snapshot(3, Health::kOk);
  publish(v3);
  s = waitFor(feed, [](const FeedStatus& f) { return f.applied_version == 3; });
  ASSERT_EQ(s.applied_version, 3u) << components::describe(s);
  EXPECT_FALSE(s.holding);
  EXPECT_TRUE(sameAnswers(v3));

  publish(snapshot(2, Health::kOk));
  publish(snapshot(9, Health::kOk), "another_robot");
  CalibrationSnapshot extended = snapshot(4, Health::kOk);
  extended.extensions = {Extension{Cause::kJointScale, 1}};
  extended.extension_params = Eigen::VectorXd::Constant(numExtensionParams(m, extended.extensions), 1e-4);
  publish(extended);
  s = waitFor(feed, [](const FeedStatus& f) { return f.older == 1 && f.unusable == 1 && f.other_robots == 1; });
  EXPECT_EQ(s.older, 1u) << components::describe(s);
  EXPECT_EQ(s.other_robots, 1u);
  EXPECT_EQ(s.unusable, 1u);
  EXPECT_NE(s.last_refusal.find("joint_scale:2"), std::string::npos) << s.last_refusal;
  EXPECT_EQ(s.applied_version, 3u);
  EXPECT_EQ(s.applied, 2u);
  EXPECT_TRUE(sameAnswers(v3));
  std::printf("  %s\n", components::describe(s).c_str());
}

// The C API (cellcal/servo_compensation.h, libcellcal_servo.so) on a cell file of its own: before any calibration the
// setpoints come back as given; once the engine's v1 arrives, every answer equals the in-memory compensator's given v1
// directly; a robot not in the file is named.
TEST_F(FeedFixture, TheCApiAnswersWithTheCellsCalibrations) {
  const std::string dir = (std::filesystem::temp_directory_path() / ("cellcal_capi_" + std::to_string(seed))).string();
  std::filesystem::create_directories(dir);
  const std::string file = dir + "/cell.yaml";
  std::ofstream(file) << "dds: { domain_id: " << cell.dds.domain_id << ", profiles_file: " << CELLCAL_CONFIG_DIR
                      << "/dds/cellcal_qos.xml, participant_profile: cellcal_loopback }\n"
                      << "robots:\n  - { robot_id: tx60, target_id: tx60_target, robot_file: " << CELLCAL_CONFIG_DIR
                      << "/robots/staubli_tx60.yaml, measurement: pose6d }\n";
  cell = loadCellConfig(file);
  const RobotModel& m = robot().model;
  char why[512] = "";
  EXPECT_EQ(cellcal_servo_create(file.c_str(), "kr150", why, sizeof why), nullptr);
  EXPECT_NE(std::string(why).find("'kr150' is not in " + file + " (its robots: tx60)"), std::string::npos) << why;
  cellcal_servo* servo = cellcal_servo_create(file.c_str(), "tx60", why, sizeof why);
  ASSERT_NE(servo, nullptr) << why;
  ASSERT_EQ(cellcal_servo_joints(servo), m.numJoints());
  Eigen::VectorXd q = 0.5 * (Eigen::VectorXd(m.numJoints()) << 0.2, -0.5, 1.4, 0.1, 0.7, -0.3).finished();
  Eigen::VectorXd out(m.numJoints());
  cellcal_servo_answer a;
  EXPECT_EQ(cellcal_servo_correct(servo, 0, q.data(), m.numJoints(), out.data(), &a), CELLCAL_SERVO_NO_CALIBRATION);
  EXPECT_EQ(out, q);

  components::DdsNode engine(cell, "test_engine", components::identity::kCalibrationEngine);
  auto writer = engine.writer<msg::CalibrationState>();
  const CalibrationSnapshot v1 = snapshot(1, Health::kOk);
  msg::CalibrationState state = components::toCalibrationState(robot(), v1, 0, 1);
  writer.write(state);
  std::int64_t t = 0;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (cellcal_servo_version(servo) != 1 && std::chrono::steady_clock::now() < until) {
    cellcal_servo_correct(servo, t += 4'000'000, q.data(), m.numJoints(), out.data(), &a);
    std::this_thread::sleep_for(std::chrono::milliseconds(4));
  }
  ASSERT_EQ(cellcal_servo_version(servo), 1u);
  RealtimeSettings settings{cell.compensation, cell.compensation.blend_s};
  RealtimeCompensator direct(m, settings);
  std::string reason;
  direct.publish(ServoVersion::prepare(m, 1, IdentifiedModel(v1), &reason));
  // Both past the first version's arrival (the C API's blended in from the stream's zero correction): over blend_s.
  t += static_cast<std::int64_t>((cell.compensation.blend_s + 1) * 1e9);
  int applied = 0;
  for (int k = 0; k < 50; ++k) {
    q[k % m.numJoints()] += 0.01;
    t += 4'000'000;
    const int status = cellcal_servo_correct(servo, t, q.data(), m.numJoints(), out.data(), &a);
    const RealtimeAnswer b = direct.correct(t, q.data(), m.numJoints());
    EXPECT_EQ(status, static_cast<int>(b.status));
    EXPECT_EQ(out, Eigen::VectorXd(b.q_rad));
    applied += status == CELLCAL_SERVO_APPLIED;
  }
  EXPECT_GT(applied, 40);
  char text[256];
  cellcal_servo_describe(servo, text, sizeof text);
  EXPECT_NE(std::string(text).find("tx60: applying v1"), std::string::npos) << text;
  cellcal_servo_destroy(servo);
  std::filesystem::remove_all(dir);
}

TEST_F(FeedFixture, ARobotNotInTheCellIsNamed) {
  RealtimeCompensator rt(robot().model, RealtimeSettings{});
  try {
    CalibrationFeed feed(cell, "kr150", rt);
    FAIL() << "a robot not in the cell file was taken";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'kr150' is not in the cell file (its robots: " + robot().robot_id),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace cellcal
