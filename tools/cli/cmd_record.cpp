// `cellcal record`: the cell's topics to an MCAP file (recording/recording.hpp), and --recover of a file cut short.
#include <fastdds/rtps/common/Guid.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/components/profile_probe.hpp"
#include "cellcal/recording/recording.hpp"
#include "commands.hpp"

namespace cellcal::cli {
namespace {

namespace fs = std::filesystem;
using namespace cellcal::components;
using namespace cellcal::recording;

std::string fileSizeText(const std::string& path) {
  std::error_code ec;
  const auto n = fs::file_size(path, ec);
  if (ec) return "?";
  char b[32];
  std::snprintf(b, sizeof b, "%.2f MB", static_cast<double>(n) / 1e6);
  return b;
}


std::map<std::string, std::string> qosMetadata(const fdds::DataReaderQos& q) {
  std::map<std::string, std::string> md;
  md["reliability"] = q.reliability().kind == fdds::RELIABLE_RELIABILITY_QOS ? "reliable" : "best_effort";
  switch (q.durability().kind) {
    case fdds::VOLATILE_DURABILITY_QOS: md["durability"] = "volatile"; break;
    case fdds::TRANSIENT_LOCAL_DURABILITY_QOS: md["durability"] = "transient_local"; break;
    case fdds::TRANSIENT_DURABILITY_QOS: md["durability"] = "transient"; break;
    default: md["durability"] = "persistent";
  }
  md["history"] = q.history().kind == fdds::KEEP_LAST_HISTORY_QOS ? "keep_last" : "keep_all";
  md["depth"] = std::to_string(q.history().depth);
  return md;
}

struct RecordArgs {
  ProcessOptions common;
  std::string out, topics = "all", recover, json;
  double duration_s = 0, flush_period_s = 1.0;
  std::size_t chunk_kib = 1024;
  bool quiet = false;
};

void addOptions(CLI::App& cmd, RecordArgs& a) {
  addCommonOptions(cmd, a.common);
  cmd.add_option("--out", a.out, "MCAP file to write")->required()->check(outputFile());
  cmd.add_option("--topics", a.topics, "all | inputs | comma-separated topic names")->capture_default_str();
  cmd.add_option("--duration-s", a.duration_s, "stop after this many seconds (0: until SIGINT/SIGTERM)")->check(nonNegative());
  cmd.add_option("--flush-period-s", a.flush_period_s, "close the chunk and flush it this often")->check(positive())->capture_default_str();
  cmd.add_option("--chunk-kib", a.chunk_kib, "close a chunk when it reaches this size")->check(positive())->capture_default_str();
  cmd.add_option("--recover", a.recover, "instead of recording: rewrite this (cut short) recording whole to --out")
      ->check(CLI::ExistingFile);
  cmd.add_option("--json", a.json, "write the counts as JSON")->check(outputFile());
  cmd.add_flag("-q,--quiet", a.quiet, "no status line every 10 s");
}

int runRecover(const RecordArgs& a) {
  mcap::ReadOptions o;
  o.tolerate_truncation = true;
  const auto before = mcap::readFile(a.recover, o);
  if (before.complete) std::printf("record --recover: %s is already complete\n", a.recover.c_str());
  else std::printf("record --recover: %s: %s\n", a.recover.c_str(), before.problem.c_str());
  const std::uint64_t n = mcap::recover(a.recover, a.out);
  std::printf("record --recover: %llu messages of the complete chunks written to %s (%s)\n",
              static_cast<unsigned long long>(n), a.out.c_str(), fileSizeText(a.out).c_str());
  return 0;
}

int runRecord(const RecordArgs& a) {
  if (!a.recover.empty()) return runRecover(a);
  installStopHandlers();
  const CellConfig cell = loadCell(a.common);
  const std::vector<std::string> topics = parseTopicList(a.topics);
  if (!(a.flush_period_s > 0)) throw std::runtime_error("--flush-period-s must be > 0");
  RecordingWriter rec(a.out, a.chunk_kib * 1024);
  struct TopicStats {
    std::uint64_t received = 0, lost = 0;
    std::map<eprosima::fastrtps::rtps::GUID_t, std::uint64_t> last_sequence;  // per writer: gaps are lost samples
  };
  std::mutex mutex;
  std::map<std::string, TopicStats> stats;
  for (const auto& t : topics) stats[t];
  DdsNode node(cell, "cellcal_recorder", identity::kObserver);
  for (const auto& topic : topics) {
    visitTopic(topic, [&](auto tag) {
      using M = typename decltype(tag)::type;
      {
        std::lock_guard<std::mutex> lock(mutex);
        rec.channel(topic, qosMetadata(node.readerQos<M>()));
      }
      TopicStats* st = &stats[topic];
      const std::string* name = &stats.find(topic)->first;
      node.reader<M>([&rec, &mutex, st, name](const M& m, const fdds::SampleInfo& info) {
        const std::int64_t now = wallNs();
        std::string cdr = encodeCdr(m);
        const std::uint64_t seq = static_cast<std::uint64_t>(info.sample_identity.sequence_number().to64long());
        std::lock_guard<std::mutex> lock(mutex);
        ++st->received;
        auto [it, fresh] = st->last_sequence.emplace(info.sample_identity.writer_guid(), seq);
        if (!fresh) {
          if (seq > it->second + 1) st->lost += seq - it->second - 1;
          it->second = std::max(it->second, seq);
        }
        rec.writeEncoded(*name, std::move(cdr), static_cast<std::uint64_t>(now),
                         static_cast<std::uint64_t>(info.source_timestamp.to_ns()), static_cast<std::uint32_t>(seq));
      });
    });
  }
  std::fprintf(stderr, "record: %zu topic(s) on domain %d (%s) -> %s; chunks flushed every %g s\n", topics.size(),
               cell.dds.domain_id, cell.dds.participant_profile.c_str(), a.out.c_str(), a.flush_period_s);
  const auto start = std::chrono::steady_clock::now();
  const RunLimit limit(a.duration_s);
  auto next_flush = start;
  auto next_status = start + std::chrono::seconds(10);
  while (sleepUntil(std::chrono::steady_clock::now() + std::chrono::milliseconds(20))) {
    const auto now = std::chrono::steady_clock::now();
    if (limit.timeUp()) break;
    if (now >= next_flush) {
      next_flush = now + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                             std::chrono::duration<double>(a.flush_period_s));
      std::lock_guard<std::mutex> lock(mutex);
      rec.file().flush();  // whole chunks on disk: a SIGKILL loses at most this period
    }
    if (!a.quiet && now >= next_status) {
      next_status = now + std::chrono::seconds(10);
      std::lock_guard<std::mutex> lock(mutex);
      std::fprintf(stderr, "record: %llu messages, %llu on disk\n",
                   static_cast<unsigned long long>(rec.file().messagesWritten()),
                   static_cast<unsigned long long>(rec.file().messagesInFile()));
    }
  }
  node.shutdown();  // no callback after this
  rec.file().close();
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::uint64_t lost = 0;
  nlohmann::json per_topic = nlohmann::json::object();
  std::printf("record: %llu messages in %.1f s written to %s (%s)\n",
              static_cast<unsigned long long>(rec.file().messagesWritten()), wall_s, a.out.c_str(),
              fileSizeText(a.out).c_str());
  for (const auto& [t, s] : stats) {
    std::printf("record:   %-34s %10llu received, %llu lost before the recorder (writer sequence gaps)\n", t.c_str(),
                static_cast<unsigned long long>(s.received), static_cast<unsigned long long>(s.lost));
    per_topic[t] = {{"received", s.received}, {"lost", s.lost}};
    lost += s.lost;
  }
  const nlohmann::json counts = {{"file", a.out},
                                 {"messages", rec.file().messagesWritten()},
                                 {"lost", lost},
                                 {"duration_s", wall_s},
                                 {"topics", per_topic}};
  writeJsonFile(a.json, counts);
  stats::writeProcessStats(a.common.stats_json, "recorder", node.stats(), counts);
  if (rec.file().messagesWritten() == 0) {
    std::fprintf(stderr, "record: WARNING: nothing received in %.1f s on domain %d with participant profile %s (exit 3); "
                 "looking on the other profiles...\n",
                 wall_s, cell.dds.domain_id, cell.dds.participant_profile.c_str());
    std::fprintf(stderr, "%s", describeSightings(cell, probeOtherProfiles(cell), "record: ").c_str());
    return 3;
  }
  return 0;
}

}  // namespace

Runner addRecordCommand(CLI::App& app) { return addCommand(app, "record", addOptions, runRecord); }

}  // namespace cellcal::cli
