#include "cellcal/lab/ipa_dataset.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <ctime>
#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>

#include "cellcal/core/model/se3.hpp"

namespace cellcal {
namespace {

std::vector<std::string> split(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::string cell;
  std::istringstream in(line);
  while (std::getline(in, cell, sep)) {
    if (!cell.empty() && cell.back() == '\r') cell.pop_back();
    out.push_back(cell);
  }
  return out;
}

// Seconds since the epoch of YYYYMMDDhhmmss (UTC as written), or NaN when it is not such a stamp.
double parseStamp(const std::string& s) {
  if (s.size() != 14 || s.find_first_not_of("0123456789") != std::string::npos) return std::nan("");
  std::tm tm{};
  tm.tm_year = std::stoi(s.substr(0, 4)) - 1900;
  tm.tm_mon = std::stoi(s.substr(4, 2)) - 1;
  tm.tm_mday = std::stoi(s.substr(6, 2));
  tm.tm_hour = std::stoi(s.substr(8, 2));
  tm.tm_min = std::stoi(s.substr(10, 2));
  tm.tm_sec = std::stoi(s.substr(12, 2));
  return static_cast<double>(timegm(&tm));
}

}  // namespace

MeasurementFile readIpaSeries(const std::string& path, const RobotModel& robot, std::string* notes) {
  std::ifstream in(path);
  if (!in) throw ConfigError(path + ": cannot open");
  std::string line;
  if (!std::getline(in, line)) throw ConfigError(path + ": empty file");
  const auto header = split(line, ';');
  std::map<std::string, int> col;
  for (size_t i = 0; i < header.size(); ++i) col[header[i]] = static_cast<int>(i);
  const std::vector<std::string> joints = {"shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                           "wrist_1_joint",      "wrist_2_joint",       "wrist_3_joint"};
  if (robot.numJoints() != 6) throw ConfigError(path + ": the ipa series are of a 6-joint UR10; robot " + robot.name);
  for (const auto& c : joints)
    if (!col.count(c)) throw ConfigError(path + ":1: header: missing column " + c);
  for (const char* c : {"measurement_x", "measurement_y", "measurement_z", "measurement_rx", "measurement_ry", "measurement_rz"})
    if (!col.count(c)) throw ConfigError(path + std::string(":1: header: missing column ") + c);
  MeasurementFile f;
  f.source = path;
  int lineno = 1, damaged = 0;
  double t_first = std::nan(""), tmin = 1e9, tmax = -1e9;
  bool stamps_ok = col.count("Timestamp") > 0;
  std::vector<double> stamps;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    auto cells = split(line, ';');
    auto number = [&](const std::string& name) {
      const int c = col.at(name);
      std::string s = c < static_cast<int>(cells.size()) ? cells[c] : "";
      for (char& ch : s)
        if (ch == ',') ch = '.';
      char* end = nullptr;
      const double v = std::strtod(s.c_str(), &end);
      if (s.empty() || *end != '\0' || !std::isfinite(v))
        throw ConfigError(path + ":" + std::to_string(lineno) + ":" + std::to_string(c + 1) + ": " + name + ": '" +
                          (c < static_cast<int>(cells.size()) ? cells[c] : "") + "' is not a number");
      return v;
    };
    MeasurementRow r;
    r.line = lineno;
    r.q_rad.resize(6);
    for (int j = 0; j < 6; ++j) r.q_rad[j] = number(joints[j]);
    r.position_m = Eigen::Vector3d(number("measurement_x"), number("measurement_y"), number("measurement_z")) * 1e-3;
    // Intrinsic X-Y-Z (scipy 'XYZ'): R = Rx(a) Ry(b) Rz(c).
    const double a = degToRad(number("measurement_rx")), b = degToRad(number("measurement_ry")),
                 c = degToRad(number("measurement_rz"));
    const Eigen::Matrix3d R = (Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(b, Eigen::Vector3d::UnitY()) *
                               Eigen::AngleAxisd(c, Eigen::Vector3d::UnitZ())).toRotationMatrix();
    r.orientation = Eigen::Quaterniond(R).normalized();
    // The tracker's own uncertainty of the reading, where the series has it (mm and deg per axis): one sigma per axis
    // for the position and for the orientation (the RMS of the three).
    auto rms3 = [&](const char* x, const char* y, const char* z) {
      const double a2 = number(x), b2 = number(y), c2 = number(z);
      return std::sqrt((a2 * a2 + b2 * b2 + c2 * c2) / 3.0);
    };
    if (col.count("measurement_std_x") && col.count("measurement_std_y") && col.count("measurement_std_z"))
      r.sigma_position_m = rms3("measurement_std_x", "measurement_std_y", "measurement_std_z") * 1e-3;
    if (col.count("measurement_std_rx") && col.count("measurement_std_ry") && col.count("measurement_std_rz"))
      r.sigma_orientation_rad = degToRad(rms3("measurement_std_rx", "measurement_std_ry", "measurement_std_rz"));
    if (r.sigma_position_m && !(*r.sigma_position_m > 0)) r.sigma_position_m.reset();
    if (r.sigma_orientation_rad && !(*r.sigma_orientation_rad > 0)) r.sigma_orientation_rad.reset();
    if (col.count("measurement_temperature")) {
      r.temperature_c = number("measurement_temperature");
      tmin = std::min(tmin, *r.temperature_c);
      tmax = std::max(tmax, *r.temperature_c);
    }
    if (stamps_ok) {
      const double t = parseStamp(cells.at(col.at("Timestamp")));
      if (std::isnan(t)) {
        stamps_ok = false;
        ++damaged;
      } else {
        if (std::isnan(t_first)) t_first = t;
        stamps.push_back(t - t_first);
      }
    }
    for (int j = 0; j < 6; ++j)
      if (r.q_rad[j] < robot.limits[j].lower_rad || r.q_rad[j] > robot.limits[j].upper_rad)
        throw ConfigError(path + ":" + std::to_string(lineno) + ":" + std::to_string(col.at(joints[j]) + 1) + ": " +
                          joints[j] + ": outside the joint limits of " + robot.name);
    f.rows.push_back(std::move(r));
  }
  // The CSV's row order is the visiting order: with usable stamps, rows are written in time order (stable), and the
  // notes say how many were not, how long the stamps span and in how many sessions (gaps over an hour) the robot was
  // measured.
  size_t out_of_order = 0, sessions = 0;
  double span_h = 0, measured_h = 0;
  if (stamps_ok && stamps.size() == f.rows.size() && !stamps.empty()) {
    for (size_t i = 0; i < f.rows.size(); ++i) f.rows[i].stamp_s = stamps[i];
    for (size_t i = 1; i < stamps.size(); ++i) out_of_order += stamps[i] < stamps[i - 1];
    std::stable_sort(f.rows.begin(), f.rows.end(),
                     [](const MeasurementRow& a, const MeasurementRow& b) { return *a.stamp_s < *b.stamp_s; });
    const double t0 = *f.rows.front().stamp_s;
    for (auto& r : f.rows) *r.stamp_s -= t0;
    span_h = *f.rows.back().stamp_s / 3600.0;
    sessions = 1;
    for (size_t i = 1; i < f.rows.size(); ++i) {
      const double gap_h = (*f.rows[i].stamp_s - *f.rows[i - 1].stamp_s) / 3600.0;
      if (gap_h > 1.0) ++sessions;
      else measured_h += gap_h;
    }
  }
  if (notes) {
    std::ostringstream n;
    n << f.rows.size() << " rows from " << path << "; ";
    if (stamps_ok && !stamps.empty()) {
      n << "stamps span " << std::fixed << std::setprecision(2) << span_h << " h in " << sessions
        << " session(s) (gaps over 1 h between them), " << measured_h << " h of measuring";
      if (out_of_order) n << "; " << out_of_order << " rows out of time order in the source, written in time order";
    } else
      n << "timestamps unusable (damaged, e.g. '2,02011E+13'): row order only";
    if (tmax >= tmin) n << "; temperature " << std::fixed << std::setprecision(2) << tmin << " .. " << tmax << " C";
    *notes = n.str();
  }
  (void)damaged;
  return f;
}

}  // namespace cellcal
