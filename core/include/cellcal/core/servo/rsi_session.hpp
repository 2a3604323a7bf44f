// One KUKA RSI connection's packets answered by a RealtimeCompensator: what cellcal_rsi_bridge does with each
// datagram between receiving it and sending the answer, without the socket (so a test or a simulated controller can
// drive it in memory). No allocation, no lock, no system call.
//
// Each <Rob> is one controller cycle: its IPOC (the controller's cycle stamp, ms) is the compensator's clock, its
// ASPos (the program's axis setpoint, deg) the setpoint, and the answer <Sen> carries AK = the correction (deg) in
// RSI's AXISCORR absolute mode: the controller commands ASPos + AK. Configure AXISCORR's limits (LowerLimA1 ...
// UpperLimA6) at or above RsiSettings::max_correction_deg (rsiLimitDeg by default).
//
// Faults (counted in RsiCounters, never answered with a correction built from them): a packet the reader refuses
// (rsi_xml.hpp; answered with the correction last sent when its IPOC can be read, else not at all), a packet with
// another number of axes than the robot, an IPOC not newer than the last (repeated or older), and a correction over
// max_correction_deg on any axis: each answered with the correction last sent, so the robot keeps what it has. An IPOC
// that jumps by more than a cycle counts the cycles missed and is answered normally. The limit is a last guard, not a
// bound the compensator knows: keep compensation.max_joint_correction_deg below it, so that it never trips while the
// compensator goes on from a correction that was not sent.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

#include "cellcal/core/servo/realtime_compensator.hpp"
#include "cellcal/core/servo/rsi_xml.hpp"

namespace cellcal {

// The limit that never trips on an answer the compensator gives: its max_joint_correction_rad (above which it refuses
// and holds by itself), in degrees, with 1e-6 deg for the conversion's rounding. The bridge's default.
double rsiLimitDeg(const CompensationSettings& compensation);

struct RsiSettings {
  const char* sensor_type = "ImFree";  // the Type of <Sen>, as RSI's ETHERNET object is configured
  double cycle_s = 0.004;              // RSI's interpolation cycle: 4 ms (IPO_FAST) or 12 ms
  // Per axis; above it the correction last sent is sent again.
  double max_correction_deg = rsiLimitDeg(CompensationSettings{});
};

struct RsiCounters {
  std::uint64_t packets = 0;         // every datagram given
  std::uint64_t answered = 0;        // with an answer written
  std::uint64_t applied = 0;         // the compensator's correction sent
  std::uint64_t held = 0;            // the correction last sent, sent again (every fault below, and the compensator's held)
  std::uint64_t no_calibration = 0;  // no version yet: zero correction
  std::array<std::uint64_t, 12> refused{};  // by RsiError (index: its value)
  std::uint64_t wrong_axes = 0;
  std::uint64_t stale_ipoc = 0;      // repeated or older
  std::uint64_t missed_cycles = 0;   // cycles an IPOC jumped over
  std::uint64_t over_limit = 0;      // a correction over max_correction_deg
};

class RsiSession {
 public:
  // `compensator` must outlive the session; `axes`: the robot's joints.
  RsiSession(RealtimeCompensator& compensator, int axes, const RsiSettings& settings);
  // One datagram from the controller: the answer written into `out`, its length returned (0: no answer).
  std::size_t onPacket(const char* data, std::size_t size, char* out, std::size_t capacity) noexcept;
  const RsiCounters& counters() const noexcept { return counters_; }
  const RsiSettings& settings() const noexcept { return settings_; }
  // The compensator's answer to the last packet it was given (for a log, off the controller's thread).
  const RealtimeAnswer& lastAnswer() const noexcept { return last_answer_; }
  // The IPOC of the last packet whose IPOC was read (0: none yet).
  std::uint64_t lastIpoc() const noexcept { return last_ipoc_; }
  // The correction last sent, deg.
  const std::array<double, kMaxServoJoints>& lastSentDeg() const noexcept { return sent_deg_; }

 private:
  std::size_t answerHeld(std::uint64_t ipoc, char* out, std::size_t capacity) noexcept;
  void seen(std::uint64_t ipoc) noexcept;  // a newer cycle: the ones it jumped over counted

  RealtimeCompensator* compensator_;
  int axes_;
  RsiSettings settings_;
  RsiCounters counters_;
  RealtimeAnswer last_answer_;
  std::array<double, kMaxServoJoints> sent_deg_{};
  bool have_ipoc_ = false;
  std::uint64_t last_ipoc_ = 0;
};

}  // namespace cellcal
