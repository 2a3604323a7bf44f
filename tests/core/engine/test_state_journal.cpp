// The engine state's journal (core/engine/state_journal.hpp), checked against the plain reference, the JSON snapshot:
// a binary record keeps everything the JSON keeps, bit for bit, for random states with every optional part; a journal
// cut at any byte or corrupted anywhere in its last record reads as the state before it; a reopened journal never
// puts records after a torn one; compaction and a clean close leave the snapshot current; random damage to a record
// is refused with a reason, never a crash. Sizes, values and cut points are drawn from the test seed.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "cellcal/core/engine/state_file.hpp"
#include "cellcal/core/engine/state_journal.hpp"
#include "core/engine/engine_feed.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

namespace fs = std::filesystem;

// A state with every part filled at random (sizes too): what no single engine run is guaranteed to produce.
EngineState randomState(std::mt19937_64& rng, std::uint64_t version) {
  std::uniform_real_distribution<double> u(-1, 1);
  std::uniform_int_distribution<int> small(0, 6);
  auto vec = [&](int n) {
    Eigen::VectorXd v(n);
    for (int i = 0; i < n; ++i) v[i] = u(rng) * std::pow(10.0, small(rng) - 4);
    return v;
  };
  auto ints = [&](int n) {
    std::vector<int> v(static_cast<std::size_t>(n));
    for (auto& x : v) x = small(rng);
    return v;
  };
  auto cov = [&](int n) {
    const Eigen::MatrixXd a = Eigen::MatrixXd::NullaryExpr(n, n, [&]() { return u(rng); });
    return Eigen::MatrixXd(a * a.transpose());
  };
  EngineState s;
  s.robot_id = "robot_" + std::to_string(small(rng));
  s.robot_name = "model \"" + std::to_string(version) + "\"";
  s.num_params = 20 + small(rng);
  s.nominal = vec(s.num_params);
  s.mode = small(rng) % 2 ? EngineMode::kPeriodic : EngineMode::kContinuous;
  s.version = version;
  s.poses_used = static_cast<std::uint32_t>(version + small(rng));
  s.last_measurement_stamp_ns = 1'700'000'000'000'000'000 + static_cast<std::int64_t>(rng() % 1'000'000'000'000);
  s.last_tracker_sequence = rng();
  s.last_update_stamp_ns = -static_cast<std::int64_t>(rng() % 1000);
  s.params = vec(s.num_params);
  const int estimated = 1 + small(rng) + 10;
  s.estimated = ints(estimated);
  const int n_ext = small(rng) % 3;
  for (int i = 0; i < n_ext; ++i) s.extensions.push_back(i ? "backlash:3" : "joint_compliance:2");
  s.extension_params = vec(2 * n_ext);
  s.estimated_extension = ints(2 * n_ext);
  s.covariance = cov(estimated + 2 * n_ext);
  s.consecutive_outliers = small(rng);
  s.gate_window = std::vector<double>(static_cast<std::size_t>(small(rng)), 0.0);
  for (auto& g : s.gate_window) g = std::abs(u(rng)) * 100;
  if (small(rng) % 2) {
    EngineState::Good g;
    g.version = version - 1;
    g.params = vec(s.num_params);
    g.extension_params = vec(2 * n_ext);
    g.estimated = ints(5);
    g.covariance = cov(5);
    s.last_good = g;
  }
  if (n_ext) {
    EngineState::Play play;
    for (int j = 0; j < 6; ++j) {
      PlayTracker::Joint x;
      for (int t = small(rng); t > 0; --t) x.turns.push_back({static_cast<std::int64_t>(rng() % 100000), u(rng)});
      x.direction = small(rng) % 3 - 1;
      x.extreme = {static_cast<std::int64_t>(rng() % 100000), u(rng)};
      play.joints.push_back(std::move(x));
    }
    play.last_stamp_ns = static_cast<std::int64_t>(rng() % 100000);
    s.play = std::move(play);
  }
  for (int i = small(rng); i > 0; --i) s.recent.push_back({u(rng), u(rng), u(rng), std::abs(u(rng))});
  auto pendingPose = [&] {
    EngineState::PendingPose p;
    p.reading.observation.q_rad = vec(6);
    p.reading.observation.measured_in_tracker = Pose::Identity();
    p.reading.observation.measured_in_tracker.translation() = vec(3);
    p.reading.observation.measured_in_tracker.linear() =
        Eigen::Quaterniond(Eigen::Vector4d(vec(4)).normalized()).toRotationMatrix();
    p.reading.observation.kind = small(rng) % 2 ? MeasurementKind::kPose6D : MeasurementKind::kPosition3D;
    p.reading.observation.sigma_position_m = std::abs(u(rng)) * 1e-4;
    p.reading.observation.sigma_orientation_rad = std::abs(u(rng)) * 1e-3;
    p.reading.tracker_stamp_ns = static_cast<std::int64_t>(rng() % 1'000'000'000);
    p.reading.tracker_sequence = rng();
    p.reading.joint_stamp_ns = static_cast<std::int64_t>(rng() % 1'000'000'000);
    if (n_ext) {
      Drivers d;
      d.motion_direction = vec(6);
      d.recent_steps_rad = Eigen::MatrixXd::NullaryExpr(6, kPlayHistory, [&]() { return u(rng); });
      p.drivers = std::move(d);
    }
    return p;
  };
  for (int i = small(rng); i > 0; --i) s.pending_batch.push_back(pendingPose());
  // How the engine started (absent in states written before it was kept).
  if (const int start = small(rng) % 5; start < 4) s.started_from = static_cast<EngineState::Start>(start);
  if (small(rng) % 2) s.file_drift_pending_since_ns = 1'600'000'000'000'000'000 + static_cast<std::int64_t>(rng() % 1'000'000'000);
  if (small(rng) % 2) s.start_warning = "calibration_file \"x.yaml\" does not fit this cell: " + std::to_string(rng());
  for (int i = small(rng); i > 0; --i) s.work_configurations.push_back(vec(6));
  if (small(rng) % 2) {  // a calibration file on trial
    EngineState::FileTrialState t{vec(s.num_params), vec(2 * n_ext), vec(s.num_params), {}};
    for (int i = small(rng); i > 0; --i) t.poses.push_back(pendingPose());
    s.file_trial = std::move(t);
  }
  return s;
}

// Two states in the snapshot's JSON form are the same: every value equal, except a pending pose's orientation, which
// a trip through the snapshot (its quaternion -> rotation -> quaternion) may move by an ulp.
::testing::AssertionResult sameState(const EngineState& a, const EngineState& b) {
  const auto ja = nlohmann::json::parse(engineStateToJson(a)), jb = nlohmann::json::parse(engineStateToJson(b));
  for (const auto& op : nlohmann::json::diff(ja, jb)) {
    const std::string path = op.at("path");
    const nlohmann::json::json_pointer ptr(path);
    const bool quaternion = path.find("/orientation_xyzw/") != std::string::npos && op.at("op") == "replace" &&
                            std::abs(ja.at(ptr).get<double>() - jb.at(ptr).get<double>()) < 1e-15;
    if (!quaternion) return ::testing::AssertionFailure() << "differ at " << op.dump().substr(0, 300);
  }
  return ::testing::AssertionSuccess();
}

struct JournalTest : ::testing::Test {
  std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng{seed};
  std::string dir = test::tempDir(::testing::UnitTest::GetInstance()->current_test_info()->name());
  std::string file = stateFilePath(dir, "robot");
  void TearDown() override { fs::remove_all(dir); }
  std::string bytesOf(const std::string& path) { return test::readTextFile(path); }
  void writeBytes(const std::string& path, const std::string& b) {
    std::ofstream(path, std::ios::binary | std::ios::trunc) << b;
  }
};

TEST_F(JournalTest, ABinaryRecordKeepsEverythingTheJsonSnapshotKeeps) {
  for (int k = 0; k < 200; ++k) {
    const EngineState s = randomState(rng, 1 + k);
    const std::string a = engineStateToJson(engineStateFromBinary(engineStateToBinary(s))), b = engineStateToJson(s);
    EXPECT_TRUE(a == b) << "k " << k << ": "
                        << nlohmann::json::diff(nlohmann::json::parse(b), nlohmann::json::parse(a)).dump().substr(0, 600);
  }
  // The comparison sees a change in the last value written (the file trial's last nominal value, before its count of
  // poses), and in the last of the fields the first records ended with (the pending pose's joint stamp, before its "no
  // drivers" flag).
  EngineState s = randomState(rng, 7);
  s.start_warning = "refused";
  s.work_configurations = {Eigen::VectorXd::Constant(6, 0.25)};
  s.file_trial = EngineState::FileTrialState{Eigen::VectorXd::Constant(3, 0.5), Eigen::VectorXd(),
                                             Eigen::VectorXd::Constant(4, 0.75), {}};
  std::string b = engineStateToBinary(s);
  b[b.size() - 1 - 8] ^= 0x01;
  EXPECT_NE(engineStateToJson(engineStateFromBinary(b)), engineStateToJson(s));
  s.file_trial.reset();
  s.pending_batch.resize(1);
  s.pending_batch[0].drivers.reset();
  const std::size_t appended = 1 + (s.started_from ? 1 : 0) + 8 + 8 + s.start_warning.size() + 8 + 8 + 6 * 8 + 1;
  b = engineStateToBinary(s);
  b[b.size() - appended - 2] ^= 0x01;
  EXPECT_NE(engineStateToJson(engineStateFromBinary(b)), engineStateToJson(s));
  // A record written before the appended fields (it ends with the pending batch) reads, as a state without them.
  EngineState old = s;
  old.started_from.reset();
  old.file_drift_pending_since_ns = 0;
  old.start_warning.clear();
  old.work_configurations.clear();
  const std::string old_record = engineStateToBinary(s).substr(0, engineStateToBinary(s).size() - appended);
  EXPECT_EQ(engineStateToJson(engineStateFromBinary(old_record)), engineStateToJson(old));
}

TEST_F(JournalTest, AJournalCutOrCorruptedInItsLastRecordReadsAsTheStateBeforeIt) {
  DurableState store(file, {});
  std::vector<EngineState> saved;
  std::vector<std::uint64_t> ends;  // journal size after each record
  const int n = 3 + static_cast<int>(rng() % 6);
  for (int k = 0; k < n; ++k) {
    saved.push_back(randomState(rng, 10 + k));
    store.save(saved.back());
    ends.push_back(store.journalBytes());
  }
  EXPECT_FALSE(fs::exists(file)) << "no snapshot before the first compaction";
  const std::string whole = bytesOf(store.journalPath());
  ASSERT_EQ(whole.size(), ends.back());
  LoadedState l = loadDurableState(file);
  ASSERT_TRUE(l.state);
  EXPECT_EQ(l.journal_records, static_cast<std::size_t>(n));
  EXPECT_EQ(l.torn_bytes, 0u);
  EXPECT_EQ(engineStateToJson(*l.state), engineStateToJson(saved.back()));

  const std::uint64_t last_start = ends[ends.size() - 2];
  std::uniform_int_distribution<std::uint64_t> in_last(last_start, whole.size() - 1);
  for (int trial = 0; trial < 40; ++trial) {
    const std::uint64_t at = trial == 0 ? last_start : in_last(rng);
    std::string damaged = whole;
    const bool cut = trial % 2 == 0;
    if (cut) damaged.resize(at);
    else damaged[at] = static_cast<char>(damaged[at] ^ (1 + rng() % 255));
    writeBytes(store.journalPath(), damaged);
    l = loadDurableState(file);
    ASSERT_TRUE(l.state);
    if (cut && at == last_start) {
      EXPECT_EQ(l.torn_bytes, 0u);
    } else {
      EXPECT_EQ(l.torn_bytes, whole.size() - (cut ? whole.size() - at : 0) - last_start) << l.torn_reason;
      EXPECT_FALSE(l.torn_reason.empty());
    }
    EXPECT_EQ(l.journal_records, static_cast<std::size_t>(n - 1)) << (cut ? "cut at " : "byte flipped at ") << at;
    EXPECT_EQ(engineStateToJson(*l.state), engineStateToJson(saved[saved.size() - 2]));
  }
}

TEST_F(JournalTest, AReopenedJournalStartsFromWhatItReadAndNeverAppendsAfterATornRecord) {
  std::vector<EngineState> saved;
  {
    DurableState store(file, {});
    for (int k = 0; k < 4; ++k) {
      saved.push_back(randomState(rng, 1 + k));
      store.save(saved.back());
    }
  }  // "killed": the destructor only closes the file
  // A crash in the middle of the fifth record.
  const std::string fifth_payload = engineStateToBinary(randomState(rng, 5));
  {
    std::ofstream out(stateJournalPath(file), std::ios::binary | std::ios::app);
    out.write("CCJ1", 4);
    out.write(fifth_payload.data(), static_cast<std::streamsize>(fifth_payload.size() / 2));
  }
  DurableState store(file, {});
  const auto loaded = store.load();
  ASSERT_TRUE(loaded);
  EXPECT_EQ(engineStateToJson(*loaded), engineStateToJson(saved.back()));
  EXPECT_EQ(store.compactions(), 1u);
  EXPECT_EQ(fs::file_size(stateJournalPath(file)), 0u);
  EXPECT_TRUE(sameState(*loadEngineState(file), saved.back()));
  const EngineState next = randomState(rng, 6);
  store.save(next);
  const LoadedState l = loadDurableState(file);
  EXPECT_EQ(l.journal_records, 1u);
  EXPECT_EQ(engineStateToJson(*l.state), engineStateToJson(next));
}

TEST_F(JournalTest, CompactionAndACleanCloseLeaveTheSnapshotCurrent) {
  EngineState last;
  std::uint64_t records = 0;
  {
    DurableState store(file, {Durability::kJournal, 200'000});
    for (int k = 0; k < 120; ++k) {
      last = randomState(rng, 1 + k);
      store.save(last);
      ++records;
      if (store.compactionDue()) store.compact(last);
      // Read back at every step, as a restart at this point would.
      const LoadedState l = loadDurableState(file);
      ASSERT_TRUE(l.state);
      ASSERT_TRUE(sameState(*l.state, last)) << "after record " << records;
    }
    EXPECT_GT(store.compactions(), 1u);
    EXPECT_LT(store.journalBytes(), 200'000u + 100'000u);
    store.close(last);
  }
  EXPECT_EQ(fs::file_size(stateJournalPath(file)), 0u);
  EXPECT_TRUE(sameState(*loadEngineState(file), last));
  // The snapshot mode writes the JSON per change and no journal.
  const std::string other = stateFilePath(dir, "other");
  DurableState snap(other, {Durability::kSnapshot});
  snap.save(last);
  EXPECT_EQ(snap.savedPath(), other);
  EXPECT_FALSE(fs::exists(stateJournalPath(other)));
  EXPECT_TRUE(sameState(*loadEngineState(other), last));
}

TEST_F(JournalTest, DamageThatIsNotACrashIsRefusedWithTheFileNamedAndNeverCrashes) {
  // A whole record (its CRC matches) that this version cannot read: damage or another format, not a torn write.
  const EngineState s = randomState(rng, 3);
  {
    DurableState store(file, {});
    store.save(s);
  }
  std::string j = bytesOf(stateJournalPath(file));
  std::string payload = j.substr(12);
  payload[0] = 9;  // format 9
  std::uint32_t head[3];
  std::memcpy(head, j.data(), 12);
  // Build the frame by hand: magic, length, CRC-32 of the payload (computed by a second, bitwise implementation).
  auto crc = [](const std::string& d) {
    std::uint32_t c = 0xFFFFFFFFu;
    for (unsigned char b : d) {
      c ^= b;
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return ~c;
  };
  EXPECT_EQ(crc(j.substr(12)), head[2]) << "the journal's CRC-32 is the IEEE one";
  head[2] = crc(payload);
  std::string framed(reinterpret_cast<const char*>(head), 12);
  writeBytes(stateJournalPath(file), framed + payload);
  try {
    loadDurableState(file);
    ADD_FAILURE() << "a record of an unknown format was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("robot.state.journal"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("unknown record format 9"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("start this robot's calibration over"), std::string::npos) << e.what();
  }
  // Random damage to a payload: refused with a reason, never a crash or an allocation beyond the record.
  const std::string good = engineStateToBinary(randomState(rng, 4));
  int refused = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    std::string b = good;
    const int flips = 1 + static_cast<int>(rng() % 4);
    for (int f = 0; f < flips; ++f) b[rng() % b.size()] = static_cast<char>(rng());
    if (rng() % 3 == 0) b.resize(rng() % b.size());
    try {
      engineStateFromBinary(b);
    } catch (const std::runtime_error& e) {
      ++refused;
      EXPECT_FALSE(std::string(e.what()).empty());
    }
  }
  EXPECT_GT(refused, 0);
}

// Files written before the field list (state_fields.hpp), by 59b9ca6's two hand-written codecs, for one random state
// with every part: golden/engine_state_v1.json (the state file) and .bin (a journal record's payload), the JSON with
// the keys older files lack removed (.stripped.json) and the record cut before the fields appended since the first
// records (.cut.bin); beside each, what that code read from it, as a record (*read.bin). Today's code reads each as it
// did, and writes the state it read from the record as those files were written, plus the fields appended since
// (empty in those states: the work configurations' count 0, an empty array in JSON; no file trial, absent in JSON).
TEST(StateFormats, FilesWrittenBeforeTheFieldListReadAsThey) {
  const std::string dir = std::string(CELLCAL_CONFIG_DIR) + "/../tests/core/engine/golden/engine_state_v1";
  auto bytes = [&](const std::string& suffix) { return test::readTextFile(dir + suffix); };
  const std::string appended_since(8 + 1, '\0');  // work_configurations: none; file_trial: absent
  auto withAppended = [&](const std::string& suffix) { return bytes(suffix) + appended_since; };
  const std::string record = bytes(".bin");
  ASSERT_GT(record.size(), 1000u);
  const EngineState s = engineStateFromBinary(record);
  ASSERT_TRUE(s.last_good && s.play && s.started_from && !s.pending_batch.empty() && s.pending_batch[0].drivers &&
              !s.recent.empty() && !s.start_warning.empty())
      << "the golden state lost a part";
  EXPECT_TRUE(s.work_configurations.empty());
  EXPECT_EQ(engineStateToBinary(s), record + appended_since);
  nlohmann::json written = nlohmann::json::parse(engineStateToJson(s));
  EXPECT_EQ(written.at("work_configurations"), nlohmann::json::array());
  written.erase("work_configurations");
  EXPECT_EQ(written.dump(), nlohmann::json::parse(bytes(".json")).dump());
  EXPECT_EQ(engineStateToBinary(engineStateFromJson(bytes(".json"))), withAppended(".jsonread.bin"));
  EXPECT_EQ(engineStateToBinary(engineStateFromJson(bytes(".stripped.json"))), withAppended(".strippedread.bin"));
  EXPECT_EQ(engineStateToBinary(engineStateFromBinary(bytes(".cut.bin"))), withAppended(".cutread.bin"));
}

}  // namespace
}  // namespace cellcal
