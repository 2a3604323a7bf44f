// cellnet_shaper: the delay, jitter and loss of `tc netem`, in user space, for kernels without sch_netem.
//
// Each link joins two TAP devices that this program creates and holds: HOST, the host's interface (cellnet.sh moves it
// into the host's namespace and names it eth0 once this program says it is ready), and PORT, a port of the switch's
// bridge. A frame the host sends (read from HOST) is dropped with the loss probability, or held for the delay plus a
// jitter drawn uniformly from [-jitter, +jitter] and then written to PORT. Frames are sent in the order of their due
// times, so jitter reorders them, as netem's does. Frames the switch sends to the host pass at once: the same
// shaping as `tc qdisc add dev eth0 root netem ...` on every host, which shapes what the host sends.
//
// TAP devices have no checksum offload, so the kernel completes every checksum before a frame reaches this program.
// The devices disappear when it exits. A link whose PORT is set down (cellnet.sh link ... down) loses what is sent
// to it, as a pulled cable.
//
//   cellnet_shaper --link HOST_TAP:PORT_TAP [--link ...] [--seed N] [--ready-file F] [--stats-json F]
//                  [delay TIME [JITTER]] [loss PERCENT%]
//   TIME, JITTER: 2ms, 500us, 0.5ms, 1s. The stats file (rewritten every second and at exit) has, per link, the frames
//   the host sent, dropped and forwarded, the frames to the host, and the delay each forwarded frame was held
//   (p50/p99/min/max, measured from its read to its write). SIGINT or SIGTERM end it; exit 0, 2 on bad arguments,
//   1 when a device cannot be made.
#include <fcntl.h>
#include <linux/if.h>
#include <linux/if_tun.h>
#include <poll.h>
#include <sys/prctl.h>
#include <signal.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <queue>
#include <random>
#include <string>
#include <vector>

namespace {

using Clock = std::chrono::steady_clock;

[[noreturn]] void usage(const std::string& why) {
  std::fprintf(stderr,
               "cellnet_shaper: %s\nusage: cellnet_shaper --link HOST_TAP:PORT_TAP [--link ...] [--seed N] "
               "[--ready-file F] [--stats-json F] [delay TIME [JITTER]] [loss PERCENT%%]\n",
               why.c_str());
  std::exit(2);
}

// "2ms", "500us", "0.5ms", "1s" -> nanoseconds; -1 when it is not a time.
int64_t parseTimeNs(const std::string& s) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (end == s.c_str() || v < 0 || !std::isfinite(v)) return -1;
  const std::string unit(end);
  double scale = 0;
  if (unit == "s") scale = 1e9;
  else if (unit == "ms") scale = 1e6;
  else if (unit == "us") scale = 1e3;
  else if (unit == "ns") scale = 1;
  else return -1;
  return static_cast<int64_t>(std::llround(v * scale));
}

// A TAP device named `name`, without packet information, non-blocking; -1 and `why` when it cannot be made.
int openTap(const std::string& name, std::string* why) {
  if (name.empty() || name.size() >= IFNAMSIZ) {
    *why = "device name '" + name + "': 1 to " + std::to_string(IFNAMSIZ - 1) + " characters";
    return -1;
  }
  const int fd = ::open("/dev/net/tun", O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    *why = std::string("/dev/net/tun: ") + std::strerror(errno);
    return -1;
  }
  ifreq ifr{};
  ifr.ifr_flags = IFF_TAP | IFF_NO_PI;
  std::strncpy(ifr.ifr_name, name.c_str(), IFNAMSIZ - 1);
  if (::ioctl(fd, TUNSETIFF, &ifr) < 0) {
    *why = "TUNSETIFF " + name + ": " + std::strerror(errno);
    ::close(fd);
    return -1;
  }
  return fd;
}

// Held delays in 10 us bins up to 2 s (beyond: the last bin), for quantiles without keeping every frame.
struct DelayHistogram {
  static constexpr int kBinNs = 10000;
  std::vector<uint64_t> bins = std::vector<uint64_t>(200001, 0);
  uint64_t count = 0;
  int64_t min_ns = 0, max_ns = 0;
  void add(int64_t ns) {
    bins[static_cast<size_t>(std::min<int64_t>(std::max<int64_t>(ns, 0) / kBinNs, bins.size() - 1))]++;
    min_ns = count == 0 ? ns : std::min(min_ns, ns);
    max_ns = count == 0 ? ns : std::max(max_ns, ns);
    ++count;
  }
  // The upper edge of the bin holding quantile q, in microseconds.
  double quantileUs(double q) const {
    if (count == 0) return 0;
    const uint64_t rank = static_cast<uint64_t>(std::ceil(q * static_cast<double>(count)));
    uint64_t seen = 0;
    for (size_t i = 0; i < bins.size(); ++i) {
      seen += bins[i];
      if (seen >= std::max<uint64_t>(rank, 1)) return (static_cast<double>(i) + 1) * kBinNs / 1e3;
    }
    return static_cast<double>(bins.size()) * kBinNs / 1e3;
  }
};

