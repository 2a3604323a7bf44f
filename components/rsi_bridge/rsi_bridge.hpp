// The RSI bridge process: a KUKA controller's RSI Ethernet stream answered inside its cycle with the cell's
// calibrations. The controller sends one <Rob> datagram per interpolation cycle (4 ms) to this process's UDP port; the
// bridge answers each from the same thread with core's RsiSession (the RealtimeCompensator's correction as AK), and a
// CalibrationFeed brings the cell's ok calibrations of its robot over DDS. Nothing else happens on the cycle's thread,
// which runs SCHED_FIFO on its own core when asked (--rt-priority, --cpu) with its memory locked.
//
// Lifetime: the constructor loads the cell file, creates the compensator, the feed (its participant joins the
// domain), the session and the socket, in that order; run() answers until SIGINT/SIGTERM or the duration, then writes
// --stats-json; the destructor closes the socket, then the feed leaves the domain.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <netinet/in.h>
#include <string>
#include <thread>

#include "cellcal/components/calibration_feed.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/core/servo/rsi_session.hpp"

namespace cellcal::components {

class RsiBridge {
 public:
  struct Options {
    ProcessOptions process;
    std::string robot;                   // the cell file's robot this controller drives (default: its only one)
    std::string listen = "0.0.0.0:49152";  // where the controller's RSI ETHERNET object sends to
    std::string controller;              // the controller's IPv4 address: datagrams from any other are dropped
    std::string sensor_type = "ImFree";
    double cycle_ms = 4;
    double max_correction_deg = 0;  // 0: rsiLimitDeg of the cell file's compensation settings
    int rt_priority = 0;  // SCHED_FIFO priority of the cycle's thread (1-99); 0: the default scheduler
    int cpu = -1;         // pin the cycle's thread to this core
    double duration_s = 0;
    // Answer every readable <Rob> with a zero correction, with no compensator: the floor of the transport and the
    // host (bench-servo --pass-through), never for a robot.
    bool pass_through = false;
  };
  explicit RsiBridge(const Options& options);
  ~RsiBridge();
  RsiBridge(const RsiBridge&) = delete;
  RsiBridge& operator=(const RsiBridge&) = delete;
  int run();

 private:
  void setUpRealTime();
  void monitor();  // a thread of normal priority: says the feed's changes and a silent controller
  std::size_t passThrough(const char* in, std::size_t n, char* out, std::size_t capacity) noexcept;

  Options options_;
  CellConfig cell_;
  const CellRobot* robot_;
  RealtimeCompensator compensator_;
  CalibrationFeed feed_;
  RsiSession session_;
  int socket_ = -1;
  in_addr controller_{};
  // Receive-to-send time of each answer, µs (the last bin: 10 ms and over).
  std::array<std::uint32_t, 10001> latency_us_{};
  // (IPOC, version) of each cycle whose answer came from another version than the one before (the first of each
  // version), kept in storage of the cycle's thread for --stats-json: a check replays the stream with them.
  std::array<std::pair<std::uint64_t, std::uint64_t>, 4096> taken_{};
  std::size_t taken_count_ = 0;
  std::atomic<std::uint64_t> foreign_{0}, packets_{0};
  std::atomic<std::int64_t> last_packet_ns_{0};
  std::atomic<bool> done_{false};
  std::thread monitor_;
};

}  // namespace cellcal::components
