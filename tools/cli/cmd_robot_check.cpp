// `cellcal robot check`: does the robot's controller compute with this calibration? Its own tool poses at its joint
// angles against the forward kinematics of a robot file or URDF (core's checkController: controller_check.hpp).
// `cellcal robot fk`: the tool poses a robot file or URDF computes at given joint angles, as a controller running it
// would report them (the same frames as the check).
#include <cstdio>
#include <fstream>
#include <memory>

#include <nlohmann/json.hpp>

#include "cellcal/core/files/measurement_csv.hpp"
#include "cellcal/core/files/robot_yaml.hpp"
#include "cellcal/core/identification/controller_check.hpp"
#include "cellcal/core/identification/registration.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "commands.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {
namespace {

struct CheckArgs {
  std::string robot, data, json, base_in_controller, tool_in_flange;
  double tolerance_mm = 0.01, tolerance_deg = 0.001;
};

struct FkArgs {
  std::string robot, data, out, base_in_controller, tool_in_flange;
};

Pose frameMmDeg(const std::string& text, const std::string& option) {
  return text.empty() ? Pose::Identity() : parseFrameMmDeg(text, option);
}

int runCheck(const CheckArgs& a) {
  const RobotModel model = loadRobotModel(a.robot);
  MeasurementCsvOptions csv;
  const MeasurementFile f = readMeasurementCsv(a.data, model, csv);
  std::vector<Observation> readings;
  for (const auto& row : f.rows) readings.push_back(toObservation(row, MeasurementKind::kPose6D, 1e-6, 1e-5));
  ControllerCheckOptions o;
  o.base_in_controller = frameMmDeg(a.base_in_controller, "--base-in-controller");
  o.tool_in_flange = frameMmDeg(a.tool_in_flange, "--tool-in-flange");
  o.tolerance_mm = a.tolerance_mm;
  o.tolerance_deg = a.tolerance_deg;
  const ControllerCheck c = checkController(model, model.nominal, readings, o);
  std::printf("robot check: %s against %s: %d rows (%d with orientation)\n", a.data.c_str(), a.robot.c_str(), c.rows,
              c.oriented);
  std::printf("  the controller's tool pose against the model's: %.5f mm mean (max %.5f at line %d)", c.mean_mm, c.max_mm,
              c.worst_row >= 0 ? f.rows[static_cast<size_t>(c.worst_row)].line : 0);
  if (c.oriented > 0) std::printf(", %.5f deg mean (max %.5f)", c.mean_deg, c.max_deg);
  std::printf("\n");
  nlohmann::json j = {{"robot", a.robot}, {"data", a.data}, {"rows", c.rows}, {"oriented", c.oriented},
                      {"mean_mm", c.mean_mm}, {"max_mm", c.max_mm}, {"mean_deg", c.mean_deg}, {"max_deg", c.max_deg},
                      {"tolerance_mm", o.tolerance_mm}, {"tolerance_deg", o.tolerance_deg}, {"matches", c.matches}};
  if (c.matches) {
    std::printf("result: the controller computes with this model (every row within %g mm and %g deg)\n", o.tolerance_mm,
                o.tolerance_deg);
  } else {
    std::printf("result: the controller does NOT compute with this model (beyond %g mm or %g deg: exit 3)\n",
                o.tolerance_mm, o.tolerance_deg);
    nlohmann::json params = nlohmann::json::array();
    std::string text;
    for (size_t k = 0; k < c.explained_by.size(); ++k) {
      const auto [i, change] = c.explained_by[k];
      params.push_back({{"name", model.paramNameHuman(i)}, {"change", model.toHuman(i, change)}});
      if (k < 8) {
        char buf[120];
        std::snprintf(buf, sizeof buf, " %s %+.4f", model.paramNameHuman(i).c_str(), model.toHuman(i, change));
        text += buf;
      }
    }
    std::printf("  the controller's model differs from this one by, largest first (the base and tool frames as given):%s%s\n",
                text.c_str(), c.explained_by.size() > 8 ? " ..." : "");
    std::printf("  those changes leave %.5f mm mean of the difference%s\n", c.left_mean_mm,
                c.fit_converged ? "" : " (the fit did not converge)");
    j["explained_by"] = params;
    j["left_mean_mm"] = c.left_mean_mm;
  }
  if (!a.json.empty()) std::ofstream(a.json) << j.dump(2) << "\n";
  return c.matches ? 0 : 3;
}

// The model's kinematics (its extensions left out: no controller runs them) with the controller's frames:
// T = base_in_controller * mount * chain(q) * flange * tool_in_flange, each row's pose replaced by it.
int runFk(const FkArgs& a) {
  const RobotModel model = loadRobotModel(a.robot);
  MeasurementCsvOptions csv;
  csv.joints_only = true;
  MeasurementFile f = readMeasurementCsv(a.data, model, csv);
  if (f.rows.empty()) throw ConfigError(a.data + ": no rows");
  Eigen::VectorXd p = model.nominal;
  p.segment<6>(model.baseParam(FrameParam::kX)) = xyzRpyFromPose(frameMmDeg(a.base_in_controller, "--base-in-controller"));
  p.segment<6>(model.toolParam(FrameParam::kX)) = xyzRpyFromPose(frameMmDeg(a.tool_in_flange, "--tool-in-flange"));
  KinematicsData data(model);
  for (MeasurementRow& row : f.rows) {
    const Pose& T = forwardKinematics(model, data, p, row.q_rad);
    row.position_m = T.translation();
    row.orientation = Eigen::Quaterniond(T.linear()).normalized();
    row.sigma_position_m.reset();
    row.sigma_orientation_rad.reset();
  }
  std::ofstream out(a.out);
  writeMeasurementCsv(out, f, model.numJoints(),
                      "the tool poses " + a.robot + " computes at the joint angles of " + a.data +
                          " (cellcal robot fk), in the controller's base frame");
  out.close();
  if (!out) throw std::runtime_error(a.out + ": cannot write");
  std::printf("robot fk: %zu rows of %s through %s -> %s\n", f.rows.size(), a.data.c_str(), a.robot.c_str(),
              a.out.c_str());
  return 0;
}

void addControllerFrames(CLI::App* c, std::string& base_in_controller, std::string& tool_in_flange) {
  c->add_option("--base-in-controller", base_in_controller,
                "the robot's base link in the controller's base frame, X,Y,Z,ROLL,PITCH,YAW (mm, deg; default: the same "
                "frame; UR: 0,0,0,0,0,180)");
  c->add_option("--tool-in-flange", tool_in_flange,
                "the tool the controller reports, on the robot's tip link, X,Y,Z,ROLL,PITCH,YAW (mm, deg; default: the tip "
                "link itself)");
}

}  // namespace

