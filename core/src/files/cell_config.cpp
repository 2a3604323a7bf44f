#include "cellcal/core/files/cell_config.hpp"

#include "cellcal/core/files/measurement_csv.hpp"

#include <algorithm>
#include <cmath>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "cellcal/core/model/se3.hpp"
#include "yaml_reader.hpp"

namespace cellcal {

const char* durabilityName(Durability d) { return d == Durability::kJournal ? "journal" : "snapshot"; }
namespace {

namespace fs = std::filesystem;
using detail::YamlReader;

std::string resolve(const std::string& base_dir, const std::string& p) {
  if (p.empty() || fs::path(p).is_absolute()) return p;
  return (fs::path(base_dir) / p).lexically_normal().string();
}

// Optional number in a map: absent/null keeps `value`; `scale` converts the file's unit to SI.
struct Section {
  const YamlReader& r;
  YAML::Node node;
  std::string field;
  bool has(const char* key) const { return node[key].IsDefined() && !node[key].IsNull(); }
  std::string f(const char* key) const { return field + "." + key; }
  void num(const char* key, double& value, double scale = 1.0, double min = -1e300, bool min_exclusive = false) const {
    if (!has(key)) return;
    const double v = r.number(node[key], f(key)) * scale;
    if (min_exclusive ? !(v > min) : !(v >= min))
      r.fail(node[key], f(key), std::string("must be ") + (min_exclusive ? "> " : ">= ") + std::to_string(min / scale));
    value = v;
  }
  void integer(const char* key, int& value, long long min, long long max) const {
    if (!has(key)) return;
    const long long v = r.integer(node[key], f(key));
    if (v < min || v > max)
      r.fail(node[key], f(key), "must be in [" + std::to_string(min) + ", " + std::to_string(max) + "]");
    value = static_cast<int>(v);
  }
};

Section section(const YamlReader& r, const YAML::Node& root, const char* key, const std::set<std::string>& keys) {
  const YAML::Node n = root[key];
  if (!n.IsDefined() || n.IsNull()) return {r, YAML::Node(YAML::NodeType::Map), key};
  r.requireMap(n, key);
  r.checkKeys(n, key, keys);
  return {r, n, key};
}

constexpr double kDeg = 3.14159265358979323846 / 180.0;

// dds.discovery: the peers' IPv4 addresses or one Discovery Server.
void parseDiscovery(const YamlReader& r, const YAML::Node& d, DdsSettings& dds) {
  const std::string fd = "dds.discovery";
  r.requireMap(d, fd);
  r.checkKeys(d, fd, {"peers", "server", "server_id"});
  auto ipv4 = [&](const YAML::Node& n, const std::string& f, const std::string& text) {
    int parts = 0;
    std::stringstream ss(text);
    std::string part;
    bool ok = true;
    while (std::getline(ss, part, '.')) {
      ++parts;
      ok = ok && !part.empty() && part.size() <= 3 && part.find_first_not_of("0123456789") == std::string::npos &&
           std::stoi(part) <= 255;
    }
    if (!ok || parts != 4 || text.back() == '.') r.fail(n, f, "expected an IPv4 address (a.b.c.d), got '" + text + "'");
  };
  if (d["peers"].IsDefined()) {
    const YAML::Node p = d["peers"];
    if (!p.IsSequence() || p.size() == 0) r.fail(p, fd + ".peers", "expected a non-empty list of IPv4 addresses");
    for (size_t k = 0; k < p.size(); ++k) {
      const std::string fk = fd + ".peers[" + std::to_string(k) + "]";
      const std::string ip = r.string(p[k], fk);
      ipv4(p[k], fk, ip);
      dds.discovery_peers.push_back(ip);
    }
  }
  if (d["server"].IsDefined()) {
    const std::string fs_ = fd + ".server";
    if (!dds.discovery_peers.empty()) r.fail(d["server"], fs_, "give peers or a server, not both");
    const std::string text = r.string(d["server"], fs_);
    const auto colon = text.rfind(':');
    if (colon == std::string::npos) r.fail(d["server"], fs_, "expected address:port, e.g. 10.0.0.3:11811");
    ipv4(d["server"], fs_, text.substr(0, colon));
    const std::string port = text.substr(colon + 1);
    if (port.empty() || port.size() > 5 || port.find_first_not_of("0123456789") != std::string::npos ||
        std::stoi(port) < 1 || std::stoi(port) > 65535)
      r.fail(d["server"], fs_, "port '" + port + "' not in 1..65535");
    dds.discovery_server_address = text.substr(0, colon);
    dds.discovery_server_port = std::stoi(port);
  }
  if (d["server_id"].IsDefined()) {
    if (dds.discovery_server_port == 0) r.fail(d["server_id"], fd + ".server_id", "only with server");
    const Section ds{r, d, fd};
    ds.integer("server_id", dds.discovery_server_id, 0, 255);
  }
  if (dds.discovery_peers.empty() && dds.discovery_server_port == 0)
    r.fail(d, fd, "expected peers or server");
}

void parseDds(const YamlReader& r, const YAML::Node& root, const std::string& base_dir, DdsSettings& out) {
  const Section dds = section(r, root, "dds", {"domain_id", "profiles_file", "participant_profile", "security_dir",
                                                "type_information", "discovery"});
  dds.integer("domain_id", out.domain_id, 0, 232);
  out.profiles_file = resolve(base_dir, "dds/cellcal_qos.xml");
  if (dds.has("profiles_file")) out.profiles_file = resolve(base_dir, r.string(dds.node["profiles_file"], dds.f("profiles_file")));
  if (dds.has("participant_profile"))
    out.participant_profile = r.string(dds.node["participant_profile"], dds.f("participant_profile"));
  if (dds.has("type_information")) out.type_information = r.boolean(dds.node["type_information"], dds.f("type_information"));
  if (dds.has("security_dir")) out.security_dir = resolve(base_dir, r.string(dds.node["security_dir"], dds.f("security_dir")));
  if (dds.has("discovery")) parseDiscovery(r, dds.node["discovery"], out);
}

// robots[i].calibration_file: a calibration (`cellcal calibrate --save-robot`) of this robot_file's robot.
void checkCalibrationFile(const YamlReader& r, const YAML::Node& n, const std::string& f, const std::string& base_dir,
                          CellRobot& rb) {
  const std::string fc = f + ".calibration_file";
  rb.calibration_file = resolve(base_dir, r.string(n["calibration_file"], fc));
  try {
    rb.start = loadRobotFile(rb.calibration_file);
  } catch (const ConfigError& e) {
    r.fail(n["calibration_file"], fc, e.what());
  }
  if (!rb.start->calibration)
    r.fail(n["calibration_file"], fc,
           rb.calibration_file + " has no calibration section: not written by `cellcal calibrate --save-robot` "
           "(the controller's nominal model belongs in robot_file)");
  const RobotModel& sm = rb.start->model;
  bool same = sm.numParams() == rb.model.numParams();
  for (int i = 0; same && i < sm.numParams(); ++i) same = sm.paramName(i) == rb.model.paramName(i);
  if (!same)
    r.fail(n["calibration_file"], fc,
           "its kinematic parameters differ from those of robot_file " + rb.robot_file +
               " (another robot or joint layout)");
  // Another robot of the same layout (a UR10's calibration in a TX60's cell): its name, or its joints further
  // from robot_file's drawing than a calibration moves them (20 mm, 5 deg).
  std::string other;
  if (sm.name != rb.model.name) other = "its robot is '" + sm.name + "', robot_file's '" + rb.model.name + "'";
  for (int j = 0; other.empty() && j < sm.numJoints(); ++j)
    for (const JointParam p : {JointParam::kThetaOffset, JointParam::kD, JointParam::kA, JointParam::kAlpha}) {
      const int i = sm.jointParam(j, p);
      const double diff = std::abs(sm.nominal[i] - rb.model.nominal[i]);
      if (sm.isLength(i) ? diff > 0.02 : diff > 5.0 * 3.14159265358979323846 / 180.0) {
        other = "its " + sm.paramNameHuman(i) + " is " + std::to_string(sm.toHuman(i, sm.nominal[i])) +
                ", robot_file's " + std::to_string(rb.model.toHuman(i, rb.model.nominal[i])) +
                " (more than a calibration moves a joint: 20 mm, 5 deg)";
        break;
      }
    }
  if (!other.empty())
    r.fail(n["calibration_file"], fc,
           rb.calibration_file + " is not a calibration of robot_file " + rb.robot_file + ": " + other +
               " (another robot's calibration?)");
}

// robots[i] (f names it); ids and targets hold the robots' before it, and get its own.
CellRobot parseRobot(const YamlReader& r, const YAML::Node& n, const std::string& f, const std::string& base_dir,
                     std::set<std::string>& ids, std::set<std::string>& targets) {
  r.requireMap(n, f);
  r.checkKeys(n, f, {"robot_id", "target_id", "robot_file", "measurement", "base_in_tracker", "tool_in_flange",
                       "extensions", "calibration_file", "ros2_joint_names"});
  CellRobot rb;
  rb.robot_id = r.string(r.required(n, "robot_id", f + ".robot_id"), f + ".robot_id");
  rb.target_id = r.string(r.required(n, "target_id", f + ".target_id"), f + ".target_id");
  if (rb.robot_id.size() > 64) r.fail(n["robot_id"], f + ".robot_id", "at most 64 characters (the DDS key bound)");
  if (rb.target_id.size() > 64) r.fail(n["target_id"], f + ".target_id", "at most 64 characters (the DDS key bound)");
  if (!ids.insert(rb.robot_id).second) r.fail(n["robot_id"], f + ".robot_id", "robot_id '" + rb.robot_id + "' used twice");
  if (!targets.insert(rb.target_id).second)
    r.fail(n["target_id"], f + ".target_id", "target_id '" + rb.target_id + "' used twice");
  rb.robot_file = resolve(base_dir, r.string(r.required(n, "robot_file", f + ".robot_file"), f + ".robot_file"));
  if (n["measurement"].IsDefined()) {
    const std::string m = r.string(n["measurement"], f + ".measurement");
    if (m == "pose6d") rb.measurement = MeasurementKind::kPose6D;
    else if (m == "position3d") rb.measurement = MeasurementKind::kPosition3D;
    else r.fail(n["measurement"], f + ".measurement", "expected pose6d or position3d, got '" + m + "'");
  }
  double v[6];
  // Metres written in the _mm fields. The robot base's origin lies inside its casing: a tracker can't stand
  // within 100 mm of it, unless the tracker frame was aligned to the base (then within 1 mm and 1 deg of identity).
  // A target's centre lies at least an SMR's radius off the flange: 0-5 mm, other than exactly 0 (not known yet).
  auto checkUnits = [&](const char* key, double hi_m, bool identity_ok) {
    const double d = Eigen::Vector3d(v[0], v[1], v[2]).norm();
    const double angle = std::max({std::abs(v[3]), std::abs(v[4]), std::abs(v[5])});
    const bool identity = d <= 1e-3 && angle <= 3.14159265358979323846 / 180.0;
    if (d > 0.0 && d < hi_m && !(identity_ok && identity))
      r.fail(n[key], f + "." + key,
             "x_mm, y_mm, z_mm put it " + std::to_string(d * 1e3) +
                 " mm from the origin, which no real cell has: metres written where millimetres are expected?");
  };
  if (n["base_in_tracker"].IsDefined()) {
    r.frame(n["base_in_tracker"], f + ".base_in_tracker", v);
    checkUnits("base_in_tracker", 0.1, true);
    rb.base_in_tracker = Eigen::Map<Eigen::Matrix<double, 6, 1>>(v);
  }
  if (n["tool_in_flange"].IsDefined()) {
    r.frame(n["tool_in_flange"], f + ".tool_in_flange", v);
    checkUnits("tool_in_flange", 5e-3, false);
    rb.tool_in_flange = Eigen::Map<Eigen::Matrix<double, 6, 1>>(v);
  }
  try {
    rb.model = loadRobotModel(rb.robot_file);
  } catch (const ConfigError& e) {
    r.fail(n["robot_file"], f + ".robot_file", e.what());
  }
  if (n["calibration_file"].IsDefined()) checkCalibrationFile(r, n, f, base_dir, rb);
  if (n["ros2_joint_names"].IsDefined()) {
    const YAML::Node x = n["ros2_joint_names"];
    const std::string fx = f + ".ros2_joint_names";
    if (!x.IsSequence() || static_cast<int>(x.size()) != rb.model.numJoints())
      r.fail(x, fx, "expected a list of " + std::to_string(rb.model.numJoints()) +
                        " joint names (one per joint of " + rb.robot_file + ", base to flange)");
    std::set<std::string> seen;
    for (size_t k = 0; k < x.size(); ++k) {
      const std::string fk = fx + "[" + std::to_string(k) + "]";
      const std::string name = r.string(x[k], fk);
      if (!seen.insert(name).second) r.fail(x[k], fk, "'" + name + "' named twice");
      rb.ros2_joint_names.push_back(name);
    }
  }
  if (rb.base_in_tracker) rb.model.nominal.segment<6>(rb.model.baseParam(FrameParam::kX)) = *rb.base_in_tracker;
  if (rb.tool_in_flange) rb.model.nominal.segment<6>(rb.model.toolParam(FrameParam::kX)) = *rb.tool_in_flange;
  if (n["extensions"].IsDefined() && !n["extensions"].IsNull()) {
    const YAML::Node x = n["extensions"];
    const std::string fx = f + ".extensions";
    if (!x.IsSequence()) r.fail(x, fx, "expected a list, e.g. [joint_compliance:2]");
    for (size_t k = 0; k < x.size(); ++k) {
      const std::string fk = fx + "[" + std::to_string(k) + "]";
      const std::string item = r.string(x[k], fk);
      if (const auto cause = causeFromName(item.substr(0, item.find(':'))); cause && followsThermalDriver(*cause))
        r.fail(x[k], fk, std::string(causeName(*cause)) + " needs a temperature, which the cell's topics do not carry "
                         "(the engine's drift model follows warm-up; engine.drift sets how fast)");
      try {
        const Extension ext = parseExtension(item, rb.model, false);
        for (const auto& o : rb.extensions)
          if (o.cause == ext.cause && o.joint == ext.joint) r.fail(x[k], fk, "'" + item + "' is listed twice");
        rb.extensions.push_back(ext);
      } catch (const std::invalid_argument& err) {
        r.fail(x[k], fk, err.what());
      }
    }
  }
  return rb;
}

void parseDrift(const YamlReader& r, const YAML::Node& d, EngineSettings& engine) {
  r.requireMap(d, "engine.drift");
  r.checkKeys(d, "engine.drift",
              {"joint_offset_deg", "joint_length_mm", "axis_angle_deg", "frame_length_mm", "frame_angle_deg", "per_h"});
  const Section ds{r, d, "engine.drift"};
  ds.num("joint_offset_deg", engine.drift_joint_offset_rad, kDeg, 0);
  ds.num("joint_length_mm", engine.drift_joint_length_m, 1e-3, 0);
  ds.num("axis_angle_deg", engine.drift_axis_angle_rad, kDeg, 0);
  ds.num("frame_length_mm", engine.drift_frame_length_m, 1e-3, 0);
  ds.num("frame_angle_deg", engine.drift_frame_angle_rad, kDeg, 0);
  ds.num("per_h", engine.drift_per_h, 1, 0, true);
}

void parsePoseRequests(const YamlReader& r, const YAML::Node& d, PoseRequestSettings& pr) {
  r.requireMap(d, "engine.pose_requests");
  r.checkKeys(d, "engine.pose_requests",
              {"count", "candidates", "min_period_s", "range_mm", "link_radius_mm", "acceptance_deg", "min_radius_mm",
               "sigma_position_mm", "sigma_orientation_deg"});
  const Section ps{r, d, "engine.pose_requests"};
  ps.integer("count", pr.count, 0, 64);
  ps.integer("candidates", pr.candidates, 1, 100000);
  if (pr.count > pr.candidates) r.fail(d["count"], ps.f("count"), "more than the candidates (" + std::to_string(pr.candidates) + ")");
  ps.num("min_period_s", pr.min_period_s, 1, 0);
  ps.num("link_radius_mm", pr.link_radius_m, 1e-3, 0);
  ps.num("acceptance_deg", pr.acceptance_rad, kDeg, 0);
  ps.num("min_radius_mm", pr.min_radius_m, 1e-3, 0);
  ps.num("sigma_position_mm", pr.sigma_position_m, 1e-3, 0, true);
  ps.num("sigma_orientation_deg", pr.sigma_orientation_rad, kDeg, 0, true);
  if (ps.has("range_mm")) {
    const YAML::Node rn = d["range_mm"];
    if (!rn.IsSequence() || rn.size() != 2) r.fail(rn, ps.f("range_mm"), "expected [MIN, MAX] in mm");
    const double lo = r.number(rn[0], ps.f("range_mm")) * 1e-3, hi = r.number(rn[1], ps.f("range_mm")) * 1e-3;
    if (!(lo >= 0 && hi > lo)) r.fail(rn, ps.f("range_mm"), "expected 0 <= MIN < MAX");
    pr.min_range_m = lo;
    pr.max_range_m = hi;
  }
}

// simulation.hidden_effect: an effect of the configuration alone, on a joint it applies to in every robot.
void parseHiddenEffect(const YamlReader& r, const YAML::Node& h, const std::vector<CellRobot>& robots,
                       SimulationSettings& sim) {
  const std::string fh = "simulation.hidden_effect";
  r.requireMap(h, fh);
  r.checkKeys(h, fh, {"cause", "joint", "size_deg"});
  const std::string cause = r.string(r.required(h, "cause", fh + ".cause"), fh + ".cause");
  const auto ca = causeFromName(cause);
  if (!ca || !(*ca == Cause::kNone || *ca == Cause::kJointCompliance || *ca == Cause::kCyclicTransmission ||
               *ca == Cause::kJointScale))
    r.fail(h["cause"], fh + ".cause",
           "expected none, joint_compliance, cyclic_transmission or joint_scale (effects that depend on the "
           "configuration alone), got '" + cause + "'");
  sim.effect = *ca;
  if (*ca != Cause::kNone) {
    const long long j = r.integer(r.required(h, "joint", fh + ".joint"), fh + ".joint");
    const Section hs{r, h, fh};
    hs.num("size_deg", sim.effect_size_rad, kDeg);
    if (!hs.has("size_deg")) r.fail(h, fh, "size_deg (RMS joint error over the workspace) is required");
    for (const auto& rb : robots)
      if (j < 1 || j > rb.model.numJoints() || !applicable(rb.model, Extension{*ca, static_cast<int>(j - 1)}, false))
        r.fail(h["joint"], fh + ".joint",
               "joint " + std::to_string(j) + ": " + cause + " does not apply to " + rb.model.name);
    sim.effect_joint = static_cast<int>(j - 1);
  }
}

void parseEngine(const YamlReader& r, const YAML::Node& root, const std::string& base_dir, EngineSettings& engine) {
  const Section e = section(r, root, "engine",
                            {"mode", "batch_poses", "state_dir", "durability", "max_pairing_skew_ms", "settle_tolerance_deg",
                             "max_sample_age_s", "stale_input_s", "stale_stand_stills", "tracker_silence_s", "republish_period_s", "outlier_gate_nis_per_row", "outlier_hold_after",
                             "hold_prediction_sigma_mm", "drift_alarm_nis_per_row",
                             "prior_length_mm", "prior_angle_deg", "drift", "pose_requests"});
  if (e.has("mode")) {
    const std::string m = r.string(e.node["mode"], e.f("mode"));
    if (m == "continuous") engine.mode = EngineMode::kContinuous;
    else if (m == "periodic") engine.mode = EngineMode::kPeriodic;
    else r.fail(e.node["mode"], e.f("mode"), "expected continuous or periodic, got '" + m + "'");
  }
  if (e.has("durability")) {
    const std::string m = r.string(e.node["durability"], e.f("durability"));
    if (m == "journal") engine.durability = Durability::kJournal;
    else if (m == "snapshot") engine.durability = Durability::kSnapshot;
    else r.fail(e.node["durability"], e.f("durability"), "expected journal or snapshot, got '" + m + "'");
  }
  e.integer("batch_poses", engine.batch_poses, 1, 100000);
  engine.state_dir = resolve(base_dir, engine.state_dir);
  if (e.has("state_dir")) engine.state_dir = resolve(base_dir, r.string(e.node["state_dir"], e.f("state_dir")));
  e.num("max_pairing_skew_ms", engine.max_pairing_skew_s, 1e-3, 0, true);
  e.num("settle_tolerance_deg", engine.settle_tolerance_rad, kDeg, 0);
  e.num("max_sample_age_s", engine.max_sample_age_s, 1, 0, false);
  e.num("stale_input_s", engine.stale_input_s, 1, 0, true);
  e.num("tracker_silence_s", engine.tracker_silence_s, 1, 0, false);
  e.num("republish_period_s", engine.republish_period_s, 1, 0, true);
  e.num("outlier_gate_nis_per_row", engine.outlier_gate_nis_per_row, 1, 0);
  e.integer("outlier_hold_after", engine.outlier_hold_after, 1, 1000000);
  e.integer("stale_stand_stills", engine.stale_stand_stills, 1, 1000000);
  e.num("hold_prediction_sigma_mm", engine.hold_prediction_sigma_m, 1e-3, 0, true);
  e.num("drift_alarm_nis_per_row", engine.drift_alarm_nis_per_row, 1, 0, true);
  e.num("prior_length_mm", engine.prior_length_m, 1e-3, 0, true);
  e.num("prior_angle_deg", engine.prior_angle_rad, kDeg, 0, true);
  if (e.has("drift")) parseDrift(r, e.node["drift"], engine);
  if (e.has("pose_requests")) parsePoseRequests(r, e.node["pose_requests"], engine.pose_requests);
}

void parseCompensation(const YamlReader& r, const YAML::Node& root, CompensationSettings& out) {
  const Section cp = section(r, root, "compensation", {"max_correction_mm", "max_correction_deg", "on_exceed", "max_ik_error_mm",
                                                       "max_predicted_sigma_mm", "blend_s", "max_joint_correction_deg"});
  cp.num("max_correction_mm", out.max_correction_m, 1e-3, 0, true);
  cp.num("max_correction_deg", out.max_correction_rad, kDeg, 0, true);
  cp.num("max_ik_error_mm", out.max_ik_error_m, 1e-3, 0, true);
  cp.num("max_predicted_sigma_mm", out.max_predicted_sigma_m, 1e-3, 0, false);
  cp.num("blend_s", out.blend_s, 1, 0, false);
  cp.num("max_joint_correction_deg", out.max_joint_correction_rad, kDeg, 0, true);
  if (cp.has("on_exceed")) {
    const std::string a = r.string(cp.node["on_exceed"], cp.f("on_exceed"));
    if (a == "refuse") out.on_exceed = ExceedAction::kRefuse;
    else if (a == "clamp") out.on_exceed = ExceedAction::kClamp;
    else r.fail(cp.node["on_exceed"], cp.f("on_exceed"), "expected refuse or clamp, got '" + a + "'");
  }
}

// simulation, after robots and engine: its checks read both.
void parseSimulation(const YamlReader& r, const YAML::Node& root, const std::string& base_dir, CellConfig& c) {
  const Section s = section(r, root, "simulation",
                            {"seed", "initial_poses", "poses_per_group", "groups", "hours_between_groups", "pose_time_s",
                             "settle_fraction", "joint_rate_hz", "tracker_readings_per_pose", "tracker_delay_fraction",
                             "hidden_effect", "tracker_clock_offset_ms", "true_robot_file", "program_csv",
                             "follow_pose_requests", "rsi_hz"});
  if (s.has("seed")) {
    c.simulation.seed = r.unsignedInteger(s.node["seed"], s.f("seed"));
  }
  s.integer("initial_poses", c.simulation.initial_poses, 1, 100000);
  s.integer("poses_per_group", c.simulation.poses_per_group, 1, 100000);
  s.integer("groups", c.simulation.groups, 1, 100000);
  s.num("hours_between_groups", c.simulation.hours_between_groups, 1, 0);
  s.num("pose_time_s", c.simulation.pose_time_s, 1, 0, true);
  s.num("settle_fraction", c.simulation.settle_fraction, 1, 0, true);
  if (c.simulation.settle_fraction > 1) r.fail(s.node["settle_fraction"], s.f("settle_fraction"), "must be <= 1");
  s.num("joint_rate_hz", c.simulation.joint_rate_hz, 1, 0, true);
  s.integer("tracker_readings_per_pose", c.simulation.tracker_readings_per_pose, 1, 1000);
  s.num("tracker_delay_fraction", c.simulation.tracker_delay_fraction, 1, 0);
  if (c.simulation.tracker_delay_fraction >= 1)
    r.fail(s.node["tracker_delay_fraction"], s.f("tracker_delay_fraction"), "must be < 1");
  s.num("tracker_clock_offset_ms", c.simulation.tracker_clock_offset_s, 1e-3);
  if (std::abs(c.simulation.tracker_clock_offset_s) > 10)
    r.fail(s.node["tracker_clock_offset_ms"], s.f("tracker_clock_offset_ms"), "must be within +-10000 ms");
  s.num("rsi_hz", c.simulation.rsi_hz, 1, 0);
  if (c.simulation.rsi_hz > 1000) r.fail(s.node["rsi_hz"], s.f("rsi_hz"), "must be <= 1000 (a controller cycle of 1 ms or more)");
  if (s.has("follow_pose_requests"))
    c.simulation.follow_pose_requests = r.boolean(s.node["follow_pose_requests"], s.f("follow_pose_requests"));
  if (c.simulation.follow_pose_requests && c.engine.pose_requests.count == 0)
    r.fail(s.node["follow_pose_requests"], s.f("follow_pose_requests"), "engine.pose_requests.count is 0: nothing to follow");
  if (s.has("true_robot_file")) {
    const std::string ft = s.f("true_robot_file");
    c.simulation.true_robot_file = resolve(base_dir, r.string(s.node["true_robot_file"], ft));
    try {
      c.simulation.true_robot = loadRobotFile(c.simulation.true_robot_file);
    } catch (const ConfigError& e) {
      r.fail(s.node["true_robot_file"], ft, e.what());
    }
    for (const auto& rb : c.robots) {
      const RobotModel& t = c.simulation.true_robot->model;
      bool same = t.numParams() == rb.model.numParams();
      for (int i = 0; same && i < t.numParams(); ++i) same = t.paramName(i) == rb.model.paramName(i);
      if (!same)
        r.fail(s.node["true_robot_file"], ft,
               c.simulation.true_robot_file + " is not of the structure of " + rb.robot_id + "'s robot_file " +
                   rb.robot_file + " (another joint layout)");
    }
  }
  if (s.has("program_csv")) {
    const std::string fp = s.f("program_csv");
    c.simulation.program_csv = resolve(base_dir, r.string(s.node["program_csv"], fp));
    MeasurementCsvOptions po;
    po.joints_only = true;
    for (const auto& rb : c.robots) {
      try {
        const MeasurementFile program = readMeasurementCsv(c.simulation.program_csv, rb.model, po);
        if (c.simulation.program.empty())
          for (const auto& row : program.rows) c.simulation.program.push_back(row.q_rad);
      } catch (const ConfigError& e) {
        r.fail(s.node["program_csv"], fp, std::string(e.what()) + " (robot " + rb.robot_id + ")");
      }
    }
  }
  if (c.simulation.follow_pose_requests && !c.simulation.program.empty())
    r.fail(s.node["follow_pose_requests"], s.f("follow_pose_requests"),
           "the program of program_csv is fixed: follow the engine's proposals or run a program, not both");
  if (s.has("hidden_effect")) parseHiddenEffect(r, s.node["hidden_effect"], c.robots, c.simulation);
}

}  // namespace

const CellRobot* CellConfig::robotById(const std::string& id) const {
  for (const auto& r : robots)
    if (r.robot_id == id) return &r;
  return nullptr;
}

const CellRobot* CellConfig::robotByTarget(const std::string& id) const {
  for (const auto& r : robots)
    if (r.target_id == id) return &r;
  return nullptr;
}

CellConfig parseCellConfig(const std::string& yaml_text, const std::string& source, const std::string& base_dir) try {
  YamlReader r(source);
  const YAML::Node root = r.load(yaml_text);
  if (!root.IsMap()) r.fail(root, "<document>", "expected a mapping with dds, robots, engine, ...");
  r.checkKeys(root, "", {"dds", "time_compression", "robots", "engine", "compensation", "simulation"});
  CellConfig c;
  c.source = source;
  parseDds(r, root, base_dir, c.dds);
  if (root["time_compression"].IsDefined()) {
    c.time_compression = r.number(root["time_compression"], "time_compression");
    if (!(c.time_compression >= 1.0)) r.fail(root["time_compression"], "time_compression", "must be >= 1");
  }
  const YAML::Node robots = r.required(root, "robots", "robots");
  if (!robots.IsSequence() || robots.size() == 0) r.fail(robots, "robots", "expected a non-empty list of robots");
  if (robots.size() > 256)  // the DDS profiles keep 256 instances (robots) per topic (config/dds/cellcal_qos.xml)
    r.fail(robots, "robots", std::to_string(robots.size()) + " robots: at most 256 in one cell (one DDS domain)");
  std::set<std::string> ids, targets;
  for (size_t i = 0; i < robots.size(); ++i) {
    CellRobot rb = parseRobot(r, robots[i], "robots[" + std::to_string(i) + "]", base_dir, ids, targets);
    rb.index = static_cast<int>(c.robots.size());
    c.robots.push_back(std::move(rb));
  }
  parseEngine(r, root, base_dir, c.engine);
  parseCompensation(r, root, c.compensation);
  parseSimulation(r, root, base_dir, c);
  return c;
} catch (const YAML::Exception& e) {
  // The checks above name file, line and field; a yaml-cpp error that slips past them still names the file.
  throw ConfigError(source + ": " + e.what());
}

CellConfig loadCellConfig(const std::string& path) {
  return parseCellConfig(detail::readConfigFile(path, "cell file"), path, fs::path(path).parent_path().string());
}

}  // namespace cellcal
