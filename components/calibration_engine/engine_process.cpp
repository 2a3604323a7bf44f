#include "engine_process.hpp"

#include <unistd.h>

#include <chrono>
#include <iostream>

#include "cellcal/components/process_stats.hpp"
#include "cellcal/components/convert.hpp"
#include "cellcal/core/engine/state_file.hpp"

namespace cellcal::components {

namespace {

// Says how each robot starts (resumed or not, extensions, what the restore changed).
void reportStart(const EngineHost& host) {
  for (const auto& [id, r] : host.robots()) {
    const auto& snap = r.engine->snapshot();
    std::cerr << "calibration_engine: " << id << " (" << r.robot->model.name << ") "
              << (r.restored ? "resumed version " + std::to_string(snap.version) + " (" + std::to_string(snap.poses_used) +
                                   " poses) from "
                             : !r.engine->startNote().empty()
                                   ? "starts calibrated (version 1, health " + std::string(healthName(snap.health)) +
                                         "); state in "
                                   : "starts uncalibrated; state in ")
              << r.state_file << "\n";
    if (!r.robot->extensions.empty()) {
      std::cerr << "calibration_engine: " << id << " model extensions:";
      for (const auto& e : r.robot->extensions) std::cerr << " " << extensionSpec(e);
      std::cerr << " (" << snap.extension_params.size() << " extra parameters in the RLS state)\n";
    }
    if (!r.engine->startNote().empty()) std::cerr << "calibration_engine: " << id << ": " << r.engine->startNote() << "\n";
    if (!r.engine->restoreNote().empty()) std::cerr << "calibration_engine: " << id << ": " << r.engine->restoreNote() << "\n";
  }
}

// [[tracker sequence number, stamp_ns], ...]: what an in-process replay needs to feed the same readings.
nlohmann::json appliedReadingsJson(const std::deque<CalibrationEngine::AppliedReading>& applied) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& a : applied) out.push_back({a.tracker_sequence, a.stamp_ns});
  return out;
}

}  // namespace

EngineProcess::EngineProcess(const Options& options)
    : options_(options),
      cell_(loadCell(options.process)),
      host_(cell_, {}, [this](EngineHost::Robot& r) { onUpdate(r); }),
      node_(cell_, "cellcal_calibration_engine", identity::kCalibrationEngine),
      state_writer_(node_.writer<msg::CalibrationState>()),
      diag_writer_(node_.writer<msg::CalibrationDiagnostics>()),
      request_writer_(node_.writer<msg::PoseRequest>()) {
  reportStart(host_);
  const PoseRequestSettings& prs = cell_.engine.pose_requests;
  for (auto& [id, r] : host_.robots()) {
    Requests& q = requests_[id];
    if (prs.count == 0) continue;
    try {
      q.requester = std::make_unique<PoseRequester>(*r.robot, prs, poseRequestSeed(r.robot->index));
      std::cerr << "calibration_engine: " << id << ": " << poseRequesterText(*q.requester, prs) << "\n";
    } catch (const std::invalid_argument& e) {  // a cell whose tracker sees too little: calibrate all the same
      std::cerr << "calibration_engine: " << id << ": warning: no pose requests: " << e.what() << "\n";
    }
  }
  inputs_ = std::make_unique<WorkQueue<Input>>(
      kMaxQueuedInputs, [this](std::vector<Input>& batch) { handle(batch); }, EngineHost::kTickPeriod, [this] {
        std::lock_guard<std::mutex> lock(mutex_);
        host_.tick(wallNs());
      });
  node_.reader<msg::JointState>([this](const msg::JointState& m, const fdds::SampleInfo&) {
    inputs_->push({m.robot_id().to_string(), toJointSample(m), wallNs()});
  });
  node_.reader<msg::TrackerPose>([this](const msg::TrackerPose& m, const fdds::SampleInfo&) {
    inputs_->push({m.target_id().to_string(), toTrackerSample(m), wallNs()});
  });
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto& [id, r] : host_.robots()) {
    publishState(r);  // restored or uncalibrated: late joiners learn where the engine stands
    publishDiagnostics(r, wallNs());
  }
}

void EngineProcess::publishState(EngineHost::Robot& r) {
  Published& p = published_[r.robot->robot_id];
  fillCalibrationState(*r.robot, r.engine->snapshot(), wallNs(), ++p.state_seq, p.state);
  state_writer_.write(p.state);
}

// Per stream: nothing received for engine.stale_input_s, or no writer left (a killed adapter is unmatched when its
// participant lease expires).
std::string EngineProcess::staleInputs(EngineHost::Robot& r, std::int64_t now) {
  std::string out = r.engine->staleInputs(now);
  auto noWriter = [&](const char* topic, int writers) {
    if (writers == 0) out += std::string(out.empty() ? "" : "; ") + topic + ": no writer";
  };
  noWriter("joint_state", node_.matchedWriters<msg::JointState>());
  noWriter("tracker_pose", node_.matchedWriters<msg::TrackerPose>());
  return out;
}