Runner addRobotFk(CLI::App& robot) {
  auto a = std::make_shared<FkArgs>();
  CLI::App* c = addSubcommand(robot, "fk");
  c->add_option("--robot", a->robot, "robot file or URDF")->required()->check(CLI::ExistingFile);
  c->add_option("--data", a->data, "the joint angles: a measurement CSV or a robot program (q*_deg or q*_rad columns)")
      ->required()->check(CLI::ExistingFile);
  c->add_option("--out", a->out, "measurement CSV to write: the joints with the model's tool pose")->required()
      ->check(outputFile());
  addControllerFrames(c, a->base_in_controller, a->tool_in_flange);
  return [=]() -> int { return runFk(*a); };
}

Runner addRobotCheck(CLI::App& robot) {
  auto a = std::make_shared<CheckArgs>();
  CLI::App* c = addSubcommand(robot, "check");
  c->add_option("--robot", a->robot, "robot file or URDF the controller should compute with")->required()->check(CLI::ExistingFile);
  c->add_option("--data", a->data,
                "the controller's joint angles with the tool pose it reports in its base frame (measurement CSV: "
                "q*_deg or q*_rad, x_mm, y_mm, z_mm, qw..qz)")->required()->check(CLI::ExistingFile);
  addControllerFrames(c, a->base_in_controller, a->tool_in_flange);
  c->add_option("--tolerance-mm", a->tolerance_mm, "largest position difference of a controller running the model")
      ->check(CLI::PositiveNumber)->capture_default_str();
  c->add_option("--tolerance-deg", a->tolerance_deg, "largest orientation difference of a controller running the model")
      ->check(CLI::PositiveNumber)->capture_default_str();
  c->add_option("--json", a->json, "also write the result as JSON")->check(outputFile());
  return [=]() -> int { return runCheck(*a); };
}

}  // namespace cellcal::cli
