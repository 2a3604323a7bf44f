// What a tool that sees nothing would see with another participant profile. On one host the usual reason a tool
// finds no cell is that it joined with another profile than the cell (`cellcal cell` runs on cellcal_loopback, the
// tools default to the cell file's, cellcal): `status`, `record` and `foxglove` then look on the profile file's other
// participant profiles, on the same domain, and say where the cell is.
#pragma once

#include <string>
#include <vector>

#include "cellcal/core/files/cell_config.hpp"

namespace cellcal::components {

// The participant profile names of a Fast DDS XML profiles file, in file order. Throws std::runtime_error naming
// the file when it cannot be read.
std::vector<std::string> participantProfiles(const std::string& profiles_file);

struct ProfileSighting {
  std::string profile;
  int engine_writers = 0;        // CalibrationState writers matched
  int compensation_writers = 0;  // CompensatedTarget writers matched
  int sensor_writers = 0;        // JointState and TrackerPose writers matched
  std::string error;             // the participant could not be made with this profile (then nothing is counted)
  bool sawAnything() const { return engine_writers + compensation_writers + sensor_writers > 0; }
};

// Joins the cell's domain once per other participant profile of its profiles file (as the observer identity), for
// wait_s, and counts the cell's writers each one matched.
std::vector<ProfileSighting> probeOtherProfiles(const CellConfig& cell, double wait_s = 2.0);

// The sightings for a person: one line per profile, ending with the option to use where the cell was seen.
// `indent` starts each line.
std::string describeSightings(const CellConfig& cell, const std::vector<ProfileSighting>& sightings,
                              const std::string& indent);

}  // namespace cellcal::components
