#include <cstdlib>
#include <filesystem>
#include <fstream>

#include "commands.hpp"

namespace cellcal::cli {

bool renderGnuplot(const std::string& dir, const std::string& name, const std::string& data,
                   const std::string& script, std::string* error, const std::string& format) {
  namespace fs = std::filesystem;
  fs::create_directories(dir);
  // The script names its data and its figure by their names in its own folder: `cd DIR && gnuplot NAME.gp` draws it
  // again (after editing the script, say), wherever the folder was moved.
  const std::string dat = name + ".dat", gp = name + (format == "svg" ? ".svg.gp" : ".gp"), out = name + "." + format;
  std::ofstream(dir + "/" + dat) << data;
  std::ofstream(dir + "/" + gp) << (format == "svg" ? "set terminal svg size 1000,500 noenhanced font 'sans,11' background 'white'\n"
                                                    : "set terminal pngcairo size 1000,600 noenhanced font 'sans,11'\n")
                                << "set output '" << out << "'\n"
                                << "datafile = '" << dat << "'\n"
                                << script;
  if (std::system("command -v gnuplot >/dev/null 2>&1") != 0) {
    *error = "gnuplot not found (install gnuplot-nox); data and script left in " + dir;
    return false;
  }
  const std::string cmd = "cd '" + dir + "' && gnuplot '" + gp + "' 2>'" + name + ".log'";
  if (std::system(cmd.c_str()) != 0) {
    *error = "gnuplot failed on " + dir + "/" + gp + " (see " + dir + "/" + name + ".log)";
    return false;
  }
  return true;
}

}  // namespace cellcal::cli