// The engine's notes for the operator (the drift added at the first reading, a refused calibration file), once.
void EngineProcess::logNotes(EngineHost::Robot& r) {
  for (const auto& n : r.engine->takeNotes()) std::cerr << "calibration_engine: " << r.robot->robot_id << ": " << n << "\n";
}

void EngineProcess::publishDiagnostics(EngineHost::Robot& r, std::int64_t now) {
  logNotes(r);
  Published& p = published_[r.robot->robot_id];
  const std::string stale = staleInputs(r, now);
  auto d = toCalibrationDiagnostics(r, stale, inputs_refused_, now, ++p.diag_seq);
  diag_writer_.write(d);
  // Say it once on stderr when it changes (the diagnostics topic carries it every republish period).
  const auto& snap = r.engine->snapshot();
  // Without its figures ("nothing for 4.1 s" grows every period): a line when what is stale changes, not each second.
  const std::string clock = d.clock_warning().to_string();
  const std::string line = maskFigures(stale) + "|" + r.persist_error + "|" + healthName(snap.health) + "/" +
                           healthCauseName(snap.health_verdict.cause) + "|" + (clock.empty() ? "" : "clock");
  if (p.reported == line) return;
  p.reported = line;
  const std::string& id = r.robot->robot_id;
  if (!stale.empty()) std::cerr << "calibration_engine: " << id << ": stale input: " << stale << "\n";
  if (!r.persist_error.empty()) std::cerr << "calibration_engine: " << id << ": " << r.persist_error << "\n";
  if (!clock.empty()) std::cerr << "calibration_engine: " << id << ": clock: " << clock << "\n";
  if (snap.health != Health::kOk && snap.health != Health::kUncalibrated)
    std::cerr << "calibration_engine: " << id << ": health " << healthName(snap.health) << ": "
              << describe(snap.health_verdict) << "\n";
}

// A new version: published at once (the latency path; the state file was replaced before).
void EngineProcess::onUpdate(EngineHost::Robot& r) {
  publishState(r);
  logNotes(r);
  const auto& snap = r.engine->snapshot();
  if (!options_.quiet)
    std::cerr << "calibration_engine: " << r.robot->robot_id << " v" << snap.version << " poses " << snap.poses_used
              << " health " << healthName(snap.health) << " predicted-pose error (mean of recent) "
              << snap.verification_mean_position_m * 1e3 << " mm\n";
}

std::vector<std::pair<std::string, CalibrationSnapshot>> EngineProcess::dueProposals(std::chrono::steady_clock::time_point now) {
  std::vector<std::pair<std::string, CalibrationSnapshot>> due;
  const auto period = std::chrono::duration<double>(cell_.engine.pose_requests.min_period_s);
  for (auto& [id, q] : requests_) {
    if (!q.requester) continue;
    const CalibrationSnapshot& snap = host_.robots().at(id).engine->snapshot();
    if (q.proposed && (snap.version == q.version || now - q.at < period)) continue;
    q.proposed = true;
    q.version = snap.version;
    q.at = now;
    due.emplace_back(id, snap);
  }
  return due;
}

void EngineProcess::propose(const std::string& robot_id, const CalibrationSnapshot& snap) {
  Requests& q = requests_.at(robot_id);
  const auto t0 = std::chrono::steady_clock::now();
  const PoseProposal p = q.requester->propose(snap);
  q.compute_ns.push_back(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - t0).count());
  if (q.compute_ns.size() > 1000) q.compute_ns.pop_front();
  if (p.q_rad.empty()) return;
  q.last_sigma_now_m = p.predicted_sigma_now_m;
  q.last_sigma_after_m = p.predicted_sigma_after_m;
  auto m = toPoseRequest(robot_id, p, q.requester->candidates().q.size(), wallNs(), ++q.seq);
  request_writer_.write(m);
}

// The worker: every sample in arrival order.
void EngineProcess::handle(std::vector<Input>& batch) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto& in : batch) {
    if (auto* j = std::get_if<JointSample>(&in.sample))
      host_.onJointState(in.key, *j, in.received_ns);
    else
      host_.onTrackerSample(in.key, std::get<TrackerSample>(in.sample), in.received_ns);
  }
}

EngineProcess::~EngineProcess() {
  if (inputs_) inputs_->stop();
  node_.shutdown();
}

