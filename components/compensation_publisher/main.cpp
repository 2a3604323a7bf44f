// cellcal_compensation_publisher: corrected targets for the unmodified robot controller (cellcal/target_pose ->
// cellcal/compensated_target) with the latest healthy calibration. The process: compensation_publisher.hpp.
#include "compensation_publisher.hpp"

using namespace cellcal::components;

int main(int argc, char** argv) {
  CLI::App app{"cellcal compensation publisher: corrected targets for the unmodified robot controller"};
  app.footer(manFooter(
      "cellcal/target_pose, cellcal/calibration_state, cellcal/calibration_diagnostics",
      "cellcal/compensated_target (never a correction beyond compensation.max_correction_mm / _deg); with\n"
      "  --ros-pose-topic also the applied corrections as ROS 2 geometry_msgs/PoseStamped",
      "  cellcal_compensation_publisher                                   answer targets with the latest ok calibration\n"
      "  cellcal_compensation_publisher --wait-for-calibration-s 30      wait for the engine before answering\n"
      "  cellcal_compensation_publisher --ros-pose-topic /cellcal/corrected_pose   corrections for a ROS 2 node\n",
      ""));
  CompensationPublisher::Options o;
  addCommonOptions(app, o.process);
  app.add_option("--wait-for-calibration-s", o.wait_for_calibration_s,
                 "at start, wait this long for every robot's calibration before taking targets")
      ->capture_default_str();
  app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  app.add_option("--ros-pose-topic", o.ros_pose_topic,
                 "also publish each applied correction as geometry_msgs/PoseStamped on this ROS 2 topic "
                 "(several robots: <topic>/<robot_id>)");
  app.add_option("--ros-frame-id", o.ros_frame_id, "header.frame_id of those poses (the targets' frame)")
      ->capture_default_str();
  return runMain("cellcal_compensation_publisher", argc, argv, app, [&] { return CompensationPublisher(o).run(); });
}
