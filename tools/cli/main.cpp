// cellcal: command-line entry point. Subcommands live in cmd_*.cpp.
#include <filesystem>
#include <iostream>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/components/process.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "commands.hpp"

namespace cellcal::cli {
const CLI::Validator& outputFile() {
  static const CLI::Validator v(
      [](std::string& path) -> std::string {
        const std::filesystem::path dir = std::filesystem::path(path).parent_path();
        if (dir.empty()) return "";
        std::error_code ec;
        std::filesystem::create_directories(dir, ec);
        return ec ? "cannot make the folder " + dir.string() + ": " + ec.message() : "";
      },
      "", "");
  return v;
}

std::string defaultRobotFile(const std::string& name) { return components::configDir() + "/robots/" + name; }

CLI::App* addSubcommand(CLI::App& parent, const std::string& name) {
  const std::string page = "cellcal-" + (parent.get_parent() ? parent.get_name() + "-" : std::string()) + name;
  CLI::App* c = parent.add_subcommand(name);
  components::applyManPage(*c, page);
  return c;
}

}  // namespace cellcal::cli

int main(int argc, char** argv) {
  CLI::App app{
      "cellcal: continuous kinematic calibration for DDS robot cells.\n"
      "Identifies the kinematic parameter errors of a robot from laser-tracker poses with recursive least squares\n"
      "and compensates targets with the identified model. See README.md."};
  app.require_subcommand(1);
  using namespace cellcal::cli;
  // In the order of `cellcal --help`.
  const std::vector<std::pair<std::string, Runner>> commands = {
      {"experiment", addExperimentCommand(app)}, {"cell", addCellCommand(app)},
      {"bench-cell", addBenchCellCommand(app)},  {"calibrate", addCalibrateCommand(app)},
      {"import", addImportCommand(app)},         {"diagnose", addDiagnoseCommand(app)},
      {"continuous", addContinuousCommand(app)}, {"record", addRecordCommand(app)},
      {"replay", addReplayCommand(app)},         {"validate", addValidateCommand(app)},
      {"export", addExportCommand(app)},         {"status", addStatusCommand(app)},
      {"foxglove", addFoxgloveCommand(app)}};
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return cellcal::components::usageExit(app, e);
  }
  try {
    for (const auto& [name, run] : commands)
      if (app.got_subcommand(name)) return run();
    return 2;  // unreachable: require_subcommand(1)
  } catch (const cellcal::ConfigError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
