// One DomainParticipant per process, with typed writers and readers on cellcal's topics. The only place that knows
// Fast DDS entity plumbing; components see `DdsNode::writer<Msg>()` and `DdsNode::reader<Msg>(callback)`.
// Topic names, types and QoS profile per message type are in TopicOf<> (one table, docs/ARCHITECTURE.md).
#pragma once

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>

#include <atomic>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "cellcal/components/key_filter.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal_msgsPubSubTypes.h"
#include "ros2_msgsPubSubTypes.h"

namespace cellcal::components {

namespace fdds = eprosima::fastdds::dds;

template <class M>
struct TopicOf;
#define CELLCAL_TOPIC(Msg, Name, Profile, Input)                \
  template <>                                                   \
  struct TopicOf<Msg> {                                         \
    using PubSub = Msg##PubSubType;                             \
    static constexpr const char* name = Name;                   \
    static constexpr const char* profile = Profile;             \
    static constexpr bool cell_input = Input;                   \
  };
// The cell's topics, one line each: type, name, QoS profile of the cell's XML, and whether the cell's sources publish
// it (adapters, simulation, the application's targets; not the engine or the compensation publisher: what a replay
// republishes by default to drive a new engine). TopicOf<>, forEachCellTopic (the recorder, replay, the Foxglove
// bridge, status) and the recording's topic list all come from this table: a new topic is its IDL and one line here.
// The simulation's truth is not an input: replayed, it would make a sim tracker adapter measure again.
#define CELLCAL_CELL_TOPICS(X)                                                                         \
  X(cellcal::msg::JointState, "cellcal/joint_state", "sensor_stream", true)                            \
  X(cellcal::msg::TrackerPose, "cellcal/tracker_pose", "sensor_stream", true)                          \
  X(cellcal::msg::CalibrationState, "cellcal/calibration_state", "calibration_state", false)           \
  X(cellcal::msg::CalibrationDiagnostics, "cellcal/calibration_diagnostics", "calibration_state", false) \
  X(cellcal::msg::PoseRequest, "cellcal/pose_request", "calibration_state", false)                     \
  X(cellcal::msg::TargetPose, "cellcal/target_pose", "command", true)                                  \
  X(cellcal::msg::CompensatedTarget, "cellcal/compensated_target", "command", false)                   \
  X(cellcal::msg::ServoSetpoint, "cellcal/servo_setpoint", "servo", false)                             \
  X(cellcal::msg::ServoCorrection, "cellcal/servo_correction", "servo", false)                         \
  X(cellcal::sim::RobotTruth, "cellcal/sim/robot_truth", "sensor_stream", false)
CELLCAL_CELL_TOPICS(CELLCAL_TOPIC)
// ROS 2 messages (ros2_msgs.idl): no fixed topic, the user names it (ros2.hpp turns "/joint_states" into
// "rt/joint_states"); QoS profile "ros2": readers best effort (they match reliable and best-effort publishers),
// writers reliable, volatile, keep last 10 (ROS 2's default). std_msgs/String carries robot_description: profile
// "ros2_latched" (reliable, transient local, keep last 1, as robot_state_publisher).
CELLCAL_TOPIC(sensor_msgs::msg::dds_::JointState_, "", "ros2", false)
CELLCAL_TOPIC(geometry_msgs::msg::dds_::PoseStamped_, "", "ros2", false)
CELLCAL_TOPIC(std_msgs::msg::dds_::String_, "", "ros2_latched", false)
#undef CELLCAL_TOPIC

template <class M>
struct TopicTag {
  using type = M;
};
// Calls f(TopicTag<M>{}) for every topic type of the cell, in the table's order.
template <class F>
void forEachCellTopic(F&& f) {
#define CELLCAL_VISIT_TOPIC(Msg, Name, Profile, Input) f(TopicTag<Msg>{});
  CELLCAL_CELL_TOPICS(CELLCAL_VISIT_TOPIC)
#undef CELLCAL_VISIT_TOPIC
}

struct TopicCounters {
  std::atomic<std::uint64_t> published{0}, received{0};
  std::atomic<int> matched_writers{0};  // writers our reader of the topic is matched with (a dead peer leaves on lease expiry)
};

template <class M>
class Writer {
 public:
  Writer(fdds::DataWriter* w, std::shared_ptr<TopicCounters> c) : w_(w), c_(std::move(c)) {}
  // False when DDS refused the sample (the caller decides whether that matters).
  bool write(M& sample) {
    const bool ok = w_->write(&sample);
    if (ok) ++c_->published;
    return ok;
  }
  fdds::DataWriter* entity() const { return w_; }

