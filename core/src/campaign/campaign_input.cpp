#include "cellcal/core/campaign/campaign_input.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/calibration.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/identification/setup_change.hpp"

namespace cellcal {

bool InputOptions::IsValid(std::string* why) const {
  auto fail = [why](const std::string& s) {
    if (why) *why = s;
    return false;
  };
  if (split != "alternate" && split != "halves" && split != "positions")
    return fail("split: '" + split + "' is not alternate, halves or positions");
  if (!(sigma_position_m > 0) || !std::isfinite(sigma_position_m)) return fail("sigma_position_m: must be positive");
  if (!(sigma_orientation_rad > 0) || !std::isfinite(sigma_orientation_rad))
    return fail("sigma_orientation_rad: must be positive");
  return outliers.IsValid(why);
}

std::vector<std::pair<std::string, MeasurementFile>> splitBySetup(const MeasurementFile& file) {
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

namespace {

// No robot is off its nominal model by this much (RMS of one registration, mm): rows of two placements.
constexpr double kSetupHintRmsMm = 5.0;

void addModelErrorComponent(CampaignInput& in, const InputOptions& options) {
  CalibrationProblem p{&in.robot, in.start, in.data.identification, std::nullopt, {}, {}};
  p.outliers = options.outliers;
  const CalibrationResult r = solveGaussNewton(p);
  in.model_error = modelErrorSigma(in.robot, r.params, in.data.identification, r.outliers.rows);
  in.model_error_added = true;
  addModelError(in.data.identification, in.model_error);
  addModelError(in.data.verification, in.model_error);
}

// The nominal kinematics at their least-squares frames, weighted as the calibration weighs the rows: what 'before'
// is measured with, as 'after' and --frames-only register (the closed form only starts it; on rows the nominal model
// fits badly it can leave twice the error, and a 'before' from it overstates the gain).
void refineStart(CampaignInput& in) {
  const RegistrationResult best = refineFrames(in.robot, in.start, {}, Eigen::VectorXd(), in.data.identification,
                                               in.data.identification_drivers);
  in.start = best.params;
  in.registration_rms_mm = best.rms_position_m * 1e3;
}

}  // namespace

CampaignInput prepareCampaignInput(const std::string& name, RobotFile rf, MeasurementFile file,
                                   const InputOptions& a) {
  std::string why;
  if (!a.IsValid(&why)) throw ConfigError(name + ": " + why);
  CampaignInput in;
  in.name = name;
  in.path = name;  // a block or a labelled set-up of a file: the caller names the file
  in.split = a.split;
  in.robot = std::move(rf.model);
  in.calibration = std::move(rf.calibration);
  in.source = rf.source;
  in.file = std::move(file);
  in.kind = a.position_only ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
  const auto& rows = in.file.rows;
  const DriverTable drivers = driversOf(in.file);
  in.data.has_thermal = drivers.has_thermal;
  in.data.thermal_source = drivers.thermal_source;
  in.data.constant_temperature_c = drivers.constant_temperature_c;
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
    const Observation o = toObservation(rows[i], in.kind, a.sigma_position_m, a.sigma_orientation_rad);
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
  if (a.register_frames) {
    const RegistrationResult reg = registerFrames(in.robot, in.robot.nominal, in.data.identification);
    in.start = reg.params;
    in.registration_rms_mm = reg.rms_position_m * 1e3;
    if (reg.line_direction) {
      char b[400];
      std::snprintf(b, sizeof b,
                    "the positions lie on a line (direction %.3f %.3f %.3f in the tracker frame): the robot's turn "
                    "about it is not in these rows; the registration takes the smallest turn, the calibration holds "
                    "what the rows leave open, and its figures hold on that line only",
                    reg.line_direction->x(), reg.line_direction->y(), reg.line_direction->z());
      in.registration_note = b;
    }
    // No robot is off its nominal model by this much: rows of two placements of the tracker (or the target)?
    if (in.registration_rms_mm > kSetupHintRmsMm) {
      std::vector<Observation> all;
      for (const auto& r : rows) all.push_back(toObservation(r, in.kind, a.sigma_position_m, a.sigma_orientation_rad));
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
  if (a.register_frames) refineStart(in);
  return in;
}

namespace {

void splitAt(const RobotModel& robot, const std::vector<MeasurementRow>& rows, int begin, int end,
             const InputOptions& a, FoundSetupChange f, std::vector<FoundSetupChange>* out);

// Rows [begin, end) of `rows` scanned as one set-up; the changes found, recursively, appended to `out`.
void searchSetups(const RobotModel& robot, const std::vector<MeasurementRow>& rows, int begin, int end,
                  const InputOptions& a, std::vector<FoundSetupChange>* out) {
  const SetupChangeOptions so;
  if (end - begin < 2 * so.min_rows || static_cast<int>(out->size()) + 1 >= kMaxFoundSetups) return;
  const MeasurementKind kind = a.position_only ? MeasurementKind::kPosition3D : MeasurementKind::kPose6D;
  std::vector<Observation> obs;
  std::vector<double> times, temperatures;
  for (int i = begin; i < end; ++i) {
    const auto& r = rows[static_cast<size_t>(i)];
    obs.push_back(toObservation(r, kind, a.sigma_position_m, a.sigma_orientation_rad));
    if (r.stamp_s && (times.empty() || *r.stamp_s >= times.back())) times.push_back(*r.stamp_s);
    if (r.temperature_c) temperatures.push_back(*r.temperature_c);
  }
  if (times.size() != obs.size()) times.clear();  // some row without a stamp, or stamps out of order: the rows' order
  if (temperatures.size() != obs.size()) temperatures.clear();
  // Rows no registration fits (a tracker moved by far more than a robot's error): where registering each side apart
  // fits them ten times better (findSetupChange); else, and for every smaller change, the scan of a calibration of
  // them all.
  const RegistrationResult reg = registerFrames(robot, robot.nominal, obs);
  if (reg.rms_position_m * 1e3 > kSetupHintRmsMm) {
    const auto c = findSetupChange(robot, robot.nominal, obs, 10, so.min_rows);
    if (c) {
      FoundSetupChange f;
      f.first_row = begin + c->first_row;
      f.probability = 0;
      f.registration_rms_mm = {c->rms_single_m * 1e3, c->rms_first_m * 1e3, c->rms_second_m * 1e3};
      return splitAt(robot, rows, begin, end, a, f, out);
    }
  }
  CalibrationProblem p;
  p.model = &robot;
  p.initial_params = reg.params;
  p.observations = obs;
  p.outliers.enabled = false;  // the scan clips each row itself
  const CalibrationResult fit = solveGaussNewton(p);
  // The scan fits the model's columns itself, about the point it is given: the fit where it got closer than the
  // registration (rows of two set-ups can keep it from converging), else the registration.
  const bool closer = fit.params.allFinite() && fit.final_cost_per_observation <= fit.initial_cost_per_observation;
  const SetupChangeScan scan =
      scanSetupChange(robot, closer ? fit.params : reg.params, fit.estimated, obs, so, times, temperatures);
  if (!scan.found) return;
  FoundSetupChange f;
  f.first_row = begin + scan.first_row;
  f.probability = scan.probability;
  f.move_mm = scan.move_m * 1e3;
  splitAt(robot, rows, begin, end, a, f, out);
}

// The change f splits rows [begin, end): each side searched again, in row order (the changes come out sorted).
void splitAt(const RobotModel& robot, const std::vector<MeasurementRow>& rows, int begin, int end,
             const InputOptions& a, FoundSetupChange f, std::vector<FoundSetupChange>* out) {
  f.line = rows[static_cast<size_t>(f.first_row)].line;
  searchSetups(robot, rows, begin, f.first_row, a, out);
  out->push_back(f);
  searchSetups(robot, rows, f.first_row, end, a, out);
}

}  // namespace

std::vector<FoundSetupChange> findSetupChanges(const RobotModel& robot, const MeasurementFile& file,
                                               const InputOptions& options) {
  std::vector<FoundSetupChange> out;
  searchSetups(robot, file.rows, 0, static_cast<int>(file.rows.size()), options, &out);
  return out;
}

MeasurementFile foundSetupBlock(const MeasurementFile& file, const std::vector<FoundSetupChange>& found, size_t b) {
  const auto first = b == 0 ? file.rows.begin() : file.rows.begin() + found[b - 1].first_row;
  const auto last = b == found.size() ? file.rows.end() : file.rows.begin() + found[b].first_row;
  MeasurementFile block;
  block.source = file.source;
  block.rows.assign(first, last);
  return block;
}

std::string foundSetupBlockName(const std::string& path, const MeasurementFile& block) {
  return path + " [lines " + std::to_string(block.rows.front().line) + "-" + std::to_string(block.rows.back().line) +
         "]";
}

std::vector<CampaignInput> prepareCampaignSetups(const std::string& path, const RobotFile& robot,
                                                 const MeasurementFile& file, const InputOptions& options) {
  if (file.rows.empty()) throw ConfigError(path + ": no data rows");  // readMeasurementCsv refuses it already
  std::vector<CampaignInput> out;
  for (auto& [label, part] : splitBySetup(file)) {
    if (label.empty() && file.rows.size() != part.rows.size())
      throw ConfigError(path + ": line " + std::to_string(part.rows.front().line) +
                        ": setup: empty, while other rows name their set-up");
    const std::vector<FoundSetupChange> found =
        label.empty() && options.find_setup_changes ? findSetupChanges(robot.model, part, options)
                                                    : std::vector<FoundSetupChange>{};
    if (found.empty()) {
      out.push_back(prepareCampaignInput(label.empty() ? path : path + " [setup " + label + "]", robot,
                                         std::move(part), options));
      out.back().path = path;
      continue;
    }
    // One set-up per block between the changes found, named by its lines.
    for (size_t b = 0; b <= found.size(); ++b) {
      MeasurementFile block = foundSetupBlock(part, found, b);
      const std::string name = foundSetupBlockName(path, block);
      out.push_back(prepareCampaignInput(name, robot, std::move(block), options));
      out.back().path = path;
      out.back().found_changes = found;
      out.back().found_block = static_cast<int>(b) + 1;
    }
  }
  return out;
}

void weighSetupsAlike(std::vector<CampaignInput>* setups, const InputOptions& options) {
  bool any = false;
  for (const auto& in : *setups) any = any || in.own_sigmas;
  for (auto& in : *setups)
    if (any && !in.model_error_added) {
      addModelErrorComponent(in, options);
      if (options.register_frames) refineStart(in);
    }
}

std::string CampaignInput::modelErrorText() const {
  if (!model_error_added) return "";
  char b[400];
  std::snprintf(b, sizeof b,
                "reading sigmas: %s; a geometric fit leaves %.4f mm and %.4f deg per axis beyond them, added to every "
                "row's sigmas (model_error.hpp)",
                own_sigmas ? "the file's own" : "the defaults, beside set-ups with their own", model_error.position_m * 1e3,
                model_error.orientation_rad * 180 / kPi);
  return b;
}

std::string CampaignInput::measurementText() const {
  if (position_rows == 0) return "6D";
  if (oriented_rows == 0) return "position only";
  return "mixed: " + std::to_string(oriented_rows) + " 6D, " + std::to_string(position_rows) + " position-only rows";
}

std::string CampaignInput::measurementName() const {
  if (position_rows == 0) return "pose6d";
  return oriented_rows == 0 ? "position3d" : "mixed";
}

}  // namespace cellcal
