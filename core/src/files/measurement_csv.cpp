#include "cellcal/core/files/measurement_csv.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <iomanip>
#include <sstream>

#include <Eigen/SVD>

#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/model/se3.hpp"

namespace cellcal {
namespace {

std::vector<std::string> splitCsv(const std::string& line) {
  std::vector<std::string> out;
  std::string cell;
  std::istringstream in(line);
  while (std::getline(in, cell, ',')) out.push_back(cell);
  if (!line.empty() && line.back() == ',') out.emplace_back();
  return out;
}

std::string trim(const std::string& s) {
  const auto a = s.find_first_not_of(" \t\r");
  if (a == std::string::npos) return "";
  const auto b = s.find_last_not_of(" \t\r");
  return s.substr(a, b - a + 1);
}

struct RowError {
  int column;  // 1-based
  std::string name, message;
};

}  // namespace

namespace {

// RMS distance of points about their centre (the same in any frame).
double rmsSpread(const std::vector<Eigen::Vector3d>& p) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& x : p) c += x;
  c /= static_cast<double>(p.size());
  double s = 0;
  for (const auto& x : p) s += (x - c).squaredNorm();
  return std::sqrt(s / static_cast<double>(p.size()));
}

// Metres in the _mm columns: the readings spread a thousandth of what the rows' joint angles move the target under
// the nominal model (registration and tool offsets change that by far less than the factor 20 allowed here).
void checkPositionUnits(const MeasurementFile& f, const RobotModel& robot, const std::string& where) {
  if (f.rows.size() < 3) return;
  KinematicsData d(robot);
  std::vector<Eigen::Vector3d> measured, nominal;
  for (const auto& r : f.rows) {
    measured.push_back(r.position_m);
    nominal.push_back(forwardKinematics(robot, d, robot.nominal, r.q_rad).translation());
  }
  const double moved_mm = rmsSpread(nominal) * 1e3, read_mm = rmsSpread(measured) * 1e3;
  if (moved_mm < 20.0 || read_mm * 20.0 >= moved_mm) return;
  char buf[400];
  std::snprintf(buf, sizeof buf,
                ": x_mm, y_mm, z_mm: the readings spread %.3g mm about their centre (RMS over %zu rows) while the "
                "rows' joint angles move the target %.0f mm under the nominal model: metres written where millimetres "
                "are expected? (multiply by 1000)",
                read_mm, f.rows.size(), moved_mm);
  throw ConfigError(where + buf);
}

// Radians written in the _deg columns: every joint value lies within +-2 pi, and the readings spread far more than
// those angles, read as degrees, move the target under the nominal model (a 57x smaller motion).
void checkJointUnits(const MeasurementFile& f, const RobotModel& robot, const std::string& where) {
  if (f.rows.size() < 3) return;
  double largest_deg = 0;
  for (const auto& r : f.rows) largest_deg = std::max(largest_deg, radToDeg(r.q_rad.cwiseAbs().maxCoeff()));
  if (largest_deg > 2 * kPi + 1e-9) return;
  KinematicsData d(robot);
  std::vector<Eigen::Vector3d> measured, as_degrees, as_radians;
  for (const auto& r : f.rows) {
    measured.push_back(r.position_m);
    as_degrees.push_back(forwardKinematics(robot, d, robot.nominal, r.q_rad).translation());
    as_radians.push_back(forwardKinematics(robot, d, robot.nominal, r.q_rad * (180.0 / kPi)).translation());
  }
  const double read_mm = rmsSpread(measured) * 1e3, deg_mm = rmsSpread(as_degrees) * 1e3,
               rad_mm = rmsSpread(as_radians) * 1e3;
  // Read as radians the angles explain the readings' spread; read as degrees they fall short by a factor 3 or more.
  if (read_mm < 20.0 || deg_mm * 3.0 >= read_mm || rad_mm * 1.6 < read_mm || rad_mm > 1.6 * read_mm) return;
  char buf[480];
  std::snprintf(buf, sizeof buf,
                ": q1_deg..q%d_deg: every joint value lies within +-%.2f while the readings spread %.0f mm about their "
                "centre (RMS over %zu rows) and these angles, read as degrees, move the target only %.1f mm under the "
                "nominal model (%.0f mm read as radians): radians written where degrees are expected? (name the "
                "columns q1_rad.. or multiply by 57.2958)",
                robot.numJoints(), largest_deg, read_mm, f.rows.size(), deg_mm, rad_mm);
  throw ConfigError(where + buf);
}

