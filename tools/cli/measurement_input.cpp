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

std::pair<RobotFile, MeasurementFile> readInput(const InputArgs& a, const std::string& path) {
  RobotFile rf = loadRobotFile(a.robot);
  MeasurementCsvOptions mo;
  mo.skip_bad_rows = a.skip_bad_rows;
  MeasurementFile file = readMeasurementCsv(path, rf.model, mo);
  for (const auto& w : file.warnings) std::fprintf(stderr, "skipped: %s\n", w.c_str());
  for (const auto& c : file.ignored_columns) std::fprintf(stderr, "%s: column '%s' ignored\n", path.c_str(), c.c_str());
  return {std::move(rf), std::move(file)};
}

}  // namespace

InputOptions inputOptions(const InputArgs& a) {
  InputOptions o;
  o.split = a.split;
  o.sigma_position_m = a.sigma_position_mm * 1e-3;
  o.sigma_orientation_rad = a.sigma_orientation_deg * kPi / 180;
  o.position_only = a.position_only;
  o.register_frames = !a.no_register;
  o.find_setup_changes = !a.one_setup;
  o.outliers = outlierOptions(a);
  return o;
}

LoadedInput loadInput(const InputArgs& a) {
  if (!a.more_data.empty())
    throw ConfigError("--data given " + std::to_string(1 + a.more_data.size()) +
                      " times: only `cellcal calibrate` takes several set-ups (a usage error, exit 2)");
  auto [rf, file] = readInput(a, a.data);
  const auto parts = splitBySetup(file);
  if (parts.size() > 1) {
    std::string labels;
    for (const auto& p : parts) labels += (labels.empty() ? "" : ", ") + (p.first.empty() ? "(none)" : p.first);
    throw ConfigError(a.data + ": rows of " + std::to_string(parts.size()) + " set-ups (column setup: " + labels +
                      "): only `cellcal calibrate` takes several set-ups (a usage error, exit 2)");
  }
  const InputOptions options = inputOptions(a);
  const std::vector<FoundSetupChange> found =
      options.find_setup_changes ? findSetupChanges(rf.model, file, options) : std::vector<FoundSetupChange>{};
  if (found.empty()) return prepareCampaignInput(a.data, std::move(rf), std::move(file), options);
  // Several set-ups found: this command takes one, the largest block (the first of equals).
  size_t best = 0;
  MeasurementFile block = foundSetupBlock(file, found, 0);
  for (size_t b = 1; b <= found.size(); ++b)
    if (MeasurementFile other = foundSetupBlock(file, found, b); other.rows.size() > block.rows.size())
      best = b, block = std::move(other);
  const std::string name = foundSetupBlockName(a.data, block);
  LoadedInput in = prepareCampaignInput(name, std::move(rf), std::move(block), options);
  in.path = a.data;
  in.found_changes = found;
  in.found_block = static_cast<int>(best) + 1;
  return in;
}

nlohmann::json foundChangeJson(const FoundSetupChange& f) {
  if (f.registration_rms_mm.size() == 3)  // no registration fits both sides: found by registering each apart
    return {{"line", f.line}, {"found_by", "registration"}, {"probability", nullptr}, {"move_mm", nullptr},
            {"registration_rms_mm", {{"one", f.registration_rms_mm[0]}, {"before", f.registration_rms_mm[1]},
                                     {"after", f.registration_rms_mm[2]}}}};
  return {{"line", f.line}, {"found_by", "scan"}, {"probability", f.probability}, {"move_mm", f.move_mm}};
}

std::string foundSetupsText(const CampaignInput& in) {
  if (in.found_changes.empty()) return "";
  const auto& f = in.found_changes;
  std::string s = "the rows of " + in.path + " are " + std::to_string(f.size() + 1) +
                  " set-ups (the tracker or the target moved; no setup column says so): ";
  for (size_t k = 0; k < f.size(); ++k) {
    char b[240];
    const char* sep = k == 0 ? "" : k + 1 == f.size() ? " and " : ", ";
    if (f[k].registration_rms_mm.size() == 3)
      std::snprintf(b, sizeof b, "%sa change before line %d (one registration leaves %.1f mm RMS; each side on its "
                    "own %.2f and %.2f mm)", sep, f[k].line, f[k].registration_rms_mm[0], f[k].registration_rms_mm[1],
                    f[k].registration_rms_mm[2]);
    else
      std::snprintf(b, sizeof b, "%sa change before line %d (the target moves %.3f mm RMS after it; probability %.1e "
                    "that rows of one set-up split as clearly)", sep, f[k].line, f[k].move_mm, f[k].probability);
    s += b;
  }
  return s + ". Each is registered apart; --one-setup takes them as one";
}

std::vector<LoadedInput> loadSetups(const InputArgs& a) {
  std::vector<std::string> paths = {a.data};
  paths.insert(paths.end(), a.more_data.begin(), a.more_data.end());
  const InputOptions options = inputOptions(a);
  std::vector<LoadedInput> out;
  for (const auto& path : paths) {
    auto [rf, file] = readInput(a, path);
    for (auto& in : prepareCampaignSetups(path, rf, file, options)) out.push_back(std::move(in));
  }
  weighSetupsAlike(&out, options);
  return out;
}

nlohmann::json modelErrorJson(const CampaignInput& in) {
  if (!in.model_error_added) return nullptr;
  return {{"position_mm", in.model_error.position_m * 1e3}, {"orientation_deg", in.model_error.orientation_rad * 180 / kPi}};
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
  nlohmann::json j = {{p + "mean_mm", s.mean_mm}, {p + "rms_mm", s.rms_mm}, {p + "p997_mm", s.p997_mm}, {p + "max_mm", s.max_mm}};
  if (s.oriented)
    j.update({{p + "mean_deg", s.mean_deg}, {p + "rms_deg", s.rms_deg}, {p + "p997_deg", s.p997_deg}, {p + "max_deg", s.max_deg}});
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
  cmd->add_flag("--one-setup", a.one_setup,
                "take a file without a setup column as one set-up: no search for rows where the tracker or the target "
                "moved");
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

Pose parseFrameMmDeg(const std::string& text, const std::string& option) {
  const std::vector<double> v = parseNumbers(text, 6, option, "X,Y,Z,ROLL,PITCH,YAW in mm and deg");
  return poseFromXyzRpy(v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3, degToRad(v[3]), degToRad(v[4]), degToRad(v[5]));
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
