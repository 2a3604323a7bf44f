#include "svg.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

namespace cellcal::cli {
namespace {

std::string escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (c == '<') o += "&lt;";
    else if (c == '>') o += "&gt;";
    else if (c == '&') o += "&amp;";
    else o += c;
  }
  return o;
}

// About five round tick values covering [lo, hi].
std::vector<double> ticks(double lo, double hi) {
  const double span = hi - lo;
  const double raw = span / 5;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = mag;
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (raw <= m * mag) {
      step = m * mag;
      break;
    }
  std::vector<double> t;
  for (double v = std::ceil(lo / step) * step; v <= hi + 1e-9 * span; v += step) t.push_back(std::abs(v) < 1e-12 * span ? 0.0 : v);
  return t;
}

std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%g", v);
  return b;
}

}  // namespace

std::string scatterSvg(const std::vector<ScatterPanel>& panels, const std::string& x_label, const std::string& y_label) {
  double xlo = INFINITY, xhi = -INFINITY, ylo = INFINITY, yhi = -INFINITY;
  for (const auto& p : panels) {
    for (double v : p.x) xlo = std::min(xlo, v), xhi = std::max(xhi, v);
    for (double v : p.y) ylo = std::min(ylo, v), yhi = std::max(yhi, v);
  }
  if (!(xhi > xlo)) xlo -= 1, xhi += 1;
  if (!(yhi > ylo)) ylo -= 1, yhi += 1;
  const double px = 0.05 * (xhi - xlo), py = 0.05 * (yhi - ylo);
  xlo -= px, xhi += px, ylo -= py, yhi += py;
  const int W = 460, H = 360, ml = 70, mr = 15, mt = 30, mb = 50;
  const int total_w = W * static_cast<int>(panels.size());
  std::ostringstream s;
  s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << total_w << "\" height=\"" << H
    << "\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  for (size_t k = 0; k < panels.size(); ++k) {
    const int ox = static_cast<int>(k) * W;
    const double pw = W - ml - mr, ph = H - mt - mb;
    auto X = [&](double v) { return ox + ml + (v - xlo) / (xhi - xlo) * pw; };
    auto Y = [&](double v) { return mt + (yhi - v) / (yhi - ylo) * ph; };
    s << "<text x=\"" << ox + ml + pw / 2 << "\" y=\"18\" text-anchor=\"middle\" font-weight=\"bold\">"
      << escape(panels[k].title) << "</text>\n";
    s << "<rect x=\"" << ox + ml << "\" y=\"" << mt << "\" width=\"" << pw << "\" height=\"" << ph
      << "\" fill=\"none\" stroke=\"black\"/>\n";
    for (double t : ticks(xlo, xhi))
      s << "<line x1=\"" << X(t) << "\" x2=\"" << X(t) << "\" y1=\"" << mt << "\" y2=\"" << mt + ph
        << "\" stroke=\"#ddd\"/><text x=\"" << X(t) << "\" y=\"" << mt + ph + 15 << "\" text-anchor=\"middle\">"
        << num(t) << "</text>\n";
    for (double t : ticks(ylo, yhi))
      s << "<line x1=\"" << ox + ml << "\" x2=\"" << ox + ml + pw << "\" y1=\"" << Y(t) << "\" y2=\"" << Y(t)
        << "\" stroke=\"" << (t == 0 ? "#999" : "#ddd") << "\"/><text x=\"" << ox + ml - 5 << "\" y=\"" << Y(t) + 4
        << "\" text-anchor=\"end\">" << num(t) << "</text>\n";
    for (size_t i = 0; i < panels[k].x.size() && i < panels[k].y.size(); ++i)
      s << "<circle cx=\"" << X(panels[k].x[i]) << "\" cy=\"" << Y(panels[k].y[i]) << "\" r=\"2.2\" fill=\"#1f77b4\" fill-opacity=\"0.7\"/>\n";
    s << "<text x=\"" << ox + ml + pw / 2 << "\" y=\"" << H - 12 << "\" text-anchor=\"middle\">" << escape(x_label)
      << "</text>\n";
    s << "<text transform=\"translate(" << ox + 16 << "," << mt + ph / 2 << ") rotate(-90)\" text-anchor=\"middle\">"
      << escape(y_label) << "</text>\n";
  }
  s << "</svg>\n";
  return s.str();
}

}  // namespace cellcal::cli
