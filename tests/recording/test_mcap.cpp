// The MCAP writer and reader (tools/mcap): a round trip keeps every schema, channel and message; the summary and
// index agree with the data; a file cut anywhere (SIGKILL) still gives every message of its complete chunks, and
// recover() turns it into a complete file; a damaged chunk is an error naming its byte. Sizes, cut points and the
// damaged byte are drawn from the test seed.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "cellcal/mcap/mcap.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;

struct Recording {
  std::vector<mcap::Message> messages;
  std::string path;
};

std::string tempPath(const std::string& name) {
  return (fs::temp_directory_path() / ("cellcal_mcap_" + name + "_" + std::to_string(::getpid()) + ".mcap")).string();
}

std::string slurp(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
}

// Writes 3 channels, random payloads; returns what was written.
Recording writeRandom(const std::string& path, std::mt19937_64& rng, int n, std::size_t chunk_bytes) {
  mcap::WriterOptions o;
  o.chunk_size_bytes = chunk_bytes;
  mcap::Writer w(path, o);
  const auto s1 = w.addSchema("cellcal::msg::JointState", "omgidl", "module cellcal { struct JointState { double x; }; };");
  const auto s2 = w.addSchema("cellcal::msg::TrackerPose", "omgidl", "struct TrackerPose { double y; };");
  w.addChannel(s1, "cellcal/joint_state", "cdr", {{"reliability", "best_effort"}, {"durability", "volatile"}});
  w.addChannel(s2, "cellcal/tracker_pose", "cdr", {{"reliability", "reliable"}});
  w.addChannel(s1, "cellcal/other", "cdr");
  Recording r;
  r.path = path;
  std::uint64_t t = 1'700'000'000'000'000'000ULL;
  for (int i = 0; i < n; ++i) {
    mcap::Message m;
    m.channel_id = static_cast<std::uint16_t>(rng() % 3);
    m.sequence = static_cast<std::uint32_t>(i);
    t += 1 + rng() % 2'000'000;
    m.log_time_ns = t;
    m.publish_time_ns = t - rng() % 100'000;
    m.data.resize(rng() % 300);
    for (auto& c : m.data) c = static_cast<char>(rng());
    w.write(m);
    r.messages.push_back(m);
  }
  w.close();
  return r;
}

bool same(const mcap::Message& a, const mcap::Message& b) {
  return a.channel_id == b.channel_id && a.sequence == b.sequence && a.log_time_ns == b.log_time_ns &&
         a.publish_time_ns == b.publish_time_ns && a.data == b.data;
}

TEST(Mcap, RoundTripKeepsEverythingAndTheSummaryAgrees) {
  std::mt19937_64 rng(test::testSeed());
  const Recording r = writeRandom(tempPath("rt"), rng, 2000, 4096 + rng() % 8192);
  const mcap::ReadResult in = mcap::readFile(r.path);
  EXPECT_TRUE(in.complete) << in.problem;
  EXPECT_TRUE(in.has_summary);
  EXPECT_EQ(in.library, "cellcal");
  ASSERT_EQ(in.schemas.size(), 2u);
  EXPECT_EQ(in.schemas[0].encoding, "omgidl");
  ASSERT_EQ(in.channels.size(), 3u);
  EXPECT_EQ(in.channels[0].metadata.at("reliability"), "best_effort");
  EXPECT_EQ(in.channels[1].schema_id, 2);
  ASSERT_EQ(in.messages.size(), r.messages.size());
  for (std::size_t i = 0; i < r.messages.size(); ++i) ASSERT_TRUE(same(in.messages[i], r.messages[i])) << i;
  EXPECT_EQ(in.summary_statistics.message_count, r.messages.size());
  EXPECT_GT(in.chunks, 10u);
  EXPECT_EQ(in.summary_statistics.chunk_count, in.chunks);
  EXPECT_EQ(in.chunk_indexes.size(), in.chunks);
  std::uint64_t per_channel = 0;
  for (const auto& [c, n] : in.summary_statistics.channel_message_counts) per_channel += n;
  EXPECT_EQ(per_channel, r.messages.size());
  EXPECT_EQ(in.summary_statistics.message_start_time_ns, r.messages.front().log_time_ns);
  EXPECT_EQ(in.summary_statistics.message_end_time_ns, r.messages.back().log_time_ns);
  // The message index of each chunk points at its messages: check the first chunk's offsets by parsing at them.
  const std::string bytes = slurp(r.path);
  const mcap::ChunkIndex& ci = in.chunk_indexes.front();
  EXPECT_EQ(bytes[ci.chunk_start_offset], '\x06');
  for (const auto& [channel, offset] : ci.message_index_offsets) EXPECT_EQ(bytes[offset], '\x07') << channel;
  fs::remove(r.path);
}

