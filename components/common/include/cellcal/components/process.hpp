// What every cellcal process shares: the common command line, the cell file with its overrides, clean stop on
// SIGINT/SIGTERM, the wall clock, and the exit summary.
//
// Overrides, strongest last: cell file < environment (CELLCAL_DOMAIN_ID, CELLCAL_DDS_PROFILE, CELLCAL_SECURITY_DIR)
// < command line.
#pragma once

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "cellcal/core/files/cell_config.hpp"

namespace cellcal::components {

struct ProcessOptions {
  std::string config_path;
  std::optional<int> domain_id;
  std::string participant_profile;
  std::string stats_json;     // written at exit: what this process published/received, its own counters
  std::string state_dir;      // engine only
  std::vector<std::string> robots;  // --robots: serve only these robots of the cell file (a shard); empty: all
};

// The shipped configuration (cell.yaml, robots/, dds/, security/): <prefix>/share/cellcal/config next to an
// installed binary (<prefix>/bin), else the source tree's config/ the build came from.
std::string configDir();

void addCommonOptions(CLI::App& app, ProcessOptions& o);

// A command's man page: docs/man/<name>.txt (e.g. cellcal_tracker_adapter, cellcal-diagnose), built into the
// binaries. Its first paragraph (lines joined by spaces) is the description --help shows above the options; the rest
// (TOPICS, EXAMPLES, FILES, EXIT STATUS, ...) the footer below them, with {config_dir} replaced by configDir().
// Throws std::logic_error when no page of that name was built in: a programming error, which the test that runs
// every command's --help catches.
struct ManPage {
  std::string description;
  std::string footer;
};
ManPage manPage(const std::string& name);
// Sets app's description and footer from manPage(name).
void applyManPage(CLI::App& app, const std::string& name);
CellConfig loadCell(const ProcessOptions& o);

void installStopHandlers();
bool stopRequested();
void requestStop();
// Sleeps until `until` (steady clock) or a stop request; false when stopped.
bool sleepUntil(std::chrono::steady_clock::time_point until);

// A process's --duration-s from the moment it is made (0: no limit). over(): the time is up or a stop was requested.
class RunLimit {
 public:
  explicit RunLimit(double duration_s) : duration_s_(duration_s), start_(std::chrono::steady_clock::now()) {}
  bool timeUp() const {
    return duration_s_ > 0 &&
           std::chrono::steady_clock::now() - start_ >= std::chrono::duration<double>(duration_s_);
  }
  bool over() const { return stopRequested() || timeUp(); }

 private:
  double duration_s_;
  std::chrono::steady_clock::time_point start_;
};

inline std::int64_t wallNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// `text` with each run of figures (digits, decimal points) as one '#': "nothing for 4.1 s" and "nothing for 5.2 s"
// read alike (a message said once per change, not per figure; reasons counted by kind).
std::string maskFigures(const std::string& text);

// Writes `j` to `path` (if not empty) through a temporary file and rename.
void writeJsonFile(const std::string& path, const nlohmann::json& j);

// A usage error's exit: CLI11's message, then 0 for --help / --version and 2 for every usage error (CLI11's own
// codes, 105, 106, ..., are not the documented ones).
int usageExit(CLI::App& app, const CLI::ParseError& e);

// Runs `body` and turns exceptions into "<program>: error: <message>" on stderr and exit code 1 (2 for usage).
int runMain(const char* program, int argc, char** argv, CLI::App& app, const std::function<int()>& body);

// A component's main(): the app with the man page named `program` (docs/man/<program>.txt), the options `add`
// declares on it, then Process(options).run() under runMain.
template <class Process>
int componentMain(const char* program, int argc, char** argv,
                  const std::function<void(CLI::App&, typename Process::Options&)>& add) {
  CLI::App app;
  applyManPage(app, program);
  typename Process::Options options;
  add(app, options);
  return runMain(program, argc, argv, app, [&] { return Process(options).run(); });
}

}  // namespace cellcal::components
