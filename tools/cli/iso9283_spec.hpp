// `cellcal iso9283 --spec-ap-mm / --spec-rp-mm`: a test judged against a specification.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

#include "cellcal/core/accuracy/iso9283_test.hpp"

namespace cellcal::cli {

// Every test pose's AP_p (spec_ap_mm > 0) and RP_l (spec_rp_mm > 0) against the bound, for each report in order: the
// first is the measured one (commanded by the nominal model: what the robot did) and decides; the others (a calibrated
// model's commands) are a prediction at these poses and said as such. Prints a line per bound and report, adds
// spec_ap / spec_rp to `j` ({bound_mm, measured, predicted_after: {pass, worst_pose, worst_mm}}). True when the
// measured figures pass (or no bound is given).
bool judgeIso9283Spec(double spec_ap_mm, double spec_rp_mm,
                      const std::vector<std::pair<std::string, const Iso9283Report*>>& reports, nlohmann::json* j);

}  // namespace cellcal::cli
