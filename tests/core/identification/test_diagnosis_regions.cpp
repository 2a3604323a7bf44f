// The region check of diagnosis.hpp: a cause chosen on part of the workspace or of a joint's range must not make the
// error worse beyond it. Two kinds of draw, each a campaign (diagnosed with alternate rows verifying, as `cellcal
// diagnose` does by default) and rows beyond it that no campaign row reached, which grade the model chosen against
// the campaign's own geometric fit:
//  - a library cause (hidden_effect.hpp: every kind, joint and size) over the whole workspace, the campaign the rows
//    on one side of a random plane (60 % of them): the check must keep it;
//  - a joint with a local defect outside the library (an error bump over 0.2 rad of its angle) measured on 60 % of
//    its range: a cyclic term follows the bump inside and is off by millimetres beyond; the check must leave it out.
// And the workspace split itself against a plain computation.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>

#include "core/identification/hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

int drawsOr(int fallback) {
  const char* env = std::getenv("CELLCAL_DIAGNOSIS_DRAWS");
  return env ? std::atoi(env) : fallback;
}

// A campaign and the rows beyond it.
struct Campaign {
  DiagnosisData data;                  // the campaign's rows, alternate split
  Eigen::VectorXd start;               // frames registered on its identification rows
  std::vector<Observation> beyond;
  std::vector<Drivers> beyond_drivers;
  std::string text;
};

// Rows in visiting order: those `inside` form the campaign (alternate rows verify), the others are beyond it.
Campaign campaignOf(const RobotModel& model, const std::vector<Observation>& rows, const std::vector<Drivers>& drivers,
                    const std::vector<bool>& inside, bool has_thermal, const std::string& thermal_source) {
  Campaign c;
  int k = 0;
  for (size_t i = 0; i < rows.size(); ++i) {
    if (!inside[i]) {
      c.beyond.push_back(rows[i]);
      c.beyond_drivers.push_back(drivers[i]);
      continue;
    }
    const bool verify = k++ % 2 == 1;
    (verify ? c.data.verification : c.data.identification).push_back(rows[i]);
    (verify ? c.data.verification_drivers : c.data.identification_drivers).push_back(drivers[i]);
  }
  c.data.has_thermal = has_thermal;
  c.data.thermal_source = thermal_source;
  c.start = registerFrames(model, model.nominal, c.data.identification).params;
  return c;
}

// A library cause over the whole workspace; the campaign on one side of a random plane.
Campaign libraryCause(const test::HiddenEffectData& h, std::mt19937_64& rng) {
  std::vector<Observation> rows;
  std::vector<Drivers> drivers;
  for (size_t i = 0; i < h.data.identification.size() + h.data.verification.size(); ++i) {
    const bool ident = i % 2 == 0;
    rows.push_back((ident ? h.data.identification : h.data.verification)[i / 2]);
    drivers.push_back((ident ? h.data.identification_drivers : h.data.verification_drivers)[i / 2]);
  }
  std::normal_distribution<double> g;
  const Eigen::Vector3d dir = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
  std::vector<double> x;
  for (const auto& o : rows) x.push_back(dir.dot(o.measured_in_tracker.translation()));
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  const double cut = sorted[sorted.size() * 6 / 10];
  std::vector<bool> inside;
  for (double v : x) inside.push_back(v < cut);
  Campaign c = campaignOf(h.model, rows, drivers, inside, h.data.has_thermal, h.data.thermal_source);
  c.text = h.draw.describe();
  return c;
}