// Quaternions written in x, y, z, w order under qw, qx, qy, qz. The rotation from one row's reading to the next,
// seen from the target (M_i^T M_j = T^T F_i^T F_j T), is the nominal model's from the flange, turned by the target's
// one fixed rotation T: one rotation maps every such rotation vector of the model onto the readings'. Read in the
// wrong order the readings' are no rotation of the model's (a permutation keeps the angles, not the axes).
double rotationMismatchDeg(const std::vector<Eigen::Vector3d>& model, const std::vector<Eigen::Vector3d>& read) {
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (size_t k = 0; k < model.size(); ++k) H += read[k] * model[k].transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  const Eigen::Matrix3d R = svd.matrixU() * D * svd.matrixV().transpose();
  double s = 0;
  for (size_t k = 0; k < model.size(); ++k) s += (read[k] - R * model[k]).squaredNorm();
  return radToDeg(std::sqrt(s / static_cast<double>(model.size())));
}

void checkQuaternionOrder(const MeasurementFile& f, const RobotModel& robot, const std::string& where) {
  std::vector<const MeasurementRow*> rows;
  for (const auto& r : f.rows)
    if (r.orientation && rows.size() < 400) rows.push_back(&r);
  if (rows.size() < 4) return;
  KinematicsData d(robot);
  std::vector<Eigen::Matrix3d> nominal, written, reordered;
  for (const auto* r : rows) {
    nominal.push_back(forwardKinematics(robot, d, robot.nominal, r->q_rad).linear());
    const Eigen::Quaterniond& q = *r->orientation;
    written.push_back(q.toRotationMatrix());
    // As read, w holds the file's x, x its y, y its z and z its w.
    reordered.push_back(Eigen::Quaterniond(q.z(), q.w(), q.x(), q.y()).normalized().toRotationMatrix());
  }
  std::vector<Eigen::Vector3d> model, as_written, as_reordered;
  // Every pair of a small file, rows one and two apart in a large one.
  const size_t reach = rows.size() <= 40 ? rows.size() : 2;
  for (size_t i = 0; i + 1 < rows.size(); ++i)
    for (size_t j = i + 1; j < rows.size() && j <= i + reach; ++j) {
      const Eigen::Vector3d a = logSO3(nominal[i].transpose() * nominal[j]);
      const Eigen::Vector3d w = logSO3(written[i].transpose() * written[j]);
      const Eigen::Vector3d r = logSO3(reordered[i].transpose() * reordered[j]);
      // Near half a turn the rotation vector's sign is ambiguous: such pairs say nothing here.
      if (a.norm() > 2.9 || w.norm() > 2.9 || r.norm() > 2.9 || a.norm() < 0.05) continue;
      model.push_back(a);
      as_written.push_back(w);
      as_reordered.push_back(r);
    }
  if (model.size() < 3) return;
  const double off_written = rotationMismatchDeg(model, as_written);
  const double off_reordered = rotationMismatchDeg(model, as_reordered);
  if (off_written < 5.0 || off_reordered * 5.0 > off_written) return;
  char buf[520];
  std::snprintf(buf, sizeof buf,
                ": qw, qx, qy, qz: the rotations between consecutive readings are no rotation of the nominal model's "
                "(%.1f deg RMS apart as written, %.2f deg read as x, y, z, w; %zu pairs of rows): quaternions written "
                "in x, y, z, w order? (CSV v1 names the columns; name them qx, qy, qz, qw in the header)",
                off_written, off_reordered, model.size());
  throw ConfigError(where + buf);
}

}  // namespace

