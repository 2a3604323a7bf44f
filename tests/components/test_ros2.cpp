// ROS 2 over plain DDS (components/common ros2.hpp, idl/ros2_msgs.idl): the wire names a ROS 2 node announces, topic
// names as ROS 2 maps them, joints found by name in any order, and the stand-still detector against the segments of a
// random joint stream whose still and moving parts the test knows.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "cellcal/components/ros2.hpp"
#include "components/cdr_round_trip.hpp"
#include "ros2_msgsPubSubTypes.h"
#include "test_support.hpp"

namespace cellcal::components {
namespace {

TEST(Ros2, TypesCarryTheNamesRos2Announces) {
  EXPECT_STREQ(sensor_msgs::msg::dds_::JointState_PubSubType().getName(), "sensor_msgs::msg::dds_::JointState_");
  EXPECT_STREQ(geometry_msgs::msg::dds_::PoseStamped_PubSubType().getName(), "geometry_msgs::msg::dds_::PoseStamped_");
  sensor_msgs::msg::dds_::JointState_ js;
  js.header().stamp().sec(1764370000);
  js.header().stamp().nanosec(123456789);
  js.header().frame_id("base");
  js.name({"elbow_joint", "shoulder_lift_joint"});
  js.position({1.5, -0.25});
  js.velocity({0.0, 1e-4});
  const auto back = test::roundTrip<sensor_msgs::msg::dds_::JointState_PubSubType>(js);
  EXPECT_EQ(back.header().stamp().sec(), 1764370000);
  EXPECT_EQ(back.header().stamp().nanosec(), 123456789u);
  EXPECT_EQ(back.name(), js.name());
  EXPECT_EQ(back.position(), js.position());
  EXPECT_EQ(back.velocity(), js.velocity());
  EXPECT_TRUE(back.effort().empty());
}

TEST(Ros2, TopicNamesMapAsRos2MapsThem) {
  std::string err;
  EXPECT_EQ(ros2DdsTopic("/joint_states", &err).value_or("?"), "rt/joint_states");
  EXPECT_EQ(ros2DdsTopic("joint_states", &err).value_or("?"), "rt/joint_states");
  EXPECT_EQ(ros2DdsTopic("/ur/joint_states", &err).value_or("?"), "rt/ur/joint_states");
  EXPECT_EQ(ros2DdsTopic("/cellcal/corrected_pose_2", &err).value_or("?"), "rt/cellcal/corrected_pose_2");
  for (const std::string bad : {"", "/", "/joint_states/", "//joint_states", "/a//b", "/2d/points", "~/joint_states",
                                "/{ns}/joint_states", "/joint-states", "/joint states"}) {
    err.clear();
    EXPECT_FALSE(ros2DdsTopic(bad, &err)) << bad;
    EXPECT_NE(err.find("'" + bad + "'"), std::string::npos) << err;
  }
}

TEST(Ros2, JointsAreFoundByNameInAnyOrder) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-3, 3);
  const std::vector<std::string> robot = {"shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                          "wrist_1_joint",      "wrist_2_joint",       "wrist_3_joint"};
  for (int trial = 0; trial < 50; ++trial) {
    std::vector<std::string> names = robot;
    for (int k = 0; k < static_cast<int>(rng() % 3); ++k) names.push_back("gripper_" + std::to_string(k));
    std::shuffle(names.begin(), names.end(), rng);
    std::vector<double> pos;
    for (size_t i = 0; i < names.size(); ++i) pos.push_back(u(rng));
    std::string why;
    const auto q = jointPositionsByName(names, pos, robot, &why);
    ASSERT_TRUE(q) << why;
    for (size_t j = 0; j < robot.size(); ++j) {
      const size_t k = static_cast<size_t>(std::find(names.begin(), names.end(), robot[j]) - names.begin());
      EXPECT_EQ((*q)[static_cast<Eigen::Index>(j)], pos[k]);
    }
    // Each fault refused with what is wrong.
    auto refused = [&](std::vector<std::string> n, std::vector<double> p, const std::string& expect) {
      std::string w;
      EXPECT_FALSE(jointPositionsByName(n, p, robot, &w));
      EXPECT_NE(w.find(expect), std::string::npos) << w;
    };
    const size_t drop = rng() % names.size();
    std::vector<std::string> fewer = names;
    std::vector<double> fewer_pos = pos;
    fewer.erase(fewer.begin() + static_cast<std::ptrdiff_t>(drop));
    fewer_pos.erase(fewer_pos.begin() + static_cast<std::ptrdiff_t>(drop));
    if (std::find(robot.begin(), robot.end(), names[drop]) != robot.end())
      refused(fewer, fewer_pos, "no joint '" + names[drop] + "'");
    refused(names, std::vector<double>(pos.begin(), pos.end() - 1), "names but");
    std::vector<double> nan_pos = pos;
    const size_t at = static_cast<size_t>(std::find(names.begin(), names.end(), robot[rng() % robot.size()]) - names.begin());
    nan_pos[at] = std::nan("");
    refused(names, nan_pos, "not finite");
    std::vector<std::string> twice = names;
    twice.push_back(robot[rng() % robot.size()]);
    std::vector<double> twice_pos = pos;
    twice_pos.push_back(0.0);
    refused(twice, twice_pos, "named twice");
  }
}

// A random stream at a random rate: moves (every joint steps far beyond the tolerance each sample) and stand-stills of
// random length with encoder noise within a quarter of the tolerance. Settled exactly when a stand-still has lasted
// the window (by the stamps) and no reported velocity is above the bound.
TEST(Ros2, StandStillIsSaidOnceTheWindowHasPassed) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 20; ++trial) {
    const double rate_hz = 50 + 450 * std::abs(u(rng));
    const double window_s = 0.05 + 0.3 * std::abs(u(rng));
    const double tol = 1e-5, vel_bound = 1e-3;
    const bool with_velocity = trial % 2;
    StandStillDetector det(window_s, tol, vel_bound);
    Eigen::VectorXd q = Eigen::VectorXd::Random(6);
    std::int64_t t = 1764370000LL * 1000000000LL;
    const auto dt = static_cast<std::int64_t>(1e9 / rate_hz);
    int settled = 0, expected_settled = 0;
    for (int seg = 0; seg < 12; ++seg) {
      const bool still = seg % 2;
      const int n = 1 + static_cast<int>(rng() % static_cast<unsigned>(rate_hz));  // up to 1 s
      std::int64_t still_since = t;
      for (int i = 0; i < n; ++i, t += dt) {
        std::vector<double> v;
        if (still && i == 0) q += Eigen::VectorXd::Constant(6, 1e-3);  // the move's last step: arrival
        Eigen::VectorXd sample = q;
        if (still) {
          sample += Eigen::VectorXd::Random(6) * (tol / 4);
          if (with_velocity) v.assign(6, 0.2 * vel_bound * u(rng));
        } else {
          q += Eigen::VectorXd::Constant(6, 1e-3) + 1e-3 * Eigen::VectorXd::Random(6).cwiseAbs();
          sample = q;
          if (with_velocity) v.assign(6, 0.5);
        }
        if (still && i == 0) still_since = t;
        // A slow joint in a stand-still (velocity reported above the bound, position still within the tolerance).
        const bool creeping = still && with_velocity && i % 7 == 3;
        if (creeping) v[2] = 2 * vel_bound;
        const bool want = still && !creeping && t - still_since >= static_cast<std::int64_t>(window_s * 1e9);
        const bool got = det.update(t, sample, v);
        EXPECT_EQ(got, want) << "trial " << trial << " segment " << seg << " sample " << i << " at "
                             << (t - still_since) * 1e-9 << " s of " << window_s << " s";
        settled += got;
        expected_settled += want;
      }
    }
    EXPECT_EQ(settled, expected_settled);
  }
  // A stamp that goes back starts the window again.
  StandStillDetector det(0.1, 1e-5, 1e-3);
  const Eigen::VectorXd q = Eigen::VectorXd::Zero(6);
  EXPECT_FALSE(det.update(1000000000, q, {}));
  EXPECT_TRUE(det.update(1200000000, q, {}));
  EXPECT_FALSE(det.update(1100000000, q, {}));
  EXPECT_TRUE(det.update(1250000000, q, {}));
}

}  // namespace
}  // namespace cellcal::components