// A joint (2 or 3) with an error bump of 0.06-0.3 deg over 0.2 rad (1 sigma) of its angle (a damaged stretch of a
// gear, a cable that snags: nothing in the library) in the middle of the 60 % of its range the campaign works on.
Campaign bumpedJoint(const RobotModel& model, const test::RandomDraw& d, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  SimulationConfig sc = d.sc;
  sc.warmup_K = 0;
  sc.zero_drift_per_K_max_rad = 0;
  sc.zero_wear_per_h_max_rad = 0;
  const SimulatedCell cell(model, sc);
  const int j = 1 + static_cast<int>(u(rng) * 2);
  const double amplitude_rad = (0.06 + 0.24 * u(rng)) * kPi / 180;
  const std::vector<Eigen::VectorXd> qs = cell.randomConfigurations(900, rng);
  std::vector<double> sorted;
  for (const auto& q : qs) sorted.push_back(q[j]);
  std::sort(sorted.begin(), sorted.end());
  const bool low = u(rng) < 0.5;  // the lower or the upper 60 % of the joint's range
  const double cut = sorted[low ? sorted.size() * 6 / 10 : sorted.size() * 4 / 10];
  const double centre = sorted[low ? sorted.size() * 3 / 10 : sorted.size() * 7 / 10];
  std::vector<Observation> rows;
  std::vector<bool> inside;
  for (const auto& q : qs) {
    Eigen::VectorXd qt = q;
    qt[j] += amplitude_rad * std::exp(-0.5 * (q[j] - centre) * (q[j] - centre) / (0.2 * 0.2));
    rows.push_back(cell.measurePose(cell.truePose(qt, 0.0), q, rng, d.kind));
    inside.push_back(low ? q[j] < cut : q[j] >= cut);
  }
  // The drivers of each part in its own visiting order (what a file of that part would give).
  std::vector<Eigen::VectorXd> in_q, out_q;
  for (size_t i = 0; i < qs.size(); ++i) (inside[i] ? in_q : out_q).push_back(qs[i]);
  const DriverTable in_d = driversFromSequence(in_q, {}, {}), out_d = driversFromSequence(out_q, {}, {});
  std::vector<Drivers> drivers;
  size_t a = 0, b = 0;
  for (size_t i = 0; i < qs.size(); ++i) drivers.push_back(inside[i] ? in_d.rows[a++] : out_d.rows[b++]);
  Campaign c = campaignOf(model, rows, drivers, inside, false, "");
  char t[200];
  std::snprintf(t, sizeof t, "%s %s, joint %d bump %.3f deg at %.2f rad, campaign on its %s 60 %%", d.name.c_str(),
                d.kind == MeasurementKind::kPose6D ? "6D" : "points", j + 1, amplitude_rad * 180 / kPi, centre,
                low ? "lower" : "upper");
  c.text = t;
  return c;
}

// Diagnosis without and with the check, graded beyond the campaign.
struct Graded {
  DiagnosisResult off, on;
  double geometric_mm = 0, off_mm = 0, on_mm = 0;  // mean position error beyond the campaign
};
Graded grade(const RobotModel& model, const Campaign& c) {
  Graded g;
  DiagnosisOptions no_check;
  no_check.region_check = false;
  g.off = diagnose(model, c.start, c.data, no_check);
  g.on = diagnose(model, c.start, c.data);
  auto beyond = [&](const ExtendedFit& f) { return errorStats(model, f, c.beyond, c.beyond_drivers).mean_mm; };
  g.geometric_mm = beyond(g.off.geometric.fit);
  g.off_mm = beyond(g.off.best().fit);
  g.on_mm = beyond(g.on.best().fit);
  std::string checks;
  for (const auto& r : g.on.region_checks) {
    char t[200];
    std::snprintf(t, sizeof t, " [%s by %s: %+.1f %%, z %.1f]", extensionLabel(r.cause).c_str(), r.split.c_str(),
                  r.gain_pct, r.z);
    checks += t;
  }
  std::printf("  %s\n    without the check %s, with it %s; beyond: geometric %.4f, without %.4f, with %.4f mm;%s\n",
              c.text.c_str(), modelLabel(g.off.causes()).c_str(), modelLabel(g.on.causes()).c_str(), g.geometric_mm,
              g.off_mm, g.on_mm, checks.c_str());
  return g;
}

TEST(RegionCheck, LibraryCausesAreKept) {
  const int draws = drawsOr(12);
  std::mt19937_64 rng(test::testSeed());
  int dropped = 0, real = 0, named_off = 0, named_on = 0;
  double sum_off = 0, sum_on = 0, sum_geo = 0;
  for (int k = 0; k < draws; ++k) {
    test::DrawOptions o;
    o.category = test::DrawCategory::kSingle;
    const test::HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    const Campaign c = libraryCause(h, rng);
    const Graded g = grade(h.model, c);
    sum_geo += g.geometric_mm, sum_off += g.off_mm, sum_on += g.on_mm;
    dropped += !g.on.not_transferred.empty();
    if (h.draw.effects.front().effect_rms_mm > h.noise_rms_mm) {
      ++real;
      auto hit = [&](const DiagnosisResult& d) {
        const auto got = d.causes();
        return !got.empty() && got.front().cause == h.draw.effects.front().cause;
      };
      named_off += hit(g.off);
      named_on += hit(g.on);
    }
  }
  std::printf("  summary: %d draws, %d causes left out; causes above the noise named first %d/%d without the check, "
              "%d/%d with it; mean beyond the campaign: geometric %.4f, without the check %.4f, with it %.4f mm\n",
              draws, dropped, named_off, real, named_on, real, sum_geo / draws, sum_off / draws, sum_on / draws);
  // Measured over 100 draws: one cause left out (CELLCAL_DIAGNOSIS_DRAWS=100).
  EXPECT_LE(dropped, 1);
  EXPECT_GE(named_on, named_off - 1);
  EXPECT_LE(sum_on, 1.02 * sum_off);
}

