// MCAP files (https://mcap.dev/spec, major version 0): what `cellcal record` writes and `replay` / `validate` /
// `export` read. Written from the published specification.
//
// Layout written: magic, Header, then the data section: Schema and Channel records as they are added (outside
// chunks), Chunk records (uncompressed, CRC32 of their records) each followed by one Message Index record per channel
// in it, Data End (CRC32 of the data section); then the summary section (every Schema, every Channel, Statistics,
// one Chunk Index per chunk), the Summary Offset section (one per group), Footer (with the summary CRC32), magic.
// A chunk reaches the file whole (flush() ends the current chunk and flushes the stream), so a file cut short by
// SIGKILL holds every message of its complete chunks: read it with ReadOptions::tolerate_truncation or recover().
//
// Times are nanoseconds (log time = receive time, publish time = source stamp for cellcal's recordings).
#pragma once

#include <cstdint>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "cellcal/core/files/crc32.hpp"

namespace cellcal::mcap {

struct Schema {
  std::uint16_t id = 0;  // 1..; 0 means "no schema" in a Channel
  std::string name;      // e.g. "cellcal::msg::JointState"
  std::string encoding;  // e.g. "omgidl"
  std::string data;      // the schema text (IDL) or bytes
};

struct Channel {
  std::uint16_t id = 0;
  std::uint16_t schema_id = 0;
  std::string topic;
  std::string message_encoding;  // e.g. "cdr"
  std::map<std::string, std::string> metadata;
};

struct Message {
  std::uint16_t channel_id = 0;
  std::uint32_t sequence = 0;
  std::uint64_t log_time_ns = 0;
  std::uint64_t publish_time_ns = 0;
  std::string data;
};

struct Statistics {
  std::uint64_t message_count = 0;
  std::uint16_t schema_count = 0;
  std::uint32_t channel_count = 0;
  std::uint32_t chunk_count = 0;
  std::uint64_t message_start_time_ns = 0, message_end_time_ns = 0;
  std::map<std::uint16_t, std::uint64_t> channel_message_counts;
};

struct ChunkIndex {
  std::uint64_t message_start_time_ns = 0, message_end_time_ns = 0;
  std::uint64_t chunk_start_offset = 0, chunk_length = 0;
  std::map<std::uint16_t, std::uint64_t> message_index_offsets;
  std::uint64_t message_index_length = 0;
  std::string compression;
  std::uint64_t compressed_size = 0, uncompressed_size = 0;
};

struct WriterOptions {
  std::string profile;                      // Header profile ("" = none; "ros2" is for ROS 2 bags)
  std::string library = "cellcal";
  std::size_t chunk_size_bytes = 1 << 20;   // a chunk is closed when its records reach this size
};

class Writer {
 public:
  // Creates (truncates) the file and writes the magic and the Header. Throws std::runtime_error naming the file.
  Writer(const std::string& path, WriterOptions options = {});
  ~Writer();  // close()s; errors are swallowed (call close() to see them)
  Writer(const Writer&) = delete;
  Writer& operator=(const Writer&) = delete;

  std::uint16_t addSchema(const std::string& name, const std::string& encoding, const std::string& data);
  std::uint16_t addChannel(std::uint16_t schema_id, const std::string& topic, const std::string& message_encoding,
                           const std::map<std::string, std::string>& metadata = {});
  // Messages of a channel must come in non-decreasing log time for the index to be useful (not enforced).
  void write(const Message& message);
  // Ends the current chunk (if any) and flushes it to the operating system.
  void flush();
  // Ends the data section and writes the summary, the footer and the closing magic. Idempotent.
  void close();
  std::uint64_t messagesWritten() const { return stats_.message_count; }
  std::uint64_t messagesInFile() const { return messages_flushed_; }  // in complete chunks

 private:
  // Appends one record; `crc` accumulates its bytes (the data section's CRC unless told otherwise).
  void writeRecord(std::uint8_t opcode, const std::string& body, std::uint32_t* crc);
  void writeRecord(std::uint8_t opcode, const std::string& body) { writeRecord(opcode, body, &data_crc_); }
  void endChunk();
  std::string path_;
  WriterOptions options_;
  std::FILE* file_ = nullptr;
  std::uint64_t offset_ = 0;
  std::uint32_t data_crc_ = 0;
  std::vector<Schema> schemas_;
  std::vector<Channel> channels_;
  std::vector<ChunkIndex> chunk_indexes_;
  Statistics stats_;
  std::uint64_t messages_flushed_ = 0;
  // The open chunk.
  std::string chunk_;
  std::uint64_t chunk_start_ns_ = 0, chunk_end_ns_ = 0, chunk_messages_ = 0;
  std::map<std::uint16_t, std::vector<std::pair<std::uint64_t, std::uint64_t>>> chunk_index_;  // channel -> (time, offset)
};

struct ReadOptions {
  // A file cut short (no Data End / summary / footer, or a record running past the end): return what the complete
  // records hold instead of failing. Without it such a file is an error.
  bool tolerate_truncation = false;
};

struct ReadResult {
  std::string profile, library;
  std::vector<Schema> schemas;
  std::vector<Channel> channels;
  std::vector<Message> messages;       // in file order
  bool complete = false;               // Data End, summary (if any), footer and closing magic all present and valid
  bool has_summary = false;
  Statistics summary_statistics;       // from the summary section (has_summary)
  std::vector<ChunkIndex> chunk_indexes;
  std::uint64_t chunks = 0;
  std::string problem;                 // why the file is not complete ("" when complete)
};

// Reads every record; checks the chunk and data CRCs, the summary CRC and that the summary agrees with the data
// (message count, one chunk index per chunk at its offset). Message Index records are skipped, not checked. Throws std::runtime_error "<file>: at byte <n>: <what>".
ReadResult readFile(const std::string& path, const ReadOptions& options = {});

// Rewrites a (possibly truncated) recording as a complete file: every message of its complete chunks, with a summary.
// Returns the number of messages written.
std::uint64_t recover(const std::string& in_path, const std::string& out_path);

using cellcal::crc32;  // cellcal/core/files/crc32.hpp: MCAP's CRC-32 is the IEEE one

}  // namespace cellcal::mcap
