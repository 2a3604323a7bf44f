// KUKA RSI's Ethernet packets (RSI's ETHERNET object: one XML datagram each way per interpolation cycle, 4 ms or
// 12 ms), read and written without allocation on the controller's thread.
//
// The controller sends <Rob>, the sensor (cellcal's bridge) answers <Sen> with the same IPOC within the cycle:
//
//   <Rob Type="KUKA"><RIst X=".." .../><AIPos A1="0.0" A2="-90.0" ... A6="0.0"/><ASPos A1=".." .../>
//        <IPOC>4208163</IPOC></Rob>
//   <Sen Type="ImFree"><Stop>0</Stop><AK A1="0.0012" ... A6="-0.0003"/><IPOC>4208163</IPOC></Sen>
//
// Axis values are degrees, as RSI has them (cellcal converts at the bridge: SI inside). ASPos is the axes' setpoint of
// the robot program, AIPos the axes' actual position, AK the axis correction (RSI's AXISCORR object). Other elements
// (RIst, RSol, Delay, digital I/O) are skipped. The reader is strict where a wrong value could move a robot: a packet
// that is not one whole <Rob> element, an axis value that is not a plain finite number, an IPOC that is not an
// unsigned integer are refused with the reason, and nothing of such a packet is used.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

#include "cellcal/core/servo/realtime_compensator.hpp"

namespace cellcal {

// The longest datagram read; RSI's own are 500-1,500 bytes.
constexpr std::size_t kMaxRsiPacketBytes = 4096;

enum class RsiError : std::uint8_t {
  kNone,
  kTooLong,          // over kMaxRsiPacketBytes
  kNotThisElement,   // not a <Rob> (or <Sen>) element at the start
  kTruncated,        // no closing tag, or an element or attribute cut off
  kMissingAxes,      // no ASPos (AK) element, or no A1 in it
  kBadAxis,          // an axis value that is not a number, axes not numbered A1..An without gaps, or more than 7
  kNotFinite,        // an axis value that is NaN or infinite
  kAxesDisagree,     // AIPos with another number of axes than ASPos
  kMissingIpoc,      // no <IPOC> element
  kBadIpoc,          // an IPOC that is not an unsigned integer
  kBadStop,          // a <Sen>'s <Stop> that is not 0 or 1
};
const char* rsiErrorName(RsiError e);  // "too_long", "not_this_element", ...

// A <Rob> packet: the controller's cycle.
struct RsiRob {
  std::uint64_t ipoc = 0;
  int axes = 0;                                          // A1..A<axes> in ASPos
  std::array<double, kMaxServoJoints> setpoint_deg{};   // ASPos
  bool has_actual = false;
  std::array<double, kMaxServoJoints> actual_deg{};     // AIPos, when given
};
RsiError parseRsiRob(const char* data, std::size_t size, RsiRob& out) noexcept;

// The IPOC of a packet the reader refused, where its <IPOC> element can be read: what the answer to it echoes.
bool rsiIpoc(const char* data, std::size_t size, std::uint64_t& ipoc) noexcept;

// A <Sen> packet: the sensor's answer (read by the simulated controller, and by tests).
struct RsiSen {
  std::uint64_t ipoc = 0;
  int axes = 0;
  std::array<double, kMaxServoJoints> correction_deg{};  // AK
  bool stop = false;                                      // <Stop>1</Stop>: the sensor asks the controller to stop
};
RsiError parseRsiSen(const char* data, std::size_t size, RsiSen& out) noexcept;

// Writes <Sen Type="sensor_type"> with <Stop>, AK A1..A<axes> (each value the shortest decimal that reads back as the
// same double) and <IPOC> into out; returns its length, or 0 when it does not fit in `capacity` bytes.
std::size_t writeRsiSen(char* out, std::size_t capacity, const char* sensor_type, const double* correction_deg, int axes,
                        std::uint64_t ipoc, bool stop) noexcept;
// The same for <Rob> (what the simulated controller sends): AIPos and ASPos, IPOC.
std::size_t writeRsiRob(char* out, std::size_t capacity, const double* actual_deg, const double* setpoint_deg, int axes,
                        std::uint64_t ipoc) noexcept;

}  // namespace cellcal
