// Recordings of a cell (MCAP, components/recording.hpp): `record` (DDS -> file), `replay` (file -> DDS),
// `validate` (the engine's logic over a file, in-process), `export` (file -> CSV v1) and `import csv` (CSV v1 -> file).
#include <fastdds/rtps/common/Guid.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/components/recording.hpp"
#include "cellcal/core/ipa_dataset.hpp"
#include "cellcal/core/robot_yaml.hpp"
#include "commands.hpp"
#include "progress.hpp"

namespace cellcal::cli {
namespace {

namespace fs = std::filesystem;
using namespace cellcal::components;

std::string fileSizeText(const std::string& path) {
  std::error_code ec;
  const auto n = fs::file_size(path, ec);
  if (ec) return "?";
  char b[32];
  std::snprintf(b, sizeof b, "%.2f MB", static_cast<double>(n) / 1e6);
  return b;
}

// ------------------------------------------------------------------------------------------------------------ record

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
  auto next_flush = start;
  auto next_status = start + std::chrono::seconds(10);
  while (sleepUntil(std::chrono::steady_clock::now() + std::chrono::milliseconds(20))) {
    const auto now = std::chrono::steady_clock::now();
    if (a.duration_s > 0 && now - start >= std::chrono::duration<double>(a.duration_s)) break;
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
  writeJsonFile(a.common.stats_json, {{"name", "recorder"}, {"pid", ::getpid()}, {"topics", node.stats()}, {"extra", counts}});
  return 0;
}

// ------------------------------------------------------------------------------------------------------------ replay

struct ReplayArgs {
  ProcessOptions common;
  std::string file, topics = "inputs", json;
  double rate = 1.0, duration_s = 0, wait_s = 10;
  int wait_for_readers = 1;
  bool as_fast_as_possible = false, loop = false, keep_stamps = false, no_progress = false;
};

int runReplay(const ReplayArgs& a) {
  installStopHandlers();
  if (!(a.rate > 0)) throw std::runtime_error("--rate must be > 0");
  const Recording rec = readRecording(a.file);
  if (!rec.file.complete)
    std::fprintf(stderr, "replay: %s is incomplete (%s): replaying the messages of its complete chunks "
                 "(`cellcal record --recover` makes it whole)\n", a.file.c_str(), rec.file.problem.c_str());
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
  const CellConfig cell = loadCell(a.common);
  DdsNode node(cell, "cellcal_replay", identity::kReplay);
  struct Out {
    std::function<int(const std::string&, std::int64_t, std::string*)> publish;  // 1 sent, 0 refused, -1 undecodable
    fdds::DataWriter* writer = nullptr;
    std::uint64_t sent = 0, refused = 0, undecodable = 0;
  };
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
  std::vector<Out*> out_of;  // per message, resolved once (not a map lookup per publish)
  for (const auto* m : msgs) out_of.push_back(&outs.at(*m->topic));
  // Subscribers first: a sample published before discovery is lost (volatile topics).
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
  const std::uint64_t t0 = msgs.front()->message->log_time_ns;
  const std::uint64_t span_ns = msgs.back()->message->log_time_ns - t0;
  if (!a.keep_stamps && !a.as_fast_as_possible && a.rate != 1.0)
    std::fprintf(stderr, "replay: stamps keep their recorded spacing; at --rate %g they drift from the clock: run the "
                 "engine with engine.max_sample_age_s: 0\n", a.rate);
  if (!a.keep_stamps && a.as_fast_as_possible)
    std::fprintf(stderr, "replay: stamps keep their recorded spacing; as fast as possible they run ahead of the clock: "
                 "run the engine with engine.max_sample_age_s: 0\n");
  std::vector<double> timing_error_us;
  timing_error_us.reserve(msgs.size());
  std::uint64_t published = 0, loops = 0;
  std::string first_error;
  std::int64_t shift_ns = 0;
  const auto start = std::chrono::steady_clock::now();
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
      if (stopRequested() ||
          (a.duration_s > 0 && std::chrono::steady_clock::now() - start >= std::chrono::duration<double>(a.duration_s))) {
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

// ---------------------------------------------------------------------------------------------------------- validate

struct ValidateArgs {
  ProcessOptions common;
  std::string file, json, figures;
  double tolerance_m = 1e-9, tolerance_rad = 1e-9;
  bool require_match = false, no_progress = false;
};

// Figures of one robot's calibrations over a recording (gnuplot, PNG): <robot>_accuracy.png, the a-priori
// verification error (each pose predicted by the calibration before it) and the a-posteriori residual against the
// time of the reading; <robot>_joint_drift.png, each joint's zero offset as identified, minus its nominal value.
void writeRecordingFigures(const std::string& dir, const std::string& robot, const RobotModel& model,
                           const std::vector<ReceivedCalibration>& versions) {
  if (versions.empty()) return;
  const double t0 = static_cast<double>(versions.front().last_measurement_stamp_ns);
  std::ostringstream acc, drift, drift_gp;
  acc << "t_h verification_mm residual_mm\n";
  drift << "t_h";
  for (int j = 0; j < model.numJoints(); ++j) drift << " joint" << j + 1;
  drift << "\n";
  for (const auto& v : versions) {
    const double t_h = (static_cast<double>(v.last_measurement_stamp_ns) - t0) / 3.6e12;
    auto num = [](double x) { return std::isfinite(x) ? std::to_string(x) : std::string("NaN"); };
    acc << t_h << ' ' << num(v.verification_mean_position_m * 1e3) << ' ' << num(v.residual_rms_position_m * 1e3) << '\n';
    drift << t_h;
    for (int j = 0; j < model.numJoints(); ++j) {
      const int i = model.jointParam(j, JointParam::kThetaOffset);
      drift << ' ' << (v.params[i] - model.nominal[i]) * 180.0 / kPi * 1e3;
    }
    drift << '\n';
  }
  std::string error;
  const std::string acc_gp =
      "set title '" + robot + ": accuracy over the recording (" + std::to_string(versions.size()) +
      " calibrations)'\nset xlabel 'time of the reading (h since the first calibration)'\n"
      "set ylabel 'position error (mm)'\nset logscale y\nset grid\nset key top right\n"
      "plot datafile using 1:($2 > 1e-3 ? $2 : 1/0) skip 1 with lines lw 2 title 'a-priori: each pose predicted before it was used', "
      "datafile using 1:($3 > 1e-3 ? $3 : 1/0) skip 1 with lines lw 1 title 'a-posteriori residual (recent poses)'\n";
  if (!renderGnuplot(dir, robot + "_accuracy", acc.str(), acc_gp, &error)) std::cerr << "warning: " << error << "\n";
  drift_gp << "set title '" << robot << ": identified joint zero offsets over the recording'\n"
           << "set xlabel 'time of the reading (h since the first calibration)'\n"
           << "set ylabel 'zero offset - nominal (millidegrees)'\nset grid\nset key outside right\n"
           << "plot for [c=2:" << model.numJoints() + 1 << "] datafile using 1:c skip 1 with lines lw 2 title sprintf('joint %d', c-1)\n";
  if (!renderGnuplot(dir, robot + "_joint_drift", drift.str(), drift_gp.str(), &error))
    std::cerr << "warning: " << error << "\n";
}

struct Difference {
  double length_m = 0, angle_rad = 0, other = 0, verification_m = 0;
  std::string worst;  // the parameter that differs most (relative to its tolerance)
  double worst_ratio = 0;
};

Difference compare(const RobotModel& model, const std::vector<Extension>& exts, const ReceivedCalibration& a,
                   const ReceivedCalibration& b,
                   double tol_m, double tol_rad) {
  Difference d;
  auto consider = [&](const std::string& name, double delta) {
    delta = std::abs(delta);
    const bool length = name.size() > 2 && name.compare(name.size() - 2, 2, "_m") == 0;
    const bool angle = name.size() > 4 && name.compare(name.size() - 4, 4, "_rad") == 0;
    double& slot = length ? d.length_m : angle ? d.angle_rad : d.other;
    slot = std::max(slot, delta);
    const double ratio = delta / (length ? tol_m : tol_rad);
    if (ratio > d.worst_ratio) d.worst_ratio = ratio, d.worst = name;
  };
  for (int i = 0; i < model.numParams(); ++i) consider(model.paramName(i), a.params[i] - b.params[i]);
  const auto names = extensionParamNames(model, exts);
  if (a.extension_params.size() == b.extension_params.size())
    for (Eigen::Index i = 0; i < a.extension_params.size(); ++i)
      consider(names[static_cast<size_t>(i)], a.extension_params[i] - b.extension_params[i]);
  else
    d.worst = "model extensions differ", d.worst_ratio = INFINITY;
  const bool both_nan = std::isnan(a.verification_mean_position_m) && std::isnan(b.verification_mean_position_m);
  d.verification_m = both_nan ? 0 : std::abs(a.verification_mean_position_m - b.verification_mean_position_m);
  if (std::isnan(d.verification_m)) d.verification_m = INFINITY;
  return d;
}

int runValidate(const ValidateArgs& a) {
  const auto t_read = std::chrono::steady_clock::now();
  const Recording rec = readRecording(a.file);
  const CellConfig cell = loadCell(a.common);
  struct Run {
    const CellRobot* robot;
    std::unique_ptr<CalibrationEngine> engine;
    std::vector<ReceivedCalibration> reproduced;
    std::map<std::uint64_t, ReceivedCalibration> recorded;  // first CalibrationState of each version
    std::uint64_t joint_states = 0, tracker_readings = 0;
  };
  std::map<std::string, Run> runs;
  std::map<std::string, Run*> by_target;
  for (const auto& r : cell.robots) {
    Run& run = runs[r.robot_id];
    run.robot = &r;
    run.engine = std::make_unique<CalibrationEngine>(r, cell.engine, cell.time_compression, /*persist=*/false);
    by_target[r.target_id] = &run;
  }
  std::uint64_t unknown_keys = 0, undecodable = 0, state_errors = 0;
  std::string first_error;
  auto note = [&](std::uint64_t& counter, const std::string& what) {
    ++counter;
    if (first_error.empty()) first_error = what;
  };
  auto step = [&](Run& run, std::int64_t now) {
    if (!run.engine->process(now)) return;
    const auto& s = run.engine->snapshot();
    ReceivedCalibration c;
    c.version = s.version;
    c.poses_used = s.poses_used;
    c.params = s.params;
    c.extensions = s.extensions;
    c.extension_params = s.extension_params;
    c.verification_mean_position_m = s.verification_mean_position_m;
    c.residual_rms_position_m = s.residual_rms_position_m;
    c.last_measurement_stamp_ns = static_cast<std::uint64_t>(s.last_measurement_stamp_ns);
    run.reproduced.push_back(std::move(c));
  };
  const double read_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_read).count();
  const auto t0 = std::chrono::steady_clock::now();
  ProgressBar bar("validate", !a.no_progress);
  // Decoded into reused samples: constructing one costs more than decoding it (see DdsNode::Listener).
  msg::JointState js;
  msg::TrackerPose tp;
  msg::CalibrationState cs;
  std::int64_t next_tick = 0;
  for (size_t i = 0; i < rec.in_log_order.size(); ++i) {
    const mcap::Message& m = *rec.in_log_order[i].message;
    const std::string& topic = *rec.in_log_order[i].topic;
    const auto now = static_cast<std::int64_t>(m.log_time_ns);
    auto where = [&] { return a.file + ": " + topic + " message " + std::to_string(i) + " (log time " + std::to_string(m.log_time_ns) + ")"; };
    std::string error;
    if (topic == TopicOf<msg::JointState>::name) {
      if (!decodeCdr(m.data, &js, &error)) { note(undecodable, where() + ": " + error); continue; }
      auto it = runs.find(js.robot_id().to_string());
      if (it == runs.end()) { note(unknown_keys, where() + ": robot_id '" + js.robot_id().to_string() + "' not in " + cell.source); continue; }
      ++it->second.joint_states;
      it->second.engine->onJointState(toJointSample(js), now);
      step(it->second, now);
    } else if (topic == TopicOf<msg::TrackerPose>::name) {
      if (!decodeCdr(m.data, &tp, &error)) { note(undecodable, where() + ": " + error); continue; }
      auto it = by_target.find(tp.target_id().to_string());
      if (it == by_target.end()) { note(unknown_keys, where() + ": target_id '" + tp.target_id().to_string() + "' not in " + cell.source); continue; }
      ++it->second->tracker_readings;
      it->second->engine->onTrackerSample(toTrackerSample(tp), now);
      step(*it->second, now);
    } else if (topic == TopicOf<msg::CalibrationState>::name) {
      if (!decodeCdr(m.data, &cs, &error)) { note(undecodable, where() + ": " + error); continue; }
      auto it = runs.find(cs.robot_id().to_string());
      if (it == runs.end()) { note(unknown_keys, where() + ": robot_id '" + cs.robot_id().to_string() + "' not in " + cell.source); continue; }
      if (cs.version() == 0 || it->second.recorded.count(cs.version())) continue;  // republished
      auto rc = fromCalibrationState(it->second.robot->model, cs, &error);
      if (!rc) { note(state_errors, where() + ": " + error); continue; }
      it->second.recorded[rc->version] = std::move(*rc);
    }
    // The engine process also polls every robot every 5 ms (readings whose joint state never came time out).
    if (now >= next_tick) {
      next_tick = now + 5000000;
      for (auto& [id, run] : runs) step(run, now);
    }
    if ((i & 1023) == 0)
      bar.update(static_cast<double>(i) / static_cast<double>(rec.in_log_order.size()),
                 std::to_string(i) + "/" + std::to_string(rec.in_log_order.size()) + " messages");
  }
  for (auto& [id, run] : runs) step(run, static_cast<std::int64_t>(rec.end_ns) + 1000000000LL);
  bar.done();
  const double process_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double span_s = (rec.end_ns - rec.start_ns) / 1e9;
  const double real_time_factor = span_s / std::max(read_s + process_s, 1e-9);
  std::printf("validate: %s: %zu messages over %.1f s of recording (%s); read in %.3f s, engine logic in %.3f s: "
              "%.0fx real time\n",
              a.file.c_str(), rec.in_log_order.size(), span_s,
              (rec.file.complete ? std::string("complete") : "incomplete: " + rec.file.problem).c_str(), read_s,
              process_s, real_time_factor);
  std::printf("validate: cell file %s\n", cell.source.c_str());
  bool all_match = true;
  nlohmann::json robots = nlohmann::json::object();
  for (auto& [id, run] : runs) {
    if (run.joint_states == 0 && run.tracker_readings == 0 && run.recorded.empty()) continue;
    const RobotModel& model = run.robot->model;
    const auto& exts = run.engine->snapshot().extensions;
    std::uint64_t compared = 0, mismatched = 0, not_recorded = 0;
    Difference worst;
    std::string first_mismatch;
    nlohmann::json series = nlohmann::json::array();
    std::set<std::uint64_t> reproduced_versions;
    for (const auto& c : run.reproduced) {
      reproduced_versions.insert(c.version);
      nlohmann::json row = {{"version", c.version}, {"poses_used", c.poses_used},
                            {"verification_mm", std::isfinite(c.verification_mean_position_m) ? nlohmann::json(c.verification_mean_position_m * 1e3) : nlohmann::json()}};
      auto it = run.recorded.find(c.version);
      if (it == run.recorded.end()) {
        ++not_recorded;
        series.push_back(row);
        continue;
      }
      ++compared;
      const Difference d = compare(model, exts, c, it->second, a.tolerance_m, a.tolerance_rad);
      row["recorded_verification_mm"] = std::isfinite(it->second.verification_mean_position_m) ? nlohmann::json(it->second.verification_mean_position_m * 1e3) : nlohmann::json();
      row["max_difference_m"] = d.length_m;
      row["max_difference_rad"] = d.angle_rad;
      series.push_back(row);
      worst.length_m = std::max(worst.length_m, d.length_m);
      worst.angle_rad = std::max(worst.angle_rad, d.angle_rad);
      worst.other = std::max(worst.other, d.other);
      worst.verification_m = std::max(worst.verification_m, d.verification_m);
      const bool ok = d.length_m <= a.tolerance_m && d.angle_rad <= a.tolerance_rad && d.other <= a.tolerance_rad &&
                      d.verification_m <= a.tolerance_m && std::isfinite(d.worst_ratio);
      if (!ok) {
        ++mismatched;
        if (first_mismatch.empty())
          first_mismatch = "v" + std::to_string(c.version) + ": " + d.worst + " differs by " + std::to_string(d.worst_ratio) +
                           "x the tolerance; verification by " + std::to_string(d.verification_m * 1e3) + " mm";
      }
    }
    std::uint64_t missing = 0;
    for (const auto& [v, c] : run.recorded)
      if (!reproduced_versions.count(v)) ++missing;
    if (mismatched || missing) all_match = false;
    const ReceivedCalibration* last_rep = run.reproduced.empty() ? nullptr : &run.reproduced.back();
    const ReceivedCalibration* last_rec = run.recorded.empty() ? nullptr : &run.recorded.rbegin()->second;
    std::printf("validate: %s: %llu joint states, %llu tracker readings -> %zu calibrations (last v%llu, %u poses, "
                "verification %.4f mm)\n",
                id.c_str(), static_cast<unsigned long long>(run.joint_states),
                static_cast<unsigned long long>(run.tracker_readings), run.reproduced.size(),
                static_cast<unsigned long long>(last_rep ? last_rep->version : 0), last_rep ? last_rep->poses_used : 0,
                last_rep ? last_rep->verification_mean_position_m * 1e3 : std::nan(""));
    if (run.recorded.empty()) {
      std::printf("validate: %s: the recording holds no CalibrationState: nothing to compare with\n", id.c_str());
    } else {
      std::printf("validate: %s: %zu recorded calibrations (last v%llu, verification %.4f mm): %llu compared, %llu differ, "
                  "%llu recorded but not reproduced, %llu reproduced but not recorded\n",
                  id.c_str(), run.recorded.size(), static_cast<unsigned long long>(last_rec->version),
                  last_rec->verification_mean_position_m * 1e3, static_cast<unsigned long long>(compared),
                  static_cast<unsigned long long>(mismatched), static_cast<unsigned long long>(missing),
                  static_cast<unsigned long long>(not_recorded));
      std::printf("validate: %s: largest differences: %.3g m, %.3g rad, verification %.3g m (tolerance %.0e m, %.0e rad)%s\n",
                  id.c_str(), worst.length_m, worst.angle_rad, worst.verification_m, a.tolerance_m, a.tolerance_rad,
                  first_mismatch.empty() ? "" : ("; first: " + first_mismatch).c_str());
    }
    const auto& c = run.engine->counters();
    nlohmann::json rej = nlohmann::json::object();
    for (size_t k = 0; k < c.rejected.size(); ++k)
      if (c.rejected[k]) rej[rejectionName(static_cast<Rejection>(k))] = c.rejected[k];
    robots[id] = {{"joint_states", run.joint_states},
                  {"tracker_readings", run.tracker_readings},
                  {"paired", c.paired},
                  {"rejected", rej},
                  {"reproduced", run.reproduced.size()},
                  {"recorded", run.recorded.size()},
                  {"compared", compared},
                  {"differ", mismatched},
                  {"recorded_not_reproduced", missing},
                  {"reproduced_not_recorded", not_recorded},
                  {"max_difference_m", worst.length_m},
                  {"max_difference_rad", worst.angle_rad},
                  {"max_difference_verification_m", worst.verification_m},
                  {"first_difference", first_mismatch},
                  {"final_version", last_rep ? last_rep->version : 0},
                  {"final_verification_mm", last_rep && std::isfinite(last_rep->verification_mean_position_m) ? nlohmann::json(last_rep->verification_mean_position_m * 1e3) : nlohmann::json()},
                  {"final_parameters", [&] {
                     nlohmann::json p = nlohmann::json::object();
                     if (!last_rep) return p;
                     for (int i = 0; i < model.numParams(); ++i) p[model.paramName(i)] = last_rep->params[i];
                     const auto names = extensionParamNames(model, exts);
                     for (size_t k = 0; k < names.size(); ++k) p[names[k]] = last_rep->extension_params[static_cast<Eigen::Index>(k)];
                     return p;
                   }()},
                  {"calibrations", series}};
  }
  if (!a.figures.empty()) {
    for (auto& [id, run] : runs) writeRecordingFigures(a.figures, id, run.robot->model, run.reproduced);
    std::printf("validate: figures in %s (<robot>_accuracy.png, <robot>_joint_drift.png)\n", a.figures.c_str());
  }
  if (unknown_keys || undecodable || state_errors)
    std::printf("validate: %llu messages of unknown robots/targets, %llu undecodable, %llu unusable CalibrationStates "
                "(first: %s)\n",
                static_cast<unsigned long long>(unknown_keys), static_cast<unsigned long long>(undecodable),
                static_cast<unsigned long long>(state_errors), first_error.c_str());
  writeJsonFile(a.json, {{"file", a.file},
                         {"cell_file", cell.source},
                         {"complete", rec.file.complete},
                         {"messages", rec.in_log_order.size()},
                         {"recording_span_s", span_s},
                         {"read_s", read_s},
                         {"engine_s", process_s},
                         {"real_time_factor", real_time_factor},
                         {"unknown_keys", unknown_keys},
                         {"undecodable", undecodable},
                         {"all_match", all_match},
                         {"robots", robots}});
  if (a.require_match && !all_match) {
    std::printf("validate: the calibrations differ from the recorded ones (--require-match)\n");
    return 3;
  }
  return 0;
}

// ------------------------------------------------------------------------------------------------------------ export

struct ExportArgs {
  ProcessOptions common;
  std::string file, out, robot_id;
};

int runExport(const ExportArgs& a) {
  const Recording rec = readRecording(a.file);
  const CellConfig cell = loadCell(a.common);
  const CellRobot* robot = a.robot_id.empty() ? &cell.robots.front() : cell.robotById(a.robot_id);
  if (!robot) throw std::runtime_error("--robot-id " + a.robot_id + ": not in " + cell.source);
  PairingBuffer pairing(robot->model, pairingOptions(*robot, cell.engine));
  std::map<std::int64_t, TrackerSample> readings;  // by stamp, for the orientation-less rows
  MeasurementFile f;
  f.source = a.file;
  std::int64_t first_stamp = 0;
  std::uint64_t rejected = 0;
  auto take = [&](const PairingOutcome& out) {
    rejected += out.rejected.size();
    for (const auto& p : out.paired) {
      const auto it = readings.find(p.tracker_stamp_ns);
      if (it == readings.end()) continue;
      if (f.rows.empty()) first_stamp = p.tracker_stamp_ns;
      MeasurementRow row;
      row.line = static_cast<int>(f.rows.size()) + 1;
      row.q_rad = p.observation.q_rad;
      row.position_m = it->second.position_m;
      if (it->second.has_orientation) {
        const auto& q = it->second.orientation_xyzw;
        row.orientation = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized();
      }
      row.stamp_s = (p.tracker_stamp_ns - first_stamp) / 1e9;
      f.rows.push_back(std::move(row));
      readings.erase(readings.begin(), std::next(it));
    }
  };
  msg::JointState js;  // reused (see runValidate)
  msg::TrackerPose tp;
  for (const auto& rm : rec.in_log_order) {
    const auto now = static_cast<std::int64_t>(rm.message->log_time_ns);
    std::string error;
    if (*rm.topic == TopicOf<msg::JointState>::name) {
      if (!decodeCdr(rm.message->data, &js, &error)) throw std::runtime_error(a.file + ": " + *rm.topic + ": " + error);
      if (js.robot_id().to_string() != robot->robot_id) continue;
      pairing.addJointState(toJointSample(js), now);
    } else if (*rm.topic == TopicOf<msg::TrackerPose>::name) {
      if (!decodeCdr(rm.message->data, &tp, &error)) throw std::runtime_error(a.file + ": " + *rm.topic + ": " + error);
      if (tp.target_id().to_string() != robot->target_id) continue;
      const TrackerSample s = toTrackerSample(tp);
      if (!pairing.addTrackerSample(s, now)) readings[s.stamp_ns] = s;
      else ++rejected;
    } else {
      continue;
    }
    take(pairing.poll(now));
  }
  take(pairing.poll(static_cast<std::int64_t>(rec.end_ns) + 1000000000LL));
  if (f.rows.empty())
    throw std::runtime_error(a.file + ": no tracker reading of " + robot->target_id + " pairs with a settled joint state of " +
                             robot->robot_id + " (" + std::to_string(rejected) + " rejected)");
  std::ofstream o(a.out);
  if (!o) throw std::runtime_error(a.out + ": cannot write");
  writeMeasurementCsv(o, f, robot->model.numJoints(),
                      "exported by `cellcal export` from " + a.file + " (robot " + robot->robot_id + ", target " +
                          robot->target_id + "): one row per tracker reading paired with a settled joint state\n"
                          "stamp_s = 0 at Unix time " + std::to_string(first_stamp) + " ns");
  std::printf("export: %zu rows (readings paired with settled joint states; %llu rejected by the pairing) -> %s\n",
              f.rows.size(), static_cast<unsigned long long>(rejected), a.out.c_str());
  return 0;
}

}  // namespace

// ------------------------------------------------------------------------------------------------------- import csv

int importCsvToRecording(const ImportCsvArgs& a) {
  const RobotModel model = loadRobotModel(a.robot_file);
  MeasurementCsvOptions mo;
  mo.skip_bad_rows = a.skip_bad_rows;
  const MeasurementFile f = readMeasurementCsv(a.csv, model, mo);
  if (f.rows.empty()) throw std::runtime_error(a.csv + ": no rows");
  if (!(a.period_s > 0)) throw std::runtime_error("--period-s must be > 0");
  const std::string robot_id = a.robot_id.empty() ? model.name : a.robot_id;
  const std::string target_id = a.target_id.empty() ? robot_id + "_target" : a.target_id;
  const bool stamped = std::all_of(f.rows.begin(), f.rows.end(), [](const auto& r) { return r.stamp_s.has_value(); });
  const std::int64_t start_ns = static_cast<std::int64_t>(std::llround(a.start_unix_s * 1e9));
  const std::int64_t bracket_ns = static_cast<std::int64_t>(std::llround(a.bracket_s * 1e9));
  RecordingWriter rec(a.out);
  std::map<std::string, std::string> md = {{"imported_from", a.csv}};
  rec.channel(TopicOf<msg::JointState>::name, md);
  rec.channel(TopicOf<msg::TrackerPose>::name, md);
  std::uint32_t joint_seq = 0, tracker_seq = 0;
  std::int64_t previous_ns = INT64_MIN;
  const double first_s = stamped ? *f.rows.front().stamp_s : 0.0;
  for (size_t k = 0; k < f.rows.size(); ++k) {
    const MeasurementRow& row = f.rows[k];
    const double rel_s = stamped ? *row.stamp_s - first_s : static_cast<double>(k) * a.period_s;
    const std::int64_t t = start_ns + static_cast<std::int64_t>(std::llround(rel_s * 1e9));
    if (previous_ns != INT64_MIN && t - previous_ns <= 2 * bracket_ns)
      throw std::runtime_error(a.csv + ":" + std::to_string(row.line) + ": the row is at " + std::to_string(rel_s) +
                               " s, not more than " + std::to_string(2 * a.bracket_s) +
                               " s after the previous row (the robot stands still around each reading)");
    previous_ns = t;
    // The robot stands still from bracket_s before the reading to bracket_s after it (two settled joint states).
    const Observation obs = toObservation(row, row.orientation ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D,
                                          a.sigma_position_mm * 1e-3, a.sigma_orientation_deg * kPi / 180);
    auto before = toJointState(robot_id, t - bracket_ns, ++joint_seq, row.q_rad, true);
    rec.write(before, static_cast<std::uint64_t>(t - bracket_ns), static_cast<std::uint64_t>(t - bracket_ns), joint_seq);
    auto reading = toTrackerPose(target_id, t, ++tracker_seq, obs);
    rec.write(reading, static_cast<std::uint64_t>(t), static_cast<std::uint64_t>(t), tracker_seq);
    auto after = toJointState(robot_id, t + bracket_ns, ++joint_seq, row.q_rad, true);
    rec.write(after, static_cast<std::uint64_t>(t + bracket_ns), static_cast<std::uint64_t>(t + bracket_ns), joint_seq);
  }
  rec.file().close();
  std::printf("import csv: %zu rows of %s (robot %s, target %s) -> %s: %u JointState + %u TrackerPose messages, "
              "%s, stamp_s 0 at Unix time %.3f s\n",
              f.rows.size(), a.csv.c_str(), robot_id.c_str(), target_id.c_str(), a.out.c_str(), joint_seq, tracker_seq,
              stamped ? "stamps from stamp_s" : ("rows " + std::to_string(a.period_s) + " s apart").c_str(), a.start_unix_s);
  if (f.skipped_rows) std::printf("import csv: %d bad rows skipped\n", f.skipped_rows);
  return 0;
}

Runner addRecordingCommands(CLI::App& app) {
  auto rec = std::make_shared<RecordArgs>();
  CLI::App* r = app.add_subcommand(
      "record",
      "Record the cell's topics to MCAP: one schema per type (encoding omgidl, the IDL text), CDR payloads as on the "
      "wire, channel metadata with the QoS; log time = receive time, publish time = DDS source timestamp, sequence = "
      "the writer's sequence number. Whole chunks reach the disk every --flush-period-s: a recorder killed with "
      "SIGKILL leaves a file readable up to its last complete chunk (replay/validate read it; --recover rewrites it "
      "whole). Stops on SIGINT/SIGTERM or after --duration-s and says how many messages it wrote.");
  r->footer(cliFooter("  cellcal record --out cell.mcap                               every topic until Ctrl-C\n  cellcal record --out in.mcap --topics inputs --duration-s 600\n  cellcal record --recover cut.mcap --out fixed.mcap           a file cut short (SIGKILL, power loss)\n",
                        "  MCAP: omgidl schemas (the IDL text), CDR payloads as on the wire (docs/recording.md)\n"));
  addCommonOptions(*r, rec->common);
  r->add_option("--out", rec->out, "MCAP file to write")->required();
  r->add_option("--topics", rec->topics, "all | inputs | comma-separated topic names")->capture_default_str();
  r->add_option("--duration-s", rec->duration_s, "stop after this many seconds (0: until SIGINT/SIGTERM)");
  r->add_option("--flush-period-s", rec->flush_period_s, "close the chunk and flush it this often")->capture_default_str();
  r->add_option("--chunk-kib", rec->chunk_kib, "close a chunk when it reaches this size")->capture_default_str();
  r->add_option("--recover", rec->recover, "instead of recording: rewrite this (cut short) recording whole to --out")
      ->check(CLI::ExistingFile);
  r->add_option("--json", rec->json, "write the counts as JSON");
  r->add_flag("-q,--quiet", rec->quiet, "no status line every 10 s");

  auto rep = std::make_shared<ReplayArgs>();
  CLI::App* p = app.add_subcommand(
      "replay",
      "Republish a recording on its topics with the recorded timing (log times) scaled by --rate, like the live cell. "
      "By default only the cell's inputs (joint_state, tracker_pose, target_pose), so a running engine and "
      "compensation publisher process them; --topics all replays everything. Source stamps are moved so the "
      "recording's first message is now (spacing kept; --keep-stamps leaves them). Prints a summary (messages, "
      "duration, drops, timing error).");
  p->footer(cliFooter("  cellcal replay cell.mcap --rate 2                             inputs at twice the recorded speed\n  cellcal replay cell.mcap --topics all\n",
                        ""));
  addCommonOptions(*p, rep->common);
  p->add_option("file", rep->file, "MCAP recording")->required()->check(CLI::ExistingFile);
  p->add_option("--rate", rep->rate, "speed factor of the recorded timing")->capture_default_str();
  p->add_flag("--as-fast-as-possible", rep->as_fast_as_possible, "no pauses between messages");
  p->add_option("--topics", rep->topics, "inputs | all | comma-separated topic names")->capture_default_str();
  p->add_flag("--loop", rep->loop, "start again at the end (stamps keep increasing) until SIGINT/--duration-s");
  p->add_option("--duration-s", rep->duration_s, "stop after this many seconds (0: at the end)");
  p->add_flag("--keep-stamps", rep->keep_stamps, "publish the recorded source stamps unchanged");
  p->add_option("--wait-for-readers", rep->wait_for_readers, "wait until every replayed topic has this many readers")
      ->capture_default_str();
  p->add_option("--wait-s", rep->wait_s, "... for at most this long")->capture_default_str();
  p->add_option("--json", rep->json, "write the summary as JSON");
  p->add_flag("--no-progress", rep->no_progress, "no progress bar");

  auto val = std::make_shared<ValidateArgs>();
  CLI::App* v = app.add_subcommand(
      "validate",
      "Run the calibration engine's logic (core CalibrationEngine, no DDS) over a recording's JointState and "
      "TrackerPose messages in log-time order, with the engine settings and robots of --config, and compare each "
      "calibration with the CalibrationState of the same robot and version in the recording (parameters, "
      "verification error). Deterministic: the same file and settings give the same output.");
  v->footer(cliFooter("  cellcal validate cell.mcap --json v.json --require-match\n  cellcal validate cell.mcap --figures figs                     accuracy and joint drift over the recording\n",
                        "", "; 3 with --require-match when a calibration differs"));
  addCommonOptions(*v, val->common);
  v->add_option("file", val->file, "MCAP recording")->required()->check(CLI::ExistingFile);
  v->add_option("--json", val->json, "write the comparison and every calibration as JSON");
  v->add_option("--tolerance-m", val->tolerance_m, "lengths (and verification errors) equal within this")->capture_default_str();
  v->add_option("--tolerance-rad", val->tolerance_rad, "angles equal within this")->capture_default_str();
  v->add_flag("--require-match", val->require_match, "exit 3 when a calibration differs from the recorded one");
  v->add_flag("--no-progress", val->no_progress, "no progress bar");
  v->add_option("--figures", val->figures,
                "write <robot>_accuracy.png (a-priori verification and residual over time) and <robot>_joint_drift.png "
                "(identified joint zero offsets over time) into this directory (gnuplot)");

  auto exp = std::make_shared<ExportArgs>();
  CLI::App* e = app.add_subcommand(
      "export", "Write a recording's measurements as CSV v1: each tracker reading paired (as the engine pairs) with "
                "the robot's settled joint state, one row per reading");
  e->footer(cliFooter("  cellcal export cell.mcap --out m.csv                          pairs readings as the engine does\n",
                        ""));
  addCommonOptions(*e, exp->common);
  e->add_option("file", exp->file, "MCAP recording")->required()->check(CLI::ExistingFile);
  e->add_option("--out", exp->out, "CSV v1 file to write")->required();
  e->add_option("--robot-id", exp->robot_id, "robot of the cell file (default: the first)");

  return [=]() -> int {
    if (*r) return runRecord(*rec);
    if (*p) return runReplay(*rep);
    if (*v) return runValidate(*val);
    if (*e) return runExport(*exp);
    return -1;
  };
}

}  // namespace cellcal::cli
