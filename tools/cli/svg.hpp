// A minimal SVG scatter plot (no dependency): panels side by side sharing the y axis.
#pragma once

#include <string>
#include <vector>

namespace cellcal::cli {

struct ScatterPanel {
  std::string title;
  std::vector<double> x, y;
};

// Writes an SVG document with the panels side by side; the panels share the x and y ranges.
std::string scatterSvg(const std::vector<ScatterPanel>& panels, const std::string& x_label, const std::string& y_label);

}  // namespace cellcal::cli
