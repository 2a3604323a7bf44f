// cellcal_joint_state_adapter: publishes the robot's joint angles (cellcal/joint_state) from the simulated robot, a
// measurement file or a controller bridge over UDP. The process: joint_state_adapter.hpp.
#include "joint_state_adapter.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  return componentMain<JointStateAdapter>(
      "cellcal_joint_state_adapter", argc, argv, [](CLI::App& app, JointStateAdapter::Options& o) {
        addSourceOptions(app, o.input, {"ros2"});
        app.add_option("--start-cell-time-s", o.start_cell_time_s, "sim: start the robot program at this cell time");
        app.add_option("--wait-for-readers", o.wait_for_readers,
                       "sim: start the program once JointState has a reader and RobotTruth has N (at most 10 s)");
        app.add_option("--ros-topic", o.ros_topic, "ros2: the ROS 2 topic of sensor_msgs/JointState")
            ->capture_default_str();
        app.add_option("--ros-joint-names", o.ros_joint_names,
                       "ros2: the JointState names of the robot's joints, base to flange (default: "
                       "robots[].ros2_joint_names)")
            ->delimiter(',');
        app.add_option("--settle-window-s", o.settle_window_s,
                       "ros2: settled once the joints stayed within the engine's settle tolerance this long")
            ->check(CLI::NonNegativeNumber)
            ->capture_default_str();
        app.add_option("--settle-velocity-radps", o.settle_velocity_radps,
                       "ros2: and no reported joint velocity above this")
            ->check(CLI::PositiveNumber)
            ->capture_default_str();
      });
}
