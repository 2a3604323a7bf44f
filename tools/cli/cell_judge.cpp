// `cellcal cell`'s judge: every calibration and compensated target scored against the simulator's truth.
#include <algorithm>
#include <chrono>
#include <fstream>
#include <cstdio>
#include <iostream>
#include <mutex>
#include <random>

#include "cell_roles.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/components/dds_node.hpp"
#include "cellcal/core/identification/statistics.hpp"
#include "cellcal/core/model/inverse_kinematics.hpp"
#include "cellcal/lab/sim_program.hpp"

namespace cellcal::cli {

using namespace cellcal::components;

// The judge's DDS callbacks only record (receipt time, sample): one receive thread serves every reader, so scoring in
// a callback would delay the others and inflate the latencies measured; score() does the work on the caller's thread.
class CellJudge::Impl {
 public:
  Impl(const CellConfig& cell, const CellArgs& a, SentTargets& sent) : cell_(cell), a_(a), sent_(sent) {
    for (size_t i = 0; i < cell.robots.size(); ++i) {
      Judge j(&cell.robots[i], makeSimulatedCell(cell.robots[i], cell.simulation, static_cast<int>(i)));
      std::mt19937_64 rng(cell.simulation.seed * 31 + 12345 + i);  // the application's targets follow (cell_application)
      j.holdout = j.sim.randomConfigurations(a.holdout_poses, rng);
      j.identified.params = j.sim.nominalParams();
      j.landed_rng.seed(cell.simulation.seed * 31 + 54321 + i);
      judges_.push_back(std::move(j));
    }
  }

