#include "cellcal/components/process_stats.hpp"
#include "compensation_publisher.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <iostream>
#include <sstream>
#include <thread>

#include "cellcal/components/ros2.hpp"
#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/files/robot_file.hpp"

namespace cellcal::components {

namespace {
constexpr const char* kPassThroughReason = "pass-through (--pass-through): not corrected";
}  // namespace

CompensationPublisher::CompensationPublisher(const Options& options)
    : options_(options),
      cell_(loadCell(options.process)),
      node_(cell_, "cellcal_compensation_publisher", identity::kCompensationPublisher),
      writer_(node_.writer<msg::CompensatedTarget>()),
      servo_writer_(node_.writer<msg::ServoCorrection>()),
      engine_writers_(node_.matchedWritersCount<msg::CalibrationState>()) {
  for (const auto& r : cell_.robots) {
    robots_[r.robot_id].robot = &r;
    robots_[r.robot_id].servo.emplace(r.model, cell_.compensation, cell_.compensation.blend_s);
  }
  if (!options_.ros_pose_topic.empty()) {
    for (auto& [id, r] : robots_) {
      const std::string ros_name = robots_.size() == 1 ? options_.ros_pose_topic : options_.ros_pose_topic + "/" + id;
      std::string err;
      const auto topic = ros2DdsTopic(ros_name, &err);
      if (!topic) throw std::runtime_error("--ros-pose-topic: " + err);
      r.ros_pose = node_.writer<geometry_msgs::msg::dds_::PoseStamped_>(*topic);
      std::cerr << "compensation_publisher: " << id << ": applied corrections also on ROS 2 topic " << ros_name
                << " (geometry_msgs/PoseStamped, frame_id " << options_.ros_frame_id << ")\n";
    }
  }
  if (!options_.ros_description_topic.empty())
    for (auto& [id, r] : robots_) openDescription(id, r);
  if (!options_.pass_through) {
    node_.reader<msg::CalibrationState>([this](const msg::CalibrationState& m, const fdds::SampleInfo&) { onCalibrationState(m); });
    node_.reader<msg::CalibrationDiagnostics>(
        [this](const msg::CalibrationDiagnostics& d, const fdds::SampleInfo&) { onDiagnostics(d); });
    waitForCalibrations();
  } else {
    std::cerr << "compensation_publisher: --pass-through: every target and setpoint answered unchanged, no "
                 "calibration applied\n";
  }
  node_.reader<msg::TargetPose>([this](const msg::TargetPose& t, const fdds::SampleInfo&) { onTarget(t); });
  node_.reader<msg::ServoSetpoint>([this](const msg::ServoSetpoint& sp, const fdds::SampleInfo&) { onServoSetpoint(sp); });
  std::cerr << "compensation_publisher: " << robots_.size() << " robot(s), bound "
            << cell_.compensation.max_correction_m * 1e3 << " mm / " << cell_.compensation.max_correction_rad * 180 / kPi
            << " deg, domain " << node_.domainId() << "\n";
}

void CompensationPublisher::onCalibrationState(const msg::CalibrationState& m) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = robots_.find(m.robot_id().to_string());
  if (it == robots_.end()) return;
  std::string error;
  auto c = fromCalibrationState(it->second.robot->model, m, &error);
  if (!c) {
    ++bad_states_;
    std::cerr << "compensation_publisher: ignored: " << error << "\n";
    return;
  }
  Robot& r = it->second;
  // A new calibration, or the same version number made again by an engine that restarted from an older state.
  const bool changed = !r.calibration || r.calibration->version != c->version ||
                       r.calibration->last_measurement_stamp_ns != c->last_measurement_stamp_ns ||
                       r.calibration->health != c->health;
  if (!changed) return;
  if (!r.calibration)
    std::cerr << "compensation_publisher: " << it->first << ": calibration v" << c->version << " received ("
              << c->poses_used << " poses)\n";
  if (c->health != msg::HEALTH_OK && (!r.calibration || r.calibration->health == msg::HEALTH_OK) && r.last_ok) {
    std::cerr << "compensation_publisher: " << it->first << ": calibration v" << c->version << " is "
              << healthText(c->health) << ": applying ";
    if (r.last_ok->version == c->version) std::cerr << "v" << c->version << " as it was received while ok\n";
    else std::cerr << "v" << r.last_ok->version << ", the last ok calibration\n";
  }
  if (c->health == msg::HEALTH_OK && r.calibration && r.calibration->health != msg::HEALTH_OK)
    std::cerr << "compensation_publisher: " << it->first << ": calibration v" << c->version << " is ok again: applying it\n";
  if (c->health == msg::HEALTH_OK) {
    r.last_ok = *c;
    r.applied_model = IdentifiedModel(*c);
    // Teach points, and how far the extensions were judged beyond their data (compensation.hpp).
    if (r.robot->start) attachRobotFile(*r.robot->start, *r.applied_model);
    if (!r.judged_ranges_said && (!r.applied_model->beyond_data.empty() || !r.applied_model->beyond_drivers.empty())) {
      std::vector<std::string> said;
      for (const BeyondRange& b : r.applied_model->beyond_data) {
        char t[600];
        std::snprintf(t, sizeof t, "extensions of joint %d were fitted on %s%s and judged %.1f deg beyond it%s", b.joint + 1,
                      b.rangeText().c_str(), b.gapsText().c_str(), b.checked_rad * 180 / kPi,
                      b.gaps_rad.empty() ? "" : " and into its gaps");
        said.push_back(t);
      }
      for (const DriverRange& d : r.applied_model->beyond_drivers) {
        char t[300];
        std::snprintf(t, sizeof t, "%s was fitted on %s and %s", extensionLabel(d.extension).c_str(),
                      d.rangeText().c_str(), d.judgedText().c_str());
        said.push_back(t);
      }
      for (const std::string& t : said)
        std::cerr << "compensation_publisher: " << it->first << ": the robot file's " << t << ": targets farther are "
                  << (cell_.compensation.max_predicted_sigma_m > 0
                          ? "passed through uncorrected (never_judged)\n"
                          : "corrected with their predicted error not known (compensation.max_predicted_sigma_mm 0)\n");
      r.judged_ranges_said = true;
    }
    r.servo->setCalibration(c->version, *r.applied_model);
  }
  r.calibration = std::move(c);
  refreshNote(r);
  if (r.description && r.last_ok &&
      (r.last_ok->version != r.description->version || r.last_ok->last_measurement_stamp_ns != r.description->stamp_ns))
    publishDescription(it->first, r);
}

