// `cellcal robot import`: a URDF as a robot file. `cellcal robot export`: a calibrated robot file back into the robot
// stack: the nominal URDF with the chain's joint origins calibrated, the `kinematics:` YAML of Universal Robots'
// driver, or the calibrated DH table (core's write(): files/export.hpp); each says what the format cannot carry and
// what that costs.
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>

#include "cellcal/core/files/export.hpp"
#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/files/urdf.hpp"
#include "cellcal/core/identification/extended_fit.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {
namespace {

struct ImportArgs {
  std::string urdf, out, base_link, tip_link;
};

struct ExportArgs {
  std::string robot, format = "urdf", urdf, out, json, base_frame_link, ur_hash, target_in_flange;
};

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path + ": cannot open");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void writeText(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw std::runtime_error(path + ": cannot write");
    out << text;
    if (!out.flush()) throw std::runtime_error(path + ": write failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) throw std::runtime_error(path + ": cannot replace");
}

int runImport(const ImportArgs& a) {
  UrdfImportOptions o;
  o.base_link = a.base_link;
  o.tip_link = a.tip_link;
  const UrdfImport u = importUrdfFile(a.urdf, o);
  const std::vector<std::pair<std::string, std::string>> source = {
      {"urdf", a.urdf}, {"sha256", fileSha256(a.urdf)}, {"base_link", u.base_link}, {"tip_link", u.tip_link},
      {"tool", "cellcal robot import"}, {"date_utc", utcNow()}};
  std::string header = u.model.name + ": converted by `cellcal robot import` from " + a.urdf +
                       " (docs/robot-file.md, from your URDF to a calibrated URDF)";
  for (const auto& n : u.notes) header += "\n" + n;
  saveRobotFile(a.out, u.model, nullptr, header, &source);
  std::printf("robot import: %s (%s) -> %s\n", a.urdf.c_str(), u.model.name.c_str(), a.out.c_str());
  for (const auto& n : u.notes) std::printf("  %s\n", n.c_str());
  return 0;
}

// The held-out error of the full calibrated model and of the written file's own model (writtenParams) on the rows it
// was calibrated on (provenance data_file, split), when that file is there; and how far the file's tool0 lies from the
// full model's over all those rows (what the file leaves out: extensions, what the format cannot carry at the tip).
struct ExportCost {
  bool measured = false;
  std::string why;
  ErrorStats full, written, at_tool0;
};

// What a format that carries no extensions gets from the robot file: of an extended calibration, the geometric
// calibration of the same data the file keeps beside it (geometric_parameters: fitted on its own, so the best
// geometric model of those data, not the extended one truncated); else the file's model (its geometric part).
// `own_fit`: whether it is that geometric calibration.
CalibratedModel exportedModel(const RobotFile& rf, bool* own_fit) {
  CalibratedModel full = calibratedModel(rf);
  *own_fit = !full.extensions.empty() && rf.calibration &&
             rf.calibration->geometric_params.size() == rf.model.numParams();
  if (!*own_fit) return full;
  CalibratedModel g = CalibratedModel::geometric(rf.calibration->geometric_params);
  g.estimated = full.estimated;  // a calibration: what the target's frame absorbed is said as for the full model
  return g;
}

ExportCost exportCost(const RobotFile& rf, const CalibratedModel& exported, const RobotExport& e, const ExportOptions& o) {
  ExportCost c;
  if (!rf.calibration) {
    c.why = "the robot file has no calibration section";
    return c;
  }
  const std::string data = rf.calibration->provenanceValue("data_file"), split = rf.calibration->provenanceValue("split");
  if (data.empty() || !std::ifstream(data)) {
    c.why = "its calibration data (" + (data.empty() ? std::string("no data_file in its provenance") : data) +
            ") is not here";
    return c;
  }
  const RobotModel& m = rf.model;
  const MeasurementFile f = readMeasurementCsv(data, m);
  std::vector<Observation> all, verify;
  std::vector<Drivers> drivers, verify_drivers;
  const DriverTable table = driversOf(f);
  for (size_t i = 0; i < f.rows.size(); ++i) {
    all.push_back(toObservation(f.rows[i], MeasurementKind::kPose6D, 0.01e-3, 0.001 * kPi / 180));
    drivers.push_back(table.rows[i]);
    if (split == "halves" ? i >= f.rows.size() / 2 : i % 2 == 1) {
      verify.push_back(all.back());
      verify_drivers.push_back(drivers.back());
    }
  }
  const CalibratedModel full = calibratedModel(rf);
  const CalibratedModel written = CalibratedModel::geometric(writtenParams(m, exported.params, e, o));
  c.full = errorStats(m, full, verify, verify_drivers);
  c.written = errorStats(m, written, verify, verify_drivers);
  // At the file's tool0: both targets moved back by the target's place on it (the nominal one given, else the
  // calibrated one).
  const int t = m.toolParam(FrameParam::kX);
  const Eigen::VectorXd& p = exported.params;
  const Pose target = o.target_in_flange ? *o.target_in_flange
                                         : poseFromXyzRpy(p[t], p[t + 1], p[t + 2], p[t + 3], p[t + 4], p[t + 5]);
  const std::vector<Pose> a = predictedPoses(m, full, all, drivers), b = predictedPoses(m, written, all, drivers);
  ErrorStatsAccumulator acc;
  for (size_t i = 0; i < all.size(); ++i) {
    Observation at_tool0;
    at_tool0.measured_in_tracker = a[i] * target.inverse();
    acc.add(at_tool0, b[i] * target.inverse());
  }
  c.at_tool0 = acc.stats();
  c.measured = true;
  return c;
}

// How the export moves base_link -> tool0 from the nominal description (tool0Change), printed and under tool0_change.
void printTool0Change(const Tool0Change& c, nlohmann::json& j) {
  if (c.configurations == 0) return;
  std::printf("  base_link -> tool0 against the nominal description (%d configurations within the joint limits): "
              "%.4f mm mean (max %.4f), %.4f deg mean (max %.4f); a rigid motion of base_link explains %.4f deg "
              "(%+.4f about joint 1's axis) and %.4f mm of it, %.4f mm mean left\n",
              c.configurations, c.mean_mm, c.max_mm, c.mean_deg, c.max_deg, c.rigid_deg, c.yaw_about_joint1_deg,
              c.rigid_mm, c.beyond_rigid_mean_mm);
  j["tool0_change"] = {{"configurations", c.configurations}, {"mean_mm", c.mean_mm}, {"max_mm", c.max_mm},
                       {"mean_deg", c.mean_deg}, {"max_deg", c.max_deg},
                       {"mean_offset_mm", {c.mean_offset_mm.x(), c.mean_offset_mm.y(), c.mean_offset_mm.z()}},
                       {"rigid_deg", c.rigid_deg}, {"rigid_mm", c.rigid_mm},
                       {"yaw_about_joint1_deg", c.yaw_about_joint1_deg},
                       {"beyond_rigid_mean_mm", c.beyond_rigid_mean_mm}};
}

// What the written file costs against the full calibrated model, printed and in the JSON.
void printExportCost(const ExportCost& cost, bool own_fit, nlohmann::json& j) {
  if (!cost.measured) {
    std::printf("  the cost of the export not measured: %s\n", cost.why.c_str());
    j["verification_full_model"] = nullptr;
    j["verification_exported"] = nullptr;
    j["cost_not_measured"] = cost.why;
    return;
  }
  std::printf("  held-out on its calibration rows: full model %.4f mm mean (%.4f RMS), the written file (%s) %.4f mm "
              "(%.4f RMS)\n",
              cost.full.mean_mm, cost.full.rms_mm, own_fit ? "the geometric calibration" : "the geometric part",
              cost.written.mean_mm, cost.written.rms_mm);
  std::printf("  the written file's tool0 against the full model's over the %d calibration rows: %.4f mm mean (max "
              "%.4f)",
              cost.at_tool0.rows, cost.at_tool0.mean_mm, cost.at_tool0.max_mm);
  if (cost.at_tool0.oriented > 0)
    std::printf(", %.4f deg mean (max %.4f)", cost.at_tool0.mean_deg, cost.at_tool0.max_deg);
  std::printf("\n");
  j["verification_full_model"] = errorStatsJson(cost.full);
  j["verification_exported"] = errorStatsJson(cost.written);
  j["left_out_at_tool0"] = errorStatsJson(cost.at_tool0);
  j["left_out_at_tool0"]["rows"] = cost.at_tool0.rows;
}

int runExport(const ExportArgs& a) {
  const RobotFile rf = loadRobotFile(a.robot);
  const RobotModel& m = rf.model;
  nlohmann::json j = {{"robot", a.robot}, {"format", a.format}, {"out", a.out}};
  const std::optional<ExportFormat> format = exportFormatFromName(a.format);
  if (!format) throw ConfigError("--format " + a.format + ": expected urdf, ur-kinematics or dh-table");
  ExportOptions o;
  if (!a.target_in_flange.empty()) o.target_in_flange = parseFrameMmDeg(a.target_in_flange, "--target-in-flange");
  o.base_frame_link = a.base_frame_link;
  o.ur_hash = a.ur_hash;
  if (*format != ExportFormat::kDhTable) {
    std::string urdf = a.urdf;
    if (urdf.empty()) {  // the URDF the robot file was imported from
      std::string why;
      const std::optional<UrdfOrigin> origin = urdfOriginOf(a.robot, rf.source, &why);
      if (!origin)
        throw ConfigError("--format " + a.format + ": --urdf NOMINAL.urdf is needed (the description to calibrate): " + why);
      urdf = origin->path;
      std::printf("robot export: the nominal description is %s (the robot file's source)\n", urdf.c_str());
    }
    for (const auto& [k, v] : rf.source) {  // the chain the robot file was imported with (else the URDF's default)
      if (k == "base_link") o.chain.base_link = v;
      if (k == "tip_link") o.chain.tip_link = v;
    }
    o.nominal_urdf_xml = readText(urdf);
    o.nominal_urdf_source = urdf;
    o.header = "written by `cellcal robot export --format ur-kinematics` from " + a.robot +
               "\nfor ur_robot_driver's kinematics_params_file (ur_calibration's format)";
  }
  o.model_source = a.robot;
  bool own_fit = false;
  const CalibratedModel exported = exportedModel(rf, &own_fit);
  RobotExport e = write(m, exported, *format, o);
  if (own_fit)
    e.not_carried.insert(e.not_carried.begin(),
                         "the model extensions (" + modelLabel(calibratedModel(rf).extensions) +
                             "): the geometric calibration of the same data, which the robot file keeps beside the "
                             "extended model, is exported in their place (the cell's compensation publisher takes the "
                             "extended model: --robot " + a.robot + ")");
  writeText(a.out, e.text);
  const Eigen::Matrix<double, 6, 1> tc = xyzRpyFromPose(e.tip_correction);
  j["tip_correction"] = {{"x_mm", tc[0] * 1e3}, {"y_mm", tc[1] * 1e3}, {"z_mm", tc[2] * 1e3}, {"roll_deg", radToDeg(tc[3])},
                         {"pitch_deg", radToDeg(tc[4])}, {"yaw_deg", radToDeg(tc[5])}};
  if (*format == ExportFormat::kUrKinematics) {
    j["not_carried_beyond_joint6_mm"] = e.not_carried_beyond_joint6_m * 1e3;
    j["not_carried_beyond_joint6_deg"] = radToDeg(e.not_carried_beyond_joint6_rad);
  }
  if (*format == ExportFormat::kDhTable) {
    nlohmann::json rows = nlohmann::json::array();
    for (const DhRow& r : e.dh_rows)
      rows.push_back({{"joint", r.joint}, {"name", r.name}, {"theta_offset_deg", r.theta_offset_deg}, {"d_mm", r.d_mm},
                      {"a_mm", r.a_mm}, {"alpha_deg", r.alpha_deg}, {"beta_deg", r.beta_deg},
                      {"parallel_to_next", r.parallel_to_next}});
    const auto b = exported.params.segment<6>(m.baseParam(FrameParam::kX)),
               t = exported.params.segment<6>(m.toolParam(FrameParam::kX));
    j["dh"] = rows;
    j["base_in_tracker"] = {b[0] * 1e3, b[1] * 1e3, b[2] * 1e3, radToDeg(b[3]), radToDeg(b[4]), radToDeg(b[5])};
    j["tool_in_flange"] = {t[0] * 1e3, t[1] * 1e3, t[2] * 1e3, radToDeg(t[3]), radToDeg(t[4]), radToDeg(t[5])};
  }
  const std::vector<std::string>& not_carried = e.not_carried;
  std::printf("robot export: %s -> %s (%s)\n", a.robot.c_str(), a.out.c_str(), a.format.c_str());
  if (o.target_in_flange)
    std::printf("  carried into tool0: the target's calibrated place against its nominal one, %.4f mm and %.4f deg "
                "(what the target's frame absorbed of the robot)\n",
                e.tip_correction.translation().norm() * 1e3, radToDeg(logSO3(e.tip_correction.linear()).norm()));
  for (const auto& n : not_carried) std::printf("  not carried: %s\n", n.c_str());
  printTool0Change(e.tool0_change, j);
  printExportCost(exportCost(rf, exported, e, o), own_fit, j);
  j["not_carried"] = not_carried;
  if (!a.json.empty()) std::ofstream(a.json) << j.dump(2) << "\n";
  return 0;
}

}  // namespace

