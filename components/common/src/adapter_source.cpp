#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/adapter_source.hpp"

#include <unistd.h>

namespace cellcal::components {

void addSourceOptions(CLI::App& app, SourceOptions& o, const std::vector<std::string>& extra_sources) {
  addCommonOptions(app, o.process);
  std::vector<std::string> sources = {"sim", "csv", "udp"};
  sources.insert(sources.end(), extra_sources.begin(), extra_sources.end());
  std::string help;
  for (const auto& s : sources) help += (help.empty() ? "" : " | ") + s;
  app.add_option("--source", o.source, help)->check(CLI::IsMember(sources))->capture_default_str();
  app.add_option("--duration-s", o.duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  addCsvReplayOptions(app, o.csv);
  app.add_option("--udp-address", o.udp_address, "udp: address to bind")->capture_default_str();
  app.add_option("--udp-port", o.udp_port, "udp: port to bind (0: any)")->capture_default_str();
}

SourceAdapter::SourceAdapter(const SourceOptions& input, const char* identity)
    : input_(input), name_(identity), cell_(loadCell(input.process)), node_(cell_, "cellcal_" + name_, identity) {}

void SourceAdapter::runRos2() { throw std::runtime_error(name_ + " has no ROS 2 source"); }

int SourceAdapter::run() {
  if (input_.source == "sim") runSim();
  else if (input_.source == "csv") runCsv();
  else if (input_.source == "ros2") runRos2();
  else runUdp();
  node_.shutdown();  // no callback after this point
  stats::writeProcessStats(input_.process.stats_json, name_, node_.stats(), extra_, {{"source", input_.source}});
  return 0;
}

}  // namespace cellcal::components
