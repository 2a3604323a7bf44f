// `cellcal replay`: a recording republished on its topics with the recorded timing, like the live cell.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <functional>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/recording/recording.hpp"
#include "commands.hpp"
#include "progress.hpp"

namespace cellcal::cli {
namespace {

using namespace cellcal::components;
using namespace cellcal::recording;

struct ReplayArgs {
  ProcessOptions common;
  std::string file, topics = "inputs", json;
  double rate = 1.0, duration_s = 0, wait_s = 10;
  int wait_for_readers = 1;
  bool as_fast_as_possible = false, loop = false, keep_stamps = false, no_progress = false;
};

void addOptions(CLI::App& cmd, ReplayArgs& a) {
  addCommonOptions(cmd, a.common);
  cmd.add_option("file", a.file, "MCAP recording")->required()->check(CLI::ExistingFile);
  cmd.add_option("--rate", a.rate, "speed factor of the recorded timing")->check(positive())->capture_default_str();
  cmd.add_flag("--as-fast-as-possible", a.as_fast_as_possible, "no pauses between messages");
  cmd.add_option("--topics", a.topics, "inputs | all | comma-separated topic names")->capture_default_str();
  cmd.add_flag("--loop", a.loop, "start again at the end (stamps keep increasing) until SIGINT/--duration-s");
  cmd.add_option("--duration-s", a.duration_s, "stop after this many seconds (0: at the end)")->check(nonNegative());
  cmd.add_flag("--keep-stamps", a.keep_stamps, "publish the recorded source stamps unchanged");
  cmd.add_option("--wait-for-readers", a.wait_for_readers, "wait until every replayed topic has this many readers")
      ->capture_default_str();
  cmd.add_option("--wait-s", a.wait_s, "... for at most this long")->check(nonNegative())->capture_default_str();
  cmd.add_option("--json", a.json, "write the summary as JSON")->check(outputFile());
  cmd.add_flag("--no-progress", a.no_progress, "no progress bar");
}

// A topic's writer, and what became of its samples.
struct Out {
  std::function<int(const std::string&, std::int64_t, std::string*)> publish;  // 1 sent, 0 refused, -1 undecodable
  fdds::DataWriter* writer = nullptr;
  std::uint64_t sent = 0, refused = 0, undecodable = 0;
};

// The recording's messages on the selected topics, in log order.
std::vector<const RecordedMessage*> selectMessages(const ReplayArgs& a, const Recording& rec) {
  const std::vector<std::string> topics = parseTopicList(a.topics);
  std::vector<const RecordedMessage*> msgs;
  for (const auto& m : rec.in_log_order)
    if (std::find(topics.begin(), topics.end(), *m.topic) != topics.end()) msgs.push_back(&m);
  if (msgs.empty()) {
    std::string have;
    for (const auto& [t, n] : rec.messages_per_topic) have += " " + t + " (" + std::to_string(n) + ")";
    throw std::runtime_error(a.file + ": no messages on the selected topics (--topics " + a.topics + "); it holds:" +
                             (have.empty() ? std::string(" nothing") : have));
  }
  return msgs;
}

// One writer per topic the messages are on, publishing a message's CDR with its stamps shifted.
std::map<std::string, Out> makeWriters(DdsNode& node, const std::vector<const RecordedMessage*>& msgs) {
  std::map<std::string, Out> outs;
  for (const auto* m : msgs) {
    if (outs.count(*m->topic)) continue;
    visitTopic(*m->topic, [&](auto tag) {
      using M = typename decltype(tag)::type;
      auto w = node.writer<M>();
      Out o;
      o.writer = w.entity();
      o.publish = [w, sample = std::make_shared<M>()](const std::string& cdr, std::int64_t shift_ns,
                                                      std::string* error) mutable -> int {
        if (!decodeCdr(cdr, sample.get(), error)) return -1;
        if (shift_ns != 0) shiftStamps(*sample, shift_ns);
        return w.write(*sample) ? 1 : 0;
      };
      outs[*m->topic] = std::move(o);
    });
  }
  return outs;
}

// Subscribers first: a sample published before discovery is lost (volatile topics).
void waitForReaders(const ReplayArgs& a, std::map<std::string, Out>& outs) {
  const auto wait_until = std::chrono::steady_clock::now() + std::chrono::duration<double>(a.wait_s);
  while (a.wait_for_readers > 0 && std::chrono::steady_clock::now() < wait_until && !stopRequested()) {
    bool all = true;
    for (auto& [t, o] : outs) {
      fdds::PublicationMatchedStatus st;
      o.writer->get_publication_matched_status(st);
      all &= st.current_count >= a.wait_for_readers;
    }
    if (all) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  for (auto& [t, o] : outs) {
    fdds::PublicationMatchedStatus st;
    o.writer->get_publication_matched_status(st);
    if (st.current_count < a.wait_for_readers)
      std::fprintf(stderr, "replay: %s has %d reader(s) after %g s (wanted %d); publishing anyway\n", t.c_str(),
                   st.current_count, a.wait_s, a.wait_for_readers);
  }
  if (a.wait_for_readers > 0) std::this_thread::sleep_for(std::chrono::milliseconds(250));  // the readers' side of the match
}

// What the replay did: counted per topic in the Outs, the rest here.
struct Played {
  std::vector<double> timing_error_us;  // publish - schedule, per message (not as fast as possible)
  std::uint64_t published = 0, loops = 0;
  std::string first_error;
};

// The messages published on their recorded schedule (scaled by --rate) or as fast as possible, looped if asked.
Played play(const ReplayArgs& a, const std::vector<const RecordedMessage*>& msgs, const std::vector<Out*>& out_of) {
  const std::uint64_t t0 = msgs.front()->message->log_time_ns;
  const std::uint64_t span_ns = msgs.back()->message->log_time_ns - t0;
  Played p;
  std::vector<double>& timing_error_us = p.timing_error_us;
  std::uint64_t& published = p.published;
  std::uint64_t& loops = p.loops;
  std::string& first_error = p.first_error;
  timing_error_us.reserve(msgs.size());
  std::int64_t shift_ns = 0;
  const RunLimit limit(a.duration_s);
  ProgressBar bar("replay", !a.no_progress);
  bool stop = false;
  while (!stop) {
    // Re-stamping: the recording's first message is "now"; each loop continues after the previous one.
    if (!a.keep_stamps) {
      const std::int64_t now_shift = wallNs() - static_cast<std::int64_t>(t0);
      shift_ns = loops == 0 ? now_shift : std::max<std::int64_t>(now_shift, shift_ns + static_cast<std::int64_t>(span_ns) + 1000000000LL);
    }
    const auto loop_start = std::chrono::steady_clock::now();
    for (size_t i = 0; i < msgs.size(); ++i) {
      if (limit.over()) {
        stop = true;
        break;
      }
      const mcap::Message& m = *msgs[i]->message;
      if (!a.as_fast_as_possible) {
        const auto due = loop_start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                          std::chrono::duration<double, std::nano>(static_cast<double>(m.log_time_ns - t0) / a.rate));
        if (!sleepUntil(due)) {
          stop = true;
          break;
        }
        timing_error_us.push_back(std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - due).count());
      }
      Out& o = *out_of[i];
      std::string error;
      const int r = o.publish(m.data, shift_ns, &error);
      if (r == 1) ++o.sent, ++published;
      else if (r == 0) ++o.refused;
      else {
        ++o.undecodable;
        if (first_error.empty())
          first_error = *msgs[i]->topic + " message at log time " + std::to_string(m.log_time_ns) + ": " + error;
      }
      if ((i & 63) == 0)
        bar.update(static_cast<double>(i + 1) / static_cast<double>(msgs.size()),
                   std::to_string(i + 1) + "/" + std::to_string(msgs.size()) + " messages" +
                       (a.loop ? ", loop " + std::to_string(loops + 1) : ""));
    }
    if (!stop) {
      ++loops;
      bar.update(1.0, std::to_string(msgs.size()) + "/" + std::to_string(msgs.size()) + " messages");
    }
    if (!a.loop) break;
  }
  bar.done();
  return p;
}

int runReplay(const ReplayArgs& a) {
  installStopHandlers();
  if (!(a.rate > 0)) throw std::runtime_error("--rate must be > 0");
  const Recording rec = readRecording(a.file);
  if (!rec.file.complete)
    std::fprintf(stderr, "replay: %s is incomplete (%s): replaying the messages of its complete chunks "
                 "(`cellcal record --recover` makes it whole)\n", a.file.c_str(), rec.file.problem.c_str());
  const std::vector<const RecordedMessage*> msgs = selectMessages(a, rec);
  const CellConfig cell = loadCell(a.common);
  DdsNode node(cell, "cellcal_replay", identity::kReplay);
  std::map<std::string, Out> outs = makeWriters(node, msgs);
  std::vector<Out*> out_of;  // per message, resolved once (not a map lookup per publish)
  for (const auto* m : msgs) out_of.push_back(&outs.at(*m->topic));
  waitForReaders(a, outs);
  const std::uint64_t t0 = msgs.front()->message->log_time_ns;
  const std::uint64_t span_ns = msgs.back()->message->log_time_ns - t0;
  if (!a.keep_stamps && !a.as_fast_as_possible && a.rate != 1.0)
    std::fprintf(stderr, "replay: stamps keep their recorded spacing; at --rate %g they drift from the clock: run the "
                 "engine with engine.max_sample_age_s: 0\n", a.rate);
  if (!a.keep_stamps && a.as_fast_as_possible)
    std::fprintf(stderr, "replay: stamps keep their recorded spacing; as fast as possible they run ahead of the clock: "
                 "run the engine with engine.max_sample_age_s: 0\n");
  const auto start = std::chrono::steady_clock::now();
  const Played played = play(a, msgs, out_of);
  const std::vector<double>& timing_error_us = played.timing_error_us;
  const std::uint64_t published = played.published, loops = played.loops;
  const std::string& first_error = played.first_error;
  // Reliable samples still in the writers' histories reach late readers before the participant goes; best-effort
  // ones get a moment to leave the socket.
  for (auto& [t, o] : outs) o.writer->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(2, 0));
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  const double wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  node.shutdown();
  std::uint64_t refused = 0, undecodable = 0;
  nlohmann::json per_topic = nlohmann::json::object();
  for (const auto& [t, o] : outs) {
    refused += o.refused;
    undecodable += o.undecodable;
    per_topic[t] = {{"published", o.sent}, {"refused", o.refused}, {"undecodable", o.undecodable}};
  }
  const double p50 = percentile(timing_error_us, 0.5), p99 = percentile(timing_error_us, 0.99);
  const double max_us = timing_error_us.empty() ? std::nan("") : *std::max_element(timing_error_us.begin(), timing_error_us.end());
  std::printf("replay: %llu messages in %.2f s (%llu full loop(s) of %.2f s recorded, %s)\n",
              static_cast<unsigned long long>(published), wall_s, static_cast<unsigned long long>(loops), span_ns / 1e9,
              a.as_fast_as_possible ? "as fast as possible" : ("rate " + std::to_string(a.rate)).c_str());
  for (const auto& [t, o] : outs)
    std::printf("replay:   %-34s %10llu published\n", t.c_str(), static_cast<unsigned long long>(o.sent));
  std::printf("replay: drops: %llu refused by DDS, %llu undecodable%s\n", static_cast<unsigned long long>(refused),
              static_cast<unsigned long long>(undecodable), first_error.empty() ? "" : (" (first: " + first_error + ")").c_str());
  if (!timing_error_us.empty())
    std::printf("replay: timing error (publish - schedule) p50 %.0f us, p99 %.0f us, max %.0f us\n", p50, p99, max_us);
  writeJsonFile(a.json, {{"file", a.file},
                         {"published", published},
                         {"refused", refused},
                         {"undecodable", undecodable},
                         {"loops", loops},
                         {"duration_s", wall_s},
                         {"recorded_span_s", span_ns / 1e9},
                         {"rate", a.as_fast_as_possible ? 0.0 : a.rate},
                         {"timing_error_p50_us", timing_error_us.empty() ? nlohmann::json() : nlohmann::json(p50)},
                         {"timing_error_p99_us", timing_error_us.empty() ? nlohmann::json() : nlohmann::json(p99)},
                         {"timing_error_max_us", timing_error_us.empty() ? nlohmann::json() : nlohmann::json(max_us)},
                         {"topics", per_topic}});
  return undecodable > 0 ? 1 : 0;
}

}  // namespace

Runner addReplayCommand(CLI::App& app) { return addCommand(app, "replay", addOptions, runReplay); }

}  // namespace cellcal::cli
