// cellcal_calibration_engine: pairs tracker readings with joint states, updates each robot's calibration with RLS
// (per pose, or per batch in periodic mode), persists it atomically, publishes cellcal/calibration_state (RELIABLE,
// TRANSIENT_LOCAL, KEEP_LAST 1 per robot: late joiners get the latest at once; republished every
// engine.republish_period_s) and cellcal/calibration_diagnostics. The logic is core's CalibrationEngine.
// Threads: the DDS listeners only convert and queue each sample (WorkQueue); one worker pairs, updates, writes the
// state file and publishes, so a slow disk delays updates instead of making the kernel drop readings; the main loop
// fsyncs the state files and republishes.
#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <deque>
#include <iostream>
#include <map>
#include <mutex>
#include <variant>

#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/components/work_queue.hpp"

using namespace cellcal;
using namespace cellcal::components;

namespace {

struct Slot {
  const CellRobot* robot = nullptr;
  std::unique_ptr<CalibrationEngine> engine;
  std::uint64_t state_seq = 0, diag_seq = 0;
  std::deque<std::int64_t> pairing_ns, update_ns;  // recent latencies
};

std::uint64_t p99(const std::deque<std::int64_t>& v) {
  if (v.empty()) return 0;
  std::vector<std::int64_t> s(v.begin(), v.end());
  const size_t k = std::min(s.size() - 1, static_cast<size_t>(0.99 * static_cast<double>(s.size())));
  std::nth_element(s.begin(), s.begin() + static_cast<std::ptrdiff_t>(k), s.end());
  return static_cast<std::uint64_t>(std::max<std::int64_t>(0, s[k]));
}

// A sample as received, waiting for the worker: the robot (joint state) or target (tracker reading) it names, and
// when it arrived (the engine judges staleness and pairing timeouts by arrival, not by when the worker got to it).
struct Input {
  std::string key;
  std::variant<JointSample, TrackerSample> sample;
  std::int64_t received_ns = 0;
};
// ~6 s of 8 robots with two 1 kHz streams, ~45 MB (~430 B a sample): what a stalled worker may fill before samples
// are refused.
constexpr size_t kMaxQueuedInputs = 100000;

void push(std::deque<std::int64_t>& d, std::int64_t v) {
  d.push_back(v);
  if (d.size() > 4096) d.pop_front();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"cellcal calibration engine: continuous kinematic calibration from tracker poses and joint states"};
  app.footer(manFooter(
      "cellcal/joint_state, cellcal/tracker_pose",
      "cellcal/calibration_state, cellcal/calibration_diagnostics (reliable, transient local: a late joiner gets the latest)",
      "  cellcal_calibration_engine --state-dir /var/lib/cellcal          run for good; state survives restarts\n"
      "  cellcal_calibration_engine --config cell.yaml --duration-s 60    a one-minute run\n",
      "  <state-dir>/<robot_id>.state.json: the estimate, replaced atomically after every pose; the engine resumes\n"
      "    from it after a restart (no accepted update lost or applied twice)\n"));
  ProcessOptions o;
  double duration_s = 0;
  bool quiet = false;
  addCommonOptions(app, o);
  app.add_option("--state-dir", o.state_dir, "where each robot's state is persisted (overrides engine.state_dir)");
  app.add_option("--duration-s", duration_s, "stop after this many seconds (0: run until SIGINT/SIGTERM)");
  app.add_flag("-q,--quiet", quiet, "no line per update on stderr");
  return runMain("cellcal_calibration_engine", argc, argv, app, [&] {
    // glibc raises its mmap threshold to the size of any large block freed, so the input queue's backlog after a
    // stall (MBs) would stay in the heap for good. A fixed threshold returns such blocks to the system when freed.
    mallopt(M_MMAP_THRESHOLD, 128 * 1024);
    const CellConfig cell = loadCell(o);
    std::map<std::string, Slot> by_robot;
    std::map<std::string, Slot*> by_target;
    for (const auto& r : cell.robots) {
      Slot& s = by_robot[r.robot_id];
      s.robot = &r;
      s.engine = std::make_unique<CalibrationEngine>(r, cell.engine, cell.time_compression);
      by_target[r.target_id] = &s;
      const auto& snap = s.engine->snapshot();
      std::cerr << "calibration_engine: " << r.robot_id << " (" << r.model.name << ") "
                << (s.engine->restored() ? "resumed version " + std::to_string(snap.version) + " (" +
                                               std::to_string(snap.poses_used) + " poses) from "
                                         : "starts uncalibrated; state in ")
                << s.engine->stateFile() << "\n";
      if (!r.extensions.empty()) {
        std::cerr << "calibration_engine: " << r.robot_id << " model extensions:";
        for (const auto& e : r.extensions) std::cerr << " " << extensionSpec(e);
        std::cerr << " (" << snap.extension_params.size() << " extra parameters in the RLS state)\n";
      }
      if (!s.engine->restoreNote().empty())
        std::cerr << "calibration_engine: " << r.robot_id << ": " << s.engine->restoreNote() << "\n";
    }
    DdsNode node(cell, "cellcal_calibration_engine", identity::kCalibrationEngine);
    auto state_writer = node.writer<msg::CalibrationState>();
    auto diag_writer = node.writer<msg::CalibrationDiagnostics>();
    std::mutex mutex;
    std::uint64_t unknown_keys = 0, updates = 0;
    std::uint64_t inputs_refused = 0;  // samples the full input queue refused (WorkQueue), as of the last main-loop round

    auto publishState = [&](Slot& s) {
      auto m = toCalibrationState(*s.robot, s.engine->snapshot(), wallNs(), ++s.state_seq);
      state_writer.write(m);
    };
    // Per stream: nothing received for engine.stale_input_s, or no writer left (a killed adapter is unmatched when its
    // participant lease expires).
    auto staleInputs = [&](Slot& s, std::int64_t now) {
      std::string out = s.engine->staleInputs(now);
      auto noWriter = [&](const char* topic, int writers) {
        if (writers == 0) out += std::string(out.empty() ? "" : "; ") + topic + ": no writer";
      };
      noWriter("joint_state", node.matchedWriters<msg::JointState>());
      noWriter("tracker_pose", node.matchedWriters<msg::TrackerPose>());
      return out;
    };
    std::map<std::string, std::string> reported;  // last stale / persist message printed per robot
    auto publishDiagnostics = [&](Slot& s, std::int64_t now) {
      const auto& c = s.engine->counters();
      msg::CalibrationDiagnostics d;
      d.robot_id(s.robot->robot_id);
      d.source_stamp_ns(static_cast<std::uint64_t>(now));
      d.sequence_number(++s.diag_seq);
      for (size_t k = 0; k < c.rejected.size(); ++k) {
        if (!c.rejected[k]) continue;
        d.rejection_reasons().push_back(rejectionName(static_cast<Rejection>(k)));
        d.rejection_counts().push_back(c.rejected[k]);
      }
      if (inputs_refused) {  // before any robot could be told: counted for every robot
        d.rejection_reasons().push_back("engine_input_queue_full");
        d.rejection_counts().push_back(inputs_refused);
      }
      const auto& snap = s.engine->snapshot();
      d.drift_alarm(snap.drift_alarm);
      const std::string stale = staleInputs(s, now);
      d.stale_input(!stale.empty());
      d.stale_inputs(stale.substr(0, 255));
      d.health(static_cast<msg::CalibrationHealth>(static_cast<int>(snap.health)));
      d.health_reason(snap.health_reason.substr(0, 255));
      d.prediction_sigma_position_m(snap.prediction_sigma_position_m);
      d.persist_failures(s.engine->persistFailures());
      d.persist_error(s.engine->persistError().substr(0, 255));
      d.identifiable_parameters(static_cast<std::uint32_t>(s.engine->snapshot().estimated.size()));
      d.condition_number(s.engine->snapshot().condition_number);
      d.pairing_latency_p99_ns(p99(s.pairing_ns));
      d.update_latency_p99_ns(p99(s.update_ns));
      d.joint_states_received(c.joint_states);
      d.tracker_readings_received(c.tracker_readings);
      d.poses_paired(c.paired);
      d.last_rejection(c.last_rejection.substr(0, 255));
      diag_writer.write(d);
      // Say it once on stderr when it changes (the diagnostics topic carries it every republish period).
      const std::string line = stale + "|" + s.engine->persistError() + "|" + snap.health_reason;
      if (reported[s.robot->robot_id] != line) {
        reported[s.robot->robot_id] = line;
        if (!stale.empty()) std::cerr << "calibration_engine: " << s.robot->robot_id << ": stale input: " << stale << "\n";
        if (!s.engine->persistError().empty())
          std::cerr << "calibration_engine: " << s.robot->robot_id << ": " << s.engine->persistError() << "\n";
        if (snap.health != Health::kOk && snap.health != Health::kUncalibrated)
          std::cerr << "calibration_engine: " << s.robot->robot_id << ": health " << healthName(snap.health) << ": " << snap.health_reason << "\n";
      }
    };
    // Pairs and updates; publishes a new version at once (the latency path).
    auto step = [&](Slot& s, std::int64_t now) {
      const std::uint64_t before = s.engine->counters().paired;
      const bool changed = s.engine->process(now);
      if (s.engine->counters().paired != before) {
        push(s.pairing_ns, wallNs() - s.engine->snapshot().last_measurement_stamp_ns);
        push(s.update_ns, s.engine->lastUpdateDurationNs());
      }
      if (!changed) return;
      publishState(s);  // the state file was replaced (atomically) before; the main loop fsyncs it
      ++updates;
      const auto& snap = s.engine->snapshot();
      if (!quiet)
        std::cerr << "calibration_engine: " << s.robot->robot_id << " v" << snap.version << " poses " << snap.poses_used
                  << " health " << healthName(snap.health) << " predicted-pose error (mean of recent) "
                  << snap.verification_mean_position_m * 1e3 << " mm\n";
    };

    // The worker: every sample in arrival order, then (with nothing queued for 5 ms) the timeouts of readings whose
    // joint state never came.
    auto handleInputs = [&](std::vector<Input>& batch) {
      std::lock_guard<std::mutex> lock(mutex);
      for (auto& in : batch) {
        if (auto* j = std::get_if<JointSample>(&in.sample)) {
          auto it = by_robot.find(in.key);
          if (it == by_robot.end()) {
            ++unknown_keys;
            continue;
          }
          it->second.engine->onJointState(std::move(*j), in.received_ns);
          step(it->second, in.received_ns);
        } else {
          auto it = by_target.find(in.key);
          if (it == by_target.end()) {
            ++unknown_keys;
            continue;
          }
          it->second->engine->onTrackerSample(std::get<TrackerSample>(in.sample), in.received_ns);
          step(*it->second, in.received_ns);
        }
      }
    };
    auto idle = [&] {
      std::lock_guard<std::mutex> lock(mutex);
      const std::int64_t now = wallNs();
      for (auto& [id, s] : by_robot) step(s, now);
    };
    WorkQueue<Input> inputs(kMaxQueuedInputs, handleInputs, std::chrono::milliseconds(5), idle);
    std::uint64_t refused_reported = 0;
    node.reader<msg::JointState>([&](const msg::JointState& m, const fdds::SampleInfo&) {
      inputs.push({m.robot_id().to_string(), toJointSample(m), wallNs()});
    });
    node.reader<msg::TrackerPose>([&](const msg::TrackerPose& m, const fdds::SampleInfo&) {
      inputs.push({m.target_id().to_string(), toTrackerSample(m), wallNs()});
    });
    {
      std::lock_guard<std::mutex> lock(mutex);
      for (auto& [id, s] : by_robot) {
        publishState(s);  // restored or uncalibrated: late joiners learn where the engine stands
        publishDiagnostics(s, wallNs());
      }
    }
    std::cerr << "calibration_engine: " << cell.robots.size() << " robot(s), mode "
              << (cell.engine.mode == EngineMode::kContinuous ? "continuous" : "periodic") << ", domain "
              << node.domainId() << "\n";
    const auto start = std::chrono::steady_clock::now();
    auto next_republish = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                      std::chrono::duration<double>(cell.engine.republish_period_s));
    std::vector<std::string> to_sync;
    while (sleepUntil(std::chrono::steady_clock::now() + std::chrono::milliseconds(5))) {
      if (duration_s > 0 && std::chrono::steady_clock::now() - start >= std::chrono::duration<double>(duration_s)) break;
      // Durability off the latency path: fsync the state files replaced since the last round, without the lock.
      for (const auto& f : to_sync) syncStateFile(f);
      to_sync.clear();
      const std::uint64_t refused = inputs.refused();
      if (refused > refused_reported) {
        std::cerr << "calibration_engine: warning: " << refused - refused_reported << " samples refused: "
                  << kMaxQueuedInputs << " were waiting for the worker (stalled on the disk?)\n";
        refused_reported = refused;
      }
      std::lock_guard<std::mutex> lock(mutex);
      inputs_refused = refused;
      const std::int64_t now = wallNs();
      for (auto& [id, s] : by_robot)
        if (s.engine->takeUnsynced()) to_sync.push_back(s.engine->stateFile());
      if (std::chrono::steady_clock::now() >= next_republish) {
        next_republish += std::chrono::duration_cast<std::chrono::steady_clock::duration>(
            std::chrono::duration<double>(cell.engine.republish_period_s));
        for (auto& [id, s] : by_robot) {
          publishState(s);
          publishDiagnostics(s, now);
        }
      }
    }
    inputs.stop();  // the worker handles what is queued (and may still publish), then stops
    node.shutdown();
    for (auto& [id, s] : by_robot) s.engine->syncToDisk();
    nlohmann::json robots = nlohmann::json::object();
    for (auto& [id, s] : by_robot) {
      const auto& snap = s.engine->snapshot();
      nlohmann::json rej = nlohmann::json::object();
      for (size_t k = 0; k < s.engine->counters().rejected.size(); ++k)
        if (s.engine->counters().rejected[k]) rej[rejectionName(static_cast<Rejection>(k))] = s.engine->counters().rejected[k];
      robots[id] = {{"version", snap.version},
                    {"poses_used", snap.poses_used},
                    {"health", healthName(snap.health)},
                    {"recent_nis_per_row", snap.recent_nis_per_row},
                    {"drift_alarm", snap.drift_alarm},
                    {"condition_number", snap.condition_number},
                    {"health_reason", snap.health_reason},
                    {"prediction_sigma_position_m", snap.prediction_sigma_position_m},
                    {"persist_failures", s.engine->persistFailures()},
                    {"rejected", rej},
                    {"pairing_latency_p99_ns", p99(s.pairing_ns)},
                    {"update_latency_p99_ns", p99(s.update_ns)}};
    }
    writeJsonFile(o.stats_json, {{"name", "calibration_engine"},
                                 {"pid", ::getpid()},
                                 {"topics", node.stats()},
                                 {"extra", {{"updates", updates}, {"unknown_keys", unknown_keys}, {"robots", robots},
                                            {"input_queue", {{"peak", inputs.peak()}, {"refused", inputs.refused()},
                                                             {"max", kMaxQueuedInputs}}}}}});
    return 0;
  });
}
