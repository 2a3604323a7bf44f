#include "cellcal/core/engine/input_watch.hpp"

#include <iomanip>
#include <sstream>

namespace cellcal {

void InputWatch::jointAdmitted(const JointSample& s) {
  const bool moved = !s.settled || (last_joint_q_.size() == s.q_rad.size() &&
                                    (s.q_rad - last_joint_q_).cwiseAbs().maxCoeff() > settings_->settle_tolerance_rad);
  if (moved) {
    motion_stamps_ns_.push_back(s.stamp_ns);
    while (motion_stamps_ns_.size() > kMotionKept) motion_stamps_ns_.pop_front();
  }
  if (!moved && !in_stand_still_) {  // a stand-still begins
    in_stand_still_ = true;
    read_in_stand_still_ = false;
  } else if (moved && in_stand_still_) {  // it ends: was the target read during it?
    in_stand_still_ = false;
    stand_stills_without_reading_ = read_in_stand_still_ ? 0 : stand_stills_without_reading_ + 1;
  }
  last_joint_q_ = s.q_rad;
}

void InputWatch::trackerReceived(std::int64_t receive_ns) {
  last_tracker_ns_ = receive_ns;
  read_in_stand_still_ = true;
  stand_stills_without_reading_ = 0;
}

bool InputWatch::movedBetween(std::int64_t after_ns, std::int64_t until_ns) const {
  for (std::int64_t t : motion_stamps_ns_)
    if (t > after_ns && t <= until_ns) return true;
  return false;
}

std::string InputWatch::staleInputs(std::int64_t now_ns) const {
  const auto limit = static_cast<std::int64_t>(settings_->stale_input_s * 1e9);
  std::string out;
  auto silence = [&](std::int64_t last) {
    std::ostringstream m;
    if (last == 0) m << "nothing received yet";
    else m << "nothing for " << std::fixed << std::setprecision(1) << (now_ns - last) * 1e-9 << " s";
    return m.str();
  };
  auto add = [&](const char* topic, const std::string& why) { out += (out.empty() ? "" : "; ") + std::string(topic) + ": " + why; };
  if (last_joint_ns_ == 0 || now_ns - last_joint_ns_ > limit) add("joint_state", silence(last_joint_ns_));
  const int without = stand_stills_without_reading_;
  const bool silent_too_long = settings_->tracker_silence_s > 0 &&
                               now_ns - (last_tracker_ns_ ? last_tracker_ns_ : now_ns) > settings_->tracker_silence_s * 1e9;
  if (without >= settings_->stale_stand_stills)
    add("tracker_pose", "no reading in the robot's last " + std::to_string(without) + " stand-stills (" +
                            silence(last_tracker_ns_) + ")");
  else if (silent_too_long)
    add("tracker_pose", silence(last_tracker_ns_) + " (engine.tracker_silence_s)");
  return out;
}

}  // namespace cellcal
