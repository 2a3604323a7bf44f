// `cellcal foxglove`: the live cell in Foxglove (recording/live_view.hpp over the Foxglove WebSocket protocol).
#include <sys/resource.h>

#include <chrono>
#include <cstdio>
#include <fstream>

#include "cellcal/components/process.hpp"
#include "cellcal/components/profile_probe.hpp"
#include "cellcal/recording/live_view.hpp"
#include "cellcal/recording/recording.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

using namespace cellcal::components;
using namespace cellcal::recording;

struct FoxgloveArgs {
  ProcessOptions common;
  std::string address = "127.0.0.1", topics = "all", port_file, summary_json;
  int port = 8765;
  double duration_s = 0;
  double max_client_queue_mib = 16;
  bool quiet = false;
};

void addOptions(CLI::App& cmd, FoxgloveArgs& a) {
  addCommonOptions(cmd, a.common);
  cmd.add_option("--address", a.address, "IP address to listen on (0.0.0.0: every interface)")->capture_default_str();
  cmd.add_option("--port", a.port, "TCP port (0: any free port; --port-file says which)")->capture_default_str();
  cmd.add_option("--port-file", a.port_file, "write the port listened on to this file")->check(outputFile());
  cmd.add_option("--topics", a.topics, "all | inputs | comma-separated topic names")->capture_default_str();
  cmd.add_option("--duration-s", a.duration_s, "stop after this many seconds (0: until SIGINT/SIGTERM)");
  cmd.add_option("--max-client-queue-mib", a.max_client_queue_mib,
                 "a client with more unsent than this loses messages")->capture_default_str();
  cmd.add_option("--summary-json", a.summary_json,
                 "at exit: samples per topic, DDS latency p50/p99, frames sent and dropped, CPU")->check(outputFile());
  cmd.add_flag("-q,--quiet", a.quiet, "no status lines");
}

double cpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

int runFoxglove(const FoxgloveArgs& a) {
  installStopHandlers();
  const CellConfig cell = loadCell(a.common);
  if (a.port < 0 || a.port > 65535) throw std::runtime_error("--port " + std::to_string(a.port) + ": not a TCP port");
  if (!(a.max_client_queue_mib > 0)) throw std::runtime_error("--max-client-queue-mib must be > 0");
  LiveViewOptions o;
  o.topics = parseTopicList(a.topics);
  o.server.address = a.address;
  o.server.port = static_cast<std::uint16_t>(a.port);
  o.server.max_queued_bytes_per_client = static_cast<std::size_t>(a.max_client_queue_mib * 1024 * 1024);
  o.server.metadata = {{"domain_id", std::to_string(cell.dds.domain_id)},
                       {"dds_profile", cell.dds.participant_profile},
                       {"security", cell.dds.security_dir.empty() ? "off" : "on"}};
  const double cpu0 = cpuSeconds();
  const auto start = std::chrono::steady_clock::now();
  LiveView view(cell, o);
  if (!a.port_file.empty()) {
    std::ofstream(a.port_file) << view.port() << "\n";
  }
  const std::string shown = a.address == "0.0.0.0" ? "<this host>" : a.address;
  std::fprintf(stderr,
               "foxglove: %zu topic(s) of domain %d (profile %s, security %s) served on ws://%s:%u%s\n"
               "foxglove: in Foxglove: Open connection > Foxglove WebSocket > ws://%s:%u; layout: Import "
               "config/foxglove/cellcal.json\n",
               o.topics.size(), cell.dds.domain_id, cell.dds.participant_profile.c_str(),
               cell.dds.security_dir.empty() ? "off" : "on", shown.c_str(), view.port(),
               a.address == "127.0.0.1" ? " (this host only: --address 0.0.0.0 serves the cell network)" : "",
               shown.c_str(), view.port());
  const RunLimit limit(a.duration_s);
  std::uint64_t clients_seen = 0;
  auto next_status = start + std::chrono::seconds(10);
  std::uint64_t last_received = 0;
  bool looked_elsewhere = false;
  while (sleepUntil(std::chrono::steady_clock::now() + std::chrono::milliseconds(50)) && !limit.timeUp()) {
    const auto st = view.serverStats();
    if (!a.quiet && st.clients_now != clients_seen) {
      std::fprintf(stderr, "foxglove: %llu client(s) connected\n", static_cast<unsigned long long>(st.clients_now));
      clients_seen = st.clients_now;
    }
    const auto now = std::chrono::steady_clock::now();
    if (!a.quiet && now >= next_status) {
      next_status = now + std::chrono::seconds(10);
      const std::uint64_t received = view.samplesReceived();
      std::fprintf(stderr, "foxglove: %llu samples from the cell (%llu in the last 10 s), %llu frames sent, %llu "
                   "dropped for slow clients%s\n",
                   static_cast<unsigned long long>(received), static_cast<unsigned long long>(received - last_received),
                   static_cast<unsigned long long>(st.frames_sent), static_cast<unsigned long long>(st.frames_dropped),
                   received == 0 ? " - nothing from the cell yet" : "");
      last_received = received;
      if (received == 0 && !looked_elsewhere) {  // once: where is the cell?
        looked_elsewhere = true;
        std::fprintf(stderr, "%s", describeSightings(cell, probeOtherProfiles(cell), "foxglove: ").c_str());
      }
    }
  }
  nlohmann::json summary = view.summary();
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double cpu_s = cpuSeconds() - cpu0;
  summary["wall_s"] = wall_s;
  summary["cpu_s"] = cpu_s;
  summary["cpu_percent_of_one_core"] = wall_s > 0 ? 100.0 * cpu_s / wall_s : 0.0;
  const std::uint64_t received = view.samplesReceived();
  writeJsonFile(a.summary_json, summary);
  std::printf("foxglove: stopped after %.1f s: %llu samples from the cell, %llu frames sent to %llu client(s), %llu "
              "dropped for slow clients; CPU %.1f %% of one core\n",
              wall_s, static_cast<unsigned long long>(received),
              static_cast<unsigned long long>(summary["server"]["frames_sent"].get<std::uint64_t>()),
              static_cast<unsigned long long>(summary["server"]["clients_accepted"].get<std::uint64_t>()),
              static_cast<unsigned long long>(summary["server"]["frames_dropped_slow_client"].get<std::uint64_t>()),
              summary["cpu_percent_of_one_core"].get<double>());
  if (received == 0) {
    std::fprintf(stderr, "foxglove: WARNING: nothing received from the cell on domain %d with profile %s (exit 3)\n",
                 cell.dds.domain_id, cell.dds.participant_profile.c_str());
    return 3;
  }
  return 0;
}

}  // namespace

Runner addFoxgloveCommand(CLI::App& app) { return addCommand(app, "foxglove", addOptions, runFoxglove); }

}  // namespace cellcal::cli