namespace {

// The header's columns, as parseMeasurementCsv reads them.
struct Columns {
  std::vector<std::string> header;
  std::map<std::string, int> col;  // name -> index
  bool deg = false;                // joints in degrees (else radians)
  std::vector<int> qcol;           // the joints' columns
  bool has_q = false;              // an orientation (qw, qx, qy, qz)
  int line = 0;                    // the header's line
  bool has(const std::string& name) const { return col.count(name) > 0; }
  int at(const std::string& name) const { return col.at(name); }
};

// The header: the first line that is neither empty nor a comment. f gets the columns it ignores.
Columns readHeader(std::istream& in, int& lineno, const std::string& source, const RobotModel& robot,
                   const MeasurementCsvOptions& options, MeasurementFile& f) {
  std::string line;
  std::vector<std::string> header;
  while (std::getline(in, line)) {
    ++lineno;
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    for (const auto& h : splitCsv(line)) header.push_back(trim(h));
    break;
  }
  if (header.empty()) throw ConfigError(source + ": no header row (expected q1_deg.., x_mm, y_mm, z_mm, ...)");
  if (header.size() == 1)
    for (const char sep : {';', '\t', ' '})
      if (header[0].find(sep) != std::string::npos)
        throw ConfigError(source + ":" + std::to_string(lineno) + ":1: header: one column '" + header[0].substr(0, 60) +
                          (header[0].size() > 60 ? "..." : "") + "': the columns are separated by " +
                          (sep == ';' ? "';'" : sep == '\t' ? "tabs" : "spaces") +
                          ", CSV v1 by ',' with '.' decimals (a spreadsheet's export with decimal commas: replace "
                          "',' by '.', then the separator by ',')");
  const int n = robot.numJoints();
  std::map<std::string, int> col;
  for (size_t i = 0; i < header.size(); ++i) {
    if (col.count(header[i]))
      throw ConfigError(source + ":" + std::to_string(lineno) + ":" + std::to_string(i + 1) + ": " + header[i] +
                        ": duplicated column");
    col[header[i]] = static_cast<int>(i);
  }
  // Joint unit: all deg or all rad.
  const bool deg = col.count("q1_deg") > 0, rad = col.count("q1_rad") > 0;
  if (deg == rad)
    throw ConfigError(source + ":" + std::to_string(lineno) + ":1: header: expected q1_deg..q" + std::to_string(n) +
                      "_deg or q1_rad..q" + std::to_string(n) + "_rad" + (deg ? " (not both)" : ""));
  const std::string unit = deg ? "_deg" : "_rad";
  std::vector<int> qcol;
  for (int j = 1; j <= n; ++j) {
    const std::string name = "q" + std::to_string(j) + unit;
    if (!col.count(name))
      throw ConfigError(source + ":" + std::to_string(lineno) + ":1: header: missing column " + name + " (the robot " +
                        robot.name + " has " + std::to_string(n) + " joints)");
    qcol.push_back(col[name]);
  }
  for (const char* req : {"x_mm", "y_mm", "z_mm"})
    if (!col.count(req) && !options.joints_only)
      throw ConfigError(source + ":" + std::to_string(lineno) + ":1: header: missing column " + req);
  const bool has_q = !options.joints_only && (col.count("qw") || col.count("qx") || col.count("qy") || col.count("qz"));
  if (has_q && !(col.count("qw") && col.count("qx") && col.count("qy") && col.count("qz")))
    throw ConfigError(source + ":" + std::to_string(lineno) + ":1: header: orientation needs all of qw, qx, qy, qz");
  std::map<std::string, bool> known = {{"x_mm", 1}, {"y_mm", 1}, {"z_mm", 1}, {"qw", 1}, {"qx", 1}, {"qy", 1},
                                       {"qz", 1}, {"stamp_s", 1}, {"group", 1}, {"temperature_c", 1}, {"payload_kg", 1},
                                       {"sigma_position_mm", 1}, {"sigma_orientation_deg", 1}, {"setup", 1},
                                       {"pose", 1}, {"cycle", 1}};
  for (int j = 1; j <= n; ++j) known["q" + std::to_string(j) + unit] = true;
  for (const auto& h : header)
    if (!known.count(h)) f.ignored_columns.push_back(h);
  return {header, col, deg, qcol, has_q, lineno};
}

// One data row's cells into row; the first error in it, if any.
std::optional<RowError> parseRow(const Columns& c, const std::vector<std::string>& cells, const RobotModel& robot,
                                 const MeasurementCsvOptions& options, MeasurementRow& row) {
  const std::vector<std::string>& header = c.header;
  const int n = robot.numJoints();
  const bool deg = c.deg;
  std::optional<RowError> err;
  auto cell = [&](int k) { return k < static_cast<int>(cells.size()) ? trim(cells[k]) : std::string(); };
  auto number = [&](int k, bool required, double* out) -> bool {
    if (err) return false;
    const std::string s = cell(k);
    if (s.empty()) {
      if (required) err = RowError{k + 1, header[k], "missing value"};
      return false;
    }
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(s.c_str(), &end);
    if (*end != '\0' || errno == ERANGE || !std::isfinite(v)) {
      err = RowError{k + 1, header[k], "'" + s + "' is not a finite number"};
      return false;
    }
    *out = v;
    return true;
  };
  if (static_cast<int>(cells.size()) > static_cast<int>(header.size()))
    err = RowError{static_cast<int>(header.size()) + 1, "row", "more cells (" + std::to_string(cells.size()) +
                                                                    ") than columns (" + std::to_string(header.size()) + ")"};
  row.q_rad.resize(n);
  for (int j = 0; j < n; ++j) {
    double v = 0;
    if (number(c.qcol[j], true, &v)) {
      row.q_rad[j] = deg ? degToRad(v) : v;
      if (row.q_rad[j] < robot.limits[j].lower_rad || row.q_rad[j] > robot.limits[j].upper_rad)
        err = RowError{c.qcol[j] + 1, header[c.qcol[j]],
                       "joint outside its limits [" + std::to_string(radToDeg(robot.limits[j].lower_rad)) + ", " +
                           std::to_string(radToDeg(robot.limits[j].upper_rad)) + "] deg" +
                           (!deg && std::abs(v) > 2 * kPi ? ": degrees written where radians are expected?" : "")};
    }
  }
  for (int k = 0; k < 3 && !options.joints_only; ++k) {
    double v = 0;
    if (number(c.at(std::string(1, "xyz"[k]) + "_mm"), true, &v)) row.position_m[k] = v * 1e-3;
  }
  if (c.has_q && !err) {
    const int cw = c.at("qw"), cx = c.at("qx"), cy = c.at("qy"), cz = c.at("qz");
    const int empty = cell(cw).empty() + cell(cx).empty() + cell(cy).empty() + cell(cz).empty();
    if (empty == 4) {
      // position-only row
    } else if (empty > 0) {
      const int k = cell(cw).empty() ? cw : cell(cx).empty() ? cx : cell(cy).empty() ? cy : cz;
      err = RowError{k + 1, header[k], "missing value (leave all of qw, qx, qy, qz empty for a position-only row)"};
    } else {
      double w = 0, x = 0, y = 0, z = 0;
      if (number(cw, true, &w) && number(cx, true, &x) && number(cy, true, &y) && number(cz, true, &z)) {
        const double norm = std::sqrt(w * w + x * x + y * y + z * z);
        if (std::abs(norm - 1.0) > options.quaternion_tolerance)
          err = RowError{cw + 1, "qw", "quaternion norm " + std::to_string(norm) + " is not 1"};
        else
          row.orientation = Eigen::Quaterniond(w, x, y, z).normalized();
      }
    }
  }
  double v = 0;
  if (c.has("stamp_s") && number(c.at("stamp_s"), false, &v)) row.stamp_s = v;
  if (c.has("temperature_c") && number(c.at("temperature_c"), false, &v)) row.temperature_c = v;
  if (c.has("payload_kg") && number(c.at("payload_kg"), false, &v)) row.payload_kg = v;
  for (const char* name : {"sigma_position_mm", "sigma_orientation_deg"})
    if (c.has(name) && number(c.at(name), false, &v)) {
      if (!(v > 0)) err = RowError{c.at(name) + 1, name, "a sigma must be > 0"};
      else if (std::string(name) == "sigma_position_mm") row.sigma_position_m = v * 1e-3;
      else row.sigma_orientation_rad = v * kPi / 180;
    }
  for (const char* name : {"setup", "pose"}) {
    if (!c.has(name) || err || cell(c.at(name)).empty()) continue;
    const std::string label = cell(c.at(name)), what = std::string(name) == "setup" ? "a set-up label" : "a pose name";
    if (label.size() > 64) err = RowError{c.at(name) + 1, name, what + " has at most 64 characters"};
    else if (label.find_first_of("\"'") != std::string::npos)
      err = RowError{c.at(name) + 1, name, what + " may not contain quotes"};
    else (std::string(name) == "setup" ? row.setup : row.pose) = label;
  }
  if (c.has("cycle") && number(c.at("cycle"), false, &v)) {
    if (v != std::floor(v)) err = RowError{c.at("cycle") + 1, "cycle", "expected an integer"};
    else row.cycle = static_cast<long long>(v);
  }
  if (c.has("group") && number(c.at("group"), false, &v)) {
    if (v != std::floor(v)) err = RowError{c.at("group") + 1, "group", "expected an integer"};
    else row.group = static_cast<long long>(v);
  }
  return err;
}

}  // namespace

