#include "cellcal/recording/live_view.hpp"

#include "cellcal/components/process.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/recording/recording.hpp"

namespace cellcal::recording {
namespace {

// One channel per served topic, numbered from 1, described exactly as RecordingWriter describes it.
std::vector<foxglove::Channel> channelsOf(const std::vector<std::string>& topics) {
  std::vector<foxglove::Channel> out;
  for (const auto& t : topics)
    out.push_back({static_cast<std::uint32_t>(out.size() + 1), t, "cdr", topicInfo(t).type_name, msgsIdlText(), "omgidl"});
  return out;
}

}  // namespace

LiveView::LiveView(const CellConfig& cell, const LiveViewOptions& options)
    : topics_(options.topics.empty() ? parseTopicList("all") : options.topics),
      stats_(topics_.size()),
      server_(options.server, channelsOf(topics_)) {
  node_ = std::make_unique<components::DdsNode>(cell, "cellcal_foxglove", components::identity::kObserver);
  for (std::size_t i = 0; i < topics_.size(); ++i) {
    visitTopic(topics_[i], [&](auto tag) {
      using M = typename decltype(tag)::type;
      const auto channel = static_cast<std::uint32_t>(i + 1);
      TopicStats* st = &stats_[i];
      node_->reader<M>([this, st, channel](const M& m, const fdds::SampleInfo& info) {
        const std::int64_t now = components::wallNs();
        server_.publish(channel, static_cast<std::uint64_t>(now), encodeCdr(m));
        const double latency_ms = static_cast<double>(now - info.source_timestamp.to_ns()) * 1e-6;
        std::lock_guard<std::mutex> lock(mutex_);
        ++st->received;
        if (st->dds_latency_ms.size() < kLatencySamples) st->dds_latency_ms.push_back(latency_ms);
        else st->dds_latency_ms[st->next++ % kLatencySamples] = latency_ms;
      });
    });
  }
}

LiveView::~LiveView() {
  node_.reset();  // no callback after this; the server closes its clients in its own destructor
}

std::uint64_t LiveView::samplesReceived() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::uint64_t n = 0;
  for (const auto& s : stats_) n += s.received;
  return n;
}

nlohmann::json LiveView::summary() const {
  nlohmann::json topics = nlohmann::json::object();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (std::size_t i = 0; i < topics_.size(); ++i) {
      const auto& s = stats_[i];
      nlohmann::json t = {{"received", s.received}};
      if (!s.dds_latency_ms.empty()) {
        t["dds_latency_p50_ms"] = percentile(s.dds_latency_ms, 0.5);
        t["dds_latency_p99_ms"] = percentile(s.dds_latency_ms, 0.99);
      }
      topics[topics_[i]] = t;
    }
  }
  const auto st = server_.stats();
  return {{"port", server_.port()},
          {"topics", topics},
          {"server",
           {{"clients_accepted", st.clients_accepted}, {"clients_rejected", st.clients_rejected},
            {"clients_now", st.clients_now}, {"messages_published", st.messages_published},
            {"frames_sent", st.frames_sent}, {"frames_dropped_slow_client", st.frames_dropped},
            {"bytes_sent", st.bytes_sent}, {"requests_refused", st.requests_refused}}}};
}

}  // namespace cellcal::recording
