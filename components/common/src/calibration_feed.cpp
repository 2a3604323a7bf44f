#include "cellcal/components/calibration_feed.hpp"

#include <cstdio>
#include <stdexcept>

#include "cellcal/components/convert.hpp"

namespace cellcal::components {

namespace {
const CellRobot& robotOf(const CellConfig& cell, const std::string& id) {
  std::string ids;
  for (const CellRobot& r : cell.robots) {
    if (r.robot_id == id) return r;
    ids += (ids.empty() ? "" : ", ") + r.robot_id;
  }
  throw std::invalid_argument("calibration feed: robot '" + id + "' is not in the cell file (its robots: " + ids + ")");
}
}  // namespace

CalibrationFeed::CalibrationFeed(const CellConfig& cell, const std::string& robot_id, RealtimeCompensator& compensator,
                                 const std::string& node_name)
    : robot_(&robotOf(cell, robot_id)),
      compensator_(compensator),
      queue_(
          64, [this](std::vector<msg::CalibrationState>& batch) { handle(batch); }, std::chrono::milliseconds(100),
          [this] { compensator_.collectRetired(); }),
      node_(cell, node_name, identity::kObserver) {
  status_.robot_id = robot_id;
  node_.reader<msg::CalibrationState>([this](const msg::CalibrationState& m, const fdds::SampleInfo&) {
    if (m.robot_id() == robot_->robot_id) {
      queue_.push(m);
    } else {
      std::lock_guard<std::mutex> l(mutex_);
      ++status_.other_robots;
    }
  });
}

CalibrationFeed::~CalibrationFeed() {
  node_.shutdown();  // no sample after this; the queue's destructor then handles what is queued
}

FeedStatus CalibrationFeed::status() const {
  std::lock_guard<std::mutex> l(mutex_);
  return status_;
}

void CalibrationFeed::handle(std::vector<msg::CalibrationState>& batch) {
  for (const msg::CalibrationState& m : batch) take(m);
  compensator_.collectRetired();
}

// One sample of this robot, on the worker: the rules of the header, then the version prepared and handed over.
void CalibrationFeed::take(const msg::CalibrationState& m) {
  std::string error;
  const auto c = fromCalibrationState(robot_->model, m, &error);
  std::unique_lock<std::mutex> l(mutex_);
  FeedStatus& s = status_;
  ++s.received;
  s.last_received = std::chrono::steady_clock::now();
  if (!c) {
    ++s.unusable;
    s.last_refusal = "v" + std::to_string(m.version()) + ": " + error;
    return;
  }
  s.received_version = c->version;
  s.received_health = c->health;
  if (c->health != msg::HEALTH_OK) {
    ++s.not_ok;
    s.holding = s.applied_version > 0;
    return;
  }
  if (c->version <= s.applied_version) {
    if (c->version < s.applied_version) {
      ++s.older;
      s.last_refusal = "v" + std::to_string(c->version) + " is older than v" + std::to_string(s.applied_version) +
                       ", applied (an engine restarted from an older state?): refused";
    }
    s.holding = false;
    return;
  }
  l.unlock();  // prepared without the lock: status() stays answerable
  std::string why;
  std::unique_ptr<const ServoVersion> v = ServoVersion::prepare(robot_->model, c->version, IdentifiedModel(*c), &why);
  l.lock();
  if (!v) {
    ++s.unusable;
    s.last_refusal = why;
    return;
  }
  compensator_.publish(std::move(v));
  s.applied_version = c->version;
  ++s.applied;
  s.holding = false;
}

RealtimeSettings realtimeSettings(const CellConfig& cell) {
  RealtimeSettings s;
  s.compensation = cell.compensation;
  s.blend_s = cell.compensation.blend_s;
  return s;
}

std::string describe(const FeedStatus& s, std::chrono::steady_clock::time_point now) {
  std::string out = s.robot_id + ": ";
  auto version = [](std::uint64_t v, msg::CalibrationHealth h) {
    return "v" + std::to_string(v) + " " + healthText(h);
  };
  if (s.received == 0) {
    out += "no calibration received yet";
  } else if (s.applied_version == 0) {
    out += "no ok calibration yet (last received: " + version(s.received_version, s.received_health) + ")";
  } else {
    out += "applying v" + std::to_string(s.applied_version);
    if (s.holding) out += "; holding it: " + version(s.received_version, s.received_health);
    char age[64];
    std::snprintf(age, sizeof age, "; last sample %.1f s ago",
                  std::chrono::duration<double>(now - s.last_received).count());
    out += age;
  }
  if (!s.last_refusal.empty()) out += "; last refused: " + s.last_refusal;
  return out;
}

}  // namespace cellcal::components