MeasurementFile parseMeasurementCsv(const std::string& text, const std::string& source, const RobotModel& robot,
                                    const MeasurementCsvOptions& options) {
  MeasurementFile f;
  f.source = source;
  std::istringstream in(text);
  int lineno = 0;
  const Columns c = readHeader(in, lineno, source, robot, options, f);
  const int header_line = c.line;
  std::string line;
  while (std::getline(in, line)) {
    ++lineno;
    if (trim(line).empty()) continue;
    MeasurementRow row;
    row.line = lineno;
    const std::optional<RowError> err = parseRow(c, splitCsv(line), robot, options, row);
    if (err) {
      const std::string msg = source + ":" + std::to_string(lineno) + ":" + std::to_string(err->column) + ": " +
                              err->name + ": " + err->message;
      if (!options.skip_bad_rows) throw ConfigError(msg);
      f.warnings.push_back(msg);
      ++f.skipped_rows;
      continue;
    }
    f.rows.push_back(std::move(row));
  }
  if (f.rows.empty())
    throw ConfigError(source + ":" + std::to_string(header_line) + ": no data rows after the header" +
                      (f.skipped_rows ? " (" + std::to_string(f.skipped_rows) + " bad rows skipped)" : std::string()));
  if (options.joints_only) {
    if (c.deg) checkJointUnits(f, robot, source + ":" + std::to_string(header_line) + ":" + std::to_string(c.qcol[0] + 1));
    return f;
  }
  checkPositionUnits(f, robot, source + ":" + std::to_string(header_line) + ":" + std::to_string(c.at("x_mm") + 1));
  if (c.deg) checkJointUnits(f, robot, source + ":" + std::to_string(header_line) + ":" + std::to_string(c.qcol[0] + 1));
  if (c.has_q) checkQuaternionOrder(f, robot, source + ":" + std::to_string(header_line) + ":" + std::to_string(c.at("qw") + 1));
  return f;
}

