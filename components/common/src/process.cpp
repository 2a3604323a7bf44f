#include <unistd.h>
#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/process.hpp"

#include <algorithm>
#include <cctype>
#include <atomic>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <stdexcept>
#include <thread>

namespace cellcal::components {
namespace detail {
extern const std::map<std::string, std::string> kManPages;  // man_pages.cpp, generated from docs/man/*.txt
}  // namespace detail
namespace {
std::atomic<bool> g_stop{false};
extern "C" void onSignal(int) { g_stop = true; }
}  // namespace

std::string configDir() {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const std::filesystem::path installed = exe.parent_path().parent_path() / "share" / "cellcal" / "config";
    if (std::filesystem::is_regular_file(installed / "cell.yaml")) return installed.string();
  }
  return CELLCAL_CONFIG_DIR;
}

void addCommonOptions(CLI::App& app, ProcessOptions& o) {
  o.config_path = configDir() + "/cell.yaml";
  app.add_option("-c,--config", o.config_path, "cell file (YAML)")->capture_default_str();
  app.add_option("--domain-id", o.domain_id, "DDS domain id 0..232 (overrides the cell file and CELLCAL_DOMAIN_ID)")
      ->check(CLI::Range(0, 232));
  app.add_option("--dds-profile", o.participant_profile,
                 "participant profile of the profiles file: cellcal, cellcal_udp, cellcal_loopback "
                 "(overrides the cell file and CELLCAL_DDS_PROFILE)");
  app.add_option("--stats-json", o.stats_json, "write what this process published and received to this file at exit");
  app.add_option("--robots", o.robots,
                 "serve only these robots of the cell file, comma-separated (a shard of a large cell: other processes "
                 "serve the others; this one's readers take only these robots' samples)")
      ->delimiter(',');
}

ManPage manPage(const std::string& name) {
  const auto it = detail::kManPages.find(name);
  if (it == detail::kManPages.end()) throw std::logic_error("no man page docs/man/" + name + ".txt in this build");
  const std::string& text = it->second;
  const auto blank = text.find("\n\n");
  ManPage page;
  page.description = text.substr(0, blank);
  std::replace(page.description.begin(), page.description.end(), '\n', ' ');
  page.footer = blank == std::string::npos ? "" : "\n" + text.substr(blank + 2);
  const std::string key = "{config_dir}";
  for (auto at = page.footer.find(key); at != std::string::npos; at = page.footer.find(key, at))
    page.footer.replace(at, key.size(), configDir());
  return page;
}

void applyManPage(CLI::App& app, const std::string& name) {
  const ManPage page = manPage(name);
  app.description(page.description);
  app.footer(page.footer);
}

CellConfig loadCell(const ProcessOptions& o) {
  CellConfig c = loadCellConfig(o.config_path);
  if (const char* env = std::getenv("CELLCAL_DOMAIN_ID"); env && *env) {
    char* end = nullptr;
    const long v = std::strtol(env, &end, 10);
    if (*end || v < 0 || v > 232) throw std::runtime_error(std::string("CELLCAL_DOMAIN_ID='") + env + "': expected 0..232");
    c.dds.domain_id = static_cast<int>(v);
  }
  if (const char* env = std::getenv("CELLCAL_DDS_PROFILE"); env && *env) c.dds.participant_profile = env;
  if (const char* env = std::getenv("CELLCAL_SECURITY_DIR"); env && *env)
    c.dds.security_dir = std::filesystem::absolute(env).string();
  if (o.domain_id) c.dds.domain_id = *o.domain_id;
  if (!o.participant_profile.empty()) c.dds.participant_profile = o.participant_profile;
  if (!o.state_dir.empty()) c.engine.state_dir = std::filesystem::absolute(o.state_dir).string();
  if (!o.robots.empty()) {
    std::vector<CellRobot> kept;
    for (const auto& id : o.robots) {
      auto it = std::find_if(c.robots.begin(), c.robots.end(), [&](const CellRobot& r) { return r.robot_id == id; });
      if (it == c.robots.end()) {
        std::string known;
        for (const auto& r : c.robots) known += (known.empty() ? "" : ", ") + r.robot_id;
        throw ConfigError("--robots: '" + id + "' is not a robot of " + c.source + " (its robots: " + known + ")");
      }
      if (std::any_of(kept.begin(), kept.end(), [&](const CellRobot& r) { return r.robot_id == id; }))
        throw ConfigError("--robots: '" + id + "' is named twice");
      kept.push_back(*it);
      c.dds.shard_robot_ids.push_back(it->robot_id);
      c.dds.shard_target_ids.push_back(it->target_id);
    }
    c.robots = std::move(kept);
  }
  return c;
}

void installStopHandlers() {
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
}
bool stopRequested() { return g_stop.load(); }
void requestStop() { g_stop = true; }

bool sleepUntil(std::chrono::steady_clock::time_point until) {
  while (!g_stop.load()) {
    const auto now = std::chrono::steady_clock::now();
    if (now >= until) return true;
    std::this_thread::sleep_for(std::min<std::chrono::steady_clock::duration>(until - now, std::chrono::milliseconds(50)));
  }
  return false;
}

void writeJsonFile(const std::string& path, const nlohmann::json& j) {
  if (path.empty()) return;
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    if (!out) throw std::runtime_error(path + ": cannot write");
    out << j.dump(2) << "\n";
  }
  std::filesystem::rename(tmp, path);
}

namespace stats {
void writeProcessStats(const std::string& path, const std::string& name, const nlohmann::json& topics,
                       const nlohmann::json& extra, const nlohmann::json& more) {
  nlohmann::json j = {{kName, name}, {kPid, ::getpid()}, {kTopics, topics}, {kExtra, extra}};
  j.update(more);
  writeJsonFile(path, j);
}
}  // namespace stats

std::string maskFigures(const std::string& text) {
  std::string out;
  for (char ch : text) {
    if (std::isdigit(static_cast<unsigned char>(ch)) || ch == '.') {
      if (out.empty() || out.back() != '#') out += '#';
    } else {
      out += ch;
    }
  }
  return out;
}

int usageExit(CLI::App& app, const CLI::ParseError& e) { return app.exit(e) == 0 ? 0 : 2; }

int runMain(const char* program, int argc, char** argv, CLI::App& app, const std::function<int()>& body) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return usageExit(app, e);
  }
  try {
    installStopHandlers();
    return body();
  } catch (const ConfigError& e) {  // a bad cell or robot file, or an option naming what is not in it
    std::cerr << program << ": error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << program << ": error: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace cellcal::components
