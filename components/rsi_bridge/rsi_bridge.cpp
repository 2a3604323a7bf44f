#include "rsi_bridge.hpp"

#include <arpa/inet.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <iostream>
#include <stdexcept>

namespace cellcal::components {

namespace {
const CellRobot& robotOf(const CellConfig& cell, const std::string& id) {
  if (id.empty() && cell.robots.size() == 1) return cell.robots[0];
  std::string ids;
  for (const CellRobot& r : cell.robots) {
    if (r.robot_id == id) return r;
    ids += (ids.empty() ? "" : ", ") + r.robot_id;
  }
  throw ConfigError(id.empty() ? "--robot: the cell file has several robots (" + ids + "): name the controller's"
                               : "--robot: '" + id + "' is not a robot of " + cell.source + " (its robots: " + ids + ")");
}
RsiSettings rsiSettings(const RsiBridge::Options& o, const CellConfig& cell) {
  RsiSettings s;
  s.sensor_type = o.sensor_type.c_str();
  s.cycle_s = o.cycle_ms * 1e-3;
  s.max_correction_deg = o.max_correction_deg == 0 ? rsiLimitDeg(cell.compensation) : o.max_correction_deg;
  return s;
}
sockaddr_in ipv4(const std::string& text, const char* option) {
  sockaddr_in a{};
  a.sin_family = AF_INET;
  const std::size_t colon = text.rfind(':');
  const std::string host = colon == std::string::npos ? text : text.substr(0, colon);
  int port = 0;
  if (colon != std::string::npos) {
    try {
      port = std::stoi(text.substr(colon + 1));
    } catch (const std::exception&) {
      port = -1;
    }
  }
  if (inet_pton(AF_INET, host.c_str(), &a.sin_addr) != 1 || port < 0 || port > 65535)
    throw ConfigError(std::string(option) + " '" + text + "': expected an IPv4 address" +
                      (colon == std::string::npos ? "" : " and a port 0-65535") + " (e.g. 192.168.1.10:49152)");
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  return a;
}
std::int64_t steadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
}  // namespace

RsiBridge::RsiBridge(const Options& o)
    : options_(o),
      cell_(loadCell(o.process)),
      robot_(&robotOf(cell_, o.robot)),
      compensator_(robot_->model, realtimeSettings(cell_)),
      feed_(cell_, robot_->robot_id, compensator_, "cellcal_rsi_bridge"),
      session_(compensator_, robot_->model.numJoints(), rsiSettings(options_, cell_)) {
  if (o.controller.empty()) throw ConfigError("--controller: the controller's IPv4 address is required");
  if (!(o.cycle_ms > 0) || !(o.max_correction_deg >= 0))
    throw ConfigError("--cycle-ms must be > 0 and --max-correction-deg >= 0");
  controller_ = ipv4(o.controller, "--controller").sin_addr;
  const sockaddr_in listen = ipv4(o.listen, "--listen");
  socket_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (socket_ < 0 || ::bind(socket_, reinterpret_cast<const sockaddr*>(&listen), sizeof listen) != 0) {
    const std::string why = std::strerror(errno);
    if (socket_ >= 0) ::close(socket_);
    throw std::runtime_error("--listen " + o.listen + ": " + why);
  }
  std::cerr << "cellcal_rsi_bridge: robot " << robot_->robot_id << " (" << robot_->model.numJoints()
            << " axes), listening on " << o.listen << " for " << o.controller << ", cycle " << o.cycle_ms
            << " ms, corrections up to " << session_.settings().max_correction_deg << " deg per axis\n";
}

RsiBridge::~RsiBridge() {
  done_ = true;
  if (monitor_.joinable()) monitor_.join();
  if (socket_ >= 0) ::close(socket_);
}

void RsiBridge::setUpRealTime() {
  if (options_.cpu >= 0) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(options_.cpu, &set);
    if (const int e = pthread_setaffinity_np(pthread_self(), sizeof set, &set); e != 0)
      throw std::runtime_error("--cpu " + std::to_string(options_.cpu) + ": " + std::strerror(e));
  }
  if (options_.rt_priority <= 0) return;
  sched_param p{};
  p.sched_priority = options_.rt_priority;
  if (const int e = pthread_setschedparam(pthread_self(), SCHED_FIFO, &p); e != 0)
    throw std::runtime_error(
        "--rt-priority " + std::to_string(options_.rt_priority) + ": SCHED_FIFO refused (" + std::strerror(e) +
        "): run as root, give the binary CAP_SYS_NICE (setcap cap_sys_nice+ep cellcal_rsi_bridge), or allow the "
        "user an rtprio in /etc/security/limits.conf (docs/deployment.md)");
  if (::mlockall(MCL_CURRENT | MCL_FUTURE) != 0)
    std::cerr << "cellcal_rsi_bridge: warning: memory not locked (" << std::strerror(errno)
              << "): a page fault can delay a cycle\n";
}