struct Link {
  std::string host_name, port_name;
  int host_fd = -1, port_fd = -1;
  uint64_t from_host = 0, dropped = 0, forwarded = 0, lost_port_down = 0, to_host = 0;
  DelayHistogram held;
};

struct Held {
  Clock::time_point due;
  uint64_t order;  // ties leave in arrival order
  size_t link;
  Clock::time_point read_at;
  std::vector<uint8_t> frame;
  bool operator>(const Held& o) const { return due != o.due ? due > o.due : order > o.order; }
};

volatile sig_atomic_t g_stop = 0;
void onSignal(int) { g_stop = 1; }

void writeStats(const std::string& path, const std::vector<Link>& links, int64_t delay_ns, int64_t jitter_ns,
                double loss, uint64_t seed) {
  if (path.empty()) return;
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    out << "{\"delay_us\": " << delay_ns / 1e3 << ", \"jitter_us\": " << jitter_ns / 1e3 << ", \"loss\": " << loss
        << ", \"seed\": " << seed << ", \"links\": [";
    for (size_t i = 0; i < links.size(); ++i) {
      const Link& l = links[i];
      out << (i ? ", " : "") << "{\"host\": \"" << l.host_name << "\", \"port\": \"" << l.port_name
          << "\", \"from_host\": " << l.from_host << ", \"dropped\": " << l.dropped << ", \"forwarded\": "
          << l.forwarded << ", \"lost_port_down\": " << l.lost_port_down << ", \"to_host\": " << l.to_host
          << ", \"held_p50_us\": " << l.held.quantileUs(0.5) << ", \"held_p99_us\": " << l.held.quantileUs(0.99)
          << ", \"held_min_us\": " << l.held.min_ns / 1e3 << ", \"held_max_us\": " << l.held.max_ns / 1e3 << "}";
    }
    out << "]}\n";
  }
  std::rename(tmp.c_str(), path.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<Link> links;
  std::string ready_file, stats_file;
  uint64_t seed = std::random_device{}();
  int64_t delay_ns = 0, jitter_ns = 0;
  double loss = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&](const char* what) -> std::string {
      if (i + 1 >= argc) usage(a + ": needs " + what);
      return argv[++i];
    };
    if (a == "--link") {
      const std::string v = next("HOST_TAP:PORT_TAP");
      const auto colon = v.find(':');
      if (colon == std::string::npos) usage("--link " + v + ": HOST_TAP:PORT_TAP");
      Link l;
      l.host_name = v.substr(0, colon);
      l.port_name = v.substr(colon + 1);
      links.push_back(std::move(l));
    } else if (a == "--seed") {
      seed = std::strtoull(next("a number").c_str(), nullptr, 10);
    } else if (a == "--ready-file") {
      ready_file = next("a file");
    } else if (a == "--stats-json") {
      stats_file = next("a file");
    } else if (a == "delay") {
      delay_ns = parseTimeNs(next("a time"));
      if (delay_ns < 0) usage("delay " + std::string(argv[i]) + ": a time such as 2ms or 500us");
      if (i + 1 < argc && parseTimeNs(argv[i + 1]) >= 0) jitter_ns = parseTimeNs(argv[++i]);
      if (i + 1 < argc && std::strchr(argv[i + 1], '%') && argv[i + 1] != std::string("loss"))
        usage(std::string("delay correlation ") + argv[i + 1] + ": not supported by the user-space shaper");
    } else if (a == "loss") {
      const std::string v = next("a percentage");
      char* end = nullptr;
      loss = std::strtod(v.c_str(), &end) / 100.0;
      if (end == v.c_str() || std::string(end) != "%" || loss < 0 || loss > 1) usage("loss " + v + ": 0% to 100%");
      if (i + 1 < argc && std::strchr(argv[i + 1], '%'))
        usage(std::string("loss correlation ") + argv[i + 1] + ": not supported by the user-space shaper");
    } else {
      usage("'" + a + "': not supported (the user-space shaper knows delay TIME [JITTER] and loss PERCENT%)");
    }
  }
  if (links.empty()) usage("no --link");
  if (jitter_ns > delay_ns) usage("jitter above the delay: a frame would leave before it came");

  for (Link& l : links) {
    std::string why;
    if ((l.host_fd = openTap(l.host_name, &why)) < 0 || (l.port_fd = openTap(l.port_name, &why)) < 0) {
      std::fprintf(stderr, "cellnet_shaper: %s\n", why.c_str());
      return 1;
    }
  }

  // SIGINT/SIGTERM reach this program only while it waits in ppoll, so none is missed between a check and a wait.
  sigset_t blocked, during_wait;
  sigemptyset(&blocked);
  sigaddset(&blocked, SIGINT);
  sigaddset(&blocked, SIGTERM);
  sigprocmask(SIG_BLOCK, &blocked, &during_wait);
  sigdelset(&during_wait, SIGINT);
  sigdelset(&during_wait, SIGTERM);
  struct sigaction sa {};
  sa.sa_handler = onSignal;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);

  ::prctl(PR_SET_TIMERSLACK, 1UL);  // wake when a frame is due, not up to 50 us later
  if (!ready_file.empty()) {
    std::ofstream(ready_file) << ::getpid() << "\n";
  }
  std::fprintf(stderr, "cellnet_shaper: %zu links, delay %.3f ms, jitter %.3f ms, loss %.2f %%, seed %llu\n",
               links.size(), delay_ns / 1e6, jitter_ns / 1e6, loss * 100, static_cast<unsigned long long>(seed));

  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::priority_queue<Held, std::vector<Held>, std::greater<Held>> held;
  uint64_t order = 0;
  std::vector<pollfd> fds;
  for (const Link& l : links) {
    fds.push_back({l.host_fd, POLLIN, 0});
    fds.push_back({l.port_fd, POLLIN, 0});
  }
  std::array<uint8_t, 65600> buf{};
  auto last_stats = Clock::now();

  while (!g_stop) {
    // Send what is due.
    auto now = Clock::now();
    while (!held.empty() && held.top().due <= now) {
      const Held& h = held.top();
      Link& l = links[h.link];
      if (::write(l.port_fd, h.frame.data(), h.frame.size()) < 0) {
        l.lost_port_down++;  // the port is down (EIO) or its queue full
      } else {
        l.forwarded++;
        l.held.add(std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now() - h.read_at).count());
      }
      held.pop();
      now = Clock::now();
    }
    if (now - last_stats > std::chrono::seconds(1)) {
      writeStats(stats_file, links, delay_ns, jitter_ns, loss, seed);
      last_stats = now;
    }
    timespec wait{1, 0};
    if (!held.empty()) {
      const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(held.top().due - now).count();
      wait = {static_cast<time_t>(ns / 1000000000), static_cast<long>(ns % 1000000000)};
    }
    const int n = ::ppoll(fds.data(), fds.size(), &wait, &during_wait);
    if (n < 0 && errno != EINTR) {
      std::perror("cellnet_shaper: ppoll");
      return 1;
    }
    if (n <= 0) continue;
    for (size_t k = 0; k < fds.size(); ++k) {
      if (!(fds[k].revents & POLLIN)) continue;
      Link& l = links[k / 2];
      const bool from_host = k % 2 == 0;
      for (;;) {
        const ssize_t got = ::read(fds[k].fd, buf.data(), buf.size());
        if (got <= 0) break;
        if (!from_host) {
          if (::write(l.host_fd, buf.data(), static_cast<size_t>(got)) >= 0) l.to_host++;
          continue;
        }
        l.from_host++;
        if (loss > 0 && unit(rng) < loss) {
          l.dropped++;
          continue;
        }
        const auto read_at = Clock::now();
        const int64_t jitter = jitter_ns > 0 ? static_cast<int64_t>((2 * unit(rng) - 1) * jitter_ns) : 0;
        held.push({read_at + std::chrono::nanoseconds(delay_ns + jitter), order++, k / 2, read_at,
                   std::vector<uint8_t>(buf.begin(), buf.begin() + got)});
      }
    }
  }
  writeStats(stats_file, links, delay_ns, jitter_ns, loss, seed);
  for (Link& l : links) {
    ::close(l.host_fd);
    ::close(l.port_fd);
  }
  return 0;
}
