#include <cerrno>
#include <cstring>
#include <stdexcept>

#include "cellcal/mcap/mcap.hpp"
#include "records.hpp"

namespace cellcal::mcap {

using detail::Out;

Writer::Writer(const std::string& path, WriterOptions options) : path_(path), options_(std::move(options)) {
  file_ = std::fopen(path.c_str(), "wb");
  if (!file_) throw std::runtime_error(path + ": cannot create: " + std::strerror(errno));
  if (std::fwrite(detail::kMagic, 1, 8, file_) != 8) throw std::runtime_error(path + ": write failed");
  data_crc_ = crc32(detail::kMagic, 8);
  offset_ = 8;
  Out h;
  h.str(options_.profile);
  h.str(options_.library);
  writeRecord(detail::kHeader, h.b);
}

Writer::~Writer() {
  try {
    close();
  } catch (...) {
  }
}

void Writer::writeRecord(std::uint8_t opcode, const std::string& body, std::uint32_t* crc) {
  Out r;
  r.u<std::uint8_t>(opcode);
  r.u<std::uint64_t>(body.size());
  r.b += body;
  if (std::fwrite(r.b.data(), 1, r.b.size(), file_) != r.b.size())
    throw std::runtime_error(path_ + ": write failed: " + std::strerror(errno));
  *crc = crc32(r.b.data(), r.b.size(), *crc);
  offset_ += r.b.size();
}

namespace {
std::string schemaBody(const Schema& s) {
  Out o;
  o.u<std::uint16_t>(s.id);
  o.str(s.name);
  o.str(s.encoding);
  o.str(s.data);
  return o.b;
}
std::string channelBody(const Channel& c) {
  Out o;
  o.u<std::uint16_t>(c.id);
  o.u<std::uint16_t>(c.schema_id);
  o.str(c.topic);
  o.str(c.message_encoding);
  o.stringMap(c.metadata);
  return o.b;
}
}  // namespace

std::uint16_t Writer::addSchema(const std::string& name, const std::string& encoding, const std::string& data) {
  if (!file_) throw std::logic_error(path_ + ": addSchema after close");
  Schema s{static_cast<std::uint16_t>(schemas_.size() + 1), name, encoding, data};
  writeRecord(detail::kSchema, schemaBody(s));
  schemas_.push_back(s);
  return s.id;
}

std::uint16_t Writer::addChannel(std::uint16_t schema_id, const std::string& topic, const std::string& message_encoding,
                                 const std::map<std::string, std::string>& metadata) {
  if (!file_) throw std::logic_error(path_ + ": addChannel after close");
  if (schema_id > schemas_.size()) throw std::invalid_argument(path_ + ": channel " + topic + ": unknown schema id");
  Channel c{static_cast<std::uint16_t>(channels_.size()), schema_id, topic, message_encoding, metadata};
  writeRecord(detail::kChannel, channelBody(c));
  channels_.push_back(c);
  return c.id;
}

void Writer::write(const Message& m) {
  if (!file_) throw std::logic_error(path_ + ": write after close");
  if (m.channel_id >= channels_.size()) throw std::invalid_argument(path_ + ": message on an unknown channel");
  if (chunk_messages_ == 0 || m.log_time_ns < chunk_start_ns_) chunk_start_ns_ = m.log_time_ns;
  if (chunk_messages_ == 0 || m.log_time_ns > chunk_end_ns_) chunk_end_ns_ = m.log_time_ns;
  chunk_index_[m.channel_id].emplace_back(m.log_time_ns, chunk_.size());
  Out r;
  r.u<std::uint8_t>(detail::kMessage);
  r.u<std::uint64_t>(2 + 4 + 8 + 8 + m.data.size());
  r.u<std::uint16_t>(m.channel_id);
  r.u<std::uint32_t>(m.sequence);
  r.u<std::uint64_t>(m.log_time_ns);
  r.u<std::uint64_t>(m.publish_time_ns);
  chunk_ += r.b;
  chunk_ += m.data;
  ++chunk_messages_;
  if (stats_.message_count == 0 || m.log_time_ns < stats_.message_start_time_ns) stats_.message_start_time_ns = m.log_time_ns;
  if (stats_.message_count == 0 || m.log_time_ns > stats_.message_end_time_ns) stats_.message_end_time_ns = m.log_time_ns;
  ++stats_.message_count;
  ++stats_.channel_message_counts[m.channel_id];
  if (chunk_.size() >= options_.chunk_size_bytes) endChunk();
}

void Writer::endChunk() {
  if (chunk_messages_ == 0) return;
  ChunkIndex ci;
  ci.message_start_time_ns = chunk_start_ns_;
  ci.message_end_time_ns = chunk_end_ns_;
  ci.chunk_start_offset = offset_;
  ci.compressed_size = ci.uncompressed_size = chunk_.size();
  Out c;
  c.u<std::uint64_t>(chunk_start_ns_);
  c.u<std::uint64_t>(chunk_end_ns_);
  c.u<std::uint64_t>(chunk_.size());
  c.u<std::uint32_t>(crc32(chunk_.data(), chunk_.size()));
  c.str("");  // no compression
  c.u<std::uint64_t>(chunk_.size());
  c.b += chunk_;
  writeRecord(detail::kChunk, c.b);
  ci.chunk_length = offset_ - ci.chunk_start_offset;
  const std::uint64_t index_start = offset_;
  for (const auto& [channel, entries] : chunk_index_) {
    ci.message_index_offsets[channel] = offset_;
    Out mi, list;
    mi.u<std::uint16_t>(channel);
    for (const auto& [t, off] : entries) {
      list.u<std::uint64_t>(t);
      list.u<std::uint64_t>(off);
    }
    mi.str(list.b);
    writeRecord(detail::kMessageIndex, mi.b);
  }
  ci.message_index_length = offset_ - index_start;
  chunk_indexes_.push_back(ci);
  ++stats_.chunk_count;
  messages_flushed_ += chunk_messages_;
  chunk_.clear();
  chunk_index_.clear();
  chunk_messages_ = 0;
}

void Writer::flush() {
  if (!file_) return;
  endChunk();
  if (std::fflush(file_) != 0) throw std::runtime_error(path_ + ": flush failed: " + std::strerror(errno));
}

void Writer::close() {
  if (!file_) return;
  endChunk();
  Out de;
  de.u<std::uint32_t>(data_crc_);
  writeRecord(detail::kDataEnd, de.b);
  // Summary section: groups of records, each group's position in a Summary Offset record.
  const std::uint64_t summary_start = offset_;
  std::uint32_t summary_crc = 0;
  std::vector<std::pair<std::uint8_t, std::pair<std::uint64_t, std::uint64_t>>> groups;
  auto summaryRecord = [&](std::uint8_t op, const std::string& body) {
    const std::uint64_t before = offset_;
    writeRecord(op, body, &summary_crc);
    if (groups.empty() || groups.back().first != op) groups.push_back({op, {before, 0}});
    groups.back().second.second = offset_ - groups.back().second.first;
  };
  for (const auto& s : schemas_) summaryRecord(detail::kSchema, schemaBody(s));
  for (const auto& c : channels_) summaryRecord(detail::kChannel, channelBody(c));
  stats_.schema_count = static_cast<std::uint16_t>(schemas_.size());
  stats_.channel_count = static_cast<std::uint32_t>(channels_.size());
  Out st;
  st.u<std::uint64_t>(stats_.message_count);
  st.u<std::uint16_t>(stats_.schema_count);
  st.u<std::uint32_t>(stats_.channel_count);
  st.u<std::uint32_t>(0);  // attachments
  st.u<std::uint32_t>(0);  // metadata
  st.u<std::uint32_t>(stats_.chunk_count);
  st.u<std::uint64_t>(stats_.message_start_time_ns);
  st.u<std::uint64_t>(stats_.message_end_time_ns);
  st.u64Map<std::uint16_t>(stats_.channel_message_counts);
  summaryRecord(detail::kStatistics, st.b);
  for (const auto& ci : chunk_indexes_) {
    Out o;
    o.u<std::uint64_t>(ci.message_start_time_ns);
    o.u<std::uint64_t>(ci.message_end_time_ns);
    o.u<std::uint64_t>(ci.chunk_start_offset);
    o.u<std::uint64_t>(ci.chunk_length);
    o.u64Map<std::uint16_t>(ci.message_index_offsets);
    o.u<std::uint64_t>(ci.message_index_length);
    o.str(ci.compression);
    o.u<std::uint64_t>(ci.compressed_size);
    o.u<std::uint64_t>(ci.uncompressed_size);
    summaryRecord(detail::kChunkIndex, o.b);
  }
  const std::uint64_t summary_offset_start = offset_;
  for (const auto& [op, range] : groups) {
    Out o;
    o.u<std::uint8_t>(op);
    o.u<std::uint64_t>(range.first);
    o.u<std::uint64_t>(range.second);
    writeRecord(detail::kSummaryOffset, o.b, &summary_crc);
  }
  // Footer: the summary CRC covers the summary and summary offset sections and the footer up to its own field.
  Out f;
  f.u<std::uint8_t>(detail::kFooter);
  f.u<std::uint64_t>(8 + 8 + 4);
  f.u<std::uint64_t>(summary_start);
  f.u<std::uint64_t>(summary_offset_start);
  summary_crc = crc32(f.b.data(), f.b.size(), summary_crc);
  f.u<std::uint32_t>(summary_crc);
  f.b.append(detail::kMagic, 8);
  const bool ok = std::fwrite(f.b.data(), 1, f.b.size(), file_) == f.b.size();
  const bool closed = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!ok || !closed) throw std::runtime_error(path_ + ": write failed at close");
}

}  // namespace cellcal::mcap
