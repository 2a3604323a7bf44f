#include "commands.hpp"
#include "measurement_input.hpp"

#include "cellcal/core/files/cell_config.hpp"

#include <algorithm>

#include <openssl/evp.h>

#include <chrono>
#include <ctime>
#include <fstream>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/prediction.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/files/robot_yaml.hpp"

namespace cellcal::cli {

OutlierOptions outlierOptions(const InputArgs& a) {
  OutlierOptions o;
  o.enabled = a.outlier_threshold > 0;
  if (o.enabled) o.threshold = a.outlier_threshold;
  std::string why;
  if (!o.IsValid(&why)) throw std::runtime_error("--outlier-threshold: " + why);
  return o;
}

namespace {

// The file's rows per set-up label, in order of first appearance (one group, unlabelled, when it has no setup column).
std::vector<std::pair<std::string, MeasurementFile>> bySetup(const MeasurementFile& file) {
  std::vector<std::pair<std::string, MeasurementFile>> out;
  for (const auto& r : file.rows) {
    const std::string label = r.setup.value_or("");
    auto it = std::find_if(out.begin(), out.end(), [&](const auto& p) { return p.first == label; });
    if (it == out.end()) {
      MeasurementFile part;
      part.source = file.source;
      out.emplace_back(label, std::move(part));
      it = out.end() - 1;
    }
    it->second.rows.push_back(r);
  }
  return out;
}

std::pair<RobotFile, MeasurementFile> readInput(const InputArgs& a, const std::string& path) {
  RobotFile rf = loadRobotFile(a.robot);
  MeasurementCsvOptions mo;
  mo.skip_bad_rows = a.skip_bad_rows;
  MeasurementFile file = readMeasurementCsv(path, rf.model, mo);
  for (const auto& w : file.warnings) std::fprintf(stderr, "skipped: %s\n", w.c_str());
  for (const auto& c : file.ignored_columns) std::fprintf(stderr, "%s: column '%s' ignored\n", path.c_str(), c.c_str());
  return {std::move(rf), std::move(file)};
}

// Splits, registers and checks the rows of one set-up; `name` (the file, and its set-up label) in messages.
LoadedInput prepareInput(const InputArgs& a, const std::string& name, RobotFile rf, MeasurementFile file);
void addModelErrorComponent(LoadedInput& in, const InputArgs& a);

}  // namespace

LoadedInput loadInput(const InputArgs& a) {
  if (!a.more_data.empty())
    throw ConfigError("--data given " + std::to_string(1 + a.more_data.size()) +
                      " times: only `cellcal calibrate` takes several set-ups (a usage error, exit 2)");
  auto [rf, file] = readInput(a, a.data);
  const auto parts = bySetup(file);
  if (parts.size() > 1) {
    std::string labels;
    for (const auto& p : parts) labels += (labels.empty() ? "" : ", ") + (p.first.empty() ? "(none)" : p.first);
    throw ConfigError(a.data + ": rows of " + std::to_string(parts.size()) + " set-ups (column setup: " + labels +
                      "): only `cellcal calibrate` takes several set-ups (a usage error, exit 2)");
  }
  return prepareInput(a, a.data, std::move(rf), std::move(file));
}

std::vector<LoadedInput> loadSetups(const InputArgs& a) {
  std::vector<std::string> paths = {a.data};
  paths.insert(paths.end(), a.more_data.begin(), a.more_data.end());
  std::vector<LoadedInput> out;
  for (const auto& path : paths) {
    auto [rf, file] = readInput(a, path);
    if (file.rows.empty()) throw ConfigError(path + ": no data rows");  // readMeasurementCsv refuses it already
    for (auto& [label, part] : bySetup(file)) {
      if (label.empty() && file.rows.size() != part.rows.size())
        throw ConfigError(path + ": line " + std::to_string(part.rows.front().line) +
                          ": setup: empty, while other rows name their set-up");
      out.push_back(prepareInput(a, label.empty() ? path : path + " [setup " + label + "]", rf, std::move(part)));
    }
  }
  // Set-ups weigh against each other by their sigmas: when one carries the tracker's own (and so the model error
  // beside them), the others get their model error too.
  bool any = false;
  for (const auto& in : out) any = any || in.own_sigmas;
  for (auto& in : out)
    if (any && !in.model_error_added) addModelErrorComponent(in, a);
  return out;
}

namespace {
LoadedInput prepareInput(const InputArgs& a, const std::string& name, RobotFile rf, MeasurementFile file) {
  LoadedInput in;
  in.name = name;
  in.robot = std::move(rf.model);
  in.calibration = std::move(rf.calibration);
  in.source = rf.source;
  in.file = std::move(file);
  in.kind = a.position_only ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
  const auto& rows = in.file.rows;
  const DriverTable drivers = driversOf(in.file);
  in.data.has_thermal = drivers.has_thermal;
  in.data.thermal_source = drivers.thermal_source;
  // 'positions': rows measured within kPositionRadiusMm of a position's first row are that position (in row order);
  // even positions identify, odd ones verify, so no verification row has an identification row that near.
  std::vector<int> position_of(rows.size(), 0);
  if (a.split == "positions") {
    std::vector<Eigen::Vector3d> first;
    for (size_t i = 0; i < rows.size(); ++i) {
      const Eigen::Vector3d p = rows[i].position_m;
      size_t k = 0;
      while (k < first.size() && (first[k] - p).norm() > kPositionRadiusMm * 1e-3) ++k;
      if (k == first.size()) first.push_back(p);
      position_of[i] = static_cast<int>(k);
    }
  }
  for (size_t i = 0; i < rows.size(); ++i) {
    const Observation o =
        toObservation(rows[i], in.kind, a.sigma_position_mm * 1e-3, a.sigma_orientation_deg * kPi / 180);
    (o.kind == MeasurementKind::kPose6D ? in.oriented_rows : in.position_rows)++;
    const bool to_verify = a.split == "alternate" ? (i % 2 == 1)
                           : a.split == "positions" ? (position_of[i] % 2 == 1)
                                                    : (i >= rows.size() / 2);
    (to_verify ? in.data.verification : in.data.identification).push_back(o);
    (to_verify ? in.data.verification_drivers : in.data.identification_drivers).push_back(drivers.rows[i]);
    (to_verify ? in.verification_lines : in.identification_lines).push_back(rows[i].line);
  }
  if (in.oriented_rows == 0) in.kind = MeasurementKind::kPosition3D;
  if (in.data.identification.size() < 8 || in.data.verification.empty())
    throw ConfigError(name + ": too few rows (" + std::to_string(rows.size()) + "): the " + a.split +
                      " split gives " + std::to_string(in.data.identification.size()) + " to identify and " +
                      std::to_string(in.data.verification.size()) +
                      " to verify; at least 8 and 1 are needed (16 rows or more)");
  const auto t0 = std::chrono::steady_clock::now();
  in.start = in.robot.nominal;
  in.registration_rms_mm = std::nan("");
  if (!a.no_register) {
    const RegistrationResult reg = registerFrames(in.robot, in.robot.nominal, in.data.identification);
    in.start = reg.params;
    in.registration_rms_mm = reg.rms_position_m * 1e3;
    // No robot is off its nominal model by this much: rows of two placements of the tracker (or the target)?
    constexpr double kSetupHintRmsMm = 5.0;
    if (in.registration_rms_mm > kSetupHintRmsMm) {
      std::vector<Observation> all;
      for (const auto& r : rows)
        all.push_back(toObservation(r, in.kind, a.sigma_position_mm * 1e-3, a.sigma_orientation_deg * kPi / 180));
      if (const auto c = findSetupChange(in.robot, in.robot.nominal, all)) {
        const auto k = static_cast<size_t>(c->first_row);
        in.setup_change_line = rows[k].line;
        char b[512];
        std::snprintf(b, sizeof b,
                      "the rows look like two set-ups (the tracker or the target moved): one registration leaves %.1f mm "
                      "RMS; lines %d-%d register to %.2f mm and lines %d-%d to %.2f mm on their own. Calibrate each "
                      "set-up from its own file, or carry a calibrated model to the other with --frames-only "
                      "(docs/real-robots.md)",
                      c->rms_single_m * 1e3, rows.front().line, rows[k - 1].line, c->rms_first_m * 1e3, rows[k].line,
                      rows.back().line, c->rms_second_m * 1e3);
        in.setup_hint = b;
      }
    }
  }
  in.registration_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // The tracker's own sigmas weight the rows only as far as they matter: beside them, the error a geometric fit
  // leaves (its gross errors screened out) as a variance component of every row (model_error.hpp).
  for (const auto& r : rows) in.own_sigmas = in.own_sigmas || r.sigma_position_m || r.sigma_orientation_rad;
  if (in.own_sigmas) addModelErrorComponent(in, a);
  return in;
}

void addModelErrorComponent(LoadedInput& in, const InputArgs& a) {
  CalibrationProblem p{&in.robot, in.start, in.data.identification, std::nullopt, {}, {}};
  p.outliers = outlierOptions(a);
  const CalibrationResult r = solveGaussNewton(p);
  in.model_error = modelErrorSigma(in.robot, r.params, in.data.identification, r.outliers.rows);
  in.model_error_added = true;
  addModelError(in.data.identification, in.model_error);
  addModelError(in.data.verification, in.model_error);
}
}  // namespace

std::string LoadedInput::modelErrorText() const {
  if (!model_error_added) return "";
  char b[400];
  std::snprintf(b, sizeof b,
                "reading sigmas: %s; a geometric fit leaves %.4f mm and %.4f deg per axis beyond them, added to every "
                "row's sigmas (model_error.hpp)",
                own_sigmas ? "the file's own" : "the defaults, beside set-ups with their own", model_error.position_m * 1e3,
                model_error.orientation_rad * 180 / kPi);
  return b;
}

nlohmann::json LoadedInput::modelErrorJson() const {
  if (!model_error_added) return nullptr;
  return {{"position_mm", model_error.position_m * 1e3}, {"orientation_deg", model_error.orientation_rad * 180 / kPi}};
}

std::string LoadedInput::measurementText() const {
  if (position_rows == 0) return "6D";
  if (oriented_rows == 0) return "position only";
  return "mixed: " + std::to_string(oriented_rows) + " 6D, " + std::to_string(position_rows) + " position-only rows";
}

std::string LoadedInput::measurementJson() const {
  if (position_rows == 0) return "pose6d";
  return oriented_rows == 0 ? "position3d" : "mixed";
}

// "backlash:3,joint_compliance:2" or "thermal_drift" (lengths) -> extensions; joints 1-based.
std::vector<Extension> parseModel(const std::string& spec, const RobotModel& robot) {
  try {
    return parseExtensionList(spec, robot);
  } catch (const std::invalid_argument& e) {
    throw ConfigError(std::string("--model: ") + e.what() + " (or geometric, auto; a usage error, exit 2)");
  }
}

std::string linesText(const std::vector<int>& rows, const std::vector<int>& lines, size_t most) {
  std::string s = rows.size() == 1 ? "line " : "lines ";
  for (size_t k = 0; k < rows.size() && k < most; ++k) {
    if (k > 0) s += k + 1 == rows.size() ? " and " : ", ";
    s += std::to_string(lines[static_cast<size_t>(rows[k])]);
  }
  if (rows.size() > most) s += " and " + std::to_string(rows.size() - most) + " more";
  return s;
}

nlohmann::json outliersJson(const OutlierScreen& s, const std::vector<int>& lines) {
  nlohmann::json rows = nlohmann::json::array();
  for (int r : s.rows)
    rows.push_back({{"line", lines[static_cast<size_t>(r)]}, {"robust_sigmas", s.z[static_cast<size_t>(r)]}});
  return {{"rows", rows}, {"robust_sigma_position_mm", s.sigma_position_m * 1e3}};
}

nlohmann::json heldJson(const std::vector<ExcitationDeficit>& held) {
  nlohmann::json j = nlohmann::json::array();
  for (const auto& h : held)
    j.push_back({{"name", h.name}, {"identification_rms", h.identification_rms}, {"elsewhere_max", h.elsewhere_max}});
  return j;
}

nlohmann::json errorStatsJson(const ErrorStats& s, const std::string& prefix) {
  const std::string& p = prefix;
  nlohmann::json j = {{p + "mean_mm", s.mean_mm}, {p + "rms_mm", s.rms_mm}, {p + "max_mm", s.max_mm}};
  if (s.oriented) j.update({{p + "mean_deg", s.mean_deg}, {p + "rms_deg", s.rms_deg}, {p + "max_deg", s.max_deg}});
  return j;
}

std::string fileSha256(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot read");
  EVP_MD_CTX* ctx = EVP_MD_CTX_new();
  EVP_DigestInit_ex(ctx, EVP_sha256(), nullptr);
  char buf[1 << 16];
  while (in) {
    in.read(buf, sizeof buf);
    if (in.gcount() > 0) EVP_DigestUpdate(ctx, buf, static_cast<size_t>(in.gcount()));
  }
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  EVP_DigestFinal_ex(ctx, md, &len);
  EVP_MD_CTX_free(ctx);
  std::string hex;
  char h[3];
  for (unsigned int i = 0; i < len; ++i) {
    std::snprintf(h, sizeof h, "%02x", md[i]);
    hex += h;
  }
  return hex;
}

std::string utcNow() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

void addInputOptions(CLI::App* cmd, InputArgs& a) {
  cmd->add_option("--robot", a.robot, "robot file (YAML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--data", a.data_files,
                  "measurement file (CSV v1, docs/measurement-csv.md); calibrate: given again for each further set-up "
                  "(another placement of the tracker or the target)")
      ->required()
      ->check(CLI::ExistingFile)
      ->each([&a](const std::string& f) {
        if (a.data.empty()) a.data = f;
        else a.more_data.push_back(f);
      });
  cmd->add_option("--split", a.split,
                  "alternate (even rows identify, odd rows verify) | halves (the first half identifies) | positions "
                  "(rows measured within 20 mm of a position's first row are that position; alternate positions "
                  "identify: the verification rows are positions the identification never saw)")
      ->check(CLI::IsMember({"alternate", "halves", "positions"}))
      ->capture_default_str();
  cmd->add_option("--sigma-position-mm", a.sigma_position_mm, "1-sigma position noise of a reading")->check(positive())->capture_default_str();
  cmd->add_option("--sigma-orientation-deg", a.sigma_orientation_deg, "1-sigma orientation noise")->check(positive())->capture_default_str();
  cmd->add_flag("--position-only", a.position_only, "use positions only, even where orientations are given");
  cmd->add_option("--outlier-threshold", a.outlier_threshold,
                  "a row whose position error exceeds this many robust sigmas (per axis, from the median residual) is a "
                  "gross error: listed by its line and left out of the fit; 0: no screening")
      ->check(CLI::Number)
      ->capture_default_str();
  cmd->add_flag("--skip-bad-rows", a.skip_bad_rows, "skip (and count) bad rows instead of stopping");
  cmd->add_flag("--no-register", a.no_register, "trust the robot file's base and tool frames as the start");
  cmd->add_option("--plausible-length-mm", a.plausible_length_mm,
                  "how far a kinematic length may plausibly lie from the robot file's (1 sigma): a length is estimated "
                  "only where the data, at the noise the fit leaves, pin it better than this; the others are held at the "
                  "file's value and named; 0: rank alone decides")
      ->check(nonNegative())
      ->capture_default_str();
  cmd->add_option("--plausible-angle-deg", a.plausible_angle_deg,
                  "the same for kinematic angles (joint offsets, alpha, beta); 0: rank alone decides")
      ->check(nonNegative())
      ->capture_default_str();
}

Eigen::VectorXd plausibleRanges(const InputArgs& a, const RobotModel& robot) {
  if (!(a.plausible_length_mm > 0) && !(a.plausible_angle_deg > 0)) return {};
  return plausibleDeviation(robot, a.plausible_length_mm * 1e-3, a.plausible_angle_deg * kPi / 180);
}

}  // namespace cellcal::cli

