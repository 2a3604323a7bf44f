// Deployment files, checked as far as a machine without a Docker engine or systemd can: docker/docker-compose.yml,
// docker/Dockerfile and config/systemd/*. Every binary they start exists in the build and knows every option they
// pass (its --help lists it); every file they name exists; the Dockerfile builds with the same scripts as `make`;
// its runtime stage installs the package of every shared library the binaries load.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>

#include "cellcal/core/files/cell_config.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;

const fs::path kRepo = fs::path(CELLCAL_CONFIG_DIR).parent_path();
const std::vector<std::string> kComponents = {"cellcal_tracker_adapter", "cellcal_joint_state_adapter",
                                              "cellcal_calibration_engine", "cellcal_compensation_publisher"};

std::string capture(const std::string& command) {
  std::string out;
  FILE* f = ::popen(command.c_str(), "r");
  if (!f) return out;
  char buf[4096];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) out.append(buf, n);
  ::pclose(f);
  return out;
}

// A command line as a process would run it: the binary exists in the build, and its --help names every option.
void expectRunnable(const std::vector<std::string>& argv, const std::string& where) {
  ASSERT_FALSE(argv.empty()) << where;
  const fs::path bin = fs::path(CELLCAL_BIN_DIR) / fs::path(argv[0]).filename();
  ASSERT_TRUE(fs::exists(bin)) << where << ": " << argv[0] << " is not a binary of the build";
  const std::string help = capture(bin.string() + " --help 2>&1");
  for (const auto& a : argv) {
    if (a.rfind("--", 0) == 0) {
      EXPECT_NE(help.find(a), std::string::npos) << where << ": " << argv[0] << " has no option " << a;
    }
  }
}