 private:
  fdds::DataWriter* w_;
  std::shared_ptr<TopicCounters> c_;
};

// Who a participant is under DDS Security: the certificate <security_dir>/<identity>.cert.pem and the grant of that
// name in permissions.p7s (config/security/permissions.xml says what each may publish and subscribe).
namespace identity {
constexpr const char* kTrackerAdapter = "tracker_adapter";
constexpr const char* kJointStateAdapter = "joint_state_adapter";
constexpr const char* kCalibrationEngine = "calibration_engine";
constexpr const char* kCompensationPublisher = "compensation_publisher";
constexpr const char* kApplication = "application";  // the cell's program: sends TargetPose, reads everything
constexpr const char* kObserver = "observer";        // recorder, status, tests: reads everything, publishes nothing
constexpr const char* kReplay = "replay";            // replay and bench-cell: publishes recorded/synthetic inputs
}  // namespace identity

class DdsNode {
 public:
  // Loads the cell's profile file and creates the participant from dds.participant_profile on dds.domain_id; with
  // dds.security_dir set, as `identity` under DDS Security (PKI-DH authentication, signed governance and permissions,
  // AES-GCM-GMAC). Throws std::runtime_error naming the file/profile/identity when that fails.
  DdsNode(const CellConfig& cell, const std::string& node_name, const std::string& identity);
  ~DdsNode();
  DdsNode(const DdsNode&) = delete;
  DdsNode& operator=(const DdsNode&) = delete;

  // `topic_name`: the DDS topic when M has no fixed one (the ROS 2 types); empty: TopicOf<M>::name.
  template <class M>
  Writer<M> writer(const std::string& topic_name = "") {
    const std::string name = topicName<M>(topic_name);
    fdds::Topic* t = topic<M>(name);
    fdds::DataWriter* w = publisher_->create_datawriter_with_profile(t, TopicOf<M>::profile);
    if (!w)
      throw std::runtime_error("cannot create a writer on " + name + " with profile " + TopicOf<M>::profile +
                               (secure_ ? " (DDS Security: the permissions may not grant it)" : ""));
    return Writer<M>(w, counters(name));
  }

  // `on_sample` runs on a Fast DDS thread for every valid sample; keep it short and thread-safe. Returns the reader
  // (owned by the node) for its QoS and status.
  template <class M>
  fdds::DataReader* reader(std::function<void(const M&, const fdds::SampleInfo&)> on_sample,
                           const std::string& topic_name = "") {
    const std::string name = topicName<M>(topic_name);
    fdds::TopicDescription* t = shardFilter<M>(topic<M>(name), name);
    auto l = std::make_unique<Listener<M>>(std::move(on_sample), counters(name));
    fdds::DataReader* r = subscriber_->create_datareader_with_profile(t, TopicOf<M>::profile, l.get());
    if (!r)
      throw std::runtime_error("cannot create a reader on " + name +
                               (secure_ ? " (DDS Security: the permissions may not grant it)" : ""));
    listeners_.push_back(std::move(l));
    return r;
  }

  // The QoS a reader of M gets from the cell's profile (what reader<M>() will use).
  template <class M>
  fdds::DataReaderQos readerQos() const {
    fdds::DataReaderQos q;
    if (subscriber_->get_datareader_qos_from_profile(TopicOf<M>::profile, q) != ReturnCode_t::RETCODE_OK)
      throw std::runtime_error(std::string("no data reader profile ") + TopicOf<M>::profile);
    return q;
  }

  // Deletes the readers (no callback runs after that: call it before the state the callbacks use goes away), waits
  // up to 1 s in all for the reliable writers' samples to be acknowledged (what a process published last reaches its
  // readers on a clean exit), then deletes the writers and the participant. stats() stays valid. Idempotent; the
  // destructor calls it.
  void shutdown();

  // {"<topic>": {"published": n, "received": n}}
  nlohmann::json stats() const;
  // Writers matched with our reader of M (0 before reader<M>() and once every writer left: the participant lease
  // of the profile, 3 s, bounds how late a killed peer is noticed).
  template <class M>
  int matchedWriters() {
    return counters(TopicOf<M>::name)->matched_writers.load();
  }
  // The same count as a value to read on a hot path (no lookup): valid as long as the node.
  template <class M>
  const std::atomic<int>& matchedWritersCount() {
    return counters(TopicOf<M>::name)->matched_writers;
  }
  fdds::DomainParticipant* participant() const { return participant_; }
  int domainId() const { return domain_id_; }
  // The largest UDP receive buffer the participant profile's transports ask for, bytes (0: the OS default). The
  // kernel caps it at net.core.rmem_max (host_limits.hpp); the node warns at start when it does.
  std::uint32_t udpReceiveBufferBytes() const { return udp_receive_buffer_bytes_; }

