#include "cellcal/components/engine_host.hpp"

#include <algorithm>
#include <stdexcept>

#include "cellcal/core/engine/state_file.hpp"
#include "cellcal/core/engine/state_journal.hpp"
#include "cellcal/core/identification/statistics.hpp"

namespace cellcal::components {

namespace {

std::int64_t wallClockNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

void push(std::deque<std::int64_t>& d, std::int64_t v) {
  d.push_back(v);
  if (d.size() > 4096) d.pop_front();
}

}  // namespace

std::uint64_t percentileNs(const std::deque<std::int64_t>& v, double p) {
  if (v.empty()) return 0;
  const double x = percentile(std::vector<double>(v.begin(), v.end()), p);
  return static_cast<std::uint64_t>(std::max(0.0, x));
}

std::uint64_t p99(const std::deque<std::int64_t>& v) { return percentileNs(v, 0.99); }

EngineHost::EngineHost(const CellConfig& cell, Options options, OnUpdate on_update)
    : options_(std::move(options)), on_update_(std::move(on_update)) {
  if (!options_.clock) options_.clock = wallClockNs;
  for (const auto& r : cell.robots) {
    Robot& slot = robots_[r.robot_id];
    slot.robot = &r;
    slot.engine = std::make_unique<CalibrationEngine>(r, cell.engine, cell.time_compression);
    if (options_.persist) {
      slot.state_file = stateFilePath(cell.engine.state_dir, r.robot_id);
      slot.store = std::make_unique<DurableState>(slot.state_file, DurableState::Options{cell.engine.durability});
      if (const auto state = slot.store->load()) {
        try {
          slot.engine->importState(*state);
        } catch (const std::runtime_error& e) {
          throw std::runtime_error(unusableStateMessage(slot.state_file, e.what()));
        }
        slot.restored = true;
        slot.saved_revision = slot.engine->stateRevision();
      }
    }
    by_target_[r.target_id] = &slot;
  }
}

bool EngineHost::onJointState(const std::string& robot_id, const JointSample& s, std::int64_t receive_ns) {
  auto it = robots_.find(robot_id);
  if (it == robots_.end()) {
    ++unknown_keys_;
    return false;
  }
  it->second.engine->onJointState(s, receive_ns);
  step(it->second, receive_ns, Cause::kJointState);
  return true;
}

bool EngineHost::onTrackerSample(const std::string& target_id, const TrackerSample& s, std::int64_t receive_ns) {
  auto it = by_target_.find(target_id);
  if (it == by_target_.end()) {
    ++unknown_keys_;
    return false;
  }
  push(it->second->reading_received_ns, receive_ns - s.stamp_ns);
  it->second->engine->onTrackerSample(s, receive_ns);
  step(*it->second, receive_ns, Cause::kReading);
  return true;
}

void EngineHost::tick(std::int64_t now_ns) {
  for (auto& [id, r] : robots_) step(r, now_ns, Cause::kTick);
}

void EngineHost::tickIfDue(std::int64_t now_ns) {
  if (now_ns < next_tick_ns_) return;
  next_tick_ns_ = now_ns + std::chrono::nanoseconds(kTickPeriod).count();
  tick(now_ns);
}

// Pairs and updates; the state file holds every change before a new version is handed on (the latency path).
void EngineHost::step(Robot& r, std::int64_t now_ns, Cause cause) {
  const std::uint64_t before = r.engine->counters().paired;
  const std::int64_t t0 = options_.clock();
  const bool changed = r.engine->process(now_ns);
  const std::int64_t t1 = options_.clock();
  const bool paired = r.engine->counters().paired != before;
  if (paired) {
    push(r.pairing_ns, t1 - r.engine->snapshot().last_measurement_stamp_ns);
    push(r.update_ns, r.engine->lastUpdateDurationNs());
    (cause == Cause::kReading ? r.paired_on_reading : cause == Cause::kJointState ? r.paired_on_joint_state : r.paired_on_tick) +=
        r.engine->counters().paired - before;
  }
  if (r.store && r.engine->stateRevision() != r.saved_revision) persist(r);
  const std::int64_t t2 = options_.clock();
  if (changed) {
    ++updates_;
    if (on_update_) on_update_(r);
    if (paired && cause != Cause::kTick) {
      const std::int64_t t3 = options_.clock();
      push(r.decided_ns, t3 - now_ns);
      push(r.queued_ns, t0 - now_ns);
      push(r.process_ns, t1 - t0);
      push(r.persist_ns, t2 - t1);
      push(r.publish_ns, t3 - t2);
    }
  }
  // After publishing: the snapshot rewritten once the journal has grown (off the latency path of this version).
  if (r.store && r.store->compactionDue()) {
    try {
      r.store->compact(r.engine->exportState());
    } catch (const std::exception& e) {
      ++r.persist_failures;
      r.persist_error = std::string("state snapshot not rewritten (the journal keeps every change): ") + e.what();
    }
  }
}

// A failed write (disk full, read-only, permissions) leaves what was saved before readable: the update stays in
// memory, the error is reported, and the next change saves the whole state again.
void EngineHost::persist(Robot& r) {
  r.saved_revision = r.engine->stateRevision();
  try {
    r.store->save(r.engine->exportState());
    r.persist_error.clear();
    r.unsynced = true;
  } catch (const std::exception& e) {
    ++r.persist_failures;
    r.persist_error =
        std::string("state not saved (what was saved before is intact; retried with the next update): ") + e.what();
  }
}

std::vector<std::string> EngineHost::takeUnsynced() {
  std::vector<std::string> out;
  for (auto& [id, r] : robots_)
    if (r.unsynced) {
      r.unsynced = false;
      out.push_back(r.store->savedPath());
    }
  return out;
}

void EngineHost::syncAll() {
  for (const auto& f : takeUnsynced()) syncStateFile(f);
}

void EngineHost::close() {
  for (auto& [id, r] : robots_) {
    if (!r.store) continue;
    try {
      if (r.engine->stateRevision() != r.saved_revision) persist(r);
      r.store->close(r.engine->exportState());
    } catch (const std::exception& e) {
      ++r.persist_failures;
      r.persist_error = std::string("state snapshot not rewritten at stop (the journal keeps every change): ") + e.what();
    }
    r.store.reset();
  }
}

EngineHost::~EngineHost() { close(); }

}  // namespace cellcal::components