Runner addRobotCommand(CLI::App& app) {
  CLI::App* robot = app.add_subcommand("robot", "Robot descriptions: a URDF as a robot file, a calibration back into the "
                                                "robot stack, a controller checked against it");
  robot->require_subcommand(1);
  auto imp = std::make_shared<ImportArgs>();
  CLI::App* i = addSubcommand(*robot, "import");
  i->add_option("urdf", imp->urdf, "the robot's URDF")->required()->check(CLI::ExistingFile);
  i->add_option("--out", imp->out, "robot file (YAML) to write")->required()->check(outputFile());
  i->add_option("--base-link", imp->base_link, "the chain's first link (default: the URDF's root)");
  i->add_option("--tip-link", imp->tip_link, "the chain's last link (default: tool0, else the one leaf)");
  auto exp = std::make_shared<ExportArgs>();
  CLI::App* e = addSubcommand(*robot, "export");
  e->add_option("--robot", exp->robot, "calibrated robot file (cellcal calibrate --save-robot)")->required()->check(CLI::ExistingFile);
  e->add_option("--format", exp->format, "urdf | ur-kinematics | dh-table")
      ->check(CLI::IsMember({"urdf", "ur-kinematics", "dh-table"}))
      ->capture_default_str();
  e->add_option("--urdf", exp->urdf,
                "the nominal URDF the robot file was converted from (urdf, ur-kinematics; default: the robot file's source)")->check(CLI::ExistingFile);
  e->add_option("--out", exp->out, "file to write")->required()->check(outputFile());
  e->add_option("--json", exp->json, "also write what was exported and what not, with its cost, as JSON")->check(outputFile());
  e->add_option("--base-frame-link", exp->base_frame_link,
                "add this link and a fixed joint from it to the base link at the calibrated base (the tracker frame)");
  e->add_option("--target-in-flange", exp->target_in_flange,
                "the target's nominal place on the flange, X,Y,Z,ROLL,PITCH,YAW (mm, deg): what the calibrated tool frame "
                "moved from it goes into the chain's last origin");
  e->add_option("--ur-hash", exp->ur_hash, "--format ur-kinematics: the controller's calibration hash");
  const Runner check = addRobotCheck(*robot);
  const Runner fk = addRobotFk(*robot);
  return [=]() -> int {
    if (*i) return runImport(*imp);
    if (*e) return runExport(*exp);
    if (robot->got_subcommand("check")) return check();
    if (robot->got_subcommand("fk")) return fk();
    return 0;
  };
}

}  // namespace cellcal::cli
