// Recordings of a cell's topics: MCAP files (recording/mcap) whose messages are the DDS payloads (CDR with its 4-byte
// encapsulation header, exactly as on the wire) and whose schemas are the IDL text (encoding "omgidl", one schema per
// type, named by the IDL's fully qualified type name, e.g. "cellcal::msg::JointState"). What `cellcal record`,
// `replay`, `validate`, `import csv` and `export` share. No DDS entities here: DDS types and their CDR only.
//
// Message times: log time = when the recorder received the sample (its wall clock, ns since the Unix epoch);
// publish time = the sample's DDS source timestamp; sequence = the DDS writer's sequence number (low 32 bits).
// Channel metadata: the topic's DDS type name, the QoS profile of the cell's XML and the reader's QoS as received
// ("reliability", "durability", "history", "depth").
#pragma once

#include <fastcdr/exceptions/Exception.h>

#include <cstdint>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "cellcal/components/dds_node.hpp"
#include "cellcal/mcap/mcap.hpp"

namespace cellcal {
const char* msgsIdlText();  // idl/cellcal_msgs.idl, compiled in (idl/CMakeLists.txt)
}

namespace cellcal::recording {

using namespace cellcal::components;  // the topic types and DdsNode

template <class M>
using Tag = TopicTag<M>;

// Calls f(Tag<M>{}) for every topic type of the cell, in the topic table's order (dds_node.hpp).
template <class F>
void forEachTopicType(F&& f) {
  forEachCellTopic(std::forward<F>(f));
}

// Calls f(Tag<M>{}) for the type of `topic`; false when the topic is not one of the cell's.
template <class F>
bool visitTopic(const std::string& topic, F&& f) {
  bool found = false;
  forEachTopicType([&](auto tag) {
    using M = typename decltype(tag)::type;
    if (!found && topic == TopicOf<M>::name) {
      found = true;
      f(tag);
    }
  });
  return found;
}

struct TopicInfo {
  std::string topic;        // "cellcal/joint_state"
  std::string type_name;    // "cellcal::msg::JointState"
  std::string qos_profile;  // endpoint profile of the cell's XML
  bool cell_input = false;  // TopicOf<M>::cell_input: what a replay republishes by default to drive a new engine
};
const std::vector<TopicInfo>& cellTopics();
// The cell topic named `topic`; throws std::runtime_error naming it when it is not one.
const TopicInfo& topicInfo(const std::string& topic);
// "all" -> every topic; "inputs" or "" -> the cell inputs; otherwise a comma-separated list of topic names.
// Throws std::runtime_error naming an unknown topic.
std::vector<std::string> parseTopicList(const std::string& list);

// One type support per type and thread: constructing one registers its TypeObject (slow).
template <class M>
typename TopicOf<M>::PubSub& typeSupport() {
  static thread_local typename TopicOf<M>::PubSub t;
  return t;
}

template <class M>
std::string typeName() {
  typename TopicOf<M>::PubSub t;
  return std::string(t.getName());
}

// The CDR payload of a sample with its encapsulation header, byte for byte what a DataWriter sends.
template <class M>
std::string encodeCdr(const M& m) {
  auto& t = typeSupport<M>();
  M& sample = const_cast<M&>(m);  // serialize() takes void*; it does not modify the sample
  eprosima::fastrtps::rtps::SerializedPayload_t payload(t.getSerializedSizeProvider(&sample)());
  if (!t.serialize(&sample, &payload)) throw std::runtime_error(std::string("CDR serialization of ") + t.getName() + " failed");
  return std::string(reinterpret_cast<const char*>(payload.data), payload.length);
}

// Decodes a payload written by encodeCdr (or any DDS writer of the type). False with *error when the bytes do not
// hold a sample of M (cut short, a sequence over its bound, a bad encapsulation header).
template <class M>
bool decodeCdr(const std::string& bytes, M* m, std::string* error) {
  auto& t = typeSupport<M>();
  if (bytes.size() < 4) {
    if (error) *error = "payload of " + std::to_string(bytes.size()) + " bytes (no CDR encapsulation header)";
    return false;
  }
  if (bytes[0] != 0 || (bytes[1] != 0 && bytes[1] != 1)) {
    if (error) *error = "not a plain CDR payload (encapsulation kind " + std::to_string(int(bytes[0])) + "," +
                        std::to_string(int(bytes[1])) + ")";
    return false;
  }
  eprosima::fastrtps::rtps::SerializedPayload_t payload(static_cast<std::uint32_t>(bytes.size()));
  std::copy(bytes.begin(), bytes.end(), payload.data);
  payload.length = static_cast<std::uint32_t>(bytes.size());
  try {
    if (t.deserialize(&payload, m)) return true;
    if (error) *error = "CDR payload of " + std::to_string(bytes.size()) + " bytes is cut short for " + std::string(t.getName());
  } catch (const eprosima::fastcdr::exception::Exception& e) {
    if (error) *error = std::string("CDR payload is not a ") + t.getName() + ": " + e.what();
  } catch (const std::exception& e) {
    if (error) *error = std::string("CDR payload is not a ") + t.getName() + ": " + e.what();
  }
  return false;
}

// Source stamps of a sample moved by delta_ns (replay re-stamping: source_stamp_ns, and the CalibrationState's
// last_measurement_stamp_ns).
template <class M>
void shiftStamps(M& m, std::int64_t delta_ns) {
  m.source_stamp_ns(static_cast<std::uint64_t>(static_cast<std::int64_t>(m.source_stamp_ns()) + delta_ns));
  if constexpr (std::is_same_v<M, msg::CalibrationState>)
    if (m.last_measurement_stamp_ns() > 0)
      m.last_measurement_stamp_ns(
          static_cast<std::uint64_t>(static_cast<std::int64_t>(m.last_measurement_stamp_ns()) + delta_ns));
}

// Writes a cellcal recording: schemas and channels on first use of a topic. Not thread-safe (the recorder locks).
class RecordingWriter {
 public:
  RecordingWriter(const std::string& path, std::size_t chunk_size_bytes = 1 << 20);
  // The channel of `topic` (a cell topic), created with its schema and `metadata` on first use.
  std::uint16_t channel(const std::string& topic, const std::map<std::string, std::string>& metadata = {});
  template <class M>
  void write(const M& m, std::uint64_t log_time_ns, std::uint64_t publish_time_ns, std::uint32_t sequence) {
    writeEncoded(TopicOf<M>::name, encodeCdr(m), log_time_ns, publish_time_ns, sequence);
  }
  void writeEncoded(const std::string& topic, std::string cdr, std::uint64_t log_time_ns,
                    std::uint64_t publish_time_ns, std::uint32_t sequence);
  mcap::Writer& file() { return writer_; }

 private:
  mcap::Writer writer_;
  std::uint16_t schema_id_ = 0;  // one IDL file holds every type; one schema record per type name
  std::map<std::string, std::uint16_t> schemas_, channels_;
};

// A recording read back: messages in log-time order (stable), with their topic.
struct RecordedMessage {
  const mcap::Message* message;
  const std::string* topic;
};
struct Recording {
  Recording() = default;
  Recording(const Recording&) = delete;  // in_log_order points into `file` and `topic_of_channel`
  Recording(Recording&&) = default;
  std::string path;
  mcap::ReadResult file;
  std::map<std::uint16_t, std::string> topic_of_channel;
  std::vector<RecordedMessage> in_log_order;
  std::uint64_t start_ns = 0, end_ns = 0;  // log times of the first and last message
  std::map<std::string, std::uint64_t> messages_per_topic;  // channels of other topics or encodings are left out
};
// Reads a recording (tolerating a file cut short when `tolerate_truncation`; `file.complete` says which).
// Throws std::runtime_error naming the file and byte when it is not MCAP.
Recording readRecording(const std::string& path, bool tolerate_truncation = true);

}  // namespace cellcal::recording