MeasurementFile readMeasurementCsv(const std::string& path, const RobotModel& robot,
                                   const MeasurementCsvOptions& options) {
  std::ifstream in(path);
  if (!in) throw ConfigError(path + ": cannot open measurement file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parseMeasurementCsv(ss.str(), path, robot, options);
}

DriverTable driversOf(const MeasurementFile& file) {
  std::vector<Eigen::VectorXd> q;
  std::vector<std::optional<double>> temperature, stamp;
  for (const auto& r : file.rows) {
    q.push_back(r.q_rad);
    temperature.push_back(r.temperature_c);
    stamp.push_back(r.stamp_s);
  }
  return driversFromSequence(q, temperature, stamp);
}

Observation toObservation(const MeasurementRow& row, MeasurementKind kind, double sigma_position_m,
                          double sigma_orientation_rad) {
  Observation o;
  o.q_rad = row.q_rad;
  o.measured_in_tracker = Pose::Identity();
  o.measured_in_tracker.translation() = row.position_m;
  if (row.orientation) o.measured_in_tracker.linear() = row.orientation->toRotationMatrix();
  o.kind = (kind == MeasurementKind::kPose6D && row.orientation) ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
  o.sigma_position_m = row.sigma_position_m.value_or(sigma_position_m);
  o.sigma_orientation_rad = row.sigma_orientation_rad.value_or(sigma_orientation_rad);
  return o;
}

void writeMeasurementCsv(std::ostream& out, const MeasurementFile& f, int joints, const std::string& comment) {
  bool oriented = false, stamped = false, grouped = false, temp = false, payload = false, sp = false, so = false,
       setups = false, poses = false, cycles = false;
  for (const auto& r : f.rows) {
    poses |= r.pose.has_value();
    cycles |= r.cycle.has_value();
    oriented |= r.orientation.has_value();
    stamped |= r.stamp_s.has_value();
    grouped |= r.group.has_value();
    temp |= r.temperature_c.has_value();
    payload |= r.payload_kg.has_value();
    sp |= r.sigma_position_m.has_value();
    so |= r.sigma_orientation_rad.has_value();
    setups |= r.setup.has_value();
  }
  std::istringstream c(comment);
  std::string line;
  while (std::getline(c, line)) out << "# " << line << "\n";
  for (int j = 1; j <= joints; ++j) out << "q" << j << "_rad,";
  out << "x_mm,y_mm,z_mm";
  if (oriented) out << ",qw,qx,qy,qz";
  if (stamped) out << ",stamp_s";
  if (grouped) out << ",group";
  if (temp) out << ",temperature_c";
  if (payload) out << ",payload_kg";
  if (sp) out << ",sigma_position_mm";
  if (so) out << ",sigma_orientation_deg";
  if (setups) out << ",setup";
  if (poses) out << ",pose";
  if (cycles) out << ",cycle";
  out << "\n" << std::setprecision(12);
  for (const auto& r : f.rows) {
    for (int j = 0; j < joints; ++j) out << r.q_rad[j] << ",";
    out << r.position_m.x() * 1e3 << "," << r.position_m.y() * 1e3 << "," << r.position_m.z() * 1e3;
    if (oriented) {
      if (r.orientation)
        out << "," << r.orientation->w() << "," << r.orientation->x() << "," << r.orientation->y() << "," << r.orientation->z();
      else
        out << ",,,,";
    }
    auto opt = [&](bool has, const auto& v) {
      if (!has) return;
      out << ",";
      if (v) out << *v;
    };
    opt(stamped, r.stamp_s);
    opt(grouped, r.group);
    opt(temp, r.temperature_c);
    opt(payload, r.payload_kg);
    opt(sp, r.sigma_position_m ? std::optional<double>(*r.sigma_position_m * 1e3) : std::nullopt);
    opt(so, r.sigma_orientation_rad ? std::optional<double>(*r.sigma_orientation_rad * 180 / kPi) : std::nullopt);
    opt(setups, r.setup);
    opt(poses, r.pose);
    opt(cycles, r.cycle);
    out << "\n";
  }
}

}  // namespace cellcal
