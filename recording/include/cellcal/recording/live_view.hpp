// The live cell for Foxglove: every cell topic read from DDS and served over the Foxglove WebSocket protocol
// (recording/foxglove), with the same channels as a recording: topic = the DDS topic name, encoding "cdr" (the
// payload with its encapsulation header, as on the wire), schema = the IDL text (schemaEncoding "omgidl",
// schemaName = the IDL type name). The receive time of a Message Data frame is the wall clock when the sample came
// in, as a recording's log time, so a Foxglove layout plots the live cell and its recordings alike
// (config/foxglove/cellcal.json).
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "cellcal/components/dds_node.hpp"
#include "cellcal/foxglove/server.hpp"

namespace cellcal::recording {

struct LiveViewOptions {
  foxglove::ServerOptions server;
  std::vector<std::string> topics;  // cell topics to serve (parseTopicList); empty: all
};

class LiveView {
 public:
  // Listens (throws naming address:port when it cannot), then joins the cell's domain as an observer.
  LiveView(const CellConfig& cell, const LiveViewOptions& options);
  // Leaves the domain first (no sample after this), then closes the clients.
  ~LiveView();
  LiveView(const LiveView&) = delete;
  LiveView& operator=(const LiveView&) = delete;

  std::uint16_t port() const { return server_.port(); }
  foxglove::ServerStats serverStats() const { return server_.stats(); }
  std::uint64_t samplesReceived() const;
  // Per topic: samples received, DDS latency (source timestamp -> received here) p50/p99 in ms over the last
  // kLatencySamples samples; the server's counts.
  nlohmann::json summary() const;

 private:
  struct TopicStats {
    std::uint64_t received = 0;
    std::vector<double> dds_latency_ms;  // the last kLatencySamples (a ring: a live view runs for days)
    std::size_t next = 0;
  };
  static constexpr std::size_t kLatencySamples = 1u << 16;
  mutable std::mutex mutex_;
  std::vector<std::string> topics_;
  std::vector<TopicStats> stats_;  // same order as topics_
  foxglove::Server server_;        // before node_: destroyed after it (the readers publish into it)
  std::unique_ptr<components::DdsNode> node_;
};

}  // namespace cellcal::recording
