#include "cellcal/components/convert.hpp"

#include "cellcal/core/engine/compensation.hpp"

#include <Eigen/Geometry>

namespace cellcal::components {

JointSample toJointSample(const msg::JointState& m) {
  JointSample s;
  s.stamp_ns = static_cast<std::int64_t>(m.source_stamp_ns());
  s.sequence = m.sequence_number();
  s.q_rad = Eigen::Map<const Eigen::VectorXd>(m.position_rad().data(), static_cast<Eigen::Index>(m.position_rad().size()));
  s.settled = m.settled();
  return s;
}

msg::JointState toJointState(const std::string& robot_id, std::int64_t stamp_ns, std::uint64_t sequence,
                             const Eigen::VectorXd& q_rad, bool settled) {
  msg::JointState m;
  m.robot_id(robot_id);
  m.source_stamp_ns(static_cast<std::uint64_t>(stamp_ns));
  m.sequence_number(sequence);
  m.position_rad(std::vector<double>(q_rad.data(), q_rad.data() + q_rad.size()));
  m.settled(settled);
  return m;
}

TrackerSample toTrackerSample(const msg::TrackerPose& m) {
  TrackerSample s;
  s.stamp_ns = static_cast<std::int64_t>(m.source_stamp_ns());
  s.sequence = m.sequence_number();
  s.position_m = Eigen::Vector3d(m.position_m()[0], m.position_m()[1], m.position_m()[2]);
  for (int i = 0; i < 4; ++i) s.orientation_xyzw[i] = m.orientation_xyzw()[i];
  s.has_orientation = m.has_orientation();
  for (int i = 0; i < 36; ++i) s.covariance[i] = m.covariance()[i];
  s.valid = m.valid();
  return s;
}

msg::TrackerPose toTrackerPose(const std::string& target_id, std::int64_t stamp_ns, std::uint64_t sequence,
                               const Observation& o) {
  msg::TrackerPose m;
  m.target_id(target_id);
  m.source_stamp_ns(static_cast<std::uint64_t>(stamp_ns));
  m.sequence_number(sequence);
  fromPose(o.measured_in_tracker, m.position_m(), m.orientation_xyzw());
  m.has_orientation(o.kind == MeasurementKind::kPose6D);
  m.covariance(readingCovariance(o.sigma_position_m, o.sigma_orientation_rad));
  m.valid(true);
  return m;
}

msg::TrackerPose toTrackerPose(const TrackerLine& line, std::int64_t stamp_ns, std::uint64_t sequence) {
  msg::TrackerPose m;
  m.target_id(line.robot->target_id);
  m.source_stamp_ns(static_cast<std::uint64_t>(stamp_ns));
  m.sequence_number(sequence);
  m.position_m({line.position_m.x(), line.position_m.y(), line.position_m.z()});
  m.has_orientation(line.orientation_xyzw.has_value());
  m.orientation_xyzw(line.orientation_xyzw.value_or(std::array<double, 4>{0, 0, 0, 1}));
  m.covariance(readingCovariance(line.sigma_position_m, line.sigma_orientation_rad));
  m.valid(line.valid);
  return m;
}

std::array<double, 36> readingCovariance(double sigma_position_m, double sigma_orientation_rad) {
  std::array<double, 36> cov{};
  for (int i = 0; i < 3; ++i) {
    cov[i * 7] = sigma_position_m * sigma_position_m;
    cov[(i + 3) * 7] = sigma_orientation_rad * sigma_orientation_rad;
  }
  return cov;
}

msg::CalibrationState toCalibrationState(const CellRobot& robot, const CalibrationSnapshot& s, std::int64_t stamp_ns,
                                         std::uint64_t sequence) {
  msg::CalibrationState m;
  fillCalibrationState(robot, s, stamp_ns, sequence, m);
  return m;
}

void fillCalibrationState(const CellRobot& robot, const CalibrationSnapshot& s, std::int64_t stamp_ns,
                          std::uint64_t sequence, msg::CalibrationState& m) {
  const RobotModel& model = robot.model;
  // The names (about 40 strings) only when they change: another robot, other extensions.
  bool same_names = m.robot_id().to_string() == robot.robot_id && m.model_extensions().size() == s.extensions.size() &&
                    m.parameter_names().size() == static_cast<size_t>(model.numParams() +
                                                                     numExtensionParams(model, s.extensions));
  for (size_t k = 0; same_names && k < s.extensions.size(); ++k)
    same_names = m.model_extensions()[k].to_string() == extensionSpec(s.extensions[k]);
  m.robot_id(robot.robot_id);
  m.source_stamp_ns(static_cast<std::uint64_t>(stamp_ns));
  m.sequence_number(sequence);
  m.version(s.version);
  m.mode(s.mode == EngineMode::kContinuous ? msg::MODE_CONTINUOUS : msg::MODE_PERIODIC);
  m.health(static_cast<msg::CalibrationHealth>(static_cast<int>(s.health)));
  m.poses_used(s.poses_used);
  if (!same_names) {
    m.model_extensions().clear();
    for (const auto& e : s.extensions) m.model_extensions().push_back(extensionSpec(e));
    m.parameter_names().clear();
    for (const auto& name : parameterNames(model, s.extensions)) m.parameter_names().push_back(name);
  }
  parametersByName(model, s, m.parameter_values(), m.parameter_stddevs(), m.parameter_correlations());
  m.residual_rms_position_m(s.residual_rms_position_m);
  m.residual_rms_orientation_rad(s.residual_rms_orientation_rad);
  m.verification_mean_position_m(s.verification_mean_position_m);
  m.last_measurement_stamp_ns(static_cast<std::uint64_t>(s.last_measurement_stamp_ns));
  m.robot_model(model.name);
}

msg::CalibrationDiagnostics toCalibrationDiagnostics(const EngineHost::Robot& r, const std::string& stale_inputs,
                                                     std::uint64_t inputs_refused, std::int64_t stamp_ns,
                                                     std::uint64_t sequence) {
  const auto& c = r.engine->counters();
  const auto& snap = r.engine->snapshot();
  msg::CalibrationDiagnostics d;
  d.robot_id(r.robot->robot_id);
  d.source_stamp_ns(static_cast<std::uint64_t>(stamp_ns));
  d.sequence_number(sequence);
  for (size_t k = 0; k < c.rejected.size(); ++k) {
    if (!c.rejected[k]) continue;
    d.rejection_reasons().push_back(rejectionName(static_cast<Rejection>(k)));
    d.rejection_counts().push_back(c.rejected[k]);
  }
  if (inputs_refused) {  // before any robot could be told: counted for every robot
    d.rejection_reasons().push_back("engine_input_queue_full");
    d.rejection_counts().push_back(inputs_refused);
  }
  d.drift_alarm(snap.drift_alarm);
  d.stale_input(!stale_inputs.empty());
  d.stale_inputs(stale_inputs.substr(0, 255));
  d.health(static_cast<msg::CalibrationHealth>(static_cast<int>(snap.health)));
  static_assert(static_cast<int>(HealthCause::kDriftAlarm) == msg::HEALTH_CAUSE_DRIFT_ALARM &&
                    static_cast<int>(HealthCause::kNone) == msg::HEALTH_CAUSE_NONE,
                "idl/cellcal_msgs.idl's HealthCause must be core's, in its order");
  d.health_cause(static_cast<msg::HealthCause>(static_cast<int>(snap.health_verdict.cause)));
  d.health_reason(describe(snap.health_verdict));
  d.prediction_sigma_position_m(snap.prediction_sigma_position_m);
  d.prediction_sigma_workspace_m(r.engine->workspacePredictionSigma());
  d.verification_mean_position_m(snap.verification_mean_position_m);
  d.verification_p997_position_m(snap.verification_p997_position_m);
  d.verification_max_position_m(snap.verification_max_position_m);
  d.verification_poses(snap.verification_poses);
  d.persist_failures(r.persist_failures);
  d.persist_error(r.persist_error.substr(0, 255));
  d.identifiable_parameters(static_cast<std::uint32_t>(snap.estimated.size()));
  d.condition_number(r.engine->conditionNumber());
  d.pairing_latency_p99_ns(p99(r.pairing_ns));
  d.update_latency_p99_ns(p99(r.update_ns));
  d.joint_states_received(c.joint_states);
  d.tracker_readings_received(c.tracker_readings);
  d.poses_paired(c.paired);
  d.last_rejection(c.last_rejection.substr(0, 255));
  d.clock_warning(r.engine->clockWarning().substr(0, 255));
  return d;
}

std::optional<ReceivedCalibration> fromCalibrationState(const RobotModel& model, const msg::CalibrationState& m,
                                                         std::string* error) {
  auto fail = [&](const std::string& e) -> std::optional<ReceivedCalibration> {
    if (error) *error = "CalibrationState of " + m.robot_id().to_string() + " v" + std::to_string(m.version()) + ": " + e;
    return std::nullopt;
  };
  if (m.robot_model().to_string() != model.name)
    return fail("model '" + m.robot_model().to_string() + "', expected '" + model.name + "'");
  ReceivedCalibration r;
  for (const auto& spec : m.model_extensions()) {
    try {
      r.extensions.push_back(parseExtension(spec.to_string(), model, false));
    } catch (const std::invalid_argument& e) {
      return fail(std::string("model_extensions: ") + e.what());
    }
  }
  std::vector<std::string> names;
  names.reserve(m.parameter_names().size());
  for (const auto& n : m.parameter_names()) names.push_back(n.to_string());
  std::string why;
  auto model_back = modelFromParameters(model, r.extensions, names, m.parameter_values(), m.parameter_stddevs(),
                                        m.parameter_correlations(), &why);
  if (!model_back) return fail(why);
  // The consumers predict from the kinematic block (the extension parameters' uncertainty is not applied).
  model_back->covariance = model_back->kinematicCovariance();
  model_back->estimated_extension.clear();
  static_cast<CalibratedModel&>(r) = std::move(*model_back);
  r.version = m.version();
  r.health = m.health();
  r.last_measurement_stamp_ns = m.last_measurement_stamp_ns();
  r.poses_used = m.poses_used();
  r.verification_mean_position_m = m.verification_mean_position_m();
  r.residual_rms_position_m = m.residual_rms_position_m();
  return r;
}

const char* healthText(msg::CalibrationHealth h) { return healthName(static_cast<Health>(static_cast<int>(h))); }

const char* healthCauseText(msg::HealthCause c) {
  return healthCauseName(static_cast<HealthCause>(static_cast<int>(c)));
}

const char* outcomeText(msg::CompensationOutcome o) {
  if (static_cast<int>(o) < kNumCompensationOutcomes) return outcomeName(static_cast<CompensationOutcome>(static_cast<int>(o)));
  switch (o) {
    case msg::OUTCOME_PASS_THROUGH: return "pass_through";
    case msg::OUTCOME_NO_CALIBRATION: return "no_calibration";
    case msg::OUTCOME_NO_GOOD_CALIBRATION: return "no_good_calibration";
    default: return "?";
  }
}

Pose toPose(const std::array<double, 3>& p, const std::array<double, 4>& q) {
  Pose T = Pose::Identity();
  T.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
  T.linear() = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized().toRotationMatrix();
  return T;
}

void fromPose(const Pose& T, std::array<double, 3>& p, std::array<double, 4>& q) {
  for (int i = 0; i < 3; ++i) p[i] = T.translation()[i];
  const Eigen::Quaterniond qn(T.linear());
  q = {qn.x(), qn.y(), qn.z(), qn.w()};
}

msg::PoseRequest toPoseRequest(const std::string& robot_id, const PoseProposal& p, std::size_t candidates,
                               std::int64_t stamp_ns, std::uint64_t sequence) {
  msg::PoseRequest m;
  m.robot_id(robot_id);
  m.source_stamp_ns(static_cast<std::uint64_t>(stamp_ns));
  m.sequence_number(sequence);
  m.calibration_version(p.version);
  const auto joints = p.q_rad.empty() ? 0 : p.q_rad.front().size();
  m.joints(static_cast<std::uint32_t>(joints));
  std::vector<double>& v = m.configurations_rad();
  v.reserve(p.q_rad.size() * static_cast<std::size_t>(joints));
  for (const auto& q : p.q_rad) {
    if (v.size() + static_cast<std::size_t>(q.size()) > 1024) break;  // the IDL bound: the most informative kept
    v.insert(v.end(), q.data(), q.data() + q.size());
  }
  m.predicted_sigma_position_m(p.predicted_sigma_now_m);
  m.predicted_sigma_after_m(p.predicted_sigma_after_m);
  m.candidates(static_cast<std::uint32_t>(candidates));
  return m;
}

std::optional<std::vector<Eigen::VectorXd>> fromPoseRequest(const msg::PoseRequest& m, int joints, std::string* error) {
  const auto fail = [&](const std::string& why) -> std::optional<std::vector<Eigen::VectorXd>> {
    if (error) *error = "pose_request of " + m.robot_id().to_string() + " #" + std::to_string(m.sequence_number()) + ": " + why;
    return std::nullopt;
  };
  if (static_cast<int>(m.joints()) != joints)
    return fail(std::to_string(m.joints()) + " joints per configuration for a robot of " + std::to_string(joints));
  const auto& v = m.configurations_rad();
  if (joints <= 0 || v.size() % static_cast<std::size_t>(joints) != 0)
    return fail(std::to_string(v.size()) + " values are not whole configurations of " + std::to_string(joints) + " joints");
  std::vector<Eigen::VectorXd> out;
  for (std::size_t k = 0; k < v.size(); k += static_cast<std::size_t>(joints)) {
    Eigen::VectorXd q = Eigen::Map<const Eigen::VectorXd>(v.data() + k, joints);
    if (!q.allFinite()) return fail("configuration " + std::to_string(k / static_cast<std::size_t>(joints)) + " is not finite");
    out.push_back(std::move(q));
  }
  return out;
}

}  // namespace cellcal::components
