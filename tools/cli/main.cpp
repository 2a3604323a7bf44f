// cellcal: command-line entry point. Subcommands live in cmd_*.cpp.
#include <algorithm>
#include <cmath>
#include <cstdlib>
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

namespace {
// Levenshtein distance: the fewest single-character edits from a to b.
std::size_t editDistance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diag = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diag = up;
    }
  }
  return row[b.size()];
}

CLI::Validator numberAtLeast(double lowest, bool strict) {
  return CLI::Validator(
      [lowest, strict](std::string& text) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (end == text.c_str() || *end != '\0' || !std::isfinite(v)) return "expected a number, got '" + text + "'";
        if (strict ? v > lowest : v >= lowest) return "";
        return std::string("must be ") + (strict ? "> " : ">= ") + "0, got " + text;
      },
      strict ? "> 0" : ">= 0", "");
}
}  // namespace

const CLI::Validator& positive() {
  static const CLI::Validator v = numberAtLeast(0.0, true);
  return v;
}

const CLI::Validator& nonNegative() {
  static const CLI::Validator v = numberAtLeast(0.0, false);
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
      {"bench-cell", addBenchCellCommand(app)},  {"bench-servo", addBenchServoCommand(app)},
      {"calibrate", addCalibrateCommand(app)},
      {"import", addImportCommand(app)},         {"diagnose", addDiagnoseCommand(app)},
      {"continuous", addContinuousCommand(app)}, {"record", addRecordCommand(app)},
      {"replay", addReplayCommand(app)},         {"validate", addValidateCommand(app)},
      {"export", addExportCommand(app)},         {"status", addStatusCommand(app)},
      {"foxglove", addFoxgloveCommand(app)},     {"robot", addRobotCommand(app)},
      {"plan", addPlanCommand(app)},             {"iso9283", addIso9283Command(app)}};
  // A mistyped command: named, with the nearest one (CLI11 alone says only "A subcommand is required").
  if (argc >= 2 && argv[1][0] != '-') {
    const std::string given = argv[1];
    std::string nearest, all;
    std::size_t best = std::string::npos;
    for (const auto& [name, run] : commands) {
      all += (all.empty() ? "" : ", ") + name;
      if (name == given) {
        best = 0;
        break;
      }
      const std::size_t d = editDistance(given, name);
      if (d < best) {
        best = d;
        nearest = name;
      }
    }
    if (best != 0) {
      std::cerr << "cellcal: '" << given << "' is not a command"
                << (best <= 3 ? "; did you mean '" + nearest + "'?" : std::string()) << " (commands: " << all
                << "; cellcal --help)\n";
      return 2;
    }
  }
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