int EngineProcess::run() {
  std::cerr << "calibration_engine: " << cell_.robots.size() << " robot(s), mode "
            << (cell_.engine.mode == EngineMode::kContinuous ? "continuous" : "periodic") << ", domain "
            << node_.domainId() << "\n";
  const RunLimit limit(options_.duration_s);
  const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(cell_.engine.republish_period_s));
  auto next_republish = std::chrono::steady_clock::now() + period;
  std::vector<std::string> to_sync;
  std::uint64_t refused_reported = 0;
  while (sleepUntil(std::chrono::steady_clock::now() + EngineHost::kTickPeriod)) {
    if (limit.timeUp()) break;
    // Durability off the latency path: fsync the state files replaced since the last round, without the lock.
    for (const auto& f : to_sync) syncStateFile(f);
    to_sync.clear();
    const std::uint64_t refused = inputs_->refused();
    if (refused > refused_reported) {
      std::cerr << "calibration_engine: warning: " << refused - refused_reported << " samples refused: "
                << kMaxQueuedInputs << " were waiting for the worker (stalled on the disk?)\n";
      refused_reported = refused;
    }
    std::vector<std::pair<std::string, CalibrationSnapshot>> due;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      inputs_refused_ = refused;
      const std::int64_t now = wallNs();
      to_sync = host_.takeUnsynced();
      if (std::chrono::steady_clock::now() >= next_republish) {
        next_republish += period;
        for (auto& [id, r] : host_.robots()) {
          publishState(r);
          publishDiagnostics(r, now);
        }
      }
      due = dueProposals(std::chrono::steady_clock::now());
    }
    for (const auto& [id, snap] : due) propose(id, snap);  // outside the lock: the worker goes on updating
  }
  stopAndReport();
  return 0;
}

void EngineProcess::stopAndReport() {
  inputs_->stop();  // the worker handles what is queued (and may still publish), then stops
  node_.shutdown();
  host_.syncAll();
  host_.close();  // each robot's snapshot current, its journal emptied
  nlohmann::json robots = nlohmann::json::object();
  for (auto& [id, r] : host_.robots()) {
    const auto& snap = r.engine->snapshot();
    robots[id] = {{"version", snap.version},
                  {stats::kPosesUsed, snap.poses_used},
                  {"health", healthName(snap.health)},
                  {"recent_nis_per_row", snap.recent_nis_per_row},
                  {"drift_alarm", snap.drift_alarm},
                  {"condition_number", r.engine->conditionNumber()},
                  {"health_cause", healthCauseName(snap.health_verdict.cause)},
                  {"health_reason", describe(snap.health_verdict)},
                  {"prediction_sigma_position_m", snap.prediction_sigma_position_m},
                  {"prediction_sigma_workspace_m", r.engine->workspacePredictionSigma()},
                  {"persist_failures", r.persist_failures},
                  {"rejected", nlohmann::json(rejectionCounts(r.engine->counters()))},
                  // the readings applied, in order (the last 4096): [tracker sequence number, stamp_ns]
                  {stats::kAppliedReadings, appliedReadingsJson(r.engine->appliedReadings())},
                  {"pose_requests",
                   {{"published", requests_[id].seq},
                    {"choose_p50_ns", percentileNs(requests_[id].compute_ns, 0.5)},
                    {"choose_max_ns", percentileNs(requests_[id].compute_ns, 1.0)},
                    {"last_predicted_sigma_now_m", requests_[id].last_sigma_now_m},
                    {"last_predicted_sigma_after_m", requests_[id].last_sigma_after_m}}},
                  {"pairing_latency_p99_ns", p99(r.pairing_ns)},
                  {"reading_received_p50_ns", percentileNs(r.reading_received_ns, 0.5)},
                  {"reading_received_p99_ns", p99(r.reading_received_ns)},
                  {"paired_on", {{"reading", r.paired_on_reading}, {"joint_state", r.paired_on_joint_state}, {"tick", r.paired_on_tick}}},
                  {"update_latency_p99_ns", p99(r.update_ns)},
                  {"decided_to_published_p99_ns", p99(r.decided_ns)},
                  {"decided_to_published_p50_ns", percentileNs(r.decided_ns, 0.5)},
                  {"decided_to_published_parts_p50_ns",
                   {{"queued", percentileNs(r.queued_ns, 0.5)},
                    {"process", percentileNs(r.process_ns, 0.5)},
                    {"persist", percentileNs(r.persist_ns, 0.5)},
                    {"publish", percentileNs(r.publish_ns, 0.5)}}}};
  }
  stats::writeProcessStats(options_.process.stats_json, "calibration_engine", node_.stats(),
                           {{stats::kUpdates, host_.updates()}, {"unknown_keys", host_.unknownKeys()},
                            {stats::kRobots, robots},
                            {stats::kInputQueue, {{"peak", inputs_->peak()}, {"refused", inputs_->refused()},
                                                  {"max", kMaxQueuedInputs}}}});
  // A clean exit says so (a silent one reads like a crash in a log).
  std::cerr << "calibration_engine: stopped (" << (stopRequested() ? "SIGINT/SIGTERM" : "--duration-s reached")
            << "), " << host_.updates() << " updates this run; state files synced:";
  for (auto& [id, r] : host_.robots())
    std::cerr << " " << id << " v" << r.engine->snapshot().version << " " << healthName(r.engine->snapshot().health);
  std::cerr << "\n";
}

}  // namespace cellcal::components
