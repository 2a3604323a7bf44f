// The calibration engines of a cell and what runs them, without DDS and without threads: one CalibrationEngine per
// robot of the cell file, joint states dispatched by robot_id and tracker readings by target_id, every robot polled
// at least every kTickPeriod (a reading whose joint state never comes times out), each robot's state saved after every
// change before the new version is handed on (EngineHost::OnUpdate: publish it; a journal record by default,
// core/engine/state_journal.hpp), fsyncs left to the caller's own thread, and the latencies of pairing, update and
// the engine's own share of the path.
//
// The engine process drives it from its worker thread (components/calibration_engine); `cellcal validate` drives it
// over a recording in log order: one piece of code decides what both publish.
//
//   EngineHost host(cell, {}, [&](EngineHost::Robot& r) { publish(r.engine->snapshot()); });
//   host.onJointState(robot_id, sample, now_ns);       // pairs, updates, persists, calls OnUpdate on a new version
//   host.tick(now_ns);                                  // with nothing arriving for kTickPeriod
//   for (const auto& f : host.takeUnsynced()) syncStateFile(f);   // off the latency path
//   host.close();                                       // a clean stop: each snapshot current, journals emptied
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "cellcal/core/engine/calibration_engine.hpp"
#include "cellcal/core/engine/state_journal.hpp"
#include "cellcal/core/files/cell_config.hpp"

namespace cellcal::components {

class EngineHost {
 public:
  static constexpr std::chrono::milliseconds kTickPeriod{5};

  struct Robot {
    const CellRobot* robot = nullptr;
    std::unique_ptr<CalibrationEngine> engine;
    std::string state_file;            // the snapshot, <robot_id>.state.json; empty without persistence
    std::unique_ptr<DurableState> store;  // null without persistence
    bool restored = false;             // resumed from its state file
    std::string persist_error;         // the last failed write of the state file; empty once one succeeds again
    std::uint64_t persist_failures = 0;
    // Recent latencies: reading stamp -> paired (the wait for the joint state after it included); the update alone;
    // and the engine's own share, from receiving the sample that made a reading pairable (the joint state after it,
    // or the reading itself) to the new version handed to OnUpdate (published) with its state saved.
    std::deque<std::int64_t> pairing_ns, update_ns, decided_ns;
    // decided_ns in its parts: waiting for the caller's thread (sample received -> step), pairing and updating
    // (CalibrationEngine::process), saving the state, handing the version on (OnUpdate: converting and publishing).
    std::deque<std::int64_t> queued_ns, process_ns, persist_ns, publish_ns;
    // Reading stamp -> received by this host: the tracker's own path (its host, its adapter, the network).
    std::deque<std::int64_t> reading_received_ns;
    // What made each paired reading pairable: its own arrival (the joint state at or after its stamp was there
    // already), a joint state arriving after it, or a tick (a reading decided by timeout).
    std::uint64_t paired_on_reading = 0, paired_on_joint_state = 0, paired_on_tick = 0;
    std::uint64_t saved_revision = 0;  // the engine's state revision last written (or tried: retried on the next change)
    bool unsynced = false;             // saved since the last takeUnsynced()
  };
  struct Options {
    bool persist = true;                   // state in the cell file's engine.state_dir, kept as engine.durability says
    std::function<std::int64_t()> clock;   // for the pairing latency; empty: the wall clock
  };
  using OnUpdate = std::function<void(Robot&)>;

  // Resumes each robot from its state file when persisting. Throws std::runtime_error naming the file when one
  // exists but cannot be used. `cell` must outlive the host (the engines refer to its robots and settings).
  EngineHost(const CellConfig& cell, Options options, OnUpdate on_update);

  // A sample as received. False for a robot_id / target_id the cell file does not have (counted).
  bool onJointState(const std::string& robot_id, const JointSample& s, std::int64_t receive_ns);
  bool onTrackerSample(const std::string& target_id, const TrackerSample& s, std::int64_t receive_ns);
  // Every robot polled (timeouts of readings whose joint state never came).
  void tick(std::int64_t now_ns);
  // tick() when kTickPeriod has passed since the last one, by the clock of `now_ns` (a recording's log time).
  void tickIfDue(std::int64_t now_ns);

  // The state files written since the last call, for syncStateFile() on any thread.
  std::vector<std::string> takeUnsynced();
  // fsync of every state file written and not synced yet.
  void syncAll();
  // A clean stop: each robot's snapshot made current and its journal emptied (errors reported, not thrown). The
  // destructor calls it; after it, no input may come.
  void close();
  ~EngineHost();

  std::map<std::string, Robot>& robots() { return robots_; }
  const std::map<std::string, Robot>& robots() const { return robots_; }
  std::uint64_t unknownKeys() const { return unknown_keys_; }
  std::uint64_t updates() const { return updates_; }

 private:
  // What caused a step: a sample received at now_ns, or a tick.
  enum class Cause { kJointState, kReading, kTick };
  void step(Robot& r, std::int64_t now_ns, Cause cause);
  void persist(Robot& r);

  Options options_;
  OnUpdate on_update_;
  std::map<std::string, Robot> robots_;
  std::map<std::string, Robot*> by_target_;
  std::uint64_t unknown_keys_ = 0, updates_ = 0;
  std::int64_t next_tick_ns_ = 0;
};

// The percentile p (0.5: the median) of recent latencies (0 when none), ns; p99 the 99th.
std::uint64_t percentileNs(const std::deque<std::int64_t>& v, double p);
std::uint64_t p99(const std::deque<std::int64_t>& v);

}  // namespace cellcal::components
