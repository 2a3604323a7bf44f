// The joint-state adapter process: publishes the robot's joint angles on cellcal/joint_state.
//   sim  the simulated robot of the cell file (one stream per robot; also its truth on cellcal/sim/robot_truth, for
//        the simulated tracker and the launcher)
//   csv  the joints of a measurement file (CSV v1), replayed in time (common/csv_replay.hpp); give the tracker adapter
//        the same file and --start-unix-ns
//   udp  one line per reading from a controller bridge (udp_lines.hpp, docs/udp-sources.md)
//   ros2 a ROS 2 driver's sensor_msgs/JointState (e.g. a UR driver's /joint_states), read directly over DDS on the
//        cell's participant: joints mapped by name (robots[].ros2_joint_names or --ros-joint-names), stamps from the
//        header, `settled` from the joint stream (ros2.hpp StandStillDetector), docs/ros2.md
// Lifetime: the constructor joins the domain and creates the writer; run() publishes until SIGINT/SIGTERM, the end of
// the file or the duration, leaves the domain and writes --stats-json.
#pragma once

#include <string>
#include <vector>

#include "cellcal/components/adapter_source.hpp"
#include "cellcal/components/dds_node.hpp"

namespace cellcal::components {

class JointStateAdapter : public SourceAdapter {
 public:
  struct Options {
    SourceOptions input = SourceOptions::withUdpPort(5610);
    double start_cell_time_s = 0;
    int wait_for_readers = 0;  // sim: start once JointState has a reader and RobotTruth has this many
    // ros2
    std::string ros_topic = "/joint_states";
    std::vector<std::string> ros_joint_names;  // overrides robots[].ros2_joint_names (robot: --robot-id)
    double settle_window_s = 0.25;            // still this long (and within the engine's settle tolerance) = settled
    double settle_velocity_radps = 1e-3;      // and no reported joint velocity above this
  };
  explicit JointStateAdapter(const Options& options);

 private:
  void runSim() override;
  void runCsv() override;
  void runUdp() override;
  void runRos2() override;

  Options options_;
  Writer<msg::JointState> joints_;
};

}  // namespace cellcal::components