// The robot's URDF (its robot_file, or the URDF a robot file was converted from), checked to be the robot of the cell
// file and to have a fixed joint after the last revolute one to carry its calibration (an export of the nominal model),
// and the writer. Any problem stops the process at start, named: the user asked for the topic.
void CompensationPublisher::openDescription(const std::string& id, Robot& r) {
  const std::string what = "--ros-description-topic: " + id + ": ";
  const CellRobot& robot = *r.robot;
  std::string why;
  const auto origin = urdfOriginOf(robot.robot_file, isUrdfPath(robot.robot_file) ? decltype(RobotFile::source){}
                                                                                   : loadRobotFile(robot.robot_file).source,
                                   &why);
  if (!origin) throw std::runtime_error(what + why + ": a calibrated URDF needs the robot's URDF");
  std::ifstream in(origin->path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  UrdfImport nominal = importUrdf(text.str(), origin->path, origin->options);
  if (const std::string mismatch = urdfMismatch(nominal, robot.model); !mismatch.empty())
    throw std::runtime_error(what + origin->path + " is not the robot of " + robot.robot_file + " (" + mismatch + ")");
  exportUrdf(text.str(), origin->path, nominal, nominal.model.nominal, Pose::Identity());  // throws, naming the element
  const std::string ros_name =
      robots_.size() == 1 ? options_.ros_description_topic : options_.ros_description_topic + "/" + id;
  const auto topic = ros2DdsTopic(ros_name, &why);
  if (!topic) throw std::runtime_error(what + why);
  r.description = Description{origin->path, text.str(), std::move(nominal),
                              node_.writer<std_msgs::msg::dds_::String_>(*topic)};
  std::cerr << "compensation_publisher: " << id << ": the calibrated URDF of " << origin->path << " on ROS 2 topic "
            << ros_name << " after each new ok calibration (std_msgs/String, transient local)\n";
}

// The calibrated URDF of the last ok calibration: its kinematic parameters in the chain's joint origins, the tool
// frame's change from the cell's registration (what the target's frame absorbed of joint 6) in the last fixed joint.
// An XML comment at the top names the robot and the version. A failure is said and counted; targets go on.
void CompensationPublisher::publishDescription(const std::string& id, Robot& r) {
  Description& d = *r.description;
  const ReceivedCalibration& c = *r.last_ok;
  const RobotModel& m = r.robot->model;
  try {
    const int tool = m.toolParam(FrameParam::kX);
    const Pose tip_correction = poseFromXyzRpy(c.params[tool], c.params[tool + 1], c.params[tool + 2], c.params[tool + 3],
                                               c.params[tool + 4], c.params[tool + 5]) *
                                poseFromXyzRpy(m.nominal[tool], m.nominal[tool + 1], m.nominal[tool + 2],
                                               m.nominal[tool + 3], m.nominal[tool + 4], m.nominal[tool + 5])
                                    .inverse();
    std::string xml = exportUrdf(d.xml, d.path, d.nominal, c.params.head(m.numParams()), tip_correction);
    std::string from = d.path;  // "--" may not stand in an XML comment
    for (size_t at = from.find("--"); at != std::string::npos; at = from.find("--", at)) from.replace(at, 2, "-_");
    const std::string comment = "<!-- cellcal: " + id + ", calibration v" + std::to_string(c.version) + " (" +
                                std::to_string(c.poses_used) + " poses): " + from +
                                " with the chain's joint origins calibrated" +
                                (c.extensions.empty() ? "" : "; its model extensions are not carried") + " -->\n";
    size_t at = 0;  // after the XML declaration (which must come first), else at the top
    if (xml.rfind("<?xml", 0) == 0) {
      const size_t end = xml.find('\n', xml.find("?>"));
      at = end == std::string::npos ? xml.size() : end + 1;
    }
    xml.insert(at, comment);
    std_msgs::msg::dds_::String_ sample;
    sample.data(std::move(xml));
    if (!d.writer.write(sample)) throw std::runtime_error("DDS refused the sample");
    ++d.published;
    d.version = c.version;
    d.stamp_ns = c.last_measurement_stamp_ns;
    if (!c.extensions.empty() && !d.extensions_said) {
      std::cerr << "compensation_publisher: " << id << ": robot_description carries the geometric part only; the model "
                << "extensions are not in a URDF\n";
      d.extensions_said = true;
    }
  } catch (const std::exception& e) {
    ++d.failed;
    d.version = c.version;  // said once per version
    d.stamp_ns = c.last_measurement_stamp_ns;
    std::cerr << "compensation_publisher: " << id << ": calibration v" << c.version
              << " not published as a URDF: " << e.what() << "\n";
  }
}

void CompensationPublisher::onDiagnostics(const msg::CalibrationDiagnostics& d) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = robots_.find(d.robot_id().to_string());
  if (it == robots_.end()) return;
  std::string warning = d.stale_inputs().size() == 0 ? "" : "engine input stale: " + d.stale_inputs().to_string();
  if (warning == it->second.engine_warning) return;
  it->second.engine_warning = std::move(warning);
  refreshNote(it->second);
}

