// A robot's durable engine state: the JSON snapshot of state_file.hpp plus an append-only journal beside it.
//
//   <dir>/<robot_id>.state.json      the snapshot: portable, readable, replaced atomically (state_file.hpp)
//   <dir>/<robot_id>.state.journal   records appended after the snapshot; each a whole EngineState, binary, framed
//                                    by a magic word, its length and a CRC-32; native byte order (a file of this
//                                    host, not for exchange: the snapshot is)
//
// Saving a state is one write(2) of one record before the new version is published: once write() returns, the data
// is in the kernel's page cache, and a SIGKILL of the process loses nothing that was published (a power loss may lose
// what was not fsynced yet: sync() off the latency path). This replaces rewriting the whole JSON file per pose, which
// costs its text encoding, a new file and a rename (tools/bench: BM_EnginePose).
//
// Reading (loadDurableState) takes the snapshot, then the journal's last whole record: a record cut short or
// corrupted (a crash during a write) ends the journal there, and the state before it is the one that was published.
// compact() writes the snapshot of the current state and empties the journal: done on open (so later records never
// follow a torn one), when the journal passes `compact_after_bytes`, and on a clean close (so the snapshot is current
// whenever the engine is not running).
//
//   DurableState store(stateFilePath(dir, id), {});
//   if (auto s = store.load()) engine.importState(*s);   // also compacts what it read
//   store.save(engine.exportState());                   // per change, before publishing
//   if (store.compactionDue()) store.compact(engine.exportState());   // after publishing
//   syncStateFile(store.journalPath());                 // any thread
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "cellcal/core/engine/engine_state.hpp"

namespace cellcal {

// <robot_id>.state.journal beside `state_file` (<robot_id>.state.json: its extension replaced).
std::string stateJournalPath(const std::string& state_file);

// A journal record's payload: everything engineStateToJson() keeps, bit for bit (poses too, where the snapshot keeps
// their quaternion). Throws std::runtime_error(why) for bytes that are not one.
std::string engineStateToBinary(const EngineState& state);
EngineState engineStateFromBinary(const std::string& bytes);

// What a state folder holds for one robot.
struct LoadedState {
  std::optional<EngineState> state;  // nullopt: neither a snapshot nor a journal record
  std::size_t journal_records = 0;   // whole records read from the journal
  std::uint64_t torn_bytes = 0;      // bytes after the last whole record (a write cut short), ignored
  std::string torn_reason;           // why they are not a record, when torn_bytes > 0
};
// Throws std::runtime_error "<file>: <why> (move the file away ...)" for a snapshot that cannot be read, or a journal
// whose first record is unreadable while the rest of the file is whole (not a crash: damage).
LoadedState loadDurableState(const std::string& state_file);

class DurableState {
 public:
  struct Options {
    Durability durability = Durability::kJournal;
    std::uint64_t compact_after_bytes = 8ull << 20;
  };
  DurableState(std::string state_file, Options options);
  ~DurableState();  // closes the journal (no compaction: close() does that)
  DurableState(const DurableState&) = delete;
  DurableState& operator=(const DurableState&) = delete;

  // loadDurableState(), then, when the journal held anything, compact() with what was read.
  std::optional<EngineState> load();
  // One change, before it is published. Journal: one appended record; snapshot: atomic replace. Throws
  // std::runtime_error naming the file; what was saved before stays readable.
  void save(const EngineState& state);
  bool compactionDue() const;
  // The snapshot replaced by `state` (the latest saved, or newer), then the journal emptied. Throws naming the file;
  // the journal is emptied only after the snapshot is in place.
  void compact(const EngineState& state);
  // A clean stop: compact() when the journal holds anything, so the snapshot alone is current.
  void close(const EngineState& state);

  const std::string& snapshotPath() const { return state_file_; }
  const std::string& journalPath() const { return journal_file_; }
  // The file save() last wrote (the journal, or the snapshot in kSnapshot mode), for syncStateFile().
  const std::string& savedPath() const;
  std::uint64_t journalBytes() const { return journal_bytes_; }
  std::uint64_t compactions() const { return compactions_; }

 private:
  void openJournal();

  std::string state_file_, journal_file_;
  Options options_;
  int fd_ = -1;
  std::uint64_t journal_bytes_ = 0, compactions_ = 0;
};

}  // namespace cellcal
