// Subcommands of the `cellcal` tool. Each registers itself on the CLI11 app and runs when selected.
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace cellcal::cli {

using Runner = std::function<int()>;

// Adds `experiment paper` under `app`; returns the function to run when it is selected.
// For options naming a file to write (--out, --json, --save-robot): makes its folder when missing, so a command runs
// as written on a fresh clone; a folder that cannot be made is a usage error naming it.
const CLI::Validator& outputFile();
// Numbers a quantity must be: "> 0" and ">= 0", said as "must be > 0, got -5" (CLI11's own ranges print 300 digits).
const CLI::Validator& positive();
const CLI::Validator& nonNegative();

Runner addExperimentCommand(CLI::App& app);
// Adds `cell` (the four-process cell on localhost).
Runner addCellCommand(CLI::App& app);
// Adds `bench-cell` (latency and load through real processes).
Runner addBenchCellCommand(CLI::App& app);
// Adds `bench-servo` (the RSI bridge against simulated controllers, through real processes).
Runner addBenchServoCommand(CLI::App& app);
// Adds `calibrate` (batch calibration of a measurement file).
Runner addCalibrateCommand(CLI::App& app);
// Adds `import ipa` (the ipa UR10 series to CSV v1) and `import csv` (CSV v1 to a recording).
Runner addImportCommand(CLI::App& app);
// Adds `diagnose` (model diagnosis of a measurement file).
Runner addDiagnoseCommand(CLI::App& app);
// Recordings of a cell (MCAP): `record`, `replay`, `validate` against a recording, `export` to CSV.
Runner addRecordCommand(CLI::App& app);
Runner addReplayCommand(CLI::App& app);
Runner addValidateCommand(CLI::App& app);
Runner addExportCommand(CLI::App& app);
// cmd_continuous.cpp
Runner addContinuousCommand(CLI::App& app);
// cmd_status.cpp: the cell at a glance (--watch: live).
Runner addStatusCommand(CLI::App& app);
// cmd_foxglove.cpp: the live cell over the Foxglove WebSocket protocol.
Runner addFoxgloveCommand(CLI::App& app);
// cmd_robot.cpp: `robot import` (a URDF as a robot file) and `robot export` (URDF, UR kinematics YAML, DH table).
Runner addRobotCommand(CLI::App& app);
// `robot check` and `robot fk` under `robot` (cmd_robot_check.cpp); the runners are `robot`'s to call when given.
Runner addRobotCheck(CLI::App& robot);
Runner addRobotFk(CLI::App& robot);
// cmd_iso9283.cpp: ISO 9283 pose and distance figures of a measured test.
Runner addIso9283Command(CLI::App& app);
// cmd_plan.cpp: `plan iso9283` (the standard's test program).
Runner addPlanCommand(CLI::App& app);

// Writes a gnuplot script and data next to each other in dir and renders it to <dir>/<name>.<format> (png or svg);
// the script sees the data file as `datafile`. Returns false with a message in *error when gnuplot is missing or fails.
bool renderGnuplot(const std::string& dir, const std::string& name, const std::string& data,
                   const std::string& script, std::string* error, const std::string& format = "png");

std::string defaultRobotFile(const std::string& name);

// A subcommand of parent described by its man page, docs/man/cellcal-<name>.txt (cellcal-<parent>-<name>.txt under a
// command group such as import): its first paragraph above the options in --help, the rest (EXAMPLES, FILES, EXIT
// STATUS, SEE ALSO) below them.
CLI::App* addSubcommand(CLI::App& parent, const std::string& name);

// Adds subcommand `name` (addSubcommand) whose options `options` declares into one Args value; returns the function
// that runs it on those values, called when the subcommand is selected.
template <class Args>
Runner addCommand(CLI::App& parent, const std::string& name, void (*options)(CLI::App&, Args&),
                  int (*run)(const Args&)) {
  auto args = std::make_shared<Args>();
  options(*addSubcommand(parent, name), *args);
  return [args, run] { return run(*args); };
}

}  // namespace cellcal::cli
