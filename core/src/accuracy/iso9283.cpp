#include "cellcal/core/accuracy/iso9283.hpp"

#include <cmath>
#include <map>
#include <stdexcept>

namespace cellcal {
namespace {

bool finite(const Pose& T) { return T.matrix().allFinite(); }

// Sample standard deviation (n - 1) of values about their mean.
template <class V>
double sampleStd(const std::vector<V>& values, const V& mean) {
  double s = 0;
  for (const auto& v : values) s += (v - mean) * (v - mean);
  return std::sqrt(s / static_cast<double>(values.size() - 1));
}

}  // namespace

Eigen::Vector3d orientationDeviation(const Pose& attained, const Pose& commanded) {
  const Eigen::Matrix3d R = attained.linear() * commanded.linear().transpose();
  // R = Rz(c) Ry(b) Rx(a): b by atan2 (accurate near zero), a from the last row, c from the first column.
  const double b = std::atan2(-R(2, 0), std::hypot(R(0, 0), R(1, 0)));
  const double a = std::atan2(R(2, 1), R(2, 2));
  const double c = std::atan2(R(1, 0), R(0, 0));
  return {a, b, c};
}

Iso9283Pose iso9283Pose(const Iso9283PoseInput& in) {
  Iso9283Pose out;
  out.name = in.name;
  out.n = static_cast<int>(in.visits.size());
  if (out.n < 2)
    throw std::invalid_argument("test pose " + in.name + ": " + std::to_string(out.n) +
                                " visit(s): ISO 9283 needs at least 2 cycles per pose (30 in the standard's test)");
  out.oriented = true;
  std::vector<Eigen::Vector3d> dp, da;
  for (const auto& v : in.visits) {
    if (!finite(v.commanded) || !finite(v.attained))
      throw std::invalid_argument("test pose " + in.name + ": a visit with a non-finite pose (cycle " +
                                  std::to_string(v.cycle) + ")");
    dp.push_back(v.attained.translation() - v.commanded.translation());
    out.oriented = out.oriented && v.has_orientation;
  }
  out.deviations_m = dp;
  Eigen::Vector3d mean_p = Eigen::Vector3d::Zero();
  for (const auto& d : dp) mean_p += d;
  mean_p /= out.n;
  out.AP_xyz_m = mean_p;
  out.AP_p_m = mean_p.norm();
  std::vector<double> l;
  for (const auto& d : dp) l.push_back((d - mean_p).norm());
  for (double x : l) out.l_mean_m += x;
  out.l_mean_m /= out.n;
  out.S_l_m = sampleStd(l, out.l_mean_m);
  out.RP_l_m = out.l_mean_m + 3 * out.S_l_m;
  if (out.oriented) {
    for (const auto& v : in.visits) da.push_back(orientationDeviation(v.attained, v.commanded));
    Eigen::Vector3d mean_a = Eigen::Vector3d::Zero();
    for (const auto& d : da) mean_a += d;
    mean_a /= out.n;
    out.AP_abc_rad = mean_a;
    for (int k = 0; k < 3; ++k) {
      std::vector<double> ak;
      for (const auto& d : da) ak.push_back(d[k]);
      out.S_abc_rad[k] = sampleStd(ak, mean_a[k]);
    }
    out.RP_abc_rad = 3 * out.S_abc_rad;
  }
  // Multi-directional: the barycentres of the visits from each known approach direction.
  std::map<std::string, std::vector<int>> by_direction;
  for (int j = 0; j < out.n; ++j)
    if (!in.visits[static_cast<size_t>(j)].approach.empty()) by_direction[in.visits[static_cast<size_t>(j)].approach].push_back(j);
  out.directions = static_cast<int>(by_direction.size());
  if (out.directions >= 2) {
    std::vector<Eigen::Vector3d> bp, ba;
    for (const auto& [dir, idx] : by_direction) {
      Eigen::Vector3d p = Eigen::Vector3d::Zero(), a = Eigen::Vector3d::Zero();
      for (int j : idx) {
        p += dp[static_cast<size_t>(j)];
        if (out.oriented) a += da[static_cast<size_t>(j)];
      }
      bp.push_back(p / static_cast<double>(idx.size()));
      ba.push_back(a / static_cast<double>(idx.size()));
    }
    double vp = 0;
    Eigen::Vector3d va = Eigen::Vector3d::Zero();
    for (size_t h = 0; h < bp.size(); ++h)
      for (size_t k = h + 1; k < bp.size(); ++k) {
        vp = std::max(vp, (bp[h] - bp[k]).norm());
        va = va.cwiseMax((ba[h] - ba[k]).cwiseAbs());
      }
    out.vAP_p_m = vp;
    if (out.oriented) out.vAP_abc_rad = va;
  }
  return out;
}

Iso9283Distance iso9283Distance(const Iso9283PoseInput& from, const Iso9283PoseInput& to) {
  Iso9283Distance out;
  out.from = from.name;
  out.to = to.name;
  auto byCycle = [](const Iso9283PoseInput& p) {
    std::map<int, const Iso9283Visit*> m;
    for (const auto& v : p.visits)
      if (!m.emplace(v.cycle, &v).second)
        throw std::invalid_argument("test pose " + p.name + ": cycle " + std::to_string(v.cycle) +
                                    " appears twice (the distance pairs one visit of each pose per cycle)");
    return m;
  };
  const auto a = byCycle(from), b = byCycle(to);
  std::vector<double> D;
  Eigen::Vector3d mean_xyz = Eigen::Vector3d::Zero(), mean_cxyz = Eigen::Vector3d::Zero();
  double mean_c = 0;
  for (const auto& [cycle, va] : a) {
    const auto it = b.find(cycle);
    if (it == b.end()) continue;
    const Iso9283Visit* vb = it->second;
    if (!finite(va->attained) || !finite(vb->attained) || !finite(va->commanded) || !finite(vb->commanded))
      throw std::invalid_argument("distance " + from.name + "-" + to.name + ": a non-finite pose in cycle " +
                                  std::to_string(cycle));
    const Eigen::Vector3d d = va->attained.translation() - vb->attained.translation();
    const Eigen::Vector3d dc = va->commanded.translation() - vb->commanded.translation();
    D.push_back(d.norm());
    mean_xyz += d;
    mean_cxyz += dc;
    mean_c += dc.norm();
  }
  out.n = static_cast<int>(D.size());
  if (out.n < 2)
    throw std::invalid_argument("distance " + from.name + "-" + to.name + ": " + std::to_string(out.n) +
                                " cycle(s) visit both poses: at least 2 are needed");
  for (double d : D) out.D_mean_m += d;
  out.D_mean_m /= out.n;
  out.D_c_m = mean_c / out.n;
  out.AD_p_m = out.D_mean_m - out.D_c_m;
  out.AD_xyz_m = (mean_xyz - mean_cxyz) / out.n;
  out.S_D_m = sampleStd(D, out.D_mean_m);
  out.RD_m = 3 * out.S_D_m;
  return out;
}

}  // namespace cellcal
