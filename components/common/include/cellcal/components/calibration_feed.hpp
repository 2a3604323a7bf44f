// The calibrations of one robot for a compensator inside a controller's loop (core/servo/realtime_compensator.hpp):
// what a bridge that owns the controller's socket (KUKA RSI, ur_rtde, a ros2_control hardware interface) creates
// beside its RealtimeCompensator. It reads cellcal/calibration_state, keeps the compensation publisher's rules, and
// prepares each version on its own thread before handing it over; the controller's thread never waits for it.
//
//   RealtimeCompensator rt(cell.robots[0].model, settings);
//   CalibrationFeed feed(cell, "tx60", rt);     // its own participant, its own worker thread
//   ... rt.correct(...) every cycle; feed.status() / describe(feed.status()) for a log, any thread
//
// Rules (as the compensation publisher applies a calibration): only a version whose health is ok is handed over; one
// that is not (degraded, hold_last_good, uncalibrated) leaves the last ok version answering, and the status says the
// feed is holding it; a version older than the one applied (an engine restarted from an older state) is refused; a
// sample of another robot is not this feed's; a sample that does not fit the robot's model, or a model the
// real-time compensator does not answer (extensions, a residual map), is refused with the reason. The same version
// republished is nothing new.
//
// Lifetime: the compensator must outlive the feed. The destructor deletes the reader first (no sample arrives after),
// then lets the worker finish what was queued.
#pragma once

#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/work_queue.hpp"
#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/servo/realtime_compensator.hpp"
#include "cellcal_msgs.h"

namespace cellcal::components {

// What the feed did with the calibrations it received (a snapshot).
struct FeedStatus {
  std::string robot_id;
  std::uint64_t applied_version = 0;   // the last version handed to the compensator (0: none yet)
  std::uint64_t received_version = 0;  // the last version received for this robot
  msg::CalibrationHealth received_health = msg::HEALTH_UNCALIBRATED;
  // The last received version is not ok: the compensator goes on with applied_version.
  bool holding = false;
  // Counts: samples of this robot received, versions handed over, versions not ok, older than the one applied,
  // unusable (not the robot's model, or not answerable in the controller's loop), samples of other robots.
  std::uint64_t received = 0, applied = 0, not_ok = 0, older = 0, unusable = 0, other_robots = 0;
  std::string last_refusal;  // why the last older or unusable version was refused
  // Steady-clock time of the last sample of this robot (0: none yet): a feed that went silent says so by its age.
  std::chrono::steady_clock::time_point last_received{};
};
// "tx60: applying v12; holding it: v13 is degraded" / "tx60: no ok calibration yet (v3 uncalibrated)" / "... last
// sample 42.0 s ago".
std::string describe(const FeedStatus& status, std::chrono::steady_clock::time_point now = std::chrono::steady_clock::now());

// The compensator's settings a cell file gives (its compensation section, blend_s included): what every bridge built
// on the feed uses, so that a check replaying a stream in memory answers as the bridge did.
RealtimeSettings realtimeSettings(const CellConfig& cell);

class CalibrationFeed {
 public:
  // `robot_id` must be one of the cell file's robots (std::invalid_argument names them); the participant follows the
  // cell file's dds settings (std::runtime_error from DdsNode names what failed).
  CalibrationFeed(const CellConfig& cell, const std::string& robot_id, RealtimeCompensator& compensator,
                  const std::string& node_name = "cellcal_calibration_feed");
  ~CalibrationFeed();
  CalibrationFeed(const CalibrationFeed&) = delete;
  CalibrationFeed& operator=(const CalibrationFeed&) = delete;

  FeedStatus status() const;
  // The robot's nominal model in this cell (what the controller believes; the compensator's).
  const RobotModel& nominal() const { return robot_->model; }

 private:
  void handle(std::vector<msg::CalibrationState>& batch);
  void take(const msg::CalibrationState& m);

  const CellRobot* robot_;
  RealtimeCompensator& compensator_;
  mutable std::mutex mutex_;
  FeedStatus status_;
  WorkQueue<msg::CalibrationState> queue_;  // before node_: the node's reader pushes into it, and goes first
  DdsNode node_;
};

}  // namespace cellcal::components