std::vector<std::string> split(const std::string& s) {
  std::istringstream in(s);
  std::vector<std::string> out;
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

// The cell file of the containers, with the image's install prefix mapped back to this repository's config/.
void expectContainerCellFileLoads(const fs::path& cell_file) {
  std::string text = test::readTextFile(cell_file);
  ASSERT_FALSE(text.empty()) << cell_file;
  text = std::regex_replace(text, std::regex("/usr/local/share/cellcal/config"), std::string(CELLCAL_CONFIG_DIR));
  const CellConfig c = parseCellConfig(text, cell_file.string(), cell_file.parent_path().string());
  EXPECT_FALSE(c.robots.empty());
  EXPECT_EQ(c.engine.state_dir, "/var/lib/cellcal");
}

TEST(Deployment, ComposeStartsTheFourComponentsTheWayFastDdsNeeds) {
  const fs::path compose = kRepo / "docker" / "docker-compose.yml";
  YAML::Node root;
  ASSERT_NO_THROW(root = YAML::LoadFile(compose.string())) << compose;
  const YAML::Node services = root["services"];
  ASSERT_TRUE(services.IsMap()) << compose << ": no services";
  std::set<std::string> started;
  for (const auto& kv : services) {
    const std::string name = kv.first.as<std::string>();
    const YAML::Node s = kv.second;
    // Keys come from the x-cellcal anchor through the merge key "<<".
    auto key = [&](const std::string& k) {
      if (s[k]) return s[k];
      return s["<<"] ? s["<<"][k] : YAML::Node();
    };
    EXPECT_EQ(key("network_mode").as<std::string>(""), "host") << name;
    EXPECT_EQ(key("ipc").as<std::string>(""), "host") << name;
    EXPECT_EQ(key("user").as<std::string>(""), "1000:1000") << name;
    EXPECT_EQ(key("build")["dockerfile"].as<std::string>(""), "docker/Dockerfile") << name;
    EXPECT_TRUE(fs::exists(compose.parent_path() / key("build")["context"].as<std::string>("") / "docker/Dockerfile"))
        << name;
    std::vector<std::string> argv;
    for (const auto& a : key("command")) {
      std::string v = a.as<std::string>();
      v = std::regex_replace(v, std::regex(R"(\$\{CELLCAL_SOURCE:-sim\})"), "sim");
      argv.push_back(v);
    }
    expectRunnable(argv, compose.string() + ": " + name);
    started.insert(fs::path(argv.at(0)).filename().string());
    // Volumes: host folders exist; the engine's state is a named volume.
    std::map<std::string, std::string> mounted;  // container path -> host side
    for (const auto& v : key("volumes")) {
      const std::string spec = v.as<std::string>();
      const auto c1 = spec.find(':');
      const std::string host = spec.substr(0, c1), rest = spec.substr(c1 + 1);
      const std::string container = rest.substr(0, rest.find(':'));
      mounted[container] = host;
      if (host.rfind("./", 0) == 0) EXPECT_TRUE(fs::is_directory(compose.parent_path() / host)) << name << ": " << host;
      else EXPECT_TRUE(root["volumes"][host]) << name << ": volume " << host << " is not declared";
    }
    for (size_t i = 0; i + 1 < argv.size(); ++i) {
      if (argv[i] == "--config") {
        const fs::path p(argv[i + 1]);
        ASSERT_TRUE(mounted.count(p.parent_path().string())) << name << ": " << p << " is not on a mounted volume";
        const fs::path host = compose.parent_path() / mounted[p.parent_path().string()] / p.filename();
        ASSERT_TRUE(fs::exists(host)) << name << ": " << host;
        expectContainerCellFileLoads(host);
      }
      if (argv[i] == "--state-dir") {
        EXPECT_TRUE(mounted.count(argv[i + 1])) << name << ": state not on a volume";
      }
    }
  }
  EXPECT_EQ(started, std::set<std::string>(kComponents.begin(), kComponents.end()));
}

TEST(Deployment, DockerfileBuildsWithMakesScriptsAndShipsEveryLibrary) {
  const std::string dockerfile = test::readTextFile(kRepo / "docker" / "Dockerfile");
  const std::string makefile = test::readTextFile(kRepo / "Makefile");
  ASSERT_FALSE(dockerfile.empty());
  // One way to build: the scripts `make deps` and `make install` run.
  for (const char* script : {"tools/install_deps.sh", "tools/build_install.sh"}) {
    EXPECT_NE(dockerfile.find(std::string("RUN bash ") + script), std::string::npos) << script;
    EXPECT_NE(makefile.find(std::string("bash ") + script), std::string::npos) << script;
    EXPECT_TRUE(fs::exists(kRepo / script)) << script;
  }
  EXPECT_NE(dockerfile.find("RUN bash tools/build_install.sh /usr/local"), std::string::npos);
  // Multi-stage, non-root.
  EXPECT_NE(dockerfile.find("FROM debian:12 AS build"), std::string::npos);
  EXPECT_NE(dockerfile.find("COPY --from=build /usr/local/bin/"), std::string::npos);
  EXPECT_NE(dockerfile.find("COPY --from=build /usr/local/share/cellcal/"), std::string::npos);
  EXPECT_NE(dockerfile.find("USER cellcal"), std::string::npos);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(dockerfile, m, std::regex(R"(COPY (tools/\S+) )")));
  EXPECT_TRUE(fs::exists(kRepo / m[1].str())) << m[1];
  // The runtime stage's packages: every shared library the binaries load belongs to one of them (or to the base).
  const auto runtime_at = dockerfile.rfind("FROM debian:12");
  const std::string runtime = dockerfile.substr(runtime_at);
  std::set<std::string> listed;
  for (const auto& w : split(std::regex_replace(runtime, std::regex(R"(\\\n)"), " ")))
    if (std::regex_match(w, std::regex(R"(lib[a-z0-9.+-]+|openssl)"))) listed.insert(w);
  std::set<std::string> bins;
  for (const auto& c : kComponents) bins.insert(c);
  bins.insert("cellcal");
  const std::set<std::string> base = {"libc6", "libgcc-s1", "libzstd1", "zlib1g", "liblzma5", "libselinux1"};
  for (const auto& b : bins) {
    const std::string libs = capture("ldd " + (fs::path(CELLCAL_BIN_DIR) / b).string() +
                                     " | awk '/=>/{print $3}' | xargs -r -n1 readlink -f | xargs -r dpkg -S 2>/dev/null"
                                     " | cut -d: -f1 | sort -u");
    const auto pkgs = split(libs);
    ASSERT_FALSE(pkgs.empty()) << "ldd/dpkg found no packages for " << b;
    for (const auto& p : pkgs)
      if (!base.count(p)) {
        EXPECT_TRUE(listed.count(p)) << b << " loads a library of " << p << ", not installed by the runtime stage";
      }
  }
}

