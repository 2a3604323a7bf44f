// cellcal: command-line entry point. Subcommands live in cmd_*.cpp.
#include <algorithm>
#include <cmath>
#include <iostream>

#include "cellcal/components/process.hpp"
#include "cellcal/core/robot_yaml.hpp"
#include "commands.hpp"

namespace cellcal::cli {
std::string defaultRobotFile(const std::string& name) { return components::configDir() + "/robots/" + name; }

std::string cliFooter(const std::string& examples, const std::string& files, const std::string& exit_extra) {
  return "\nEXAMPLES\n" + examples + (files.empty() ? "" : "\nFILES\n" + files) +
         "\nEXIT STATUS\n  0 success; 1 a runtime error; 2 a usage error or a bad input file (the message names the "
         "file, line and field)" + exit_extra + ".\n\nSEE ALSO\n  README.md; docs/ (file formats, diagnosis, recording, "
         "reliability, security, deployment, figures)\n";
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}
}  // namespace cellcal::cli

int main(int argc, char** argv) {
  CLI::App app{
      "cellcal: continuous kinematic calibration for DDS robot cells.\n"
      "Identifies the kinematic parameter errors of a robot from laser-tracker poses with recursive least squares\n"
      "and compensates targets with the identified model. See README.md."};
  app.require_subcommand(1);
  auto experiment = cellcal::cli::addExperimentCommand(app);
  auto cell = cellcal::cli::addCellCommand(app);
  auto bench_cell = cellcal::cli::addBenchCellCommand(app);
  auto calibrate = cellcal::cli::addCalibrateCommand(app);
  auto import_ = cellcal::cli::addImportCommand(app);
  auto diagnose = cellcal::cli::addDiagnoseCommand(app);
  auto continuous = cellcal::cli::addContinuousCommand(app);
  auto recording = cellcal::cli::addRecordingCommands(app);
  auto status = cellcal::cli::addStatusCommand(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  try {
    if (app.got_subcommand("cell")) return cell();
    if (app.got_subcommand("bench-cell")) return bench_cell();
    if (app.got_subcommand("calibrate")) return calibrate();
    if (app.got_subcommand("import")) return import_();
    if (app.got_subcommand("diagnose")) return diagnose();
    if (app.got_subcommand("continuous")) return continuous();
    if (app.got_subcommand("status")) return status();
    for (const char* c : {"record", "replay", "validate", "export"})
      if (app.got_subcommand(c)) return recording();
    return experiment();
  } catch (const cellcal::ConfigError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
