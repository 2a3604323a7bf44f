// `cellcal iso9283`: the ISO 9283 pose and distance figures of a measured test (core/accuracy): per test pose AP and
// RP (and vAP where a pose was approached from several directions), AD and RD between two poses; commanded by the
// nominal model (what the controller believes) and, with --model-robot, by a calibrated one (what compensation would
// command: before and after in one report).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>
#include <Eigen/SVD>
#include <nlohmann/json.hpp>

#include "cellcal/core/accuracy/iso9283_test.hpp"
#include "cellcal/core/files/robot_file.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "commands.hpp"
#include "iso9283_spec.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {
namespace {

namespace fs = std::filesystem;

struct Iso9283Args {
  std::string robot, config, robot_id, data, program, model_robot, json, report, distance;
  bool register_frames = false, position_only = false;
  bool compensated = false;  // the data: a compensated run (cellcal cell --landed-csv), the joints those asked for
  double spec_ap_mm = 0, spec_rp_mm = 0;  // the specification (0: none)
};

void addOptions(CLI::App& cmd, Iso9283Args& a) {
  addRobotOrCellOptions(cmd, a.robot, a.config, a.robot_id,
                        "robot file or URDF: the nominal model and the cell's registration (its frames)");
  cmd.add_option("--data", a.data, "measurement file (CSV v1) with the pose column (and cycle), or with --program")
      ->required()
      ->check(CLI::ExistingFile);
  cmd.add_option("--program", a.program,
                 "the program the robot ran (cellcal plan iso9283): rows without a pose get the name of the program "
                 "pose with their joints")
      ->check(CLI::ExistingFile);
  cmd.add_option("--model-robot", a.model_robot,
                 "a calibrated robot file: the figures again with the commanded poses of that model (what compensation "
                 "would command)")
      ->check(CLI::ExistingFile);
  cmd.add_flag("--compensated", a.compensated,
               "the data are a run through compensation (cellcal cell --landed-csv): each row's joints are the pose "
               "asked for, its position where the robot landed; the figures are measured after compensation");
  cmd.add_option("--distance", a.distance, "the two poses of AD and RD, e.g. P2,P4 (default: P2,P4, else the first two)");
  cmd.add_flag("--register", a.register_frames,
               "fit the base and tool frames on the data first (needs poses off one plane; the standard's five are not)");
  cmd.add_flag("--position-only", a.position_only, "position figures only, even where the rows have orientations");
  cmd.add_option("--json", a.json, "write the figures as JSON")->check(outputFile());
  cmd.add_option("--report", a.report, "write report.md and figures (each pose's cloud, AP and RP) into this directory");
  cmd.add_option("--spec-ap-mm", a.spec_ap_mm,
                 "the specification's pose accuracy: every test pose's AP_p at most this (pass/fail; the measured "
                 "figures decide the exit code, 5 when they fail)")
      ->check(CLI::PositiveNumber);
  cmd.add_option("--spec-rp-mm", a.spec_rp_mm,
                 "the specification's pose repeatability: every test pose's RP_l at most this (as --spec-ap-mm)")
      ->check(CLI::PositiveNumber);
}

// Rows without a pose name take the name of the program pose whose joints they have (to 1e-6 rad).
void nameByProgram(MeasurementFile& f, const std::string& program_path, const RobotModel& m) {
  MeasurementCsvOptions o;
  o.joints_only = true;
  const MeasurementFile program = readMeasurementCsv(program_path, m, o);
  for (auto& r : f.rows) {
    if (r.pose) continue;
    for (const auto& p : program.rows)
      if (p.pose && (p.q_rad - r.q_rad).cwiseAbs().maxCoeff() < 1e-6) {
        r.pose = p.pose;
        break;
      }
    if (!r.pose)
      throw ConfigError(f.source + ":" + std::to_string(r.line) + ": its joints are none of the poses of the program " +
                        program_path);
  }
}

// Visits of one pose commanded at joints further apart than this are said: not one test pose?
constexpr double kSamePoseRad = degToRad(0.01);

struct Model {
  std::string label;  // "nominal model of R" / "calibrated model CAL"
  Iso9283Model m;
};

nlohmann::json reportJson(const Iso9283Report& r) {
  nlohmann::json poses = nlohmann::json::array();
  for (const auto& p : r.poses) {
    nlohmann::json j = {{"name", p.name}, {"n", p.n}, {"AP_mm", p.AP_p_m * 1e3},
                        {"AP_x_mm", p.AP_xyz_m.x() * 1e3}, {"AP_y_mm", p.AP_xyz_m.y() * 1e3}, {"AP_z_mm", p.AP_xyz_m.z() * 1e3},
                        {"RP_mm", p.RP_l_m * 1e3}, {"l_mean_mm", p.l_mean_m * 1e3}, {"S_l_mm", p.S_l_m * 1e3},
                        {"directions", p.directions}};
    const char* abc = "abc";
    for (int k = 0; k < 3; ++k) {
      const std::string c(1, abc[k]);
      j["AP_" + c + "_deg"] = p.oriented ? nlohmann::json(radToDeg(p.AP_abc_rad[k])) : nlohmann::json(nullptr);
      j["RP_" + c + "_deg"] = p.oriented ? nlohmann::json(radToDeg(p.RP_abc_rad[k])) : nlohmann::json(nullptr);
    }
    j["vAP_mm"] = p.vAP_p_m ? nlohmann::json(*p.vAP_p_m * 1e3) : nlohmann::json(nullptr);
    poses.push_back(j);
  }
  nlohmann::json distances = nlohmann::json::array();
  for (const auto& d : r.distances)
    distances.push_back({{"from", d.from}, {"to", d.to}, {"n", d.n}, {"commanded_mm", d.D_c_m * 1e3},
                         {"AD_mm", d.AD_p_m * 1e3}, {"RD_mm", d.RD_m * 1e3}});
  nlohmann::json j = {{"poses", poses}, {"distances", distances}};
  j["AD_mm"] = r.distances.empty() ? nlohmann::json(nullptr) : nlohmann::json(r.distances[0].AD_p_m * 1e3);
  j["RD_mm"] = r.distances.empty() ? nlohmann::json(nullptr) : nlohmann::json(r.distances[0].RD_m * 1e3);
  return j;
}

void printReport(const Iso9283Report& r) {
  std::printf("  pose     n    AP_p mm  AP_a deg  AP_b deg  AP_c deg    RP_l mm  RP_a deg  RP_b deg  RP_c deg  vAP_p mm\n");
  for (const auto& p : r.poses) {
    std::printf("  %-6s %3d  %9.4f", p.name.c_str(), p.n, p.AP_p_m * 1e3);
    for (int k = 0; k < 3; ++k) p.oriented ? std::printf("  %8.4f", radToDeg(p.AP_abc_rad[k])) : std::printf("  %8s", "-");
    std::printf("  %9.4f", p.RP_l_m * 1e3);
    for (int k = 0; k < 3; ++k) p.oriented ? std::printf("  %8.4f", radToDeg(p.RP_abc_rad[k])) : std::printf("  %8s", "-");
    p.vAP_p_m ? std::printf("  %8.4f\n", *p.vAP_p_m * 1e3) : std::printf("  %8s\n", "-");
  }
  for (const auto& d : r.distances)
    std::printf("  distance %s-%s (%d cycles): commanded %.3f mm, AD_p %.4f mm, RD %.4f mm\n", d.from.c_str(),
                d.to.c_str(), d.n, d.D_c_m * 1e3, d.AD_p_m * 1e3, d.RD_m * 1e3);
}

double meanAp(const Iso9283Report& r) {
  double s = 0;
  for (const auto& p : r.poses) s += p.AP_p_m;
  return s / static_cast<double>(r.poses.size());
}

void writeReport(const Iso9283Args& a, const std::string& robot_label,
                 const std::vector<std::pair<Model, Iso9283Report>>& reports) {
  fs::create_directories(a.report);
  const Iso9283Report& before = reports.front().second;
  // Each pose's attained cloud about its barycentre (x-y and x-z, µm).
  std::ostringstream cloud, gp;
  double largest_um = 0;
  for (size_t k = 0; k < before.poses.size(); ++k) {
    const auto& p = before.poses[k];
    cloud << "# " << p.name << "\n";
    for (const auto& d : p.deviations_m) {
      const Eigen::Vector3d e = (d - p.AP_xyz_m) * 1e6;
      largest_um = std::max(largest_um, e.cwiseAbs().maxCoeff());
      cloud << e.x() << ' ' << e.y() << ' ' << e.z() << '\n';
    }
    cloud << "\n\n";
  }
  // One scale for every panel, a round number (10, 20, 50, 100, ... um), with a tic at its ends and the centre.
  double range_um = 10;
  for (int k = 0; range_um < largest_um; ++k) range_um *= k % 3 == 1 ? 2.5 : 2;
  gp << "set multiplot layout 2," << before.poses.size()
     << " title 'attained positions about each barycentre (um), base frame' font ',11'\nset grid\nset key off\n"
        "set size ratio -1\nset xrange [" << -range_um << ":" << range_um << "]\nset yrange [" << -range_um << ":"
     << range_um << "]\nset xtics " << range_um << "\nset ytics " << range_um << "\n";
  for (int view = 0; view < 2; ++view)
    for (size_t k = 0; k < before.poses.size(); ++k) {
      gp << "set title '" << before.poses[k].name << (view ? " x-z" : " x-y") << "'\nset xlabel 'x'\nset ylabel '"
         << (view ? "z" : "y") << "'\nplot datafile index " << k << " using 1:" << (view ? 3 : 2)
         << " with points pt 7 ps 0.5 lc rgb '#1f77b4'\n";
    }
  gp << "unset multiplot\n";
  std::string err;
  for (const char* format : {"svg", "png"})
    if (!renderGnuplot(a.report, "clouds", cloud.str(), gp.str(), &err, format)) std::cerr << "warning: " << err << "\n";
  // AP_p and RP_l per pose, for each model.
  std::ostringstream bars, gb;
  bars << "# pose";
  for (const auto& [m, r] : reports) bars << " AP_" << (&r == &before ? "before" : "after") << " RP";
  bars << "\n";
  for (size_t k = 0; k < before.poses.size(); ++k) {
    bars << before.poses[k].name;
    for (const auto& [m, r] : reports) bars << ' ' << r.poses[k].AP_p_m * 1e3 << ' ' << r.poses[k].RP_l_m * 1e3;
    bars << '\n';
  }
  gb << "set style data histograms\nset style histogram clustered gap 1\nset style fill solid 0.8 border -1\n"
        "set grid ytics\nset ylabel 'mm'\nset title 'ISO 9283 pose accuracy AP_p and repeatability RP_l per test pose'\n"
        "set key outside top center horizontal\nplot datafile using 2:xtic(1) title 'AP_p "
     << (reports.size() > 1 ? "nominal" : "") << "' lc rgb '#d62728', '' using 3 title 'RP_l' lc rgb '#7f7f7f'";
  if (reports.size() > 1) gb << ", '' using 4 title 'AP_p calibrated' lc rgb '#2ca02c'";
  gb << "\n";
  for (const char* format : {"svg", "png"})
    if (!renderGnuplot(a.report, "ap_rp", bars.str(), gb.str(), &err, format)) std::cerr << "warning: " << err << "\n";
  std::ofstream md(a.report + "/report.md");
  if (!md) throw std::runtime_error(a.report + "/report.md: cannot write");
  md << "# ISO 9283 pose characteristics\n\nData: `" << a.data << "`; robot: " << robot_label << ".\n\n";
  char buf[400];
  for (const auto& [m, r] : reports) {
    md << "## Commanded by the " << m.label << "\n\n| pose | n | AP_p mm | AP_a deg | AP_b deg | AP_c deg | RP_l mm | RP_a deg | RP_b deg | RP_c deg | vAP_p mm |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& p : r.poses) {
      std::snprintf(buf, sizeof buf, "| %s | %d | %.4f |", p.name.c_str(), p.n, p.AP_p_m * 1e3);
      md << buf;
      for (int k = 0; k < 3; ++k) {
        if (p.oriented) std::snprintf(buf, sizeof buf, " %.4f |", radToDeg(p.AP_abc_rad[k]));
        else std::snprintf(buf, sizeof buf, " - |");
        md << buf;
      }
      std::snprintf(buf, sizeof buf, " %.4f |", p.RP_l_m * 1e3);
      md << buf;
      for (int k = 0; k < 3; ++k) {
        if (p.oriented) std::snprintf(buf, sizeof buf, " ±%.4f |", radToDeg(p.RP_abc_rad[k]));
        else std::snprintf(buf, sizeof buf, " - |");
        md << buf;
      }
      md << (p.vAP_p_m ? " " + std::to_string(*p.vAP_p_m * 1e3) + " |\n" : std::string(" - |\n"));
    }
    for (const auto& d : r.distances) {
      std::snprintf(buf, sizeof buf, "\nDistance %s-%s over %d cycles: commanded %.3f mm, AD_p %.4f mm, RD ±%.4f mm.\n",
                    d.from.c_str(), d.to.c_str(), d.n, d.D_c_m * 1e3, d.AD_p_m * 1e3, d.RD_m * 1e3);
      md << buf;
    }
    md << "\n";
  }
  md << "AP: the barycentre of the attained poses against the commanded pose; RP_l = l̄ + 3 S_l; RP_a = ±3 S_a "
        "(orientation deviations about the base frame's x, y, z). Against a calibrated model the commanded pose is what "
        "compensation would command: AP is the accuracy compensation would leave at these poses, RP is the robot's.\n\n"
        "![AP and RP](ap_rp.svg)\n\n![clouds](clouds.svg)\n";
}

