#include "cellcal/components/csv_replay.hpp"

#include <algorithm>
#include <chrono>
#include <stdexcept>

namespace cellcal::components {

void addCsvReplayOptions(CLI::App& app, CsvReplayOptions& o) {
  app.add_option("--csv", o.path, "csv: measurement file (CSV v1)");
  app.add_option("--robot-id", o.robot_id, "csv: robot the file belongs to (default: the first of the cell); ros2: whose joints (default: the only one)");
  app.add_option("--period-s", o.period_s, "csv: seconds between rows without stamp_s")->capture_default_str();
  app.add_option("--rate", o.rate, "csv: replay stamp_s this many times faster")->capture_default_str();
  app.add_option("--start-unix-ns", o.start_unix_ns, "csv: wall time of the first row (same for both adapters)");
  app.add_flag("--skip-bad-rows", o.skip_bad_rows, "csv: skip (and count) bad rows instead of stopping");
}

CsvReplay loadCsvReplay(const CellConfig& cell, const CsvReplayOptions& o) {
  CsvReplay r;
  r.robot = o.robot_id.empty() ? &cell.robots.front() : cell.robotById(o.robot_id);
  if (!r.robot) throw std::runtime_error("--robot-id " + o.robot_id + ": not in " + cell.source);
  if (!(o.period_s > 0) || !(o.rate > 0)) throw std::runtime_error("--period-s and --rate must be > 0");
  MeasurementCsvOptions mo;
  mo.skip_bad_rows = o.skip_bad_rows;
  r.file = readMeasurementCsv(o.path, r.robot->model, mo);
  if (r.file.rows.empty()) throw std::runtime_error(o.path + ": no rows to replay");
  const bool stamped = std::all_of(r.file.rows.begin(), r.file.rows.end(), [](const auto& row) { return row.stamp_s.has_value(); });
  for (size_t k = 0; k < r.file.rows.size(); ++k) {
    const double t = stamped ? (*r.file.rows[k].stamp_s - *r.file.rows[0].stamp_s) / o.rate : k * o.period_s;
    if (k > 0 && !(t > r.t_s.back()))
      throw std::runtime_error(o.path + ":" + std::to_string(r.file.rows[k].line) +
                               ": stamp_s does not increase (rows are replayed in time order)");
    r.t_s.push_back(t);
  }
  double spacing = 1e9;
  for (size_t k = 1; k < r.t_s.size(); ++k) spacing = std::min(spacing, r.t_s[k] - r.t_s[k - 1]);
  r.hold_s = std::min(0.5, 0.25 * (r.t_s.size() > 1 ? spacing : 1.0));
  r.start_unix_ns = o.start_unix_ns;
  if (r.start_unix_ns == 0) {
    const std::int64_t now = std::chrono::duration_cast<std::chrono::nanoseconds>(
                                 std::chrono::system_clock::now().time_since_epoch()).count();
    r.start_unix_ns = (now / 1'000'000'000 + 2) * 1'000'000'000;
  }
  return r;
}

}  // namespace cellcal::components
