// Subcommands of the `cellcal` tool. Each registers itself on the CLI11 app and runs when selected.
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <string>

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
// cmd_continuous.cpp
Runner addContinuousCommand(CLI::App& app);

// Writes a gnuplot script and data next to each other in dir and renders it to <dir>/<name>.png.
// Returns false with a message in *error when gnuplot is missing or fails.
bool renderGnuplot(const std::string& dir, const std::string& name, const std::string& data,
                   const std::string& script, std::string* error);

std::string defaultRobotFile(const std::string& name);

}  // namespace cellcal::cli
