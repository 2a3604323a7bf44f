// What `diagnose` and `calibrate --model auto` both print and write of a diagnosis.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "cellcal/core/identification/diagnosis.hpp"
#include "measurement_input.hpp"

namespace cellcal::cli {

// The region check (DiagnosisOptions::region_check): a heading and a line per cause judged, or why it did not run;
// empty when no cause was chosen.
std::string regionCheckText(const DiagnosisResult& d);
// {"ran", "note", "causes": [{label, mean_without_mm, mean_with_mm, gain_pct, z, transfers}], "left_out": [labels]}.
nlohmann::json regionCheckJson(const DiagnosisResult& d);

// The drift check (DriftCheck): a heading, the models judged and the outcome's sentence; empty when it did not run.
std::string driftCheckText(const DiagnosisResult& d);
// {"ran", "outcome", "text", "chosen", "alternative", "both" (labels), "mean_chosen_mm", "mean_alternative_mm",
//  "mean_both_mm", "z_drift", "z_frame"}; absent figures null.
nlohmann::json driftCheckJson(const DiagnosisResult& d);

// diagnose --report: dir/report.md (the finding, the table of causes, the checks) and, when a cause was chosen, its
// signature (dir/signature.svg and .png, by gnuplot; a warning on stderr where gnuplot cannot draw).
void writeDiagnosisReport(const std::string& dir, const InputArgs& input, const LoadedInput& in, const DiagnosisResult& d);

}  // namespace cellcal::cli
