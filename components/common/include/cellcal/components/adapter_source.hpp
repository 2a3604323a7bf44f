// Where an adapter's readings come from, the same for both adapters:
//   sim  the simulated robot and tracker of the cell file
//   csv  a measurement file replayed in time (csv_replay.hpp)
//   udp  one line per reading from a bridge to the real controller or tracker (udp_lines.hpp)
//   ros2 (joint-state adapter) a ROS 2 driver's sensor_msgs/JointState, read directly over DDS (ros2.hpp)
#pragma once

#include <CLI/CLI.hpp>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cellcal/components/csv_replay.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"

namespace cellcal::components {

struct SourceOptions {
  ProcessOptions process;
  std::string source = "sim";  // sim | csv | udp | ros2 (where the adapter offers it)
  double duration_s = 0;       // 0: until SIGINT/SIGTERM (csv: the end of the file)
  std::string udp_address = "127.0.0.1";
  int udp_port = 0;
  CsvReplayOptions csv;

  static SourceOptions withUdpPort(int port) {
    SourceOptions o;
    o.udp_port = port;
    return o;
  }
};

// The common options (process.hpp), --source (sim, csv, udp and `extra_sources`), --duration-s, the csv options
// (csv_replay.hpp), --udp-address and --udp-port.
void addSourceOptions(CLI::App& app, SourceOptions& o, const std::vector<std::string>& extra_sources = {});

// What both adapters are: a participant publishing the readings of one source. The constructor loads the cell file
// and joins the domain as `identity` (dds_node.hpp); run() publishes from the chosen source until SIGINT/SIGTERM, the
// end of the file or --duration-s, leaves the domain and writes --stats-json (with the source's own counts, extra_).
class SourceAdapter {
 public:
  virtual ~SourceAdapter() = default;
  SourceAdapter(const SourceAdapter&) = delete;
  SourceAdapter& operator=(const SourceAdapter&) = delete;
  int run();

 protected:
  SourceAdapter(const SourceOptions& input, const char* identity);
  virtual void runSim() = 0;
  virtual void runCsv() = 0;
  virtual void runUdp() = 0;
  virtual void runRos2();  // throws: only the joint-state adapter has a ROS 2 source

  const SourceOptions input_;
  const std::string name_;  // the identity: "tracker_adapter", "joint_state_adapter"
  const CellConfig cell_;
  DdsNode node_;
  nlohmann::json extra_ = nlohmann::json::object();
};

}  // namespace cellcal::components
