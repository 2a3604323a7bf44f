#include "cellcal/core/servo/rsi_session.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace cellcal {

double rsiLimitDeg(const CompensationSettings& c) { return radToDeg(c.max_joint_correction_rad) + 1e-6; }

RsiSession::RsiSession(RealtimeCompensator& compensator, int axes, const RsiSettings& settings)
    : compensator_(&compensator), axes_(axes), settings_(settings) {
  if (axes < 1 || axes > kMaxServoJoints)
    throw std::invalid_argument("RsiSession: " + std::to_string(axes) + " axes (1 to " +
                                std::to_string(kMaxServoJoints) + ")");
  if (!(settings.cycle_s > 0) || !(settings.max_correction_deg > 0) || !settings.sensor_type)
    throw std::invalid_argument("RsiSession: cycle_s and max_correction_deg must be > 0, sensor_type given");
}

std::size_t RsiSession::answerHeld(std::uint64_t ipoc, char* out, std::size_t capacity) noexcept {
  ++counters_.held;
  const std::size_t n = writeRsiSen(out, capacity, settings_.sensor_type, sent_deg_.data(), axes_, ipoc, false);
  counters_.answered += n > 0;
  return n;
}

void RsiSession::seen(std::uint64_t ipoc) noexcept {
  if (have_ipoc_) {
    const double cycles = static_cast<double>(ipoc - last_ipoc_) / (settings_.cycle_s * 1e3);
    if (cycles > 1.5) counters_.missed_cycles += static_cast<std::uint64_t>(std::llround(cycles)) - 1;
  }
  have_ipoc_ = true;
  last_ipoc_ = ipoc;
}

std::size_t RsiSession::onPacket(const char* data, std::size_t size, char* out, std::size_t capacity) noexcept {
  ++counters_.packets;
  RsiRob rob;
  const RsiError e = parseRsiRob(data, size, rob);
  auto newer = [this](std::uint64_t ipoc) { return !have_ipoc_ || ipoc > last_ipoc_; };
  if (e != RsiError::kNone) {  // a cycle seen (when its IPOC can be read) but nothing of it used
    ++counters_.refused[static_cast<std::size_t>(e)];
    std::uint64_t ipoc = 0;
    if (!rsiIpoc(data, size, ipoc)) return 0;
    if (newer(ipoc)) seen(ipoc);
    return answerHeld(ipoc, out, capacity);
  }
  if (rob.axes != axes_) {
    ++counters_.wrong_axes;
    if (newer(rob.ipoc)) seen(rob.ipoc);
    return answerHeld(rob.ipoc, out, capacity);
  }
  if (!newer(rob.ipoc)) {
    ++counters_.stale_ipoc;
    return answerHeld(rob.ipoc, out, capacity);
  }
  seen(rob.ipoc);
  // The controller's clock: IPOC in ms.
  double q_rad[kMaxServoJoints];
  for (int k = 0; k < axes_; ++k) q_rad[k] = degToRad(rob.setpoint_deg[static_cast<std::size_t>(k)]);
  last_answer_ = compensator_->correct(static_cast<std::int64_t>(rob.ipoc) * 1'000'000, q_rad, axes_);
  double ak_deg[kMaxServoJoints];
  for (int k = 0; k < axes_; ++k) {
    ak_deg[k] = radToDeg(last_answer_.correction_rad[k]);
    if (!(std::abs(ak_deg[k]) <= settings_.max_correction_deg)) {
      ++counters_.over_limit;
      return answerHeld(rob.ipoc, out, capacity);
    }
  }
  switch (last_answer_.status) {
    case ServoStatus::kApplied: ++counters_.applied; break;
    case ServoStatus::kHeld: ++counters_.held; break;
    default: ++counters_.no_calibration; break;
  }
  const std::size_t n = writeRsiSen(out, capacity, settings_.sensor_type, ak_deg, axes_, rob.ipoc, false);
  if (n > 0) {
    ++counters_.answered;
    for (int k = 0; k < axes_; ++k) sent_deg_[static_cast<std::size_t>(k)] = ak_deg[k];
  }
  return n;
}

}  // namespace cellcal
