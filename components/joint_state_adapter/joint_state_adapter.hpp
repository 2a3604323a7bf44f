// The joint-state adapter process: publishes the robot's joint angles on cellcal/joint_state.
//   sim  the simulated robot of the cell file (one stream per robot; also its truth on cellcal/sim/robot_truth, for
//        the simulated tracker and the launcher)
//   csv  the joints of a measurement file (CSV v1), replayed in time (common/csv_replay.hpp); give the tracker adapter
//        the same file and --start-unix-ns
//   udp  one line per reading from a controller bridge (udp_lines.hpp, docs/udp-sources.md)
// Lifetime: the constructor joins the domain and creates the writer; run() publishes until SIGINT/SIGTERM, the end of
// the file or the duration, leaves the domain and writes --stats-json.
#pragma once

#include <string>

#include "cellcal/components/adapter_source.hpp"
#include "cellcal/components/dds_node.hpp"

namespace cellcal::components {

class JointStateAdapter : public SourceAdapter {
 public:
  struct Options {
    SourceOptions input = SourceOptions::withUdpPort(5610);
    double start_cell_time_s = 0;
    int wait_for_readers = 0;  // sim: start once JointState has a reader and RobotTruth has this many
  };
  explicit JointStateAdapter(const Options& options);

 private:
  void runSim() override;
  void runCsv() override;
  void runUdp() override;

  Options options_;
  Writer<msg::JointState> joints_;
};

}  // namespace cellcal::components
