// A simulated KUKA controller's RSI side, for the cell and the bench: it sends a <Rob> datagram to a bridge every
// cycle on its own clock (an absolute CLOCK_MONOTONIC deadline per cycle, as the controller's interpolation cycle),
// waits for the <Sen> until the cycle ends, and counts the answers that came too late or never, as RSI does. The
// setpoints follow an application's path: joint-space moves between random configurations of the simulated robot
// (SimulatedCell::randomConfigurations) that keep away from singularities, `segment_s` each with a smooth (cosine)
// profile. Each cycle is logged (setpoint, correction received, latency) into storage written before the stream, so
// the cycle's thread allocates nothing; where the corrected robot landed is computed afterwards (landedErrors).
//
// Before the stream, the controller connects: it sends the first setpoint every 100 ms (IPOC 1, 2, ...) until a bridge
// answers one, as RSI's start waits for its sensor; those attempts are logged (counted = false) but not counted as
// cycles. The stream's cycles then start at first_ipoc.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "cellcal/core/servo/realtime_compensator.hpp"
#include "cellcal/core/sim/simulation.hpp"

namespace cellcal {

struct RsiControllerOptions {
  double rate_hz = 250;  // RSI's 4 ms cycle; 500 for a UR-like stream
  std::string bridge_ip = "127.0.0.1";
  int bridge_port = 0;
  int rt_priority = 0;               // SCHED_FIFO priority of the cycle's thread (0: the default scheduler)
  std::uint64_t seed = 1;            // the path's waypoints
  double segment_s = 2.0;            // controller time per move between two waypoints
  double min_singular_value = 0.05;  // of the joint Jacobian along the path: away from singularities (see the .cpp)
  std::uint64_t first_ipoc = 1000;   // ms; IPOC advances by the cycle's ms
};

// One controller cycle.
struct RsiCycleRecord {
  std::uint64_t ipoc = 0;
  double cell_time_h = 0;                                // the simulated cell's time when it was sent
  std::array<double, kMaxServoJoints> setpoint_deg{};    // ASPos sent
  std::array<double, kMaxServoJoints> correction_deg{};  // AK received (zero when none)
  std::int64_t sent_ns = 0;                              // CLOCK_MONOTONIC when it was sent
  float latency_us = 0;                                  // send to answer (answered only)
  bool answered = false;                                 // an answer with this IPOC within the cycle
  bool reached = false;                                  // an answer with this IPOC came, in time or later: the
                                                         // bridge got the packet (a lost one: neither)
  bool counted = true;                                   // false: a connection attempt (below)
};

class SimulatedRsiController {
 public:
  // `max_cycles`: the log's length; the stream ends when it is full.
  SimulatedRsiController(const SimulatedCell& sim, const RsiControllerOptions& options, std::size_t max_cycles);
  ~SimulatedRsiController();
  SimulatedRsiController(const SimulatedRsiController&) = delete;
  SimulatedRsiController& operator=(const SimulatedRsiController&) = delete;

  // Connects, then runs the stream on the calling thread until `stop` (checked every cycle) or the log is full.
  // `cell_time_h` is the simulated cell's clock, stored with each cycle for the truth it lands in. Throws
  // std::runtime_error when the socket cannot be made or SCHED_FIFO is refused (before the first cycle).
  void run(const std::atomic<bool>& stop, const std::atomic<double>& cell_time_h);
  const std::vector<RsiCycleRecord>& cycles() const { return log_; }
  const RsiControllerOptions& options() const { return options_; }
  double cycleMs() const { return 1000.0 / options_.rate_hz; }
  int movesRejected() const { return rejected_; }  // random moves that came too near a singularity

 private:
  void setpoint(std::uint64_t k, double* q_deg) const;

  const SimulatedCell* sim_;
  RsiControllerOptions options_;
  std::vector<Eigen::VectorXd> waypoints_;
  std::vector<RsiCycleRecord> log_;
  int socket_ = -1;
  int rejected_ = 0;
  std::size_t max_cycles_ = 0;
};

// Where the robot landed, per answered cycle: the true robot at the cycle's cell time driven to setpoint + correction
// (compensated) and to the setpoint alone (uncompensated), against the pose the nominal model gives the setpoint
// (what the program asked for), mm.
struct LandedErrors {
  std::vector<double> compensated_mm, uncompensated_mm;
};
// `from_ipoc`: only cycles from this IPOC on (e.g. once a calibration was applied).
LandedErrors landedErrors(const SimulatedCell& sim, const std::vector<RsiCycleRecord>& cycles, std::uint64_t from_ipoc);

}  // namespace cellcal