TEST(Deployment, SystemdUnitsStartTheFourComponents) {
  const fs::path dir = kRepo / "config" / "systemd";
  const std::string target = test::readTextFile(dir / "cellcal.target");
  std::set<std::string> started;
  for (const auto& c : kComponents) {
    std::string unit_name = "cellcal-" + c.substr(8) + ".service";
    std::replace(unit_name.begin(), unit_name.end(), '_', '-');
    const std::string unit = test::readTextFile(dir / unit_name);
    ASSERT_FALSE(unit.empty()) << unit_name;
    EXPECT_NE(target.find(unit_name), std::string::npos) << "cellcal.target does not want " << unit_name;
    EXPECT_NE(unit.find("WantedBy=cellcal.target"), std::string::npos) << unit_name;
    EXPECT_NE(unit.find("KillSignal=SIGINT"), std::string::npos) << unit_name;
    std::smatch m;
    ASSERT_TRUE(std::regex_search(unit, m, std::regex(R"(\nExecStart=([^\n]+))"))) << unit_name;
    const auto argv = split(m[1].str());
    EXPECT_EQ(fs::path(argv[0]).parent_path(), "/usr/local/bin") << unit_name;
    expectRunnable(argv, unit_name);
    started.insert(fs::path(argv[0]).filename().string());
    for (size_t i = 0; i + 1 < argv.size(); ++i)
      if (argv[i] == "--state-dir") {
        EXPECT_EQ(argv[i + 1], "/var/lib/cellcal");
        EXPECT_NE(unit.find("StateDirectory=cellcal"), std::string::npos) << unit_name;
      }
  }
  EXPECT_EQ(started, std::set<std::string>(kComponents.begin(), kComponents.end()));
}

}  // namespace
}  // namespace cellcal

namespace cellcal {
namespace {

// Every command's --help reads like a man page (EXAMPLES, EXIT STATUS; the components also TOPICS, ENVIRONMENT,
// SIGNALS), and every option its examples use is one the command has: examples cannot rot. Its text is its page in
// docs/man, and every page there is a command's.
TEST(Help, EveryCommandHasAManPageWhoseExamplesUseRealOptions) {
  const std::vector<std::string> commands = {
      "cellcal experiment paper", "cellcal cell", "cellcal bench-cell", "cellcal bench-servo", "cellcal calibrate", "cellcal import ipa",
      "cellcal import csv", "cellcal diagnose", "cellcal continuous", "cellcal record", "cellcal replay",
      "cellcal validate", "cellcal export", "cellcal status", "cellcal foxglove", "cellcal robot import",
      "cellcal robot export", "cellcal robot check", "cellcal robot fk", "cellcal plan iso9283", "cellcal plan poses", "cellcal plan cover", "cellcal iso9283", "cellcal_tracker_adapter",
      "cellcal_joint_state_adapter", "cellcal_calibration_engine", "cellcal_compensation_publisher",
      "cellcal_rsi_bridge"};
  std::set<std::string> pages;
  for (const auto& e : fs::directory_iterator(kRepo / "docs" / "man")) pages.insert(e.path().stem().string());
  for (const auto& c : commands) {
    const std::string page = std::regex_replace(c, std::regex(" "), "-");
    EXPECT_EQ(pages.erase(page), 1u) << c << ": no docs/man/" << page << ".txt";
    const std::string help = capture(std::string(CELLCAL_BIN_DIR) + "/" + c + " --help 2>&1");
    // The page's EXAMPLES section stands in --help as written.
    std::ifstream in(kRepo / "docs" / "man" / (page + ".txt"));
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const auto from = text.find("\nEXAMPLES\n");
    ASSERT_NE(from, std::string::npos) << page << ": no EXAMPLES";
    const std::string section = text.substr(from, text.find("\n\n", from + 1) - from);
    EXPECT_NE(help.find(section), std::string::npos) << c << ": --help does not show its page's\n" << section;
    const auto examples_at = help.find("\nEXAMPLES\n");
    ASSERT_NE(examples_at, std::string::npos) << c << ":\n" << help;
    EXPECT_NE(help.find("\nEXIT STATUS\n"), std::string::npos) << c;
    if (c.rfind("cellcal_", 0) == 0) {
      for (const char* section : {"\nTOPICS\n", "\nENVIRONMENT\n", "\nSIGNALS\n"})
        EXPECT_NE(help.find(section), std::string::npos) << c << " has no " << section;
    }
    const std::string options = help.substr(0, examples_at);
    const std::string examples = help.substr(examples_at, help.find("\n\n", examples_at + 10) - examples_at);
    int used = 0;
    for (const auto& w : split(examples))
      if (w.rfind("--", 0) == 0 && w.size() > 2) {
        ++used;
        EXPECT_TRUE(options.find(" " + w) != std::string::npos || options.find("," + w) != std::string::npos)
            << c << ": an example uses " << w << ", not an option";
      }
    EXPECT_GT(used, 0) << c << ": examples without options";
  }
  EXPECT_TRUE(pages.empty()) << "docs/man has a page of no command: " << *pages.begin();
}

}  // namespace
}  // namespace cellcal