TEST(Mcap, AFileCutAnywhereKeepsItsCompleteChunksAndRecovers) {
  std::mt19937_64 rng(test::testSeed());
  const Recording r = writeRandom(tempPath("cut"), rng, 1500, 2048);
  const std::string bytes = slurp(r.path);
  const mcap::ReadResult full = mcap::readFile(r.path);
  for (int k = 0; k < 25; ++k) {
    const std::size_t cut = 8 + rng() % (bytes.size() - 8);
    const std::string cut_path = tempPath("cut_" + std::to_string(k));
    std::ofstream(cut_path, std::ios::binary) << bytes.substr(0, cut);
    EXPECT_THROW(mcap::readFile(cut_path), std::runtime_error) << "cut at " << cut;
    const mcap::ReadResult part = mcap::readFile(cut_path, {true});
    // Every message of the chunks that end before the cut, nothing else.
    std::size_t expected = 0;
    for (std::size_t c = 0; c < full.chunk_indexes.size(); ++c)
      if (full.chunk_indexes[c].chunk_start_offset + full.chunk_indexes[c].chunk_length <= cut) expected = c + 1;
    EXPECT_EQ(part.chunks, expected) << "cut at " << cut;
    std::size_t in_chunks = 0;
    for (std::size_t i = 0; i < r.messages.size() && expected > 0; ++i)
      if (r.messages[i].log_time_ns <= full.chunk_indexes[expected - 1].message_end_time_ns) in_chunks = i + 1;
    EXPECT_EQ(part.messages.size(), expected == 0 ? 0 : in_chunks) << "cut at " << cut;
    for (std::size_t i = 0; i < part.messages.size(); ++i) ASSERT_TRUE(same(part.messages[i], r.messages[i]));
    if (cut < bytes.size() - 8) {
      EXPECT_FALSE(part.complete);
    }
    const std::string fixed = cut_path + ".recovered";
    EXPECT_EQ(mcap::recover(cut_path, fixed), part.messages.size());
    const mcap::ReadResult again = mcap::readFile(fixed);
    EXPECT_TRUE(again.complete);
    EXPECT_EQ(again.messages.size(), part.messages.size());
    fs::remove(cut_path);
    fs::remove(fixed);
  }
  fs::remove(r.path);
}

TEST(Mcap, AKilledWriterLeavesEveryFlushedMessage) {
  std::mt19937_64 rng(test::testSeed());
  const std::string path = tempPath("killed");
  mcap::Writer w(path);
  const auto c = w.addChannel(w.addSchema("S", "omgidl", "struct S { long a; };"), "t", "cdr");
  const int n = 100 + static_cast<int>(rng() % 400);
  for (int i = 0; i < n; ++i) w.write(mcap::Message{c, static_cast<std::uint32_t>(i), 1000u + i, 1000u + i, "abcd"});
  w.flush();
  w.write(mcap::Message{c, 9999, 99999, 99999, "not flushed"});
  // What a SIGKILL now would leave on disk (the writer is still open).
  const std::string copy = path + ".copy";
  fs::copy_file(path, copy, fs::copy_options::overwrite_existing);
  const mcap::ReadResult part = mcap::readFile(copy, {true});
  EXPECT_EQ(part.messages.size(), static_cast<std::size_t>(n));
  EXPECT_EQ(w.messagesInFile(), static_cast<std::uint64_t>(n));
  EXPECT_EQ(w.messagesWritten(), static_cast<std::uint64_t>(n + 1));
  w.close();
  EXPECT_EQ(mcap::readFile(path).messages.size(), static_cast<std::size_t>(n + 1));
  fs::remove(path);
  fs::remove(copy);
}

TEST(Mcap, ADamagedChunkIsAnErrorNamingItsByte) {
  std::mt19937_64 rng(test::testSeed());
  const Recording r = writeRandom(tempPath("bad"), rng, 300, 1024);
  const mcap::ReadResult full = mcap::readFile(r.path);
  std::string bytes = slurp(r.path);
  const auto& ci = full.chunk_indexes[rng() % full.chunk_indexes.size()];
  // A byte in the chunk's records (past its 9-byte record header and 8+8+8+4+4+8 bytes of fields).
  const std::size_t at = ci.chunk_start_offset + 9 + 40 + rng() % (ci.uncompressed_size);
  bytes[at] = static_cast<char>(bytes[at] ^ 0x5a);
  std::ofstream(r.path, std::ios::binary) << bytes;
  try {
    mcap::readFile(r.path);
    FAIL() << "damaged chunk accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("at byte " + std::to_string(ci.chunk_start_offset) + ": chunk CRC mismatch"),
              std::string::npos) << e.what();
  }
  fs::remove(r.path);
}

// Found by Fuzz.Parsers: a footer whose summary start lies beyond the footer made the summary CRC read far past the
// file. Now an error naming the footer's byte and the offset.
TEST(Mcap, AFooterPointingOutsideTheFileIsAnError) {
  std::mt19937_64 rng(test::testSeed());
  const Recording r = writeRandom(tempPath("footer"), rng, 50 + static_cast<int>(rng() % 200), 1024);
  std::string bytes = slurp(r.path);
  const std::size_t footer_at = bytes.size() - 8 - (1 + 8 + 8 + 8 + 4);
  ASSERT_EQ(bytes[footer_at], 0x02);  // the footer's opcode
  const std::uint64_t bad = rng() % 2 ? footer_at + 1 + rng() % (1ULL << 62) : 1 + rng() % 7;
  for (int k = 0; k < 8; ++k) bytes[footer_at + 9 + k] = static_cast<char>((bad >> (8 * k)) & 0xff);
  std::ofstream(r.path, std::ios::binary) << bytes;
  try {
    mcap::readFile(r.path);
    FAIL() << "summary start " << bad << " accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("at byte " + std::to_string(footer_at) + ": footer: summary start " +
                                         std::to_string(bad) + " is not between"),
              std::string::npos) << e.what();
  }
  fs::remove(r.path);
}

TEST(Mcap, Crc32IsTheStandardOne) {
  EXPECT_EQ(mcap::crc32("123456789", 9), 0xCBF43926u);  // the CRC-32/ISO-HDLC check value
}

}  // namespace
}  // namespace cellcal
