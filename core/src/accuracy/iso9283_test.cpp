#include "cellcal/core/accuracy/iso9283_test.hpp"

#include <algorithm>
#include <map>
#include <tuple>
#include <optional>
#include <stdexcept>

#include "cellcal/core/model/kinematics.hpp"

namespace cellcal {

std::vector<Iso9283PoseInput> iso9283Visits(const MeasurementFile& file, const Iso9283Model& m, bool orientation) {
  const RobotModel& model = *m.model;
  const int b = model.baseParam(FrameParam::kX);
  const Pose base_inv = poseFromXyzRpy(m.params[b], m.params[b + 1], m.params[b + 2], m.params[b + 3], m.params[b + 4],
                                       m.params[b + 5])
                            .inverse();
  const DriverTable drivers = driversOf(file);
  KinematicsData data(model);
  std::vector<Iso9283PoseInput> out;
  std::map<std::string, size_t> index;
  std::string previous;
  for (size_t i = 0; i < file.rows.size(); ++i) {
    const MeasurementRow& r = file.rows[i];
    if (!r.pose)
      throw ConfigError(file.source + ":" + std::to_string(r.line) +
                        ": pose: a row without a test pose name (the pose column names the ISO 9283 pose each row "
                        "visits, e.g. P1)");
    auto [it, added] = index.emplace(*r.pose, out.size());
    if (added) out.push_back({*r.pose, {}});
    Iso9283PoseInput& p = out[it->second];
    Iso9283Visit v;
    const Eigen::VectorXd params =
        extendedParams(model, m.params, m.extensions, m.extension_params, r.q_rad, drivers.rows[i]);
    v.commanded = base_inv * forwardKinematics(model, data, params, r.q_rad);
    Pose attained = Pose::Identity();
    attained.translation() = r.position_m;
    v.has_orientation = orientation && r.orientation.has_value();
    if (v.has_orientation) attained.linear() = r.orientation->toRotationMatrix();
    else attained.linear() = (base_inv.inverse() * v.commanded).linear();  // unused: no orientation figures
    v.attained = base_inv * attained;
    v.cycle = r.cycle ? static_cast<int>(*r.cycle) : static_cast<int>(p.visits.size()) + 1;
    v.approach = previous;
    previous = *r.pose;
    p.visits.push_back(v);
  }
  // In the order of their names, numbers as numbers (P1, P2, ..., P10), as the standard's reports list them.
  auto key = [](const std::string& name) {
    const size_t digits = name.find_last_not_of("0123456789") + 1;
    const std::string tail = name.substr(digits);
    return std::make_tuple(name.substr(0, digits), tail.size(), tail);
  };
  std::stable_sort(out.begin(), out.end(), [&](const Iso9283PoseInput& a, const Iso9283PoseInput& b) {
    return key(a.name) < key(b.name);
  });
  return out;
}

Iso9283Report iso9283Report(const std::vector<Iso9283PoseInput>& visits,
                            const std::vector<std::pair<std::string, std::string>>& pairs) {
  Iso9283Report report;
  std::map<std::string, const Iso9283PoseInput*> by_name;
  for (const auto& p : visits) {
    report.poses.push_back(iso9283Pose(p));
    by_name[p.name] = &p;
  }
  std::vector<std::pair<std::string, std::string>> chosen = pairs;
  if (chosen.empty()) {
    if (by_name.count("P2") && by_name.count("P4")) chosen.emplace_back("P2", "P4");
    else if (visits.size() >= 2) chosen.emplace_back(visits[0].name, visits[1].name);
  }
  for (const auto& [a, b] : chosen) {
    if (!by_name.count(a) || !by_name.count(b))
      throw std::invalid_argument("distance " + a + "-" + b + ": " + (by_name.count(a) ? b : a) + " is not a test pose of the data");
    report.distances.push_back(iso9283Distance(*by_name[a], *by_name[b]));
  }
  return report;
}

}  // namespace cellcal
