#include "cellcal/components/profile_probe.hpp"

#include <chrono>
#include <fstream>
#include <memory>
#include <regex>
#include <sstream>
#include <stdexcept>

#include "cellcal/components/dds_node.hpp"
#include "cellcal/components/process.hpp"

namespace cellcal::components {

std::vector<std::string> participantProfiles(const std::string& profiles_file) {
  std::ifstream in(profiles_file);
  if (!in) throw std::runtime_error(profiles_file + ": cannot be read");
  std::stringstream text;
  text << in.rdbuf();
  const std::string s = text.str();
  // Comments may mention profiles: leave them out.
  const std::string without_comments = std::regex_replace(s, std::regex("<!--[\\s\\S]*?-->"), "");
  std::vector<std::string> out;
  const std::regex re("<participant\\s+profile_name\\s*=\\s*\"([^\"]+)\"");
  for (auto it = std::sregex_iterator(without_comments.begin(), without_comments.end(), re); it != std::sregex_iterator(); ++it)
    out.push_back((*it)[1]);
  return out;
}

std::vector<ProfileSighting> probeOtherProfiles(const CellConfig& cell, double wait_s) {
  std::vector<ProfileSighting> out;
  std::vector<std::unique_ptr<DdsNode>> nodes;
  for (const auto& name : participantProfiles(cell.dds.profiles_file)) {
    if (name == cell.dds.participant_profile) continue;
    ProfileSighting s;
    s.profile = name;
    CellConfig c = cell;
    c.dds.participant_profile = name;
    std::unique_ptr<DdsNode> node;
    try {
      node = std::make_unique<DdsNode>(c, "cellcal_profile_probe", identity::kObserver);
      node->reader<msg::CalibrationState>([](const msg::CalibrationState&, const fdds::SampleInfo&) {});
      node->reader<msg::CompensatedTarget>([](const msg::CompensatedTarget&, const fdds::SampleInfo&) {});
      node->reader<msg::JointState>([](const msg::JointState&, const fdds::SampleInfo&) {});
      node->reader<msg::TrackerPose>([](const msg::TrackerPose&, const fdds::SampleInfo&) {});
    } catch (const std::exception& e) {
      s.error = e.what();
      node.reset();
    }
    out.push_back(s);
    nodes.push_back(std::move(node));
  }
  sleepUntil(std::chrono::steady_clock::now() +
             std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(wait_s)));
  for (std::size_t i = 0; i < out.size(); ++i) {
    if (!nodes[i]) continue;
    out[i].engine_writers = nodes[i]->matchedWriters<msg::CalibrationState>();
    out[i].compensation_writers = nodes[i]->matchedWriters<msg::CompensatedTarget>();
    out[i].sensor_writers = nodes[i]->matchedWriters<msg::JointState>() + nodes[i]->matchedWriters<msg::TrackerPose>();
    nodes[i]->shutdown();
  }
  return out;
}

std::string describeSightings(const CellConfig& cell, const std::vector<ProfileSighting>& sightings,
                              const std::string& indent) {
  std::ostringstream o;
  if (sightings.empty()) {
    o << indent << "(no other participant profile in " << cell.dds.profiles_file << " to look on)\n";
    return o.str();
  }
  o << indent << "the other profiles of " << cell.dds.profiles_file << ", domain " << cell.dds.domain_id << ":\n";
  std::string seen_on;
  for (const auto& s : sightings) {
    o << indent << "  " << s.profile << ": ";
    if (!s.error.empty()) {
      o << "cannot join (" << s.error << ")\n";
      continue;
    }
    if (!s.sawAnything()) {
      o << "nothing\n";
      continue;
    }
    o << "engine " << (s.engine_writers > 0 ? "seen" : "not seen") << ", compensation "
      << (s.compensation_writers > 0 ? "seen" : "not seen") << ", " << s.sensor_writers << " sensor writer(s)\n";
    if (seen_on.empty()) seen_on = s.profile;
  }
  if (!seen_on.empty())
    o << indent << "the cell is on profile " << seen_on << ": add --dds-profile " << seen_on << "\n";
  else
    o << indent << "no cell on domain " << cell.dds.domain_id
      << " with any profile: is it running, on this domain (--domain-id)?\n";
  return o.str();
}

}  // namespace cellcal::components
