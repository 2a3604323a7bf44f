#include "diagnosis_output.hpp"

#include <cstdio>

namespace cellcal::cli {

std::string regionCheckText(const DiagnosisResult& d) {
  if (d.region_checks.empty() && d.region_note.empty()) return "";
  std::string out =
      "region check (each cause fitted on part of the rows and judged beyond them: past either end of its joint's "
      "range, or on the other half of the workspace; the gain is that of the mean squared error less what the fits' "
      "uncertainty explains there, its sigma in parentheses):\n";
  for (size_t i = 0; i < d.region_checks.size(); ++i) {
    const RegionCheck& c = d.region_checks[i];
    // A gain below -100 % reads as the factor it is: "-91378.8 %" is 915x the mean squared error without the cause.
    char gain[64];
    if (c.gain_pct >= -100)
      std::snprintf(gain, sizeof gain, "gain %+.1f %%", c.gain_pct);
    else
      std::snprintf(gain, sizeof gain, "worse: %.0fx the mean squared error", 1 - c.gain_pct / 100);
    char b[400];
    std::snprintf(b, sizeof b, "  %-36s by %-9s mean %.4f -> %.4f mm (sigma %.4f -> %.4f), %s, z %.1f: %s",
                  extensionLabel(c.cause).c_str(), c.split.c_str(), c.mean_without_mm, c.mean_with_mm,
                  c.sigma_without_mm, c.sigma_with_mm, gain, c.z,
                  c.transfers ? "transfers" : "does not transfer, left out");
    out += b;
    if (!c.transfers && d.not_transferred.size() > 1) {
      std::string after;
      for (size_t k = 1; k < d.not_transferred.size(); ++k)
        after += (after.empty() ? "" : ", ") + extensionLabel(d.not_transferred[k]);
      out += " (with " + after + ", chosen after it)";
    }
    out += "\n";
  }
  if (!d.region_note.empty()) out += "  " + d.region_note + "\n";
  return out;
}

nlohmann::json regionCheckJson(const DiagnosisResult& d) {
  nlohmann::json causes = nlohmann::json::array(), left_out = nlohmann::json::array();
  for (const auto& c : d.region_checks)
    causes.push_back({{"label", extensionLabel(c.cause)}, {"split", c.split}, {"mean_without_mm", c.mean_without_mm},
                      {"mean_with_mm", c.mean_with_mm}, {"sigma_without_mm", c.sigma_without_mm},
                      {"sigma_with_mm", c.sigma_with_mm}, {"gain_pct", c.gain_pct}, {"z", c.z},
                      {"transfers", c.transfers}, {"judged_rows", c.judged_rows[0] + c.judged_rows[1]}});
  for (const auto& e : d.not_transferred) left_out.push_back(extensionLabel(e));
  return {{"ran", !d.region_checks.empty()},
          {"note", d.region_note.empty() ? nlohmann::json(nullptr) : nlohmann::json(d.region_note)},
          {"causes", causes},
          {"left_out", left_out}};
}

std::string driftCheckText(const DiagnosisResult& d) {
  const DriftCheck& c = d.drift_check;
  if (c.outcome == DriftCheck::Outcome::kNotRun) return "";
  std::string out = "drift check (a drift in the data against the robot's base drifting in the tracker's frame):\n";
  char b[300];
  auto line = [&](const char* what, const std::vector<Extension>& m, double mean_mm) {
    std::snprintf(b, sizeof b, "  %-14s %-52s held-out mean %.4f mm\n", what, modelLabel(m).c_str(), mean_mm);
    out += b;
  };
  line("chosen", c.chosen, c.mean_chosen_mm);
  line(c.both.empty() ? "frame added" : "frame instead", c.alternative, c.mean_alternative_mm);
  if (!c.both.empty()) line("both", c.both, c.mean_both_mm);
  out += "  " + std::string(driftOutcomeName(c.outcome)) + ": " + c.text + "\n";
  return out;
}

nlohmann::json driftCheckJson(const DiagnosisResult& d) {
  const DriftCheck& c = d.drift_check;
  const bool ran = c.outcome != DriftCheck::Outcome::kNotRun;
  auto labels = [](const std::vector<Extension>& m) { return m.empty() ? nlohmann::json(nullptr) : nlohmann::json(modelLabel(m)); };
  auto num = [&](double v, bool set) { return ran && set ? nlohmann::json(v) : nlohmann::json(nullptr); };
  return {{"ran", ran},
          {"outcome", driftOutcomeName(c.outcome)},
          {"text", ran ? nlohmann::json(c.text) : nlohmann::json(nullptr)},
          {"chosen", ran ? nlohmann::json(modelLabel(c.chosen)) : nlohmann::json(nullptr)},
          {"alternative", labels(c.alternative)},
          {"both", labels(c.both)},
          {"mean_chosen_mm", num(c.mean_chosen_mm, true)},
          {"mean_alternative_mm", num(c.mean_alternative_mm, true)},
          {"mean_both_mm", num(c.mean_both_mm, !c.both.empty())},
          {"z_drift", num(c.z_drift, !c.both.empty())},
          {"z_frame", num(c.z_frame, true)}};
}

}  // namespace cellcal::cli
