#include <fstream>
#include <sstream>
#include <stdexcept>

#include "cellcal/mcap/mcap.hpp"
#include "records.hpp"

namespace cellcal::mcap {

using detail::In;

namespace {

struct Truncated {
  std::string what;
};

Schema parseSchema(In& in) {
  Schema s;
  s.id = in.u<std::uint16_t>();
  s.name = in.str();
  s.encoding = in.str();
  s.data = in.str();
  return s;
}

Channel parseChannel(In& in) {
  Channel c;
  c.id = in.u<std::uint16_t>();
  c.schema_id = in.u<std::uint16_t>();
  c.topic = in.str();
  c.message_encoding = in.str();
  c.metadata = in.stringMap();
  return c;
}

Message parseMessage(In& in) {
  Message m;
  m.channel_id = in.u<std::uint16_t>();
  m.sequence = in.u<std::uint32_t>();
  m.log_time_ns = in.u<std::uint64_t>();
  m.publish_time_ns = in.u<std::uint64_t>();
  m.data = in.rest();
  return m;
}

class Reader {
 public:
  Reader(const std::string& path, const std::string& bytes, ReadResult& out) : path_(path), b_(bytes), out_(out) {}

  void run() {
    if (b_.size() < 8 || b_.compare(0, 8, std::string(detail::kMagic, 8)) != 0) fail(0, "not an MCAP file (magic)");
    std::size_t pos = 8;
    bool data_end = false;
    while (!data_end) {
      std::uint8_t op = 0;
      const std::string body = record(pos, &op);
      In in(body);
      try {
        switch (op) {
          case detail::kHeader:
            out_.profile = in.str();
            out_.library = in.str();
            break;
          case detail::kSchema: addSchema(parseSchema(in)); break;
          case detail::kChannel: addChannel(parseChannel(in), pos); break;
          case detail::kMessage: addMessage(parseMessage(in), pos); break;
          case detail::kChunk: chunk(in, pos); break;
          case detail::kDataEnd: {
            const std::uint32_t crc = in.u<std::uint32_t>();
            if (crc != 0 && crc != crc32(b_.data(), pos)) fail(pos, "data section CRC mismatch");
            data_end = true;
            break;
          }
          case detail::kFooter: throw Truncated{"footer before Data End"};
          default: break;  // attachments, metadata: not used by cellcal, skipped
        }
      } catch (const std::out_of_range&) {
        fail(pos, "record " + std::to_string(op) + " shorter than its fields");
      }
      pos += 9 + body.size();
    }
    summary(pos);
  }

  void fail(std::size_t at, const std::string& what) const {
    throw std::runtime_error(path_ + ": at byte " + std::to_string(at) + ": " + what);
  }

 private:
  // The body of the record at pos; throws Truncated when it runs past the end of the file.
  std::string record(std::size_t pos, std::uint8_t* op) const {
    if (b_.size() - pos < 9) throw Truncated{"file ends inside a record header at byte " + std::to_string(pos)};
    In h(b_.data() + pos, 9);
    *op = h.u<std::uint8_t>();
    const std::uint64_t len = h.u<std::uint64_t>();
    if (len > b_.size() - pos - 9)
      throw Truncated{"record at byte " + std::to_string(pos) + " runs past the end of the file"};
    return b_.substr(pos + 9, len);
  }

  void addSchema(const Schema& s) {
    if (s.id == 0) return;
    for (const auto& x : out_.schemas)
      if (x.id == s.id) return;
    out_.schemas.push_back(s);
  }
  void addChannel(const Channel& c, std::size_t pos) {
    for (const auto& x : out_.channels)
      if (x.id == c.id) return;
    if (c.schema_id != 0) {
      bool known = false;
      for (const auto& s : out_.schemas) known = known || s.id == c.schema_id;
      if (!known) fail(pos, "channel " + c.topic + " refers to schema " + std::to_string(c.schema_id) + " not yet defined");
    }
    out_.channels.push_back(c);
  }
  void addMessage(Message m, std::size_t pos) {
    bool known = false;
    for (const auto& c : out_.channels) known = known || c.id == m.channel_id;
    if (!known) fail(pos, "message on channel " + std::to_string(m.channel_id) + " not yet defined");
    out_.messages.push_back(std::move(m));
  }

  void chunk(In& in, std::size_t pos) {
    in.u<std::uint64_t>();  // message start time
    in.u<std::uint64_t>();  // message end time
    const std::uint64_t uncompressed_size = in.u<std::uint64_t>();
    const std::uint32_t crc = in.u<std::uint32_t>();
    const std::string compression = in.str();
    const std::uint64_t len = in.u<std::uint64_t>();
    const std::string records = in.bytes(len);
    if (!compression.empty()) fail(pos, "chunk compression '" + compression + "' not supported by this reader");
    if (records.size() != uncompressed_size) fail(pos, "chunk size mismatch");
    if (crc != 0 && crc != crc32(records.data(), records.size())) fail(pos, "chunk CRC mismatch");
    chunk_offsets_.push_back(pos);
    ++out_.chunks;
    std::size_t at = 0;
    while (at < records.size()) {
      if (records.size() - at < 9) fail(pos, "chunk ends inside a record");
      In h(records.data() + at, 9);
      const auto op = h.u<std::uint8_t>();
      const auto n = h.u<std::uint64_t>();
      if (n > records.size() - at - 9) fail(pos, "record in a chunk runs past the chunk");
      In r(records.data() + at + 9, n);
      if (op == detail::kSchema) addSchema(parseSchema(r));
      else if (op == detail::kChannel) addChannel(parseChannel(r), pos);
      else if (op == detail::kMessage) addMessage(parseMessage(r), pos);
      at += 9 + n;
    }
  }

