// What a process writes to --stats-json at exit and another program reads (`cellcal cell`'s launcher, judge and
// in-process reference, `cellcal bench-cell`): one name per key, used on both sides. The envelope is every process's:
//   {"name": "calibration_engine", "pid": 123, "topics": {topic: {"published": n, "received": n}}, "extra": {...}}
// and "extra" holds the process's own counters; the keys below are those read elsewhere.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

namespace cellcal::components::stats {

// The envelope.
inline constexpr const char* kName = "name";
inline constexpr const char* kPid = "pid";
inline constexpr const char* kTopics = "topics";        // DdsNode::stats()
inline constexpr const char* kPublished = "published";  // per topic
inline constexpr const char* kReceived = "received";    // per topic
inline constexpr const char* kExtra = "extra";

// calibration_engine's extra.
inline constexpr const char* kUpdates = "updates";            // calibration updates published this run
inline constexpr const char* kRobots = "robots";              // {robot_id: {...}}
inline constexpr const char* kPosesUsed = "poses_used";       // per robot: poses in its calibration
inline constexpr const char* kAppliedReadings = "applied_readings";  // per robot: [[tracker sequence, stamp_ns]]
inline constexpr const char* kInputQueue = "input_queue";     // {"peak", "refused", "max"}

// tracker_adapter's extra (the simulated tracker): {robot_id: [the program's pose id of reading 1, 2, ...]}.
inline constexpr const char* kPoseOfReading = "pose_of_reading";
// joint_state_adapter's extra (the simulated program): {robot_id: [[pose id, q_1 .. q_n rad], ...]} taken from the
// engine's proposals.
inline constexpr const char* kFollowedPoses = "followed_poses";

// compensation_publisher's extra.
inline constexpr const char* kTargetCpuUs = "target_cpu_us";  // {"mean", "p99", "max"} per target callback
inline constexpr const char* kOutcomes = "outcomes";          // {outcome: count}
inline constexpr const char* kServo = "servo";                // {"cpu_us", "applied", "answered", "out_of_order"}

// The envelope with a process's counters, written to `path` (nothing when empty; writeJsonFile).
void writeProcessStats(const std::string& path, const std::string& name, const nlohmann::json& topics,
                       const nlohmann::json& extra, const nlohmann::json& more = nlohmann::json::object());

}  // namespace cellcal::components::stats