// The engine's presence, read per request from an atomic: the note changes when it comes or goes.
void CompensationPublisher::noticeEngine(Robot& r) {
  const bool gone = engine_writers_.load(std::memory_order_relaxed) == 0;
  if (gone == r.engine_gone) return;
  r.engine_gone = gone;
  refreshNote(r);
}

// Said in `reason` even when applied: what the operator should know about the calibration used.
void CompensationPublisher::refreshNote(Robot& r) {
  r.note.clear();
  if (!r.last_ok || !r.calibration) return;
  const std::string use = "v" + std::to_string(r.last_ok->version);
  if (r.calibration->health != msg::HEALTH_OK)
    r.note = "applying " + use + ": the engine's v" + std::to_string(r.calibration->version) + " is " +
             healthText(r.calibration->health);
  if (!r.engine_warning.empty()) r.note += (r.note.empty() ? "" : "; ") + r.engine_warning;
  // The engine gone (killed, its host down): its participant's lease expired, no CalibrationState writer is left.
  if (r.engine_gone)
    r.note += (r.note.empty() ? "" : "; ") + std::string("engine not seen (no CalibrationState writer): applying ") + use +
              ", the last ok calibration it published";
}

// Targets are taken only once every robot's calibration is here (TRANSIENT_LOCAL delivers the latest at once on
// discovery) or after --wait-for-calibration-s: a restarted publisher never answers from an empty state while the
// engine's calibration is on its way.
void CompensationPublisher::waitForCalibrations() {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(options_.wait_for_calibration_s);
  while (std::chrono::steady_clock::now() < deadline && !stopRequested()) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      bool all = true;
      for (const auto& [id, r] : robots_) all = all && r.calibration.has_value();
      if (all) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

namespace {
// A pose on the wire the compensation can take: finite, and a unit quaternion (to 1e-6).
bool usablePose(const std::array<double, 3>& p, const std::array<double, 4>& q) {
  bool finite = true;
  for (double v : p) finite = finite && std::isfinite(v);
  for (double v : q) finite = finite && std::isfinite(v);
  return finite && std::abs(std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0) <= 1e-6;
}

// Core's outcome on the wire: the IDL's enum holds core's in its order (compensation.hpp), checked here once.
msg::CompensationOutcome toWire(CompensationOutcome o) {
  static_assert(static_cast<int>(CompensationOutcome::kNeverJudged) == msg::OUTCOME_NEVER_JUDGED &&
                    static_cast<int>(CompensationOutcome::kApplied) == msg::OUTCOME_APPLIED &&
                    static_cast<int>(CompensationOutcome::kBadInput) == msg::OUTCOME_BAD_INPUT &&
                    kNumCompensationOutcomes == msg::OUTCOME_PASS_THROUGH,
                "idl/cellcal_msgs.idl's CompensationOutcome must start with core's CompensationOutcome, in its order");
  return static_cast<msg::CompensationOutcome>(static_cast<int>(o));
}

double threadCpuUs() {
  timespec ts{};
  ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e6 + static_cast<double>(ts.tv_nsec) * 1e-3;
}
}  // namespace

void CompensationPublisher::CpuHistogram::add(double us) {
  ++bins[std::min(bins.size() - 1, static_cast<size_t>(std::max(0.0, us)))];
  sum_us += us;
  max_us = std::max(max_us, us);
  ++n;
}

nlohmann::json CompensationPublisher::CpuHistogram::json() const {
  auto quantile = [&](double p) {
    const auto want = static_cast<std::uint64_t>(std::ceil(p * static_cast<double>(n)));
    std::uint64_t seen = 0;
    for (size_t b = 0; b < bins.size(); ++b)
      if ((seen += bins[b]) >= want && want > 0) return static_cast<double>(b) + 0.5;
    return 0.0;
  };
  return {{"samples", n}, {"mean", n ? sum_us / static_cast<double>(n) : 0.0}, {"p50", quantile(0.5)},
          {"p99", quantile(0.99)}, {"max", max_us}};
}

void CompensationPublisher::onTarget(const msg::TargetPose& t) {
  const double cpu0_us = threadCpuUs();
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = robots_.find(t.robot_id().to_string());
  if (it == robots_.end()) return;
  answer(t, it->second);
  target_cpu_.add(threadCpuUs() - cpu0_us);
}

// A servo loop's setpoint: answered at once (best effort, keep last 1 both ways: an older setpoint than the last
// answered is dropped, and the writer never waits for a reader), blended between calibration versions on the
// setpoints' own stamps.
void CompensationPublisher::onServoSetpoint(const msg::ServoSetpoint& sp) {
  const double cpu0_us = threadCpuUs();
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = robots_.find(sp.robot_id().to_string());
  if (it == robots_.end()) return;
  Robot& r = it->second;
  if (sp.sequence_number() <= r.servo_last_sequence) {
    ++servo_out_of_order_;
    return;
  }
  r.servo_last_sequence = sp.sequence_number();
  noticeEngine(r);
  const Eigen::VectorXd q = Eigen::Map<const Eigen::VectorXd>(sp.joint_position_rad().data(),
                                                              static_cast<Eigen::Index>(sp.joint_position_rad().size()));
  const auto stamp = static_cast<std::int64_t>(sp.cycle_stamp_ns());
  ServoAnswer a;
  msg::CompensationOutcome outcome;
  std::string reason;
  if (sp.cartesian() && !usablePose(sp.position_m(), sp.orientation_xyzw())) {
    a.q_rad = q;
    reason = "setpoint rejected: non-finite position or non-unit quaternion";
    outcome = msg::OUTCOME_BAD_INPUT;
  } else {
    a = sp.cartesian() ? r.servo->answerPose(stamp, toPose(sp.position_m(), sp.orientation_xyzw()), q)
                       : r.servo->answerJoints(stamp, q);
    // (With --pass-through no version is ever installed: a is the setpoint.)
    reason = options_.pass_through ? std::string(kPassThroughReason) : describe(a);
    outcome = options_.pass_through                            ? msg::OUTCOME_PASS_THROUGH
              : a.outcome == CompensationOutcome::kBadInput ? toWire(a.outcome)
              : a.version == 0                              ? msg::OUTCOME_NO_CALIBRATION
                                                            : toWire(a.outcome);
  }
  msg::ServoCorrection& out = servo_out_;
  out.robot_id(sp.robot_id());
  out.cycle_stamp_ns(sp.cycle_stamp_ns());
  out.sequence_number(++r.servo_seq);
  out.setpoint_sequence(sp.sequence_number());
  out.applied(a.applied);
  out.joint_position_rad().assign(a.q_rad.data(), a.q_rad.data() + a.q_rad.size());
  if (a.applied || !sp.cartesian()) {
    fromPose(a.commanded, out.position_m(), out.orientation_xyzw());
  } else {
    out.position_m(sp.position_m());
    out.orientation_xyzw(sp.orientation_xyzw());
  }
  out.calibration_version(a.version);
  out.blend_from_version(a.from_version);
  out.blend_weight(a.weight);
  out.reason(std::move(reason));
  out.note(r.note);
  out.outcome(a.applied ? toWire(a.outcome) : outcome);
  out.beyond_data(a.applied && a.beyond_data);
  out.source_stamp_ns(static_cast<std::uint64_t>(wallNs()));
  servo_writer_.write(out);
  ++servo_answered_;
  if (a.applied) ++servo_applied_;
  if (a.applied && a.beyond_data) ++servo_beyond_data_;
  servo_cpu_.add(threadCpuUs() - cpu0_us);
}

// Per target only what depends on the target: the model was prepared when its version arrived, the note when the
// state changed; the samples are reused.
void CompensationPublisher::answer(const msg::TargetPose& t, Robot& r) {
  msg::CompensatedTarget& out = out_;
  out.robot_id(t.robot_id());
  out.sequence_number(++r.seq);
  out.target_sequence(t.sequence_number());
  out.desired_position_m(t.position_m());
  out.desired_orientation_xyzw(t.orientation_xyzw());
  out.corrected_position_m(t.position_m());
  out.corrected_orientation_xyzw(t.orientation_xyzw());
  out.joint_position_rad().clear();
  out.correction_position_m(0);
  out.correction_orientation_rad(0);
  out.calibration_version(0);
  out.applied(false);
  out.clamped(false);
  out.reason("");
  out.beyond_data(false);
  out.older_calibration(false);
  noticeEngine(r);  // before the note is copied: the first target after the engine left already says so
  out.note(r.note);
  if (!usablePose(t.position_m(), t.orientation_xyzw())) {
    out.reason("target rejected: non-finite position or non-unit quaternion");
    out.outcome(msg::OUTCOME_BAD_INPUT);
  } else if (options_.pass_through) {
    out.reason(kPassThroughReason);
    out.outcome(msg::OUTCOME_PASS_THROUGH);
  } else if (!r.calibration) {
    out.reason("no calibration received yet");
    out.outcome(msg::OUTCOME_NO_CALIBRATION);
  } else if (!r.last_ok) {
    out.calibration_version(r.calibration->version);
    out.reason("calibration v" + std::to_string(r.calibration->version) + " is " + healthText(r.calibration->health) +
               " and no earlier one was ok");
    out.outcome(msg::OUTCOME_NO_GOOD_CALIBRATION);
  } else {
    out.calibration_version(r.last_ok->version);
    Eigen::VectorXd seed = Eigen::Map<const Eigen::VectorXd>(t.seed_position_rad().data(),
                                                             static_cast<Eigen::Index>(t.seed_position_rad().size()));
    if (seed.size() == 0 && !r.path.empty()) seed = r.path.back();
    // With model extensions, backlash's play is that of the path through the previous compensated targets.
    const CompensationResult c = compensate(r.robot->model, *r.applied_model,
                                            toPose(t.position_m(), t.orientation_xyzw()), seed, cell_.compensation, r.path);
    ++outcomes_[static_cast<size_t>(c.outcome)];
    if (c.applied && c.residual_map_applied) ++residual_map_applied_;
    out.applied(c.applied);
    out.clamped(c.clamped);
    out.outcome(toWire(c.outcome));
    const bool beyond_data = c.applied && c.beyond_data;  // said first, before why it was clamped
    out.beyond_data(beyond_data);
    out.older_calibration(c.applied && r.calibration->version != r.last_ok->version);
    if (beyond_data) ++beyond_data_applied_;
    const std::string why = describe(c);
    out.reason(beyond_data ? std::string(kBeyondDataNote) + (why.empty() ? "" : "; " + why) : why);
    out.correction_position_m(c.correction_position_m);
    out.correction_orientation_rad(c.correction_orientation_rad);
    if (c.applied) {
      fromPose(c.corrected_in_tracker, out.corrected_position_m(), out.corrected_orientation_xyzw());
      out.joint_position_rad().assign(c.q_rad.data(), c.q_rad.data() + c.q_rad.size());
      if (r.path.size() >= static_cast<size_t>(kPlayHistory)) r.path.erase(r.path.begin());
      r.path.push_back(c.q_rad);
    }
  }
  out.source_stamp_ns(static_cast<std::uint64_t>(wallNs()));
  writer_.write(out);
  if (r.ros_pose && out.applied()) {
    geometry_msgs::msg::dds_::PoseStamped_& ps = ros_sample_;
    const std::uint64_t stamp = t.source_stamp_ns() > 0 ? t.source_stamp_ns() : out.source_stamp_ns();
    ps.header().stamp().sec(static_cast<std::int32_t>(stamp / 1000000000ULL));
    ps.header().stamp().nanosec(static_cast<std::uint32_t>(stamp % 1000000000ULL));
    ps.header().frame_id(options_.ros_frame_id);
    ps.pose().position().x(out.corrected_position_m()[0]);
    ps.pose().position().y(out.corrected_position_m()[1]);
    ps.pose().position().z(out.corrected_position_m()[2]);
    ps.pose().orientation().x(out.corrected_orientation_xyzw()[0]);
    ps.pose().orientation().y(out.corrected_orientation_xyzw()[1]);
    ps.pose().orientation().z(out.corrected_orientation_xyzw()[2]);
    ps.pose().orientation().w(out.corrected_orientation_xyzw()[3]);
    r.ros_pose->write(ps);
  }
  if (out.applied()) ++applied_; else ++refused_;
  if (out.clamped()) ++clamped_;
}

int CompensationPublisher::run() {
  const RunLimit limit(options_.duration_s);
  while (!limit.timeUp() && sleepUntil(std::chrono::steady_clock::now() + std::chrono::milliseconds(20))) {
  }
  node_.shutdown();
  nlohmann::json versions = nlohmann::json::object();
  nlohmann::json descriptions = nlohmann::json::object();
  for (const auto& [id, r] : robots_) {
    versions[id] = r.calibration ? r.calibration->version : 0;
    if (r.description)
      descriptions[id] = {{"published", r.description->published}, {"failed", r.description->failed},
                          {"last_version", r.description->version}};
  }
  nlohmann::json outcomes = nlohmann::json::object();
  for (int k = 0; k < kNumCompensationOutcomes; ++k)
    if (outcomes_[static_cast<size_t>(k)] > 0)
      outcomes[outcomeName(static_cast<CompensationOutcome>(k))] = outcomes_[static_cast<size_t>(k)];
  stats::writeProcessStats(options_.process.stats_json, "compensation_publisher", node_.stats(),
                           {{"applied", applied_}, {"refused", refused_}, {"clamped", clamped_},
                            {"residual_map_applied", residual_map_applied_},
                            {"beyond_data_applied", beyond_data_applied_},
                            {"bad_calibration_states", bad_states_}, {"pass_through", options_.pass_through}, {"calibration_versions", versions},
                            {"descriptions", descriptions}, {stats::kOutcomes, outcomes},
                            {stats::kTargetCpuUs, target_cpu_.json()},
                            {stats::kServo, {{"answered", servo_answered_}, {"applied", servo_applied_},
                                             {"out_of_order", servo_out_of_order_},
                                             {"beyond_data_applied", servo_beyond_data_}, {"cpu_us", servo_cpu_.json()}}}});
  std::cerr << "compensation_publisher: stopped (" << (stopRequested() ? "SIGINT/SIGTERM" : "--duration-s reached")
            << "): " << applied_ << " targets corrected (" << beyond_data_applied_
            << " beyond the extensions' data, within the distance they were judged), " << refused_
            << " passed through uncorrected (" << clamped_ << " clamped)\n";
  return 0;
}

}  // namespace cellcal::components