void RsiBridge::monitor() {
  std::string said;
  bool silent_said = false;
  while (!done_) {
    const std::string now = describe(feed_.status());
    const std::string without_age = now.substr(0, now.find("; last sample"));
    if (without_age != said) {
      std::cerr << "cellcal_rsi_bridge: calibration " << now << "\n";
      said = without_age;
    }
    const std::int64_t last = last_packet_ns_.load();
    const bool silent = last > 0 && steadyNs() - last > 1'000'000'000;
    if (silent && !silent_said)
      std::cerr << "cellcal_rsi_bridge: no packet from the controller for 1 s (" << packets_.load()
                << " before): the RSI stream stopped\n";
    silent_said = silent;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
}

std::size_t RsiBridge::passThrough(const char* in, std::size_t n, char* out, std::size_t capacity) noexcept {
  RsiRob rob;
  if (parseRsiRob(in, n, rob) != RsiError::kNone) return 0;
  const std::array<double, kMaxServoJoints> zero{};
  return writeRsiSen(out, capacity, options_.sensor_type.c_str(), zero.data(), rob.axes, rob.ipoc, false);
}

int RsiBridge::run() {
  setUpRealTime();
  monitor_ = std::thread([this] { monitor(); });
  const RunLimit limit(options_.duration_s);
  char in[kMaxRsiPacketBytes + 1], out[kMaxRsiPacketBytes];
  pollfd pfd{socket_, POLLIN, 0};
  while (!limit.over()) {
    if (::poll(&pfd, 1, 100) <= 0) continue;
    sockaddr_in from{};
    socklen_t from_len = sizeof from;
    const ssize_t n = ::recvfrom(socket_, in, sizeof in, MSG_TRUNC, reinterpret_cast<sockaddr*>(&from), &from_len);
    const std::int64_t t0 = steadyNs();
    if (n < 0) continue;
    if (from.sin_addr.s_addr != controller_.s_addr) {
      foreign_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    packets_.fetch_add(1, std::memory_order_relaxed);
    last_packet_ns_.store(t0, std::memory_order_relaxed);
    // A datagram longer than the buffer arrives cut (MSG_TRUNC gives its length): the session refuses it as too long.
    const std::size_t m = options_.pass_through ? passThrough(in, static_cast<std::size_t>(n), out, sizeof out)
                                                : session_.onPacket(in, static_cast<std::size_t>(n), out, sizeof out);
    if (const std::uint64_t v = compensator_.version();
        v != (taken_count_ ? taken_[taken_count_ - 1].second : 0) && taken_count_ < taken_.size())
      taken_[taken_count_++] = {session_.lastIpoc(), v};
    if (m == 0) continue;
    ::sendto(socket_, out, m, 0, reinterpret_cast<const sockaddr*>(&from), from_len);
    const std::int64_t us = (steadyNs() - t0) / 1000;
    ++latency_us_[static_cast<std::size_t>(std::min<std::int64_t>(us, 10000))];
  }
  done_ = true;
  monitor_.join();
  // The summary and --stats-json.
  const RsiCounters& c = session_.counters();
  std::uint64_t total = 0, seen = 0;
  for (std::uint32_t v : latency_us_) total += v;
  double p50 = 0, p99 = 0, max = 0;
  for (std::size_t us = 0; us < latency_us_.size(); ++us) {
    if (latency_us_[us] == 0) continue;
    seen += latency_us_[us];
    if (p50 == 0 && seen * 2 >= total) p50 = static_cast<double>(us);
    if (p99 == 0 && seen * 100 >= total * 99) p99 = static_cast<double>(us);
    max = static_cast<double>(us);
  }
  nlohmann::json refused = nlohmann::json::object();
  for (std::size_t e = 1; e < c.refused.size(); ++e)
    if (c.refused[e] > 0) refused[rsiErrorName(static_cast<RsiError>(e))] = c.refused[e];
  const FeedStatus feed = feed_.status();
  nlohmann::json taken = nlohmann::json::array();
  for (std::size_t k = 0; k < taken_count_; ++k) taken.push_back({taken_[k].first, taken_[k].second});
  const nlohmann::json stats = {
      {"robot_id", robot_->robot_id},
      {"pass_through", options_.pass_through},
      {"packets", packets_.load()},
      {"answered", options_.pass_through ? total : c.answered},
      {"applied", c.applied},
      {"held", c.held},
      {"no_calibration", c.no_calibration},
      {"refused", refused},
      {"wrong_axes", c.wrong_axes},
      {"stale_ipoc", c.stale_ipoc},
      {"missed_cycles", c.missed_cycles},
      {"over_limit", c.over_limit},
      {"foreign_dropped", foreign_.load()},
      {"latency_us", {{"p50", p50}, {"p99", p99}, {"max", max}, {"count", total}}},
      {"calibration", {{"applied_version", feed.applied_version}, {"received", feed.received},
                       {"versions_applied", feed.applied}, {"holding", feed.holding}, {"describe", describe(feed)}}},
      // [IPOC, version]: the cycle each version first answered (at most 4096; taken_full says the list was cut)
      {"versions_taken", taken},
      {"taken_full", taken_count_ == taken_.size()}};
  writeJsonFile(options_.process.stats_json, stats);
  std::cerr << "cellcal_rsi_bridge: " << stats["packets"] << " packets, " << stats["answered"] << " answered ("
            << c.applied << " corrected, " << c.held << " held), " << foreign_.load() << " from other addresses dropped; answer "
            << "p50 " << p50 << " us, p99 " << p99 << " us\n";
  return 0;
}

}  // namespace cellcal::components
