// The engine's state file: an EngineState as JSON ("cellcal-engine-state/1"), replaced atomically, fsynced on request.
//
//   saveEngineState(path, engine.exportState());          // temporary file, then rename: old or new, never a mix
//   syncStateFile(path);                                  // the data and the rename reach the disk
//   if (auto s = loadEngineState(path)) engine.importState(*s);
//
// Errors (std::runtime_error) name the file: a failed write leaves the previous file whole; a file that cannot be
// read as an engine state says why and what to do.
#pragma once

#include <optional>
#include <string>

#include "cellcal/core/engine/engine_state.hpp"

namespace cellcal {

// <dir>/<robot_id>.state.json
std::string stateFilePath(const std::string& dir, const std::string& robot_id);

std::string engineStateToJson(const EngineState& state);
// Throws std::runtime_error(why) for text that is not an engine state of this format.
EngineState engineStateFromJson(const std::string& text);

// Creates the folder if needed; atomic replace. Throws std::runtime_error naming the file (the old one stays whole).
void saveEngineState(const std::string& path, const EngineState& state);
// nullopt when there is no file; throws std::runtime_error "<path>: <why> (move the file away to start this robot's
// calibration over)" when there is one that cannot be used.
std::optional<EngineState> loadEngineState(const std::string& path);
// fsync of a file and its folder.
void syncStateFile(const std::string& path);

// The message for a state file the engine cannot resume from (loadEngineState's, or importState's reason).
std::string unusableStateMessage(const std::string& path, const std::string& why);

}  // namespace cellcal