// --register: each model's base and tool frames fitted on the rows, refused where the rows cannot tell them from the
// robot's own error.
void registerModels(const Iso9283Args& a, const RobotModel& m, const MeasurementFile& f, bool orientation,
                    std::vector<Model>& models) {
  // The frames can be fitted only on poses that span space and turn the flange: the standard's five lie in one
  // plane with one orientation, where a fit would take the robot's own error into the frames and report it as gone.
  KinematicsData kd(m);
  Eigen::VectorXd flange_params = m.nominal;
  flange_params.segment<6>(m.baseParam(FrameParam::kX)).setZero();
  flange_params.segment<6>(m.toolParam(FrameParam::kX)).setZero();
  std::vector<Pose> flange;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const auto& r : f.rows) {
    flange.push_back(forwardKinematics(m, kd, flange_params, r.q_rad));
    centre += flange.back().translation() / static_cast<double>(f.rows.size());
  }
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  double turn = 0;
  for (const auto& F : flange) {
    scatter += (F.translation() - centre) * (F.translation() - centre).transpose();
    turn = std::max(turn, logSO3(F.linear() * flange.front().linear().transpose()).norm());
  }
  const Eigen::Vector3d sv = Eigen::JacobiSVD<Eigen::Matrix3d>(scatter).singularValues();
  if (sv[2] < 0.01 * sv[0] || turn < degToRad(10))
    throw ConfigError(a.data + ": --register: the rows' flange poses " +
                      (turn < degToRad(10) ? "keep one orientation (within " + std::to_string(radToDeg(turn)) + " deg)"
                                           : std::string("lie in one plane")) +
                      ": the base and tool frames cannot be told from the robot's own error there (the standard's test "
                      "poses lie in one plane with one orientation). Register the cell on other poses first "
                      "(`cellcal calibrate --frames-only`) and give its frames in the robot file");
  std::vector<Observation> obs;
  for (const auto& r : f.rows)
    obs.push_back(toObservation(r, orientation ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D, 25e-6, 1.7e-4));
  for (auto& mm : models) {
    try {
      const RegistrationResult reg = registerFrames(*mm.m.model, mm.m.params, obs);
      mm.m.params = reg.params;
      std::printf("iso9283: the %s's base and tool frames fitted on the data (--register): RMS %.4f mm\n",
                  mm.label.c_str(), reg.rms_position_m * 1e3);
    } catch (const std::invalid_argument& e) {
      throw ConfigError(a.data + ": --register: " + e.what() +
                        " (the standard's test poses lie in one plane with one orientation: register the cell on "
                        "other poses first, `cellcal calibrate --frames-only`, and give its frames in the robot file)");
    }
  }
}