namespace cellcal::cli {

void addRobotOrCellOptions(CLI::App& cmd, std::string& robot, std::string& config, std::string& robot_id,
                           const std::string& robot_help) {
  cmd.add_option("--robot", robot, robot_help)->check(CLI::ExistingFile);
  cmd.add_option("--config", config, "instead of --robot: a cell file, its robot with the cell's registration")
      ->check(CLI::ExistingFile);
  cmd.add_option("--robot-id", robot_id, "with --config: which robot (when the cell has several)");
}

std::vector<double> parseNumbers(const std::string& text, size_t count, const std::string& option,
                                 const std::string& expected) {
  std::vector<double> v;
  std::stringstream ss(text);
  for (std::string cell; std::getline(ss, cell, ',');) {
    char* end = nullptr;
    const double x = std::strtod(cell.c_str(), &end);
    if (end == cell.c_str() || *end != '\0' || !std::isfinite(x))
      throw ConfigError(option + ": '" + cell + "' is not a number (expected " + expected + ")");
    v.push_back(x);
  }
  if (v.size() != count) throw ConfigError(option + ": expected " + std::to_string(count) + " numbers " + expected);
  return v;
}

RobotFile robotOrCellRobot(const std::string& robot, const std::string& config, const std::string& robot_id,
                           std::string* label) {
  if (robot.empty() == config.empty())
    throw ConfigError("give either --robot (a robot file with its frames) or --config (a cell file: its robot and "
                      "registration)");
  if (!robot.empty()) {
    if (label) *label = robot;
    return loadRobotFile(robot);
  }
  const CellConfig cell = loadCellConfig(config);
  std::string ids;
  for (const auto& r : cell.robots) {
    ids += (ids.empty() ? "" : ", ") + r.robot_id;
    if (r.robot_id == robot_id || (robot_id.empty() && cell.robots.size() == 1)) {
      if (label) *label = r.robot_id + " of " + config;
      RobotFile f = loadRobotFile(r.robot_file);
      f.model = r.model;  // the robot file with the cell's registration
      return f;
    }
  }
  throw ConfigError(config + ": " + (robot_id.empty() ? "several robots (" + ids + "): name one with --robot-id"
                                                      : "no robot '" + robot_id + "' (" + ids + ")"));
}

}  // namespace cellcal::cli
