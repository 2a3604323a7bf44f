// `cellcal cell --rsi-hz`: a simulated KUKA controller per robot against that robot's cellcal_rsi_bridge, and the
// check of what the bridges answered (cell_roles.hpp, CellRsi).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <pthread.h>
#include <sched.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <set>
#include <thread>

#include "cell_roles.hpp"
#include "cellcal/components/calibration_feed.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/servo/rsi_session.hpp"
#include "cellcal/lab/rsi_controller.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::cli {

namespace {

double meanOf(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / static_cast<double>(v.size());
}

// The stream replayed in memory: the same <Rob> texts through an RsiSession and a RealtimeCompensator made as the
// bridge makes them, each version published just before the cycle the bridge first answered with it.
struct Replay {
  std::uint64_t replayed = 0;     // packets that reached the bridge (its `packets` when none was lost on the way back)
  std::uint64_t compared = 0;     // answered cycles whose correction was compared
  double max_difference_rad = 0;  // largest |bridge - replay| over every axis of those
  std::uint64_t first_difference_ipoc = 0;  // the first cycle over 1e-12 rad (0: none)
  std::string stopped;                      // why the replay stopped before the end ("" : it did not)
  std::vector<double> predicted_sigma_mm;   // the answering version's predicted 1-sigma where a correction was applied
};

Replay replay(const CellConfig& cell, const CellRobot& robot, const std::vector<RsiCycleRecord>& log,
              const std::vector<std::pair<std::uint64_t, std::uint64_t>>& taken,
              const std::map<std::uint64_t, CalibratedModel>& calibrations, double cycle_ms) {
  Replay out;
  RealtimeCompensator rt(robot.model, components::realtimeSettings(cell));
  RsiSettings settings;  // the bridge's, as the launcher starts it
  settings.cycle_s = cycle_ms * 1e-3;
  settings.max_correction_deg = rsiLimitDeg(cell.compensation);
  RsiSession session(rt, robot.model.numJoints(), settings);
  const int n = robot.model.numJoints();
  std::size_t next = 0;
  char rob[kMaxRsiPacketBytes], sen_text[kMaxRsiPacketBytes];
  for (const RsiCycleRecord& r : log) {
    if (!r.reached) continue;  // lost before the bridge (e.g. sent before it listened): it never ran
    ++out.replayed;
    for (; next < taken.size() && taken[next].first <= r.ipoc; ++next) {
      const auto it = calibrations.find(taken[next].second);
      if (taken[next].first < r.ipoc || it == calibrations.end()) {
        out.stopped = it == calibrations.end()
                          ? "v" + std::to_string(taken[next].second) + " never reached the launcher's reader"
                          : "the bridge took v" + std::to_string(taken[next].second) + " at IPOC " +
                                std::to_string(taken[next].first) + ", a cycle the controller did not log";
        return out;
      }
      std::string why;
      auto v = ServoVersion::prepare(robot.model, it->first, IdentifiedModel(it->second), &why);
      if (!v) {
        out.stopped = "v" + std::to_string(it->first) + ": " + why;
        return out;
      }
      rt.publish(std::move(v));
    }
    const std::size_t size = writeRsiRob(rob, sizeof rob, r.setpoint_deg.data(), r.setpoint_deg.data(), n, r.ipoc);
    const std::size_t m = session.onPacket(rob, size, sen_text, sizeof sen_text);
    RsiSen sen;
    if (m == 0 || parseRsiSen(sen_text, m, sen) != RsiError::kNone) {
      out.stopped = "the in-memory session gave no answer at IPOC " + std::to_string(r.ipoc);
      return out;
    }
    if (session.lastAnswer().status == ServoStatus::kApplied && r.counted)
      out.predicted_sigma_mm.push_back(session.lastAnswer().predicted_sigma_m * 1e3);
    if (!r.answered) continue;
    ++out.compared;
    for (int j = 0; j < n; ++j) {
      const double d = degToRad(
          std::abs(sen.correction_deg[static_cast<std::size_t>(j)] - r.correction_deg[static_cast<std::size_t>(j)]));
      out.max_difference_rad = std::max(out.max_difference_rad, d);
      if (d > 1e-12 && out.first_difference_ipoc == 0) out.first_difference_ipoc = r.ipoc;
    }
  }
  return out;
}

// A UDP port on 127.0.0.1 the kernel says is free now (bound to port 0, then closed for the bridge to take).
int freeUdpPort() {
  const int s = ::socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof a;
  const bool ok = s >= 0 && ::bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0 &&
                  ::getsockname(s, reinterpret_cast<sockaddr*>(&a), &len) == 0;
  if (s >= 0) ::close(s);
  if (!ok) throw std::runtime_error(std::string("--rsi-hz: no free UDP port on 127.0.0.1: ") + std::strerror(errno));
  return ntohs(a.sin_port);
}

// The bridge of robot `i`'s --stats-json as mergeProcessStats put it in the summary: its counts and the versions it
// took (null when it wrote none).
nlohmann::json bridgeStats(const nlohmann::json& summary, std::size_t i) {
  const std::string name = "rsi_bridge_" + std::to_string(i + 1);
  return summary.contains("rsi_bridges") && summary["rsi_bridges"].contains(name) ? summary["rsi_bridges"][name]
                                                                                  : nlohmann::json();
}

// Late cycles of several streams within 10 ms of each other are one stall of the machine, not of a stream: how many
// such stalls the (sent time, stream) of the late cycles make, and the streams late in them, summed.
void stalls(std::vector<std::pair<std::int64_t, std::size_t>> late_at, std::uint64_t* episodes,
            std::uint64_t* streams) {
  std::sort(late_at.begin(), late_at.end());
  for (std::size_t k = 0; k < late_at.size();) {
    std::set<std::size_t> late;
    std::size_t e = k;
    for (; e < late_at.size() && late_at[e].first - late_at[k].first < 10'000'000; ++e) late.insert(late_at[e].second);
    ++*episodes, *streams += late.size(), k = e;
  }
}

}  // namespace

