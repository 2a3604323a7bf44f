// ROS 2 over plain DDS, without rclcpp (docs/ros2.md). A ROS 2 topic "/joint_states" is the DDS topic
// "rt/joint_states"; its type is announced as sensor_msgs::msg::dds_::JointState_ (idl/ros2_msgs.idl). What the
// joint-state adapter's ROS 2 source needs besides DDS: the topic name, the joints by name, and whether the robot
// stands still (a JointState has no such flag; the engine pairs a tracker reading only with settled joint states).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace cellcal::components {

// The DDS topic of a ROS 2 topic name: "/joint_states" or "joint_states" -> "rt/joint_states" (a relative name is
// taken in the root namespace). nullopt, with the reason in *error, for a name ROS 2 would refuse: empty, characters
// other than letters, digits, '_' and '/', "//", a trailing '/', a token starting with a digit, or '~' / '{}'
// substitutions (there is no node here to resolve them).
std::optional<std::string> ros2DdsTopic(const std::string& ros_name, std::string* error);

// The robot's joint angles, in the order of `joint_names` (the cell file's ros2_joint_names), from a JointState's
// name and position arrays (any order; names of other joints, e.g. a gripper's, are ignored). nullopt, with the
// reason in *why, when the arrays' lengths differ, a joint is missing or named twice, or a position is not finite.
std::optional<Eigen::VectorXd> jointPositionsByName(const std::vector<std::string>& msg_names,
                                                    const std::vector<double>& msg_positions,
                                                    const std::vector<std::string>& joint_names, std::string* why);

// Whether a robot stands still, from its joint stream alone: settled once every joint has stayed within
// tolerance_rad of one position for at least window_s (by the samples' stamps) and no reported velocity exceeds
// velocity_radps (velocities are optional: drivers without them leave the array empty). A stamp that goes back starts
// the window again.
class StandStillDetector {
 public:
  StandStillDetector(double window_s, double tolerance_rad, double velocity_radps);
  // The state after this sample. `velocity_radps` may be empty; otherwise one per joint of q_rad.
  bool update(std::int64_t stamp_ns, const Eigen::VectorXd& q_rad, const std::vector<double>& velocity_radps);

 private:
  std::int64_t window_ns_;
  double tolerance_rad_, velocity_radps_;
  Eigen::VectorXd anchor_q_;
  std::int64_t anchor_ns_ = 0, last_ns_ = 0;
};

}  // namespace cellcal::components
