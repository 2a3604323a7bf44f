// Replaying a measurement file (CSV v1, core/measurement_csv.hpp) through the two adapters, as if the robot visited
// its rows: row k happens at start + t_k, with t_k = (stamp_s_k - stamp_s_0) / rate when every row has stamp_s,
// else k * period_s. The joint-state adapter holds the robot settled at q_k for hold_s on either side of t_k and
// moves (not settled) in between; the tracker adapter publishes row k's reading stamped exactly start + t_k.
// Both processes must be given the same --start-unix-ns (the default, the next whole second + 1 s, only agrees
// when they start within the same second).
#pragma once

#include <CLI/CLI.hpp>
#include <cstdint>
#include <string>
#include <vector>

#include "cellcal/core/files/cell_config.hpp"
#include "cellcal/core/files/measurement_csv.hpp"

namespace cellcal::components {

struct CsvReplayOptions {
  std::string path;
  std::string robot_id;          // empty: the first robot of the cell file
  double period_s = 0.2;         // between rows without stamps
  double rate = 1.0;             // stamps replayed this many times faster
  bool skip_bad_rows = false;
  std::int64_t start_unix_ns = 0;  // 0: next whole second + 1 s
};

struct CsvReplay {
  const CellRobot* robot = nullptr;
  MeasurementFile file;
  std::vector<double> t_s;       // offset of each row from the start
  double hold_s = 0;
  std::int64_t start_unix_ns = 0;
};

// --csv, --robot-id, --period-s, --rate, --start-unix-ns, --skip-bad-rows (the same in both adapters).
void addCsvReplayOptions(CLI::App& app, CsvReplayOptions& o);

// Throws ConfigError / std::runtime_error naming the file and line on bad input.
CsvReplay loadCsvReplay(const CellConfig& cell, const CsvReplayOptions& options);

}  // namespace cellcal::components