TEST(RegionCheck, ACyclicTermFittedOnPartOfAJointsRangeIsLeftOut) {
  const int draws = drawsOr(8);
  std::mt19937_64 rng(test::testSeed());
  int worse_off = 0, worse_on = 0, left_out = 0;
  for (int k = 0; k < draws; ++k) {
    const test::RandomDraw d = test::randomDraw(rng);
    const RobotModel model = test::robot(d.name);
    const Campaign c = bumpedJoint(model, d, rng);
    const Graded g = grade(model, c);
    worse_off += !g.off.selection.empty() && g.off_mm > g.geometric_mm;
    worse_on += !g.on.selection.empty() && g.on_mm > g.geometric_mm;
    left_out += !g.on.not_transferred.empty();
    if (!g.on.not_transferred.empty()) {
      EXPECT_NE(g.on.verdict_text.find("left out: " + modelLabel(g.on.not_transferred)), std::string::npos)
          << g.on.verdict_text;
    }
  }
  std::printf("  summary: %d draws; worse than geometric beyond the campaign: %d without the check, %d with it (%d "
              "left out)\n",
              draws, worse_off, worse_on, left_out);
  // Measured over 40 draws (CELLCAL_DIAGNOSIS_DRAWS=40): worse beyond without the check in 37 (by 0.65-111 mm), never
  // with it.
  EXPECT_GE(worse_off, draws / 2) << "the draws do not make the failure the check is for";
  EXPECT_EQ(worse_on, 0);
}

// regionSplit against a plain computation: the covariance's major axis by power iteration, the median by a full sort.
TEST(RegionSplit, HalvesAlongTheLargestSpreadAtTheMedian) {
  std::mt19937_64 rng(test::testSeed());
  std::normal_distribution<double> g;
  for (int draw = 0; draw < 20; ++draw) {
    const int n = 9 + static_cast<int>(rng() % 300);
    const Eigen::Matrix3d R = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
    const Eigen::Vector3d scale(0.2 + std::abs(g(rng)), 0.2 + std::abs(g(rng)), 0.2 + std::abs(g(rng)));
    std::vector<Observation> obs(static_cast<size_t>(n));
    for (auto& o : obs)
      o.measured_in_tracker.translation() = R * scale.cwiseProduct(Eigen::Vector3d(g(rng), g(rng), g(rng))) +
                                            Eigen::Vector3d(3, -1, 2);
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& o : obs) mean += o.measured_in_tracker.translation();
    mean /= n;
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& o : obs) {
      const Eigen::Vector3d d = o.measured_in_tracker.translation() - mean;
      C += d * d.transpose();
    }
    Eigen::Vector3d v(1, 1, 1);
    for (int it = 0; it < 2000; ++it) v = (C * v).normalized();
    std::vector<double> x;
    for (const auto& o : obs) x.push_back(v.dot(o.measured_in_tracker.translation() - mean));
    std::vector<double> sorted = x;
    std::sort(sorted.begin(), sorted.end());
    const double median = sorted[static_cast<size_t>(n / 2)];
    const std::vector<bool> side = regionSplit(obs);
    int agree = 0, flipped = 0;
    for (int i = 0; i < n; ++i) {
      const bool plain = x[static_cast<size_t>(i)] >= median;
      agree += side[static_cast<size_t>(i)] == plain;
      flipped += side[static_cast<size_t>(i)] != plain;
    }
    // The axis' sign is either way round: one half or the other is "true".
    EXPECT_TRUE(agree == n || flipped == n || std::min(agree, flipped) <= 1) << agree << " of " << n;
    const int trues = static_cast<int>(std::count(side.begin(), side.end(), true));
    EXPECT_LE(std::abs(2 * trues - n), 2) << trues << " of " << n;
  }
  EXPECT_EQ(regionSplit(std::vector<Observation>(7)), std::vector<bool>(7, false));
}

}  // namespace
}  // namespace cellcal
