// cellcal_compensation_publisher: corrected targets for the unmodified robot controller (cellcal/target_pose ->
// cellcal/compensated_target) with the latest healthy calibration. The process: compensation_publisher.hpp.
#include "compensation_publisher.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  return componentMain<CompensationPublisher>(
      "cellcal_compensation_publisher", argc, argv, [](CLI::App& app, CompensationPublisher::Options& o) {
        addCommonOptions(app, o.process);
        app.add_option("--wait-for-calibration-s", o.wait_for_calibration_s,
                       "at start, wait this long for every robot's calibration before taking targets")
            ->capture_default_str();
        app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
        app.add_flag("--pass-through", o.pass_through,
                     "answer every target and setpoint unchanged, reading and applying no calibration (a controller "
                     "bridge commissioned before a calibration; bench-cell --pass-through: the transport's floor)");
        app.add_option("--ros-pose-topic", o.ros_pose_topic,
                       "also publish each applied correction as geometry_msgs/PoseStamped on this ROS 2 topic "
                       "(several robots: <topic>/<robot_id>)");
        app.add_option("--ros-frame-id", o.ros_frame_id, "header.frame_id of those poses (the targets' frame)")
            ->capture_default_str();
        app.add_option("--ros-description-topic", o.ros_description_topic,
                       "also publish the robot's URDF with the calibrated joint origins as std_msgs/String on this "
                       "ROS 2 topic after each new ok calibration (transient local; several robots: "
                       "<topic>/<robot_id>)");
      });
}
