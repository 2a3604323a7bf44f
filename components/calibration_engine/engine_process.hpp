// The calibration engine process: the cell's engines (EngineHost) on the DDS domain.
//
// Threads: the DDS listeners only convert and queue each sample (WorkQueue); one worker feeds them to the host in
// arrival order (pairing, update, state file, publication of cellcal/calibration_state) and, with nothing queued for
// EngineHost::kTickPeriod, ticks it; the main loop (run()) fsyncs the state files, republishes the state and the
// diagnostics every engine.republish_period_s, and proposes the poses to measure next (cellcal/pose_request, after a
// new version, at most every engine.pose_requests.min_period_s; the choice runs on a copy of the estimate, outside
// the lock, so it never delays an update). A slow disk delays updates instead of making the kernel drop readings.
//
// Lifetime (as the Fast DDS examples): the constructor resumes the engines, joins the domain, creates the writers,
// the worker and then the readers, and publishes where each robot stands; run() returns on SIGINT/SIGTERM or after
// the duration, having drained the queue, left the domain (readers, writers, participant deleted), synced the state
// files and written --stats-json. The worker is stopped before the domain is left (it publishes), and a reader that
// still delivers then finds the queue closed.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <variant>

#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/engine_host.hpp"
#include "cellcal/components/process.hpp"
#include "cellcal/components/work_queue.hpp"
#include "cellcal/core/engine/pose_requests.hpp"

namespace cellcal::components {

class EngineProcess {
 public:
  struct Options {
    ProcessOptions process;
    double duration_s = 0;  // 0: until SIGINT/SIGTERM
    bool quiet = false;     // no line per update on stderr
  };
  explicit EngineProcess(const Options& options);
  // Stops the worker, then leaves the domain (what run() does when it returns; for an exception on the way).
  ~EngineProcess();
  EngineProcess(const EngineProcess&) = delete;
  EngineProcess& operator=(const EngineProcess&) = delete;
  // Runs until stopped; returns the exit code.
  int run();

  // A sample as received, waiting for the worker: the robot (joint state) or target (tracker reading) it names, and
  // when it arrived (the engine judges staleness and pairing timeouts by arrival, not by when the worker got to it).
  struct Input {
    std::string key;
    std::variant<JointSample, TrackerSample> sample;
    std::int64_t received_ns = 0;
  };
  // ~6 s of 8 robots with two 1 kHz streams, ~45 MB (~430 B a sample): what a stalled worker may fill before samples
  // are refused.
  static constexpr size_t kMaxQueuedInputs = 100000;

 private:
  struct Published {  // per robot: the sequence numbers of what it published, the last warnings printed
    std::uint64_t state_seq = 0, diag_seq = 0;
    std::string reported;
    // The robot's CalibrationState sample, filled again for every publish (fillCalibrationState: no construction,
    // the names kept).
    msg::CalibrationState state;
  };
  void onUpdate(EngineHost::Robot& r);
  void publishState(EngineHost::Robot& r);
  void publishDiagnostics(EngineHost::Robot& r, std::int64_t now);
  void logNotes(EngineHost::Robot& r);
  std::string staleInputs(EngineHost::Robot& r, std::int64_t now);
  void handle(std::vector<Input>& batch);
  // The robots whose proposal is due (a version not proposed yet, min_period_s since the last): their estimates,
  // copied under the lock.
  std::vector<std::pair<std::string, CalibrationSnapshot>> dueProposals(std::chrono::steady_clock::time_point now);
  void propose(const std::string& robot_id, const CalibrationSnapshot& snap);
  void stopAndReport();

  Options options_;
  CellConfig cell_;
  std::mutex mutex_;  // the host and what is published, between the worker and the main loop
  EngineHost host_;
  std::map<std::string, Published> published_;
  struct Requests {  // per robot: its PoseRequester (null: none proposed) and what it proposed
    std::unique_ptr<PoseRequester> requester;
    bool proposed = false;
    std::uint64_t version = 0, seq = 0;
    std::chrono::steady_clock::time_point at{};
    std::deque<std::int64_t> compute_ns;  // recent proposals' time to choose
    double last_sigma_now_m = 0, last_sigma_after_m = 0;
  };
  std::map<std::string, Requests> requests_;  // main loop only
  std::uint64_t inputs_refused_ = 0;  // samples the full queue refused, as of the last main-loop round
  DdsNode node_;
  Writer<msg::CalibrationState> state_writer_;
  Writer<msg::CalibrationDiagnostics> diag_writer_;
  Writer<msg::PoseRequest> request_writer_;
  std::unique_ptr<WorkQueue<Input>> inputs_;
};

}  // namespace cellcal::components
