#include "cellcal/components/dds_node.hpp"

#include <fastdds/dds/domain/DomainParticipantFactory.hpp>

#include <filesystem>

namespace cellcal::components {

DdsNode::DdsNode(const CellConfig& cell, const std::string& node_name) : domain_id_(cell.dds.domain_id) {
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
  participant_ = factory->create_participant(domain_id_, qos);
  if (!participant_)
    throw std::runtime_error("cannot create the DDS participant on domain " + std::to_string(domain_id_) +
                             " with profile " + cell.dds.participant_profile);
  publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
  subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
  if (!publisher_ || !subscriber_) throw std::runtime_error("cannot create the DDS publisher/subscriber");
}

DdsNode::~DdsNode() { shutdown(); }

void DdsNode::shutdown() {
  if (!participant_) return;
  participant_->delete_contained_entities();
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
  for (const auto& [name, c] : counters_) j[name] = {{"published", c->published.load()}, {"received", c->received.load()}};
  return j;
}

}  // namespace cellcal::components