  void attach(DdsNode& node) {
    node.reader<sim::RobotTruth>([this](const sim::RobotTruth& t, const fdds::SampleInfo&) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!program_start_) program_start_ = std::chrono::steady_clock::now();
      if (Judge* j = find(t.robot_id().to_string())) j->cell_time_s = std::max(j->cell_time_s, t.cell_time_s());
    });
    node.reader<msg::CalibrationState>([this](const msg::CalibrationState& m, const fdds::SampleInfo&) {
      const std::int64_t now = wallNs();
      std::lock_guard<std::mutex> lock(mutex_);
      states_in_.emplace_back(now, m);
    });
    node.reader<msg::CompensatedTarget>([this](const msg::CompensatedTarget& m, const fdds::SampleInfo&) {
      const std::int64_t now = wallNs();
      std::lock_guard<std::mutex> lock(mutex_);
      compensated_in_.emplace_back(now, m);
    });
  }

  double elapsed() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count(); }

  // --duration-s counts from the moment the robot program runs (start-up and discovery excluded), so a loaded
  // machine still sees the whole program; at most 30 s are allowed for start-up.
  double runningSeconds() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!program_start_) return elapsed() > 30 ? a_.duration_s : 0.0;
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - *program_start_).count();
  }

  // Scores what arrived since the last call; a line per calibration update unless --quiet.
  void score() {
    std::vector<std::pair<std::int64_t, msg::CalibrationState>> states;
    std::vector<std::pair<std::int64_t, msg::CompensatedTarget>> comps;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      states.swap(states_in_);
      comps.swap(compensated_in_);
    }
    for (const auto& [now, m] : states) scoreCalibration(now, m);
    for (const auto& [now, m] : comps) scoreCompensation(now, m);
  }

  // The summary of the run (processes and their topic counts: mergeProcessStats) and its two printed lines.
  void summarize(nlohmann::json* summary) const {
    nlohmann::json robots = nlohmann::json::array();
    double before = 0, after = 0, reference = 0, at_update = 0;
    std::vector<double> after_errors;  // every robot's hold-out poses at the end, calibrated (mm)
    int reference_poses = 0;
    const double n = static_cast<double>(judges_.size());
    for (size_t i = 0; i < judges_.size(); ++i) {
      const Judge& j = judges_[i];
      const double t_h = j.cell_time_s / 3600.0;
      const std::vector<double> ea = j.errors(j.identified, t_h);
      const double vb = j.verifyNominal(t_h), va = mean(ea);
      after_errors.insert(after_errors.end(), ea.begin(), ea.end());
      const std::optional<ReadingsApplied> readings = readingsApplied(*summary, j.robot->robot_id);
      const std::map<long long, Eigen::VectorXd> followed = followedPoses(*summary, j.robot->robot_id);
      const Reference r = a_.in_process_reference ? inProcessReference(cell_, *j.robot, static_cast<int>(i), j.cell_time_s, j,
                                                                       readings ? &*readings : nullptr, followed)
                                                  : Reference{};
      if (!r.why_program.empty())
        std::printf("cell: %s: the in-process engine replays the program, not the readings applied: %s\n",
                    j.robot->robot_id.c_str(), r.why_program.c_str());
      const double ref = r.verify_mm;
      reference_poses += r.poses;
      before += vb / n;
      after += va / n;
      at_update += j.verify_mm / n;
      reference += ref / n;
      robots.push_back({{"robot_id", j.robot->robot_id},
                        {"final_version", j.version},
                        {"cell_time_h", t_h},
                        {"verify_before_mm", vb},
                        {"verify_after_mm", va},
                        {"verify_after_p997_mm", percentile(ea, 0.997)},
                        {"verify_after_max_mm", *std::max_element(ea.begin(), ea.end())},
                        {"verify_after_last_update_mm", j.verify_mm},  // at the cell time of the last update
                        {"in_process_verify_after_mm", ref},
                        {"in_process_poses", r.poses},    // the poses it applied
                        {"in_process_inputs", r.inputs},  // applied_readings: the engine's; program: every pose by then
                        {"poses_followed", followed.size()},  // taken from the engine's proposals
                        // [version, poses used, cell time h, hold-out error mm] of each calibration received
                        {"holdout_by_version", j.history},
                        {"targets_applied", j.applied},
                        {"targets_applied_beyond_data", j.applied_beyond_data},
                        {"targets_refused", j.refused},
                        {"targets_refused_why", refusedWhyJson(j)},
                        // sent by the application, no answer received before the end (lost, or the cell stopped)
                        {"targets_unanswered", sent_[j.robot->robot_id].size()},
                        {"correction_mean_mm", mean(j.correction_mm)},
                        {"correction_mean_deg", mean(j.correction_deg)},
                        {"landed_error_compensated_mean_mm", mean(j.compensated_error_mm)},
                        {"landed_error_uncompensated_mean_mm", mean(j.uncompensated_error_mm)}});
    }
    auto& s = *summary;
    s["robots"] = robots;
    writeLanded(summary);
    s["verify_before_mm"] = before;
    s["verify_after_mm"] = after;
    const double after_p997 = percentile(after_errors, 0.997);
    const double after_max = after_errors.empty() ? std::nan("") : *std::max_element(after_errors.begin(), after_errors.end());
    s["verify_after_p997_mm"] = after_p997;
    s["verify_after_max_mm"] = after_max;
    s["in_process_verify_after_mm"] = reference;
    s["in_process_poses"] = reference_poses;
    s["verify_after_last_update_mm"] = at_update;
    s["latency_us"] = {{"tracker_to_state_p50", percentile(tracker_to_state_us_, 0.5)},
                       {"tracker_to_state_p99", percentile(tracker_to_state_us_, 0.99)},
                       {"target_to_compensated_p50", percentile(target_to_compensated_us_, 0.5)},
                       {"target_to_compensated_p99", percentile(target_to_compensated_us_, 0.99)},
                       {"tracker_to_state_samples", tracker_to_state_us_.size()},
                       {"target_to_compensated_samples", target_to_compensated_us_.size()}};
    s["domain_id"] = cell_.dds.domain_id;
    s["duration_s"] = elapsed();
    std::printf("cell: %llu calibration updates; hold-out error at the end: mean %.4f, 99.7%% %.4f, max %.4f mm calibrated "
                "vs mean %.3f mm uncalibrated (in-process engine on the same poses: %.4f mm); %.4f mm right after the "
                "last update\n",
                static_cast<unsigned long long>(s.value("calibration_updates", 0ULL)), after, after_p997, after_max, before,
                reference, at_update);
    std::printf("cell: latency tracker -> CalibrationState p50 %.0f us, p99 %.0f us; TargetPose -> CompensatedTarget "
                "p50 %.0f us, p99 %.0f us\n",
                percentile(tracker_to_state_us_, 0.5), percentile(tracker_to_state_us_, 0.99),
                percentile(target_to_compensated_us_, 0.5), percentile(target_to_compensated_us_, 0.99));
    if (cell_.simulation.follow_pose_requests)
      for (const auto& r : robots)
        std::printf("cell: %s: %llu poses of the program taken from the engine's proposals (cellcal/pose_request)\n",
                    r["robot_id"].get<std::string>().c_str(), r["poses_followed"].get<unsigned long long>());
    // Targets passed through uncorrected, and why: per reason, how many and the last answer that gave it; and those
    // corrected beyond the extensions' data (a periodic term standing for a growing error can err more there).
    for (const auto& j : judges_) {
      if (j.applied_beyond_data)
        std::printf("cell: %s: %llu of %llu targets %s (cellcal plan cover --beyond-data lists a program's to measure)\n",
                    j.robot->robot_id.c_str(), static_cast<unsigned long long>(j.applied_beyond_data),
                    static_cast<unsigned long long>(j.refused + j.applied), kBeyondDataNote);
      // What was sent and never answered is said too: a count of answers alone would hide it.
      if (const size_t unanswered = sent_[j.robot->robot_id].size())
        std::printf("cell: %s: %zu of %llu targets sent were never answered (lost, or the cell stopped first)\n",
                    j.robot->robot_id.c_str(), unanswered,
                    static_cast<unsigned long long>(unanswered + j.refused + j.applied));
      if (!j.refused) continue;
      std::printf("cell: %s: %llu of the %llu answered targets passed through uncorrected:\n", j.robot->robot_id.c_str(),
                  static_cast<unsigned long long>(j.refused), static_cast<unsigned long long>(j.refused + j.applied));
      for (const auto& [key, why] : j.refused_why)
        std::printf("cell:   %llu x %s: %s%s\n", static_cast<unsigned long long>(why.first), key.c_str(),
                    why.second.c_str(), why.first > 1 ? " (the last of them)" : "");
    }
  }

  double cellTimeS(std::size_t robot) {
    std::lock_guard<std::mutex> lock(mutex_);
    return judges_.at(robot).cell_time_s;
  }
  const Judge& judge(std::size_t robot) const { return judges_.at(robot); }

 private:
  static double mean(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? std::nan("") : s / static_cast<double>(v.size());
  }

  // {reason without its figures: {count, last}}.
  static nlohmann::json refusedWhyJson(const Judge& j) {
    nlohmann::json out = nlohmann::json::object();
    for (const auto& [key, why] : j.refused_why) out[key] = {{"count", why.first}, {"last", why.second}};
    return out;
  }

  Judge* find(const std::string& id) {
    for (auto& j : judges_)
      if (j.robot->robot_id == id) return &j;
    return nullptr;
  }

  void scoreCalibration(std::int64_t now, const msg::CalibrationState& m) {
    Judge* j = find(m.robot_id().to_string());
    if (!j || m.version() == j->version) return;
    std::string err;
    auto c = fromCalibrationState(j->sim.model(), m, &err);
    if (!c) {
      std::cerr << "cell: " << err << "\n";
      return;
    }
    if (m.last_measurement_stamp_ns() > 0)
      tracker_to_state_us_.push_back((now - static_cast<std::int64_t>(m.last_measurement_stamp_ns())) / 1e3);
    j->version = c->version;
    if (a_.rsi_hz > 0) j->calibrations[c->version] = *c;
    j->identified = *c;
    double cell_time;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      cell_time = j->cell_time_s;
    }
    const double t_h = cell_time / 3600.0;
    j->verify_mm = j->verify(j->identified, t_h);
    j->nominal_mm = j->verifyNominal(t_h);
    j->health = healthName(static_cast<Health>(static_cast<int>(m.health())));
    j->history.push_back({static_cast<double>(c->version), static_cast<double>(c->poses_used), t_h, j->verify_mm});
    if (a_.quiet) return;
    // The calibration as published (its health in capitals when it is not ok: the engine degraded or holds an older
    // version) and what compensation did since the last line: the version it applied, where those targets landed.
    std::string health = j->health;
    if (health != "ok") std::transform(health.begin(), health.end(), health.begin(), ::toupper);
    std::string comp = "compensation: no target corrected since the last line";
    if (j->compensated_error_mm.size() > j->landed_reported) {
      double sum = 0;
      for (size_t k = j->landed_reported; k < j->compensated_error_mm.size(); ++k) sum += j->compensated_error_mm[k];
      const size_t n = j->compensated_error_mm.size() - j->landed_reported;
      char buf[160];
      std::snprintf(buf, sizeof buf, "compensation v%llu: %zu target%s landed %.4f mm from where %s wanted",
                    static_cast<unsigned long long>(j->applied_version), n, n == 1 ? "" : "s",
                    sum / static_cast<double>(n), n == 1 ? "it was" : "they were");
      comp = buf;
      j->landed_reported = j->compensated_error_mm.size();
    }
    std::printf("[%6.2f s] %-8s v%-4llu %-14s poses %-4u cell time %5.2f h | hold-out error %.4f mm (uncalibrated "
                "%.3f mm) | %s\n",
                elapsed(), j->robot->robot_id.c_str(), static_cast<unsigned long long>(c->version), health.c_str(),
                c->poses_used, t_h, j->verify_mm, j->nominal_mm, comp.c_str());
    std::fflush(stdout);
  }

  void scoreCompensation(std::int64_t now, const msg::CompensatedTarget& m) {
    Judge* j = find(m.robot_id().to_string());
    if (!j) return;
    auto& sent = sent_[j->robot->robot_id];
    auto it = sent.find(m.target_sequence());
    if (it == sent.end()) return;
    target_to_compensated_us_.push_back((now - it->second.stamp_ns) / 1e3);
    const SentTarget target = it->second;
    const Eigen::VectorXd& q_nominal = target.q_nominal;
    sent.erase(it);
    if (!m.applied()) {
      ++j->refused;
      auto& why = j->refused_why[outcomeText(m.outcome())];
      ++why.first;
      why.second = m.reason();
      return;
    }
    ++j->applied;
    if (m.beyond_data()) ++j->applied_beyond_data;
    j->applied_version = m.calibration_version();
    j->correction_mm.push_back(m.correction_position_m() * 1e3);
    j->correction_deg.push_back(m.correction_orientation_rad() * 180 / kPi);
    // Where the real robot lands: the controller (nominal model) drives to the commanded pose.
    const RobotModel& model = j->sim.model();
    const Pose commanded = toPose(m.corrected_position_m(), m.corrected_orientation_xyzw());
    const Pose desired = toPose(m.desired_position_m(), m.desired_orientation_xyzw());
    const Eigen::VectorXd seed = Eigen::Map<const Eigen::VectorXd>(m.joint_position_rad().data(),
                                                                   static_cast<Eigen::Index>(m.joint_position_rad().size()));
    const IkResult ctrl = solveInverseKinematics(model, model.nominal, commanded, seed);
    if (!ctrl.ok()) return;
    const double t_h = j->cell_time_s / 3600.0;
    j->compensated_error_mm.push_back((j->sim.truePose(ctrl.q_rad, t_h).translation() - desired.translation()).norm() * 1e3);
    j->uncompensated_error_mm.push_back((j->sim.truePose(q_nominal, t_h).translation() - desired.translation()).norm() * 1e3);
    if (a_.landed_csv.empty() || !target.pose) return;
    // The tracker reads the robot where it landed; the row keeps the joints of the pose asked for (the program's).
    const Observation o = j->sim.measure(ctrl.q_rad, t_h, j->landed_rng, j->robot->measurement);
    MeasurementRow row;
    row.q_rad = q_nominal;
    row.position_m = o.measured_in_tracker.translation();
    if (o.kind == MeasurementKind::kPose6D) row.orientation = Eigen::Quaterniond(o.measured_in_tracker.linear());
    row.stamp_s = j->cell_time_s;
    row.pose = target.pose;
    row.cycle = target.cycle;
    j->landed.rows.push_back(std::move(row));
  }

  // --landed-csv: each robot's program targets, read where the robot landed, written and counted.
  void writeLanded(nlohmann::json* summary) const {
    if (a_.landed_csv.empty()) return;
    for (const auto& j : judges_) {
      std::string path = a_.landed_csv;
      if (judges_.size() > 1) {
        const auto dot = path.rfind(".csv");
        path.insert(dot == std::string::npos ? path.size() : dot, "_" + j.robot->robot_id);
      }
      std::ofstream out(path);
      writeMeasurementCsv(out, j.landed, j.sim.model().numJoints(),
                          "The targets of " + a_.targets_program + " compensated by the cell and read by the simulated "
                          "tracker where " + j.robot->robot_id + " landed; the joints are the program's (the pose asked "
                          "for), not the corrected ones the robot went to");
      if (!out) throw std::runtime_error("cannot write " + path);
      std::printf("cell: %s: %zu program targets landed and read into %s (cellcal iso9283 --data gives their figures)\n",
                  j.robot->robot_id.c_str(), j.landed.rows.size(), path.c_str());
      for (auto& r : (*summary)["robots"])
        if (r["robot_id"] == j.robot->robot_id) r["landed_rows"] = j.landed.rows.size(), r["landed_csv"] = path;
    }
  }

  const CellConfig& cell_;
  const CellArgs& a_;
  const std::chrono::steady_clock::time_point t0_ = std::chrono::steady_clock::now();
  std::vector<Judge> judges_;
  std::mutex mutex_;  // guards what the callbacks write: the *_in_ queues, program_start_, Judge::cell_time_s
  std::optional<std::chrono::steady_clock::time_point> program_start_;  // first RobotTruth: the robot runs
  std::vector<std::pair<std::int64_t, msg::CalibrationState>> states_in_;
  std::vector<std::pair<std::int64_t, msg::CompensatedTarget>> compensated_in_;
  std::vector<double> tracker_to_state_us_, target_to_compensated_us_;
  SentTargets& sent_;  // the application's (cell_application.cpp); scored answers are taken out
};

CellJudge::CellJudge(const CellConfig& cell, const CellArgs& a, SentTargets& sent)
    : impl_(std::make_unique<Impl>(cell, a, sent)) {}
CellJudge::~CellJudge() = default;
void CellJudge::attach(DdsNode& node) { impl_->attach(node); }
double CellJudge::runningSeconds() { return impl_->runningSeconds(); }
void CellJudge::score() { impl_->score(); }
void CellJudge::summarize(nlohmann::json* summary) const { impl_->summarize(summary); }
double CellJudge::cellTimeS(std::size_t robot) { return impl_->cellTimeS(robot); }
const Judge& CellJudge::judge(std::size_t robot) const { return impl_->judge(robot); }

}  // namespace cellcal::cli
