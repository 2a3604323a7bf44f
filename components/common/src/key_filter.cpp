#include "cellcal/components/key_filter.hpp"

#include <cstdint>
#include <cstring>

namespace cellcal::components {

bool KeyFilter::evaluate(const SerializedPayload& payload, const FilterSampleInfo&, const GUID_t&) const {
  // Encapsulation (2 bytes kind, 2 bytes options), then the string: uint32 length including its NUL, the chars.
  if (payload.length < 8 || payload.data == nullptr) return true;
  const std::uint8_t* d = payload.data;
  const bool little = d[1] == 0x01 || d[1] == 0x03;  // CDR_LE / PL_CDR_LE
  const std::uint32_t n = little ? (std::uint32_t(d[4]) | std::uint32_t(d[5]) << 8 | std::uint32_t(d[6]) << 16 |
                                    std::uint32_t(d[7]) << 24)
                                 : (std::uint32_t(d[7]) | std::uint32_t(d[6]) << 8 | std::uint32_t(d[5]) << 16 |
                                    std::uint32_t(d[4]) << 24);
  if (n == 0 || n > payload.length - 8) return true;
  const std::size_t len = d[8 + n - 1] == 0 ? n - 1 : n;
  return keys_.count(std::string(reinterpret_cast<const char*>(d + 8), len)) > 0;
}

KeyFilterFactory::ReturnCode_t KeyFilterFactory::create_content_filter(
    const char*, const char*, const eprosima::fastdds::dds::TopicDataType*, const char*,
    const ParameterSeq& filter_parameters, eprosima::fastdds::dds::IContentFilter*& filter_instance) {
  std::set<std::string> keys;
  for (ParameterSeq::size_type i = 0; i < filter_parameters.length(); ++i) {
    std::string k = filter_parameters[i];
    if (k.size() >= 2 && k.front() == '\'' && k.back() == '\'') k = k.substr(1, k.size() - 2);
    keys.insert(k);
  }
  if (keys.empty()) return ReturnCode_t::RETCODE_BAD_PARAMETER;
  delete static_cast<KeyFilter*>(filter_instance);  // an update of a filter's parameters replaces it (ours only)
  filter_instance = new KeyFilter(std::move(keys));
  return ReturnCode_t::RETCODE_OK;
}

KeyFilterFactory::ReturnCode_t KeyFilterFactory::delete_content_filter(
    const char*, eprosima::fastdds::dds::IContentFilter* filter_instance) {
  delete static_cast<KeyFilter*>(filter_instance);
  return ReturnCode_t::RETCODE_OK;
}

KeyFilterFactory& KeyFilterFactory::instance() {
  static KeyFilterFactory f;
  return f;
}

}  // namespace cellcal::components
