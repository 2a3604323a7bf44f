#include <cstdlib>
#include <filesystem>
#include <fstream>

#include "commands.hpp"

namespace cellcal::cli {

bool renderGnuplot(const std::string& dir, const std::string& name, const std::string& data,
                   const std::string& script, std::string* error, const std::string& format) {
  namespace fs = std::filesystem;
  fs::create_directories(dir);
  const std::string dat = dir + "/" + name + ".dat", gp = dir + "/" + name + ".gp", out = dir + "/" + name + "." + format;
  std::ofstream(dat) << data;
  std::ofstream(gp) << (format == "svg" ? "set terminal svg size 1000,500 noenhanced font 'sans,11' background 'white'\n"
                                        : "set terminal pngcairo size 1000,600 noenhanced font 'sans,11'\n")
                    << "set output '" << out << "'\n"
                    << "datafile = '" << dat << "'\n"
                    << script;
  if (std::system("command -v gnuplot >/dev/null 2>&1") != 0) {
    *error = "gnuplot not found (install gnuplot-nox); data and script left in " + dir;
    return false;
  }
  const std::string cmd = "gnuplot '" + gp + "' 2>'" + dir + "/" + name + ".log'";
  if (std::system(cmd.c_str()) != 0) {
    *error = "gnuplot failed on " + gp + " (see " + dir + "/" + name + ".log)";
    return false;
  }
  return true;
}

}  // namespace cellcal::cli