class CellRsi::Impl {
 public:
  Impl(const CellConfig& cell, const CellArgs& a) : cell_(cell), a_(a), cell_time_h_(cell.robots.size()) {
    if (a.rsi_rt_priority > 0) {  // allowed here? (the controllers' threads set it themselves)
      sched_param p{};
      p.sched_priority = a.rsi_rt_priority;
      if (const int e = pthread_setschedparam(pthread_self(), SCHED_FIFO, &p); e != 0)
        throw ConfigError("--rsi-rt-priority " + std::to_string(a.rsi_rt_priority) + ": SCHED_FIFO refused (" +
                          std::strerror(e) + "): run as root or with CAP_SYS_NICE (docs/deployment.md)");
      p.sched_priority = 0;
      pthread_setschedparam(pthread_self(), SCHED_OTHER, &p);
    }
    const auto max_cycles = static_cast<std::size_t>((a.duration_s + 40) * a.rsi_hz);
    sims_.reserve(cell.robots.size());
    for (std::size_t i = 0; i < cell.robots.size(); ++i) {
      sims_.push_back(makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i)));
      RsiControllerOptions o;
      o.rate_hz = a.rsi_hz;
      ports_.push_back(freeUdpPort());
      o.bridge_port = ports_.back();
      o.rt_priority = a.rsi_rt_priority;
      o.seed = cell.simulation.seed * 97 + 7 + i;
      controllers_.push_back(std::make_unique<SimulatedRsiController>(sims_.back(), o, max_cycles));
    }
    errors_.resize(cell.robots.size());
  }

  ~Impl() { stop(); }

  void start() {
    for (std::size_t i = 0; i < controllers_.size(); ++i)
      threads_.emplace_back([this, i] {
        try {
          controllers_[i]->run(stop_, cell_time_h_[i]);
        } catch (const std::exception& e) {
          errors_[i] = e.what();
        }
      });
  }

  void setCellTimeS(std::size_t robot, double t_s) { cell_time_h_.at(robot).store(t_s / 3600.0); }
  const std::vector<int>& ports() const { return ports_; }

  void stop() {
    stop_ = true;
    for (auto& t : threads_)
      if (t.joinable()) t.join();
  }

  bool summarize(const CellJudge& judge, nlohmann::json* summary) const {
    nlohmann::json robots = nlohmann::json::array();
    std::vector<double> latency, landed, unlanded, sigma;
    std::vector<std::pair<std::int64_t, std::size_t>> late_at;  // (sent, robot) of every late cycle
    std::uint64_t cycles = 0, answered = 0, switched = 0, compared = 0;
    double max_difference = 0;
    bool equal = true;
    for (std::size_t i = 0; i < controllers_.size(); ++i) {
      const CellRobot& robot = cell_.robots[i];
      const auto& log = controllers_[i]->cycles();
      std::uint64_t c = 0, a = 0;
      for (const RsiCycleRecord& r : log) {
        if (!r.counted) continue;
        ++c;
        if (r.answered)
          ++a, latency.push_back(r.latency_us);
        else
          late_at.emplace_back(r.sent_ns, i);
      }
      const nlohmann::json bridge = bridgeStats(*summary, i);
      std::vector<std::pair<std::uint64_t, std::uint64_t>> taken;  // the cycles it took each version at
      if (bridge.is_object())
        for (const auto& t : bridge["versions_taken"])
          taken.emplace_back(t[0].get<std::uint64_t>(), t[1].get<std::uint64_t>());
      Replay rp;
      if (a_.rsi_pass_through)
        rp.stopped = "pass-through: zero corrections, nothing to replay";
      else if (bridge.is_object())
        rp = replay(cell_, robot, log, taken, judge.judge(i).calibrations, controllers_[i]->cycleMs());
      else
        rp.stopped = "the bridge wrote no stats";
      // Every packet the bridge ran was replayed (an answer lost on the way back would hide one from the log).
      if (!a_.rsi_pass_through && bridge.is_object() && rp.stopped.empty() &&
          bridge.value("packets", 0ULL) != rp.replayed)
        rp.stopped = "the bridge ran " + std::to_string(bridge.value("packets", 0ULL)) +
                     " packets, the controller saw " + std::to_string(rp.replayed) + " reach it";
      // From the first version on (none taken, or pass-through: every cycle, all uncorrected).
      const std::uint64_t from = taken.empty() ? 0 : taken.front().first;
      const LandedErrors le = landedErrors(sims_[i], log, from);
      cycles += c, answered += a, switched += taken.size(), compared += rp.compared;
      max_difference = std::max(max_difference, rp.max_difference_rad);
      equal =
          equal && rp.first_difference_ipoc == 0 && errors_[i].empty() && (rp.stopped.empty() || a_.rsi_pass_through);
      landed.insert(landed.end(), le.compensated_mm.begin(), le.compensated_mm.end());
      unlanded.insert(unlanded.end(), le.uncompensated_mm.begin(), le.uncompensated_mm.end());
      sigma.insert(sigma.end(), rp.predicted_sigma_mm.begin(), rp.predicted_sigma_mm.end());
      robots.push_back(
          {{"robot_id", robot.robot_id},
           {"cycles", c},
           {"answered", a},
           {"late", c - a},
           {"controller_error", errors_[i]},
           {"path_moves_rejected", controllers_[i]->movesRejected()},
           {"versions_switched", taken.size()},
           {"replay",
            {{"replayed", rp.replayed},
             {"compared", rp.compared},
             {"max_difference_rad", rp.max_difference_rad},
             {"first_difference_ipoc", rp.first_difference_ipoc},
             {"stopped", rp.stopped}}},
           {"landed_error_compensated_mean_mm", meanOf(le.compensated_mm)},
           {"landed_error_compensated_max_mm",
            le.compensated_mm.empty() ? std::nan("")
                                      : *std::max_element(le.compensated_mm.begin(), le.compensated_mm.end())},
           {"landed_error_uncompensated_mean_mm", meanOf(le.uncompensated_mm)},
           {"predicted_sigma_mean_mm", meanOf(rp.predicted_sigma_mm)}});
      double targets_mm = std::nan("");  // the judge's: the targets the compensation publisher corrected over DDS
      if (summary->contains("robots") && i < (*summary)["robots"].size())
        targets_mm = (*summary)["robots"][i].value("landed_error_compensated_mean_mm", std::nan(""));
      std::printf(
          "cell: %s RSI at %.0f Hz: %llu cycles, %llu answered in their cycle, %llu late or missing; %zu "
          "versions taken; the robot landed %.4f mm from the program's poses (uncorrected %.4f mm; the targets "
          "corrected over DDS %.4f mm; predicted 1-sigma %.4f mm); the answers replayed in memory differ by at "
          "most %.1e rad over %llu cycles%s%s\n",
          robot.robot_id.c_str(), a_.rsi_hz, (unsigned long long)c, (unsigned long long)a, (unsigned long long)(c - a),
          taken.size(), meanOf(le.compensated_mm), meanOf(le.uncompensated_mm), targets_mm,
          meanOf(rp.predicted_sigma_mm), rp.max_difference_rad, (unsigned long long)rp.compared,
          rp.stopped.empty() ? "" : " (replay stopped: ", rp.stopped.empty() ? "" : (rp.stopped + ")").c_str());
      if (taken.empty() && !a_.rsi_pass_through)  // nothing was corrected: say why, from the bridge's feed
        std::printf("cell: %s RSI: the bridge applied no calibration, every cycle went uncorrected: %s\n",
                    robot.robot_id.c_str(),
                    bridge.is_object() ? bridge["calibration"].value("describe", std::string("?")).c_str()
                                       : "it wrote no stats");
      if (rp.first_difference_ipoc)
        std::printf("cell: %s RSI: the bridge's answer differs from the in-memory compensator's from IPOC %llu on\n",
                    robot.robot_id.c_str(), (unsigned long long)rp.first_difference_ipoc);
      if (!errors_[i].empty()) std::printf("cell: %s RSI controller: %s\n", robot.robot_id.c_str(), errors_[i].c_str());
    }
    std::uint64_t episodes = 0, robots_in_episodes = 0;
    stalls(late_at, &episodes, &robots_in_episodes);
    if (!late_at.empty())
      std::printf(
          "cell: RSI: the %zu late cycles fell in %llu stall%s of 10 ms, %.1f of the %zu streams late in each\n",
          late_at.size(), (unsigned long long)episodes, episodes == 1 ? "" : "s",
          static_cast<double>(robots_in_episodes) / static_cast<double>(episodes), controllers_.size());
    (*summary)["rsi"] = {
        {"rate_hz", a_.rsi_hz},
        {"pass_through", a_.rsi_pass_through},
        {"late_stalls", episodes},
        {"streams_late_per_stall",
         episodes ? static_cast<double>(robots_in_episodes) / static_cast<double>(episodes) : 0.0},
        {"rt_priority", a_.rsi_rt_priority},
        {"cycles", cycles},
        {"answered", answered},
        {"late", cycles - answered},
        {"latency_us",
         {{"p50", percentile(latency, 0.5)},
          {"p99", percentile(latency, 0.99)},
          {"max", latency.empty() ? std::nan("") : *std::max_element(latency.begin(), latency.end())}}},
        {"versions_switched", switched},
        {"compared_cycles", compared},
        {"max_difference_rad", max_difference},
        {"equal_to_in_memory", equal},
        {"landed_error_compensated_mean_mm", meanOf(landed)},
        {"landed_error_uncompensated_mean_mm", meanOf(unlanded)},
        {"predicted_sigma_mean_mm", meanOf(sigma)},
        {"robots", robots}};
    return equal;
  }

 private:
  const CellConfig& cell_;
  const CellArgs& a_;
  std::vector<int> ports_;
  std::vector<SimulatedCell> sims_;  // reserved below: the controllers keep pointers
  std::vector<std::unique_ptr<SimulatedRsiController>> controllers_;
  std::vector<std::atomic<double>> cell_time_h_;
  std::vector<std::string> errors_;
  std::vector<std::thread> threads_;
  std::atomic<bool> stop_{false};
};

CellRsi::CellRsi(const CellConfig& cell, const CellArgs& a) : impl_(std::make_unique<Impl>(cell, a)) {}
CellRsi::~CellRsi() = default;
const std::vector<int>& CellRsi::ports() const { return impl_->ports(); }
void CellRsi::start() { impl_->start(); }
void CellRsi::setCellTimeS(std::size_t robot, double t_s) { impl_->setCellTimeS(robot, t_s); }
void CellRsi::stop() { impl_->stop(); }
bool CellRsi::summarize(const CellJudge& judge, nlohmann::json* summary) const {
  return impl_->summarize(judge, summary);
}

}  // namespace cellcal::cli