 private:
  template <class M>
  struct Listener : fdds::DataReaderListener {
    Listener(std::function<void(const M&, const fdds::SampleInfo&)> f, std::shared_ptr<TopicCounters> c)
        : fn(std::move(f)), counters(std::move(c)) {}
    void on_data_available(fdds::DataReader* reader) override {
      // One sample per thread, reused: fastddsgen 2.3's -typeobject constructors register every type of the IDL in
      // the TypeObjectFactory again on each construction (tens of microseconds).
      static thread_local M sample;
      fdds::SampleInfo info;
      while (reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
        if (!info.valid_data) continue;
        ++counters->received;
        fn(sample, info);
      }
    }
    void on_subscription_matched(fdds::DataReader*, const fdds::SubscriptionMatchedStatus& status) override {
      counters->matched_writers = status.current_count;
    }
    std::function<void(const M&, const fdds::SampleInfo&)> fn;
    std::shared_ptr<TopicCounters> counters;
  };

  template <class M>
  static std::string topicName(const std::string& given) {
    const std::string name = given.empty() ? std::string(TopicOf<M>::name) : given;
    if (name.empty()) throw std::invalid_argument("DdsNode: this message type has no fixed topic: name one");
    return name;
  }

  template <class M>
  fdds::Topic* topic(const std::string& name) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = topics_.find(name);
    if (it != topics_.end()) return it->second;
    fdds::TypeSupport type(new typename TopicOf<M>::PubSub());
    // Discovery carries the TypeInformation (hashes; a recorder fetches the TypeObject through the TypeLookup service)
    // but not the TypeObject itself: on receiving one, Fast DDS 2.9 builds a DynamicType from the TypeObjectFactory in
    // its discovery thread, while fastddsgen 2.3's message constructors re-register every type of the IDL in that
    // factory. The race crashed `cellcal status` (SIGSEGV in DynamicType::get_all_members) about once in 80 starts.
    type->auto_fill_type_object(false);
    type->auto_fill_type_information(type_information_);
    type.register_type(participant_);
    fdds::Topic* t = participant_->create_topic(name, type.get_type_name(), fdds::TOPIC_QOS_DEFAULT);
    if (!t) throw std::runtime_error("cannot create topic " + name);
    topics_[name] = t;
    return t;
  }
  std::shared_ptr<TopicCounters> counters(const std::string& topic);

  template <class T, class = void>
  struct HasRobotId : std::false_type {};
  template <class T>
  struct HasRobotId<T, std::void_t<decltype(std::declval<const T&>().robot_id())>> : std::true_type {};

  // A shard (dds.shard_robot_ids): the topic seen through a content filter on the shard's robots (target_id for
  // TrackerPose, robot_id for the other cell types; the ROS 2 types carry no key and are not filtered): cellcal's
  // key filter (key_filter.hpp), which the writers of every cellcal process evaluate before sending.
  template <class M>
  fdds::TopicDescription* shardFilter(fdds::Topic* t, const std::string& name) {
    const std::vector<std::string>* keys = nullptr;
    std::string field;
    if constexpr (std::is_same_v<M, msg::TrackerPose>) {
      keys = &shard_target_ids_;
      field = "target_id";
    } else if constexpr (HasRobotId<M>::value) {
      keys = &shard_robot_ids_;
      field = "robot_id";
    }
    if (!keys || keys->empty()) return t;
    std::string expression;
    std::vector<std::string> parameters;
    for (std::size_t i = 0; i < keys->size(); ++i) {
      expression += (i ? " OR " : "") + field + " = %" + std::to_string(i);
      parameters.push_back("'" + (*keys)[i] + "'");
    }
    std::lock_guard<std::mutex> lock(mutex_);
    fdds::ContentFilteredTopic* f = participant_->create_contentfilteredtopic(
        name + "/shard" + std::to_string(filters_++), t, expression, parameters, kKeyFilterClass);
    if (!f) throw std::runtime_error("cannot filter " + name + " by " + expression + " (--robots)");
    return f;
  }

  std::vector<std::string> shard_robot_ids_, shard_target_ids_;
  int filters_ = 0;
  int domain_id_ = 0;
  bool secure_ = false;
  std::uint32_t udp_receive_buffer_bytes_ = 0;
  bool type_information_ = true;
  fdds::DomainParticipant* participant_ = nullptr;
  fdds::Publisher* publisher_ = nullptr;
  fdds::Subscriber* subscriber_ = nullptr;
  mutable std::mutex mutex_;
  std::map<std::string, fdds::Topic*> topics_;
  std::map<std::string, std::shared_ptr<TopicCounters>> counters_;
  std::vector<std::unique_ptr<fdds::DataReaderListener>> listeners_;
};

}  // namespace cellcal::components
