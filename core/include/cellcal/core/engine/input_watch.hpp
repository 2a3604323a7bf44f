// What the engine's two inputs say besides their values: when the robot moved and stood still (a pose is one
// stand-still), and which stream went quiet. Fed by CalibrationEngine with every joint state and tracker reading it
// receives; no clock of its own (times are the samples' stamps and the host's receive times).
//
// Stand-stills: a joint state that is settled and within settle_tolerance_rad of the previous admitted one continues
// (or begins) a stand-still; any other ends it. A stand-still that ended without a tracker reading counts towards the
// tracker's staleness; a reading resets the count.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <string>

#include "cellcal/core/engine/pairing.hpp"
#include "cellcal/core/files/cell_config.hpp"

namespace cellcal {

class InputWatch {
 public:
  // `settings` must outlive the watch (settle_tolerance_rad, stale_input_s, stale_stand_stills, tracker_silence_s).
  explicit InputWatch(const EngineSettings& settings) : settings_(&settings) {}

  // Every joint state received (admitted or not), then those admitted (they move the stand-stills).
  void jointReceived(std::int64_t receive_ns) { last_joint_ns_ = receive_ns; }
  void jointAdmitted(const JointSample& s);
  // Every tracker reading received: the target was read in this stand-still.
  void trackerReceived(std::int64_t receive_ns);

  // Whether an admitted joint state stamped in (after_ns, until_ns] showed the robot moving (of the last kMotionKept).
  bool movedBetween(std::int64_t after_ns, std::int64_t until_ns) const;
  static constexpr size_t kMotionKept = 256;

  // "joint_state: nothing for 4.1 s; tracker_pose: ..." (empty when both streams are fresh). Joint states: stale after
  // stale_input_s without a sample (or before the first). Tracker readings: after stale_stand_stills stand-stills in a
  // row without one, or after tracker_silence_s without one when that is set.
  std::string staleInputs(std::int64_t now_ns) const;

 private:
  const EngineSettings* settings_;
  std::int64_t last_joint_ns_ = 0, last_tracker_ns_ = 0;  // receive time of the last sample per stream
  bool in_stand_still_ = false, read_in_stand_still_ = false;
  int stand_stills_without_reading_ = 0;
  Eigen::VectorXd last_joint_q_;
  std::deque<std::int64_t> motion_stamps_ns_;  // admitted joint states that show the robot moving
};

}  // namespace cellcal
