#include "cellcal/lab/rsi_controller.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <Eigen/SVD>
#include <chrono>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/servo/rsi_xml.hpp"

namespace cellcal {

namespace {
std::int64_t nsUntil(const timespec& deadline) {
  timespec now{};
  clock_gettime(CLOCK_MONOTONIC, &now);
  return (deadline.tv_sec - now.tv_sec) * 1'000'000'000LL + (deadline.tv_nsec - now.tv_nsec);
}
}  // namespace

SimulatedRsiController::SimulatedRsiController(const SimulatedCell& sim, const RsiControllerOptions& options,
                                               std::size_t max_cycles)
    : sim_(&sim), options_(options) {
  if (!(options.rate_hz > 0) || !(options.segment_s > 0) || options.bridge_port <= 0 || options.bridge_port > 65535)
    throw std::invalid_argument("SimulatedRsiController: rate_hz and segment_s must be > 0, bridge_port 1-65535");
  const double cycles_per_segment = options.rate_hz * options.segment_s;
  std::mt19937_64 rng(options.seed);
  // An application's path keeps away from singularities, as robot programs do (near one, a small pose error takes
  // large joint moves, and the path itself needs fast joints): every move between two waypoints keeps the smallest
  // singular value of the joint Jacobian (position rows per metre, orientation rows per radian) at or above
  // min_singular_value, checked at 16 points along it.
  const std::size_t wanted = static_cast<std::size_t>(static_cast<double>(max_cycles) / cycles_per_segment) + 2;
  const RobotModel& model = sim.model();
  KinematicsData data(model);
  Eigen::MatrixXd J(6, model.numJoints());
  auto regular = [&](const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
    for (int k = 0; k <= 16; ++k) {
      const double w = 0.5 - 0.5 * std::cos(kPi * k / 16.0);
      forwardKinematics(model, data, sim.nominalParams(), Eigen::VectorXd((1 - w) * a + w * b));
      computeJointJacobian(model, data, J);
      if (Eigen::JacobiSVD<Eigen::MatrixXd>(J).singularValues().minCoeff() < options.min_singular_value) return false;
    }
    return true;
  };
  for (int tries = 0; waypoints_.size() < wanted; ++tries) {
    if (tries > 10000 + 1000 * static_cast<int>(wanted))
      throw std::invalid_argument("SimulatedRsiController: no path of this robot keeps away from its singularities");
    Eigen::VectorXd q = sim.randomConfigurations(1, rng).front();
    if (waypoints_.empty() ? regular(q, q) : regular(waypoints_.back(), q))
      waypoints_.push_back(std::move(q));
    else
      ++rejected_;
  }
  max_cycles_ = max_cycles;
}

SimulatedRsiController::~SimulatedRsiController() {
  if (socket_ >= 0) ::close(socket_);
}

// Cycle k's setpoint: the move from waypoint s to s + 1 with a cosine profile (zero joint speed at both ends).
void SimulatedRsiController::setpoint(std::uint64_t k, double* q_deg) const {
  const double per_segment = options_.rate_hz * options_.segment_s;
  const double x = static_cast<double>(k) / per_segment;
  const auto s = static_cast<std::size_t>(x);
  const double w = 0.5 - 0.5 * std::cos(kPi * (x - static_cast<double>(s)));
  const Eigen::VectorXd& a = waypoints_[s];
  const Eigen::VectorXd& b = waypoints_[s + 1];
  for (Eigen::Index j = 0; j < a.size(); ++j) q_deg[j] = radToDeg((1 - w) * a[j] + w * b[j]);
}

void SimulatedRsiController::run(const std::atomic<bool>& stop, const std::atomic<double>& cell_time_h) {
  if (options_.rt_priority > 0) {
    sched_param p{};
    p.sched_priority = options_.rt_priority;
    if (const int e = pthread_setschedparam(pthread_self(), SCHED_FIFO, &p); e != 0)
      throw std::runtime_error("simulated RSI controller: SCHED_FIFO " + std::to_string(options_.rt_priority) +
                               " refused (" + std::strerror(e) + "): run as root or with CAP_SYS_NICE");
  }
  socket_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<std::uint16_t>(options_.bridge_port));
  if (socket_ < 0 || inet_pton(AF_INET, options_.bridge_ip.c_str(), &to.sin_addr) != 1)
    throw std::runtime_error("simulated RSI controller: no socket to " + options_.bridge_ip);
  const int axes = sim_->model().numJoints();
  const long cycle_ns = std::lround(1e9 / options_.rate_hz);
  const auto ipoc_step = static_cast<std::uint64_t>(std::lround(cycleMs()));
  char out[kMaxRsiPacketBytes], in[kMaxRsiPacketBytes];
  // The log's storage written before the first cycle: a first touch of a page inside a cycle is a page fault, which
  // can wait for the process's memory map while another thread of the launcher (DDS, the judge) holds it.
  log_.assign(max_cycles_, RsiCycleRecord{});
  std::size_t used = 0;
  timespec deadline{};
  bool connected = false;
  for (std::uint64_t k = 0, attempt = 1; used < log_.size() && !stop.load(std::memory_order_relaxed);) {
    RsiCycleRecord r;
    r.counted = connected;
    r.ipoc = connected ? options_.first_ipoc + k * ipoc_step : attempt++;
    if (!connected && r.ipoc >= options_.first_ipoc) break;  // no bridge answered
    r.cell_time_h = cell_time_h.load(std::memory_order_relaxed);
    setpoint(k, r.setpoint_deg.data());
    const std::size_t n = writeRsiRob(out, sizeof out, r.setpoint_deg.data(), r.setpoint_deg.data(), axes, r.ipoc);
    if (!connected) clock_gettime(CLOCK_MONOTONIC, &deadline);
    deadline.tv_nsec += connected ? cycle_ns : 100'000'000L;
    if (deadline.tv_nsec >= 1'000'000'000) deadline.tv_nsec -= 1'000'000'000, ++deadline.tv_sec;
    const auto sent = std::chrono::steady_clock::now();
    r.sent_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(sent.time_since_epoch()).count();
    ::sendto(socket_, out, n, 0, reinterpret_cast<const sockaddr*>(&to), sizeof to);
    // The answer awaited until the cycle ends; older answers (late ones of earlier cycles) are read and dropped.
    for (std::int64_t left = nsUntil(deadline); left > 0; left = nsUntil(deadline)) {
      pollfd p{socket_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>((left + 999'999) / 1'000'000)) <= 0) continue;
      const ssize_t got = ::recv(socket_, in, sizeof in, 0);
      RsiSen sen;
      if (got <= 0 || parseRsiSen(in, static_cast<std::size_t>(got), sen) != RsiError::kNone) continue;
      if (sen.ipoc != r.ipoc) {  // a late answer of an earlier cycle: that packet reached the bridge
        for (std::size_t i = used; i-- > 0 && log_[i].ipoc >= sen.ipoc;)
          if (log_[i].ipoc == sen.ipoc) log_[i].reached = true;
        continue;
      }
      r.reached = true;
      if (nsUntil(deadline) < 0) break;  // arrived after the cycle's end: late
      r.answered = true;
      r.latency_us = std::chrono::duration<float, std::micro>(std::chrono::steady_clock::now() - sent).count();
      for (int j = 0; j < axes; ++j)
        r.correction_deg[static_cast<std::size_t>(j)] = sen.correction_deg[static_cast<std::size_t>(j)];
      break;
    }
    log_[used++] = r;
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &deadline, nullptr);
    if (connected) ++k;
    connected = connected || r.answered;
  }
  ::close(socket_);
  socket_ = -1;
  log_.resize(used);  // shrinks in place
}

LandedErrors landedErrors(const SimulatedCell& sim, const std::vector<RsiCycleRecord>& cycles,
                          std::uint64_t from_ipoc) {
  LandedErrors out;
  const RobotModel& model = sim.model();
  KinematicsData data(model);
  const int n = model.numJoints();
  Eigen::VectorXd q(n), q_corrected(n);
  for (const RsiCycleRecord& r : cycles) {
    if (!r.answered || !r.counted || r.ipoc < from_ipoc) continue;
    for (int j = 0; j < n; ++j) {
      q[j] = degToRad(r.setpoint_deg[static_cast<std::size_t>(j)]);
      q_corrected[j] =
          degToRad(r.setpoint_deg[static_cast<std::size_t>(j)] + r.correction_deg[static_cast<std::size_t>(j)]);
    }
    const Eigen::Vector3d desired = forwardKinematics(model, data, sim.nominalParams(), q).translation();
    out.compensated_mm.push_back((sim.truePose(q_corrected, r.cell_time_h).translation() - desired).norm() * 1e3);
    out.uncompensated_mm.push_back((sim.truePose(q, r.cell_time_h).translation() - desired).norm() * 1e3);
  }
  return out;
}

}  // namespace cellcal
