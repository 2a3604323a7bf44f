// The tracker adapter process: publishes 6D poses (or 3D points) of the target on the flange on cellcal/tracker_pose.
//   sim  the core simulator's tracker (AT960 noise, the robot's repeatability) measuring the simulated robot it learns
//        from cellcal/sim/robot_truth: one reading per settled pose of the robot program, stamped with the instant of
//        the robot state it measured (a tracker triggered in sync with the controller)
//   csv  the readings of a measurement file (CSV v1), row k stamped start + t_k (common/csv_replay.hpp)
//   udp  one line per reading from a tracker bridge (udp_lines.hpp, docs/udp-sources.md)
// Lifetime: the constructor joins the domain and creates the writer; run() publishes until SIGINT/SIGTERM, the end of
// the file or the duration, leaves the domain and writes --stats-json.
#pragma once

#include <string>

#include "cellcal/components/adapter_source.hpp"
#include "cellcal/components/dds_node.hpp"

namespace cellcal::components {

class TrackerAdapter : public SourceAdapter {
 public:
  struct Options {
    SourceOptions input = SourceOptions::withUdpPort(5611);
    double sigma_position_mm = 0.015;  // csv: the readings' noise
    double sigma_orientation_deg = 0.005;
    // sim: measure only once TrackerPose has this many readers (the engines, the recorder), at most 10 s: readings
    // made before the engine's reader is found are lost (best effort), and on a lossy link that can take seconds.
    int wait_for_readers = 0;
  };
  explicit TrackerAdapter(const Options& options);

 private:
  void runSim() override;
  void runCsv() override;
  void runUdp() override;

  Options options_;
  Writer<msg::TrackerPose> writer_;
};

}  // namespace cellcal::components
