#include "cellcal/recording/recording.hpp"

#include <algorithm>
#include <sstream>

namespace cellcal::recording {

const std::vector<TopicInfo>& cellTopics() {
  static const std::vector<TopicInfo> topics = [] {
    std::vector<TopicInfo> v;
    forEachTopicType([&](auto tag) {
      using M = typename decltype(tag)::type;
      v.push_back({TopicOf<M>::name, typeName<M>(), TopicOf<M>::profile, TopicOf<M>::cell_input});
    });
    return v;
  }();
  return topics;
}

const TopicInfo& topicInfo(const std::string& topic) {
  auto info = std::find_if(cellTopics().begin(), cellTopics().end(), [&](const auto& t) { return t.topic == topic; });
  if (info == cellTopics().end()) throw std::runtime_error("not a cellcal topic: " + topic);
  return *info;
}

std::vector<std::string> parseTopicList(const std::string& list) {
  std::vector<std::string> out;
  if (list == "all" || list == "inputs" || list.empty()) {
    for (const auto& t : cellTopics())
      if (list == "all" || t.cell_input) out.push_back(t.topic);
    return out;
  }
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item.empty()) continue;
    const bool known = std::any_of(cellTopics().begin(), cellTopics().end(), [&](const auto& t) { return t.topic == item; });
    if (!known) {
      std::string names;
      for (const auto& t : cellTopics()) names += " " + t.topic;
      throw std::runtime_error("--topics: '" + item + "' is not a cellcal topic (known:" + names + ", or all / inputs)");
    }
    if (std::find(out.begin(), out.end(), item) == out.end()) out.push_back(item);
  }
  if (out.empty()) throw std::runtime_error("--topics: no topic named");
  return out;
}

RecordingWriter::RecordingWriter(const std::string& path, std::size_t chunk_size_bytes)
    : writer_(path, [&] {
        mcap::WriterOptions o;
        o.chunk_size_bytes = chunk_size_bytes;
        return o;
      }()) {}

std::uint16_t RecordingWriter::channel(const std::string& topic, const std::map<std::string, std::string>& metadata) {
  auto it = channels_.find(topic);
  if (it != channels_.end()) return it->second;
  const TopicInfo& info = topicInfo(topic);
  auto s = schemas_.find(info.type_name);
  if (s == schemas_.end()) s = schemas_.emplace(info.type_name, writer_.addSchema(info.type_name, "omgidl", msgsIdlText())).first;
  std::map<std::string, std::string> md = metadata;
  md.emplace("dds_type", info.type_name);
  md.emplace("qos_profile", info.qos_profile);
  const std::uint16_t id = writer_.addChannel(s->second, topic, "cdr", md);
  channels_[topic] = id;
  return id;
}

void RecordingWriter::writeEncoded(const std::string& topic, std::string cdr, std::uint64_t log_time_ns,
                                   std::uint64_t publish_time_ns, std::uint32_t sequence) {
  mcap::Message m;
  m.channel_id = channel(topic);
  m.sequence = sequence;
  m.log_time_ns = log_time_ns;
  m.publish_time_ns = publish_time_ns;
  m.data = std::move(cdr);
  writer_.write(m);
}

Recording readRecording(const std::string& path, bool tolerate_truncation) {
  Recording r;
  r.path = path;
  mcap::ReadOptions o;
  o.tolerate_truncation = tolerate_truncation;
  r.file = mcap::readFile(path, o);
  for (const auto& c : r.file.channels) {
    const bool known = std::any_of(cellTopics().begin(), cellTopics().end(), [&](const auto& t) { return t.topic == c.topic; });
    if (known && c.message_encoding == "cdr") r.topic_of_channel[c.id] = c.topic;
  }
  for (const auto& m : r.file.messages) {
    auto it = r.topic_of_channel.find(m.channel_id);
    if (it == r.topic_of_channel.end()) continue;
    r.in_log_order.push_back({&m, &it->second});
    ++r.messages_per_topic[it->second];
  }
  std::stable_sort(r.in_log_order.begin(), r.in_log_order.end(),
                   [](const RecordedMessage& a, const RecordedMessage& b) { return a.message->log_time_ns < b.message->log_time_ns; });
  if (!r.in_log_order.empty()) {
    r.start_ns = r.in_log_order.front().message->log_time_ns;
    r.end_ns = r.in_log_order.back().message->log_time_ns;
  }
  return r;
}

}  // namespace cellcal::recording