  void summary(std::size_t pos) {
    std::size_t footer_at = 0;
    while (true) {
      std::uint8_t op = 0;
      const std::string body = record(pos, &op);
      In in(body);
      try {
        if (op == detail::kFooter) {
          footer_at = pos;
          const std::uint64_t summary_start = in.u<std::uint64_t>();
          in.u<std::uint64_t>();  // summary offset start: the reader walks the summary section in order
          const std::uint32_t crc = in.u<std::uint32_t>();
          if (summary_start != 0 && (summary_start < 8 || summary_start > footer_at))
            fail(pos, "footer: summary start " + std::to_string(summary_start) + " is not between the magic and the footer (" +
                          std::to_string(footer_at) + ")");
          if (summary_start != 0 && crc != 0 &&
              crc != crc32(b_.data() + summary_start, footer_at + 1 + 8 + 8 + 8 - summary_start))
            fail(pos, "summary CRC mismatch");
          out_.has_summary = summary_start != 0;
          break;
        }
        switch (op) {
          case detail::kStatistics: {
            Statistics& s = out_.summary_statistics;
            s.message_count = in.u<std::uint64_t>();
            s.schema_count = in.u<std::uint16_t>();
            s.channel_count = in.u<std::uint32_t>();
            in.u<std::uint32_t>();
            in.u<std::uint32_t>();
            s.chunk_count = in.u<std::uint32_t>();
            s.message_start_time_ns = in.u<std::uint64_t>();
            s.message_end_time_ns = in.u<std::uint64_t>();
            s.channel_message_counts = in.u64Map<std::uint16_t>();
            break;
          }
          case detail::kChunkIndex: {
            ChunkIndex c;
            c.message_start_time_ns = in.u<std::uint64_t>();
            c.message_end_time_ns = in.u<std::uint64_t>();
            c.chunk_start_offset = in.u<std::uint64_t>();
            c.chunk_length = in.u<std::uint64_t>();
            c.message_index_offsets = in.u64Map<std::uint16_t>();
            c.message_index_length = in.u<std::uint64_t>();
            c.compression = in.str();
            c.compressed_size = in.u<std::uint64_t>();
            c.uncompressed_size = in.u<std::uint64_t>();
            out_.chunk_indexes.push_back(c);
            break;
          }
          default: break;  // schemas and channels repeat the data section's; summary offsets
        }
      } catch (const std::out_of_range&) {
        fail(pos, "summary record " + std::to_string(op) + " shorter than its fields");
      }
      pos += 9 + body.size();
    }
    pos = footer_at + 9 + 20;
    if (b_.size() - pos < 8) throw Truncated{"file ends before the closing magic"};
    if (b_.compare(pos, 8, std::string(detail::kMagic, 8)) != 0) fail(pos, "closing magic missing");
    if (out_.has_summary) {
      const Statistics& s = out_.summary_statistics;
      if (s.message_count != out_.messages.size())
        fail(footer_at, "summary says " + std::to_string(s.message_count) + " messages, the data hold " +
                            std::to_string(out_.messages.size()));
      if (out_.chunk_indexes.size() != chunk_offsets_.size()) fail(footer_at, "chunk index count differs from the chunks");
      for (std::size_t i = 0; i < chunk_offsets_.size(); ++i)
        if (out_.chunk_indexes[i].chunk_start_offset != chunk_offsets_[i]) fail(footer_at, "chunk index offset wrong");
    }
    out_.complete = true;
  }

  const std::string& path_;
  const std::string& b_;
  ReadResult& out_;
  std::vector<std::size_t> chunk_offsets_;
};

}  // namespace

ReadResult readFile(const std::string& path, const ReadOptions& options) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error(path + ": cannot open");
  std::stringstream ss;
  ss << f.rdbuf();
  const std::string bytes = ss.str();
  ReadResult out;
  Reader r(path, bytes, out);
  try {
    r.run();
  } catch (const Truncated& t) {
    if (!options.tolerate_truncation) throw std::runtime_error(path + ": truncated: " + t.what);
    out.complete = false;
    out.problem = "truncated: " + t.what;
  }
  return out;
}

std::uint64_t recover(const std::string& in_path, const std::string& out_path) {
  const ReadResult in = readFile(in_path, ReadOptions{true});
  WriterOptions o;
  o.profile = in.profile;
  o.library = in.library.empty() ? "cellcal" : in.library;
  Writer w(out_path, o);
  std::map<std::uint16_t, std::uint16_t> schema_id, channel_id;
  for (const auto& s : in.schemas) schema_id[s.id] = w.addSchema(s.name, s.encoding, s.data);
  for (const auto& c : in.channels)
    channel_id[c.id] = w.addChannel(c.schema_id ? schema_id.at(c.schema_id) : 0, c.topic, c.message_encoding, c.metadata);
  for (Message m : in.messages) {
    m.channel_id = channel_id.at(m.channel_id);
    w.write(m);
  }
  w.close();
  return in.messages.size();
}

}  // namespace cellcal::mcap