int runIso9283(const Iso9283Args& a) {
  std::string robot_label;
  const RobotFile rf = robotOrCellRobot(a.robot, a.config, a.robot_id, &robot_label);
  const RobotModel& m = rf.model;
  MeasurementFile f = readMeasurementCsv(a.data, m);
  if (!a.program.empty()) nameByProgram(f, a.program, m);
  std::vector<std::pair<std::string, std::string>> pairs;
  if (!a.distance.empty()) {
    const auto comma = a.distance.find(',');
    if (comma == std::string::npos || a.distance.find(',', comma + 1) != std::string::npos)
      throw ConfigError("--distance " + a.distance + ": expected two pose names, e.g. P2,P4");
    pairs.emplace_back(a.distance.substr(0, comma), a.distance.substr(comma + 1));
  }
  const bool orientation = !a.position_only;
  std::vector<Model> models;
  if (a.compensated && !a.model_robot.empty())
    throw ConfigError("--compensated with --model-robot: the data were already compensated (measured), not predicted");
  models.push_back({"nominal model of " + robot_label +
                        (a.compensated ? ", through compensation (measured where the robot landed)" : ""),
                    {CalibratedModel::geometric(m.nominal), &m}});
  std::optional<RobotFile> cal;
  if (!a.model_robot.empty()) {
    cal = loadRobotFile(a.model_robot);
    bool same = cal->model.numParams() == m.numParams();
    for (int i = 0; same && i < m.numParams(); ++i) same = cal->model.paramName(i) == m.paramName(i);
    if (!same) throw ConfigError(a.model_robot + ": not a model of " + robot_label + " (another joint layout)");
    models.push_back({"calibrated model " + a.model_robot, {calibratedModel(*cal), &cal->model}});
  }
  if (a.register_frames) registerModels(a, m, f, orientation, models);
  // Visits of one pose at other joints are said (not one test pose?).
  std::map<std::string, std::pair<Eigen::VectorXd, double>> spread;
  for (const auto& r : f.rows) {
    if (!r.pose) continue;
    auto [it, added] = spread.emplace(*r.pose, std::make_pair(r.q_rad, 0.0));
    if (!added) it->second.second = std::max(it->second.second, (r.q_rad - it->second.first).cwiseAbs().maxCoeff());
  }
  for (const auto& [name, s] : spread)
    if (s.second > kSamePoseRad)
      std::printf("WARNING: the visits of %s were commanded at joints up to %.3f deg apart: one test pose? (each "
                  "visit is taken against its own command)\n", name.c_str(), radToDeg(s.second));
  std::vector<std::pair<Model, Iso9283Report>> reports;
  for (const auto& mm : models) {
    try {
      const std::vector<Iso9283PoseInput> visits = iso9283Visits(f, mm.m, orientation);
      reports.emplace_back(mm, iso9283Report(visits, pairs));
    } catch (const std::invalid_argument& e) {
      throw ConfigError(a.data + ": " + e.what());
    }
  }
  const Iso9283Report& before = reports.front().second;
  int visits = 0, oriented = 0;
  for (const auto& p : before.poses) {
    visits += p.n;
    oriented += p.oriented;
  }
  std::printf("iso9283: %zu test poses, %d visits of %s; base frame of %s%s\n", before.poses.size(), visits,
              a.data.c_str(), robot_label.c_str(),
              oriented == static_cast<int>(before.poses.size()) ? "" : "; positions only where rows lack orientations");
  for (const auto& [mm, r] : reports) {
    std::printf("commanded by the %s:\n", mm.label.c_str());
    printReport(r);
  }
  int code = 0;
  if (reports.size() > 1) {
    const double b = meanAp(before), c = meanAp(reports[1].second);
    std::printf("mean AP_p over the test poses: %.4f mm commanded by the nominal model, %.4f mm by the calibrated one "
                "(%s)\n", b * 1e3, c * 1e3,
                c < b ? "what compensation with it would leave at these poses" : "WORSE: do not deploy it (exit 4)");
    if (!(c < b)) code = 4;
  }
  nlohmann::json spec = nlohmann::json::object();
  std::vector<std::pair<std::string, const Iso9283Report*>> judged;
  for (const auto& [mm, r] : reports) judged.emplace_back(mm.label, &r);
  if (!judgeIso9283Spec(a.spec_ap_mm, a.spec_rp_mm, judged, &spec) && code == 0) code = 5;
  if (!a.json.empty()) {
    nlohmann::json j = reportJson(before);
    j.update(spec);
    j["robot"] = robot_label;
    j["data"] = a.data;
    j["commanded_by"] = a.compensated ? "nominal, through compensation" : "nominal";
    j["frames_registered"] = a.register_frames;
    if (reports.size() > 1) {
      j["after"] = reportJson(reports[1].second);
      j["after"]["model_robot"] = a.model_robot;
    }
    std::ofstream o(a.json);
    if (!o) throw std::runtime_error(a.json + ": cannot write");
    o << j.dump(2) << "\n";
  }
  if (!a.report.empty()) {
    writeReport(a, robot_label, reports);
    std::printf("report: %s/report.md\n", a.report.c_str());
  }
  return code;
}

}  // namespace

Runner addIso9283Command(CLI::App& app) { return addCommand(app, "iso9283", addOptions, runIso9283); }

}  // namespace cellcal::cli
