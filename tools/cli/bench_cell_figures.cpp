// `cellcal bench-cell`: the figures from what the bench received, its samples and the recorder's counts.
#include <algorithm>
#include <cstdio>
#include <fstream>

#include "bench_cell.hpp"

namespace cellcal::cli::bench_cell {

BenchLatencies latencies(const BenchReceived& rx) {
  BenchLatencies l;
  std::map<std::string, std::uint64_t> last_version;
  for (const auto& s : rx.states) {
    if (s.version <= last_version[s.robot] || s.stamp == 0) continue;
    last_version[s.robot] = s.version;
    l.state_us.push_back((s.at - s.stamp) / 1e3);
  }
  for (size_t i = 0; i < l.state_us.size(); ++i) {
    if (i < l.state_us.size() / 3) l.first_third.push_back(l.state_us[i]);
    if (i >= 2 * l.state_us.size() / 3) l.last_third.push_back(l.state_us[i]);
  }
  for (const auto& [at, sq] : rx.comps)
    if (auto it = rx.target_sent.find(sq); it != rx.target_sent.end()) l.comp_us.push_back((at - it->second) / 1e3);
  for (const auto& [r, v] : last_version) l.versions += v;
  return l;
}

// Soak figures: memory and error at the end of the first third of the run (warm-up done) and at its end.
nlohmann::json soakFigures(const BenchPlayed& played, double uncalibrated_mm, std::uint64_t bad_states,
                           const BenchSample** third_out) {
  const auto& series = played.series;
  const double wall = played.wall_s;
  const BenchSample& third = *std::min_element(series.begin(), series.end(), [&](const BenchSample& x, const BenchSample& y) {
    return std::abs(x.t_s - wall / 3) < std::abs(y.t_s - wall / 3);
  });
  *third_out = &third;
  const BenchSample& end = series.back();
  const double minutes = std::max(1e-9, (end.t_s - third.t_s) / 60.0);
  return {{"uncalibrated_error_mm", uncalibrated_mm},
          {"error_mm_first_third", third.error_mm},
          {"error_mm_end", end.error_mm},
          {"bad_calibration_states", bad_states},
          {"rss_mb_first_third", {{"engine", third.engine_rss_mb}, {"compensation_publisher", third.compensation_rss_mb}, {"bench_publisher", third.publisher_rss_mb}}},
          {"rss_mb_end", {{"engine", end.engine_rss_mb}, {"compensation_publisher", end.compensation_rss_mb}, {"bench_publisher", end.publisher_rss_mb}}},
          {"rss_growth_mb_per_min_after_first_third",
           {{"engine", (end.engine_rss_mb - third.engine_rss_mb) / minutes},
            {"compensation_publisher", (end.compensation_rss_mb - third.compensation_rss_mb) / minutes},
            {"bench_publisher", (end.publisher_rss_mb - third.publisher_rss_mb) / minutes}}},
          {"minutes_compared", minutes}};
}

void writeSeriesCsv(const std::string& path, const std::vector<BenchSample>& series) {
  if (path.empty()) return;
  std::ofstream csv(path);
  if (!csv) throw std::runtime_error(path + ": cannot be written");
  csv << "t_s,engine_rss_mb,compensation_rss_mb,bench_publisher_rss_mb,mean_error_mm\n";
  for (const auto& x : series)
    csv << x.t_s << ',' << x.engine_rss_mb << ',' << x.compensation_rss_mb << ',' << x.publisher_rss_mb << ','
        << x.error_mm << '\n';
}

// The recorder's counts (record.json) against what was published; adds them to out.
void reportRecorder(const fs::path& dir, const BenchArgs& a, std::uint64_t published, double cpu, double rss,
                    nlohmann::json* out) {
  const auto rj = nlohmann::json::parse(std::ifstream((dir / "record.json").string()), nullptr, false);
  if (rj.is_discarded()) throw std::runtime_error("the recorder wrote no counts (see " + (dir / "record.log").string() + ")");
  const std::uint64_t rec_js = rj["topics"]["cellcal/joint_state"].value("received", 0ULL);
  const std::uint64_t rec_tp = rj["topics"]["cellcal/tracker_pose"].value("received", 0ULL);
  std::printf("recorder: %llu messages to %s; joint states %llu of %llu, tracker readings %llu of %llu; %llu lost "
              "(writer sequence gaps); CPU %.2f of a core, peak RSS %.1f MB\n",
              static_cast<unsigned long long>(rj.value("messages", 0ULL)), a.record.c_str(),
              static_cast<unsigned long long>(rec_js), static_cast<unsigned long long>(published),
              static_cast<unsigned long long>(rec_tp), static_cast<unsigned long long>(published),
              static_cast<unsigned long long>(rj.value("lost", 0ULL)), cpu, rss);
  (*out)["recorder"] = {{"messages", rj["messages"]}, {"joint_states_received", rec_js}, {"tracker_readings_received", rec_tp},
                        {"lost", rj["lost"]}, {"cpu_share_of_one_core", cpu}, {"peak_rss_mb", rss}};
}

}  // namespace cellcal::cli::bench_cell
