// The content filter of a shard's readers (--robots): a sample passes when its key, the first member of every
// keyed cellcal type (robot_id, or target_id for TrackerPose), is one of the filter's parameters. It reads the key
// straight from the CDR payload, so it costs a string compare per sample and reader; Fast DDS's DDS-SQL filter
// deserializes each sample into a dynamic type first, and at 2,000 samples/s it held the engine's joint states back
// by ~0.5 s (NetnsCell.SixteenRobotsOnTwoCellServers). Every cellcal participant registers it (DdsNode), so writers
// evaluate their remote readers' filters before sending: a shard's streams do not cross to another shard's host.
#pragma once

#include <fastdds/dds/topic/IContentFilter.hpp>
#include <fastdds/dds/topic/IContentFilterFactory.hpp>

#include <set>
#include <string>

namespace cellcal::components {

// The filter class name in discovery (a ContentFilteredTopic's filter_class_name).
constexpr const char* kKeyFilterClass = "CELLCAL_KEY_IN";

class KeyFilter final : public eprosima::fastdds::dds::IContentFilter {
 public:
  explicit KeyFilter(std::set<std::string> keys) : keys_(std::move(keys)) {}
  // True when the payload's first member (a CDR string, after the 4-byte encapsulation header) is one of the keys;
  // true as well for a payload it cannot read (the reader's deserializer then says what is wrong with it).
  bool evaluate(const SerializedPayload& payload, const FilterSampleInfo& info, const GUID_t& reader) const override;

 private:
  std::set<std::string> keys_;
};

// Makes a KeyFilter of the parameters (each a quoted key, 'r1'); the expression names the key field, for people.
class KeyFilterFactory : public eprosima::fastdds::dds::IContentFilterFactory {
 public:
  ReturnCode_t create_content_filter(const char* filter_class_name, const char* type_name,
                                     const eprosima::fastdds::dds::TopicDataType* data_type,
                                     const char* filter_expression, const ParameterSeq& filter_parameters,
                                     eprosima::fastdds::dds::IContentFilter*& filter_instance) override;
  ReturnCode_t delete_content_filter(const char* filter_class_name,
                                     eprosima::fastdds::dds::IContentFilter* filter_instance) override;
  // The one factory every participant of this process registers.
  static KeyFilterFactory& instance();
};

}  // namespace cellcal::components
