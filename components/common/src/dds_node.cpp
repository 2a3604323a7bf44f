#include "cellcal/components/dds_node.hpp"

#include "cellcal/components/dds_security.hpp"
#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/host_limits.hpp"

#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/rtps/attributes/ServerAttributes.h>
#include <fastdds/rtps/transport/UDPTransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iostream>
#include <vector>

namespace cellcal::components {

namespace {

// Discovery without multicast (cell file dds.discovery): static peers, or a client of a Fast DDS Discovery Server.
// Returns what it set, for the start banner ("" when the profile's discovery stays).
std::string setDiscovery(fdds::DomainParticipantQos& qos, const DdsSettings& dds) {
  namespace rtps = eprosima::fastrtps::rtps;
  auto& b = qos.wire_protocol().builtin;
  if (!dds.discovery_peers.empty()) {
    b.initialPeersList.clear();
    for (const auto& ip : dds.discovery_peers) {
      rtps::Locator_t l;  // port 0: the well-known discovery ports of participants 0..maxInitialPeersRange
      rtps::IPLocator::setIPv4(l, ip);
      b.initialPeersList.push_back(l);
    }
    b.avoid_builtin_multicast = true;
    b.metatrafficMulticastLocatorList.clear();
    std::string s = "static peers";
    for (const auto& ip : dds.discovery_peers) s += " " + ip;
    return s;
  }
  if (dds.discovery_server_port > 0) {
    b.discovery_config.discoveryProtocol = rtps::DiscoveryProtocol_t::CLIENT;
    rtps::RemoteServerAttributes server;
    if (!eprosima::fastdds::rtps::get_server_client_default_guidPrefix(dds.discovery_server_id, server.guidPrefix))
      throw std::runtime_error("dds.discovery.server_id " + std::to_string(dds.discovery_server_id) +
                               ": no Discovery Server prefix for it");
    rtps::Locator_t l;
    rtps::IPLocator::setIPv4(l, dds.discovery_server_address);
    l.port = static_cast<std::uint32_t>(dds.discovery_server_port);
    server.metatrafficUnicastLocatorList.push_back(l);
    b.discovery_config.m_DiscoveryServers.clear();
    b.discovery_config.m_DiscoveryServers.push_back(server);
    b.avoid_builtin_multicast = true;
    b.metatrafficMulticastLocatorList.clear();
    return "Discovery Server " + dds.discovery_server_address + ":" + std::to_string(dds.discovery_server_port) +
           " (id " + std::to_string(dds.discovery_server_id) + ")";
  }
  return "";
}

// The DDS Security properties of `identity` from the folder make_pki.sh filled; every file must exist.
void addSecurity(fdds::DomainParticipantQos& qos, const std::string& dir, const std::string& identity) {
  const std::filesystem::path d(dir);
  auto file = [&](const std::string& name) {
    const std::filesystem::path p = d / name;
    if (!std::filesystem::is_regular_file(p))
      throw std::runtime_error("DDS Security: " + p.string() + " does not exist (identity '" + identity +
                               "'; make the folder with config/security/make_pki.sh, dds.security_dir / "
                               "CELLCAL_SECURITY_DIR)");
    return "file://" + std::filesystem::absolute(p).string();
  };
  auto& props = qos.properties().properties();
  props.emplace_back("dds.sec.auth.plugin", "builtin.PKI-DH");
  props.emplace_back("dds.sec.auth.builtin.PKI-DH.identity_ca", file("ca.cert.pem"));
  props.emplace_back("dds.sec.auth.builtin.PKI-DH.identity_certificate", file(identity + ".cert.pem"));
  props.emplace_back("dds.sec.auth.builtin.PKI-DH.private_key", file(identity + ".key.pem"));
  props.emplace_back("dds.sec.access.plugin", "builtin.Access-Permissions");
  props.emplace_back("dds.sec.access.builtin.Access-Permissions.permissions_ca", file("ca.cert.pem"));
  props.emplace_back("dds.sec.access.builtin.Access-Permissions.governance", file("governance.p7s"));
  props.emplace_back("dds.sec.access.builtin.Access-Permissions.permissions", file("permissions.p7s"));
  props.emplace_back("dds.sec.crypto.plugin", "builtin.AES-GCM-GMAC");
}

// The kernel caps the UDP socket buffers a profile's transports ask for (host_limits.hpp): say so once, at start.
// Returns the largest receive buffer asked for.
std::uint32_t warnOfCappedSocketBuffers(const fdds::DomainParticipantQos& qos, const std::string& node_name,
                                        const std::string& profile) {
  // (receive, send) bytes asked for: the builtin transports' (participant level), then each UDP descriptor's.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> asked;
  if (qos.transport().use_builtin_transports)
    asked.emplace_back(qos.transport().listen_socket_buffer_size, qos.transport().send_socket_buffer_size);
  for (const auto& t : qos.transport().user_transports)
    if (const auto udp = std::dynamic_pointer_cast<eprosima::fastdds::rtps::UDPTransportDescriptor>(t))
      asked.emplace_back(udp->receiveBufferSize, udp->sendBufferSize);
  const auto rmem_max = readKernelLimit("/proc/sys/net/core/rmem_max");
  const auto wmem_max = readKernelLimit("/proc/sys/net/core/wmem_max");
  std::uint32_t largest = 0;
  for (const auto& [receive, send] : asked) {
    largest = std::max(largest, receive);
    const std::string w = socketBufferWarning("participant profile '" + profile + "'", receive, send, rmem_max, wmem_max);
    if (!w.empty()) std::cerr << node_name << ": warning: " << w << "\n";
  }
  return largest;
}

}  // namespace

DdsNode::DdsNode(const CellConfig& cell, const std::string& node_name, const std::string& identity)
    : domain_id_(cell.dds.domain_id),
      secure_(!cell.dds.security_dir.empty()),
      type_information_(cell.dds.type_information) {
  shard_robot_ids_ = cell.dds.shard_robot_ids;
  shard_target_ids_ = cell.dds.shard_target_ids;
  auto* factory = fdds::DomainParticipantFactory::get_instance();
  if (!std::filesystem::exists(cell.dds.profiles_file))
    throw std::runtime_error(cell.source + ": dds.profiles_file: " + cell.dds.profiles_file + " does not exist");
  if (factory->load_XML_profiles_file(cell.dds.profiles_file) != ReturnCode_t::RETCODE_OK)
    throw std::runtime_error(cell.dds.profiles_file + ": Fast DDS could not load the XML profiles");
  fdds::DomainParticipantQos qos;
  if (factory->get_participant_qos_from_profile(cell.dds.participant_profile, qos) != ReturnCode_t::RETCODE_OK)
    throw std::runtime_error(cell.dds.profiles_file + ": no participant profile '" + cell.dds.participant_profile +
                             "' (cell file dds.participant_profile / CELLCAL_DDS_PROFILE)");
  qos.name(node_name);
  udp_receive_buffer_bytes_ = warnOfCappedSocketBuffers(qos, node_name, cell.dds.participant_profile);
  if (!cell.dds.security_dir.empty()) addSecurity(qos, cell.dds.security_dir, identity);
  const std::string discovery = setDiscovery(qos, cell.dds);
  participant_ = factory->create_participant(domain_id_, qos);
  if (!participant_) {
    std::string why;
    if (!cell.dds.security_dir.empty()) {
      const std::string found = explainSecurityRefusal(cell.dds.security_dir, identity);
      why = " as identity '" + identity + "' under DDS Security: " +
            (found.empty() ? "Fast DDS refused its security files in " + cell.dds.security_dir +
                                 " (its log above may say why)"
                           : found);
    }
    throw std::runtime_error("cannot create the DDS participant on domain " + std::to_string(domain_id_) +
                             " with profile " + cell.dds.participant_profile + why);
  }
  if (participant_->register_content_filter_factory(kKeyFilterClass, &KeyFilterFactory::instance()) !=
      ReturnCode_t::RETCODE_OK)
    throw std::runtime_error(std::string("cannot register the content filter ") + kKeyFilterClass);
  publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  if (!publisher_ || !subscriber_) throw std::runtime_error("cannot create the DDS publisher/subscriber");
  // Where it joined: what a second tool must match to see it (`cellcal cell` runs on cellcal_loopback).
  std::cerr << node_name << ": DDS domain " << domain_id_ << ", participant profile " << cell.dds.participant_profile
            << ", DDS Security " << (secure_ ? "on (identity " + identity + ")" : std::string("off"))
            << (discovery.empty() ? "" : ", discovery by " + discovery);
  if (!shard_robot_ids_.empty()) {
    std::cerr << ", robots";
    for (const auto& id : shard_robot_ids_) std::cerr << (&id == &shard_robot_ids_.front() ? " " : ",") << id;
    std::cerr << " only (--robots: content-filtered readers)";
  }
  std::cerr << "\n";
}

DdsNode::~DdsNode() { shutdown(); }

void DdsNode::shutdown() {
  if (!participant_) return;
  // The readers first: no callback runs once shutdown() has begun.
  if (subscriber_) subscriber_->delete_contained_entities();
  // Then a clean exit flushes: a reliable writer's last samples (the engine's final CalibrationState, say) may still
  // be unacknowledged, and deleting the writer would drop them. Bounded: a reader that died is not waited for long.
  std::vector<fdds::DataWriter*> writers;
  if (publisher_) publisher_->get_datawriters(writers);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(1000);
  for (fdds::DataWriter* w : writers) {
    if (w->get_qos().reliability().kind != fdds::RELIABLE_RELIABILITY_QOS) continue;
    const auto left_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(deadline - std::chrono::steady_clock::now()).count();
    if (left_ns <= 0) break;
    w->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(static_cast<std::int32_t>(left_ns / 1000000000),
                                                               static_cast<std::uint32_t>(left_ns % 1000000000)));
  }
  participant_->delete_contained_entities();
  participant_->unregister_content_filter_factory(kKeyFilterClass);
  fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
  participant_ = nullptr;
  publisher_ = nullptr;
  subscriber_ = nullptr;
  topics_.clear();
}

std::shared_ptr<TopicCounters> DdsNode::counters(const std::string& topic) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto& c = counters_[topic];
  if (!c) c = std::make_shared<TopicCounters>();
  return c;
}

nlohmann::json DdsNode::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  nlohmann::json j = nlohmann::json::object();
  for (const auto& [name, c] : counters_) j[name] = {{stats::kPublished, c->published.load()}, {stats::kReceived, c->received.load()}};
  return j;
}

}  // namespace cellcal::components
