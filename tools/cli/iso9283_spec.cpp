// `cellcal iso9283 --spec-ap-mm / --spec-rp-mm`: every test pose against the specification's bounds.
#include "iso9283_spec.hpp"

#include <cstdio>
#include <tuple>

namespace cellcal::cli {
namespace {

// A figure of every test pose against the specification's bound: passed when none is above it; the worst pose.
struct SpecCheck {
  bool pass = true;
  std::string worst_pose;
  double worst_m = 0;
};
SpecCheck checkSpec(const Iso9283Report& r, bool repeatability, double bound_m) {
  SpecCheck c;
  for (const auto& p : r.poses) {
    const double v = repeatability ? p.RP_l_m : p.AP_p_m;
    if (c.worst_pose.empty() || v > c.worst_m) {
      c.worst_pose = p.name;
      c.worst_m = v;
    }
  }
  c.pass = !(c.worst_m > bound_m);
  return c;
}

}  // namespace

bool judgeIso9283Spec(double spec_ap_mm, double spec_rp_mm,
                      const std::vector<std::pair<std::string, const Iso9283Report*>>& reports, nlohmann::json* j) {
  bool pass = true;
  for (const auto& [name, repeatability, bound_mm] :
       {std::tuple{"AP_p", false, spec_ap_mm}, std::tuple{"RP_l", true, spec_rp_mm}}) {
    if (!(bound_mm > 0)) continue;
    nlohmann::json entry = {{"bound_mm", bound_mm}};
    for (size_t k = 0; k < reports.size(); ++k) {
      const SpecCheck c = checkSpec(*reports[k].second, repeatability, bound_mm * 1e-3);
      const bool measured = k == 0;
      std::printf("spec %s <= %.4f mm at every test pose: %s %s (commanded by the %s): worst %s %.4f mm%s\n", name,
                  bound_mm, c.pass ? "PASS" : "FAIL", measured ? "as measured" : "predicted", reports[k].first.c_str(),
                  c.worst_pose.c_str(), c.worst_m * 1e3,
                  measured ? "" : " (not measured: run the compensated program and judge its data to accept it)");
      entry[measured ? "measured" : "predicted_after"] = {{"pass", c.pass}, {"worst_pose", c.worst_pose},
                                                          {"worst_mm", c.worst_m * 1e3}};
      if (measured) pass = pass && c.pass;
    }
    (*j)[repeatability ? "spec_rp" : "spec_ap"] = entry;
  }
  return pass;
}

}  // namespace cellcal::cli
