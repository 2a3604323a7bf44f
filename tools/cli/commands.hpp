// Subcommands of the `cellcal` tool. Each registers itself on the CLI11 app and runs when selected.
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

namespace cellcal::cli {

using Runner = std::function<int()>;

// Adds `experiment paper` under `app`; returns the function to run when it is selected.
Runner addExperimentCommand(CLI::App& app);
// Adds `cell` (the four-process cell on localhost).
Runner addCellCommand(CLI::App& app);
// Adds `bench-cell` (latency and load through real processes).
Runner addBenchCellCommand(CLI::App& app);
// Adds `calibrate` (batch calibration of a measurement file) and `import ipa`.
Runner addCalibrateCommand(CLI::App& app);
Runner addImportCommand(CLI::App& app);
// Adds `diagnose` (model diagnosis of a measurement file).
Runner addDiagnoseCommand(CLI::App& app);
// Adds `record`, `replay`, `validate` and `export` (recordings of a cell, MCAP).
Runner addRecordingCommands(CLI::App& app);
// `import csv`: a measurement file (CSV v1) as a recording: per row, the robot settled bracket_s before and after
// the reading (two JointStates) and the TrackerPose at the row's time.
struct ImportCsvArgs {
  std::string csv, robot_file, out, robot_id, target_id;
  double start_unix_s = 1.7e9;  // stamp_s = 0 (or the first row) at this Unix time
  double period_s = 30;         // rows without stamp_s: this far apart
  double bracket_s = 0.01;
  double sigma_position_mm = 0.025, sigma_orientation_deg = 0.01;
  bool skip_bad_rows = false;
};
int importCsvToRecording(const ImportCsvArgs& args);
// cmd_continuous.cpp
Runner addContinuousCommand(CLI::App& app);
// cmd_status.cpp: the cell at a glance (--watch: live).
Runner addStatusCommand(CLI::App& app);

// Writes a gnuplot script and data next to each other in dir and renders it to <dir>/<name>.<format> (png or svg);
// the script sees the data file as `datafile`. Returns false with a message in *error when gnuplot is missing or fails.
bool renderGnuplot(const std::string& dir, const std::string& name, const std::string& data,
                   const std::string& script, std::string* error, const std::string& format = "png");

std::string defaultRobotFile(const std::string& name);

// The man-page part of a command's --help: EXAMPLES and FILES as given, then EXIT STATUS and SEE ALSO.
std::string cliFooter(const std::string& examples, const std::string& files, const std::string& exit_extra = "");

// The p-quantile (0..1) of v by rank (element floor(p n)); NaN when empty.
double percentile(std::vector<double> v, double p);

}  // namespace cellcal::cli
