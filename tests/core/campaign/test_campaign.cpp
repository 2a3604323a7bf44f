// calibrateCampaign (campaign.hpp) on measurement files drawn at random (robot, tracker placement, target offset,
// points or 6D, a hidden cause, gross errors): its split, its figures and its verdict against a plain reference
// computed here from the forward kinematics and the rules as the header states them.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "cellcal/core/campaign/campaign.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "core/identification/hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

using test::DrawCategory;
using test::DrawOptions;
using test::HiddenEffectData;

// Plain reference: position error (mm) of every row under a geometric model, orientation error (deg) of 6D rows.
ErrorStats plainStats(const RobotModel& robot, const Eigen::VectorXd& params, const std::vector<Observation>& obs,
                      const std::vector<int>& skip = {}) {
  ErrorStats s;
  KinematicsData data(robot);
  double sum = 0, sq = 0, osum = 0, osq = 0;
  for (size_t i = 0; i < obs.size(); ++i) {
    if (std::count(skip.begin(), skip.end(), static_cast<int>(i))) continue;
    const Pose p = forwardKinematics(robot, data, params, obs[i].q_rad);
    const double e = (p.translation() - obs[i].measured_in_tracker.translation()).norm() * 1e3;
    ++s.rows;
    sum += e;
    sq += e * e;
    s.max_mm = std::max(s.max_mm, e);
    if (obs[i].kind != MeasurementKind::kPose6D) continue;
    const double a = Eigen::AngleAxisd(p.linear().transpose() * obs[i].measured_in_tracker.linear()).angle() * 180 / kPi;
    ++s.oriented;
    osum += a;
    osq += a * a;
    s.max_deg = std::max(s.max_deg, a);
  }
  s.mean_mm = sum / s.rows;
  s.rms_mm = std::sqrt(sq / s.rows);
  if (s.oriented) {
    s.mean_deg = osum / s.oriented;
    s.rms_deg = std::sqrt(osq / s.oriented);
  }
  return s;
}

void expectSame(const ErrorStats& got, const ErrorStats& want, const std::string& what) {
  EXPECT_EQ(got.rows, want.rows) << what;
  EXPECT_EQ(got.oriented, want.oriented) << what;
  EXPECT_NEAR(got.mean_mm, want.mean_mm, 1e-9 * (1 + want.mean_mm)) << what;
  EXPECT_NEAR(got.rms_mm, want.rms_mm, 1e-9 * (1 + want.rms_mm)) << what;
  EXPECT_NEAR(got.max_mm, want.max_mm, 1e-9 * (1 + want.max_mm)) << what;
  EXPECT_NEAR(got.mean_deg, want.mean_deg, 1e-6 * (1 + want.mean_deg)) << what;
  EXPECT_NEAR(got.max_deg, want.max_deg, 1e-6 * (1 + want.max_deg)) << what;
}

InputOptions inputOptions(const HiddenEffectData& h, const std::string& split) {
  InputOptions o;
  o.split = split;
  o.sigma_position_m = h.sigma_position_mm * 1e-3;
  return o;
}

TEST(Campaign, AFileIsSplitAsItsRuleSays) {
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 4; ++draw) {
    DrawOptions o;
    o.category = DrawCategory::kNoiseOnly;
    o.poses = 60 + static_cast<int>(rng() % 60);
    o.repeat_probability = 1;  // 10 % of the poses measured again later
    const HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    SCOPED_TRACE(h.draw.describe());
    RobotFile rf;
    rf.model = h.model;
    const auto& rows = h.file.rows;
    for (const std::string split : {"alternate", "halves", "positions"}) {
      const CampaignInput in = prepareCampaignInput("drawn.csv", rf, h.file, inputOptions(h, split));
      ASSERT_EQ(in.identification_lines.size() + in.verification_lines.size(), rows.size()) << split;
      std::vector<bool> verify(rows.size() + 2, false);
      for (int line : in.verification_lines) verify[static_cast<size_t>(line)] = true;
      if (split != "positions") {
        for (size_t i = 0; i < rows.size(); ++i)
          EXPECT_EQ(verify[static_cast<size_t>(rows[i].line)], split == "alternate" ? i % 2 == 1 : i >= rows.size() / 2)
              << split << " row " << i;
        continue;
      }
      // A row joins the first position whose first row lies within 20 mm; alternate positions verify. A pose measured
      // again lies on the side of its first visit.
      std::vector<size_t> first;
      for (size_t i = 0; i < rows.size(); ++i) {
        size_t k = 0;
        while (k < first.size() && (rows[first[k]].position_m - rows[i].position_m).norm() > 0.020) ++k;
        if (k == first.size()) first.push_back(i);
        EXPECT_EQ(verify[static_cast<size_t>(rows[i].line)], k % 2 == 1) << "positions row " << i;
        for (size_t j = 0; j < i; ++j)
          if ((rows[j].q_rad - rows[i].q_rad).norm() == 0) {
            EXPECT_EQ(verify[static_cast<size_t>(rows[j].line)], verify[static_cast<size_t>(rows[i].line)]);
          }
      }
    }
    // Too few rows: refused, the file named.
    MeasurementFile few = h.file;
    few.rows.resize(14);  // alternate: 7 to identify, 8 are needed
    try {
      prepareCampaignInput("few.csv", rf, few, inputOptions(h, "alternate"));
      ADD_FAILURE() << "14 rows accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("few.csv: too few rows (14)"), std::string::npos) << e.what();
    }
  }
}

TEST(Campaign, ItsFiguresAndVerdictAreThoseOfAPlainReference) {
  std::mt19937_64 rng(test::testSeed());
  int flagged = 0, gross = 0;
  for (int draw = 0; draw < 6; ++draw) {
    DrawOptions o;
    o.category = draw % 2 ? DrawCategory::kNoiseOnly : DrawCategory::kSingle;
    o.poses = 80 + static_cast<int>(rng() % 120);
    o.max_outlier_fraction = 0.06;
    const HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    SCOPED_TRACE(h.draw.describe());
    RobotFile rf;
    rf.model = h.model;
    CampaignProblem p;
    p.setups = {prepareCampaignInput("drawn.csv", rf, h.file, inputOptions(h, "alternate"))};
    p.provenance = {{"tool", "test"}, {"data_file", "drawn.csv"}};
    const CampaignReport r = calibrateCampaign(p);
    const CampaignInput& in = p.setups.front();
    const RobotModel& robot = in.robot;
    ASSERT_TRUE(r.converged) << r.message;
    ASSERT_FALSE(r.several_setups);
    EXPECT_EQ(r.model_label, "geometric");
    // The figures, from the forward kinematics of the start and of the fitted parameters.
    const auto& e = r.errors;
    const auto& ident = in.data.identification;
    const auto& verify = in.data.verification;
    expectSame(e.identification_before, plainStats(robot, in.start, ident), "identification before");
    expectSame(e.identification_after, plainStats(robot, r.after.params, ident), "identification after");
    expectSame(e.verification_before, plainStats(robot, in.start, verify), "verification before");
    expectSame(e.verification_after, plainStats(robot, r.after.params, verify), "verification after");
    const std::vector<int>& vo = e.verification_outliers.rows;
    expectSame(e.verification_kept_before, plainStats(robot, in.start, verify, vo), "verification kept before");
    expectSame(e.verification_kept_after, plainStats(robot, r.after.params, verify, vo), "verification kept after");
    expectSame(e.identification_kept_after, plainStats(robot, r.after.params, ident, e.identification_outliers.rows),
               "identification kept after");
    // The gross errors drawn (1-5 mm) are flagged where nothing but noise is left beside them.
    if (o.category == DrawCategory::kNoiseOnly) {
      for (int row : h.outlier_verification) {
        ++gross;
        flagged += std::count(vo.begin(), vo.end(), row) > 0;
      }
      for (int row : h.outlier_identification) {
        ++gross;
        flagged += std::count(e.identification_outliers.rows.begin(), e.identification_outliers.rows.end(), row) > 0;
      }
    }
    // The verdict, by the rules campaign.hpp and unusableFit state.
    const bool worse = e.verification_kept_after.mean_mm > e.verification_kept_before.mean_mm;
    const bool extrapolates = e.verification_kept_after.max_mm > 3.0 * e.identification_kept_after.max_mm;
    EXPECT_EQ(r.unusable.empty(), !worse && !extrapolates) << r.unusable;
    EXPECT_EQ(r.exitCode(), r.unusable.empty() ? 0 : 4);
    if (r.exitCode() != 0) {
      EXPECT_NE(r.verdict.find("do not deploy"), std::string::npos) << r.verdict;
      continue;
    }
    char mean[32];
    std::snprintf(mean, sizeof mean, "%.4f mm", e.verification_kept_after.mean_mm);
    EXPECT_NE(r.verdict.find("deploy the geometric model: held-out mean " + std::string(mean)), std::string::npos)
        << r.verdict;
    // The calibration a robot file saves: the fitted kinematics, the caller's provenance first, then the figures.
    EXPECT_TRUE(r.saved_params.isApprox(r.after.params, 0));
    ASSERT_GE(r.calibration.provenance.size(), 3u);
    EXPECT_EQ(r.calibration.provenance[0], (std::pair<std::string, std::string>{"tool", "test"}));
    EXPECT_EQ(r.calibration.provenance[1].first, "data_file");
    EXPECT_EQ(r.calibration.provenance[2], (std::pair<std::string, std::string>{"rows", std::to_string(h.file.rows.size())}));
    const auto it = std::find_if(r.calibration.provenance.begin(), r.calibration.provenance.end(),
                                 [](const auto& kv) { return kv.first == "verification_mean_mm"; });
    ASSERT_NE(it, r.calibration.provenance.end());
    EXPECT_EQ(it->second + " mm", std::string(mean));
  }
  if (gross > 0) {
    EXPECT_EQ(flagged, gross) << "gross errors flagged";
  }
}

TEST(Campaign, SetUpsShareTheKinematicsAndAModelCarriedKeepsIt) {
  std::mt19937_64 rng(test::testSeed());
  for (int draw = 0; draw < 3; ++draw) {
    DrawOptions o;
    o.category = DrawCategory::kNoiseOnly;
    o.poses = 120;
    HiddenEffectData h = test::makeHiddenEffectData(o, rng());
    SCOPED_TRACE(h.draw.describe());
    RobotFile rf;
    rf.model = h.model;
    // One file, two labelled set-ups (the same placement: the frames of both must come out alike).
    MeasurementFile two = h.file;
    for (size_t i = 0; i < two.rows.size(); ++i) two.rows[i].setup = i < two.rows.size() / 2 ? "A" : "B";
    CampaignProblem p;
    p.setups = prepareCampaignSetups("two.csv", rf, two, inputOptions(h, "alternate"));
    ASSERT_EQ(p.setups.size(), 2u);
    EXPECT_EQ(p.setups[1].name, "two.csv [setup B]");
    const CampaignReport r = calibrateCampaign(p);
    ASSERT_TRUE(r.several_setups);
    ASSERT_TRUE(r.converged) << r.message;
    ASSERT_EQ(r.setups.size(), 2u);
    const int f0 = h.model.baseParam(FrameParam::kX);
    for (size_t s = 0; s < 2; ++s) {
      const Eigen::VectorXd& params = r.setups_fit.params[s];
      EXPECT_TRUE(params.head(f0).isApprox(r.setups_fit.params[0].head(f0), 0)) << "one kinematic model";
      EXPECT_TRUE(params.segment(f0, 12).isApprox(r.setups[s].frames, 0));
      const CampaignInput& in = p.setups[s];
      expectSame(r.setups[s].errors.verification_after, plainStats(h.model, params, in.data.verification),
                 "set-up " + std::to_string(s + 1) + " verification after");
      expectSame(r.setups[s].errors.identification_before, plainStats(h.model, in.start, in.data.identification),
                 "set-up " + std::to_string(s + 1) + " identification before");
    }
    EXPECT_LT((r.setups[0].frames.head<3>() - r.setups[1].frames.head<3>()).norm(), 2e-3) << "same placement";
    // Carried with frames only: the kinematics stay the file's; only the frames move.
    ASSERT_EQ(r.exitCode(), 0) << r.unusable;
    RobotFile carried;
    carried.model = h.model.withParams(r.saved_params);
    carried.calibration = r.calibration;
    CampaignProblem q;
    q.frames_only = true;
    q.setups = {prepareCampaignInput("again.csv", carried, h.file, inputOptions(h, "alternate"))};
    const CampaignReport c = calibrateCampaign(q);
    ASSERT_TRUE(c.converged);
    EXPECT_TRUE(c.after.params.head(f0).isApprox(r.saved_params.head(f0), 0)) << "kinematics kept";
    EXPECT_LE(c.estimated, 12u);
    for (int col : c.after.estimated) EXPECT_GE(col, f0) << "only frames estimated";
    expectSame(c.errors.verification_after, plainStats(h.model, c.after.params, q.setups[0].data.verification),
               "carried verification after");
  }
}

}  // namespace
}  // namespace cellcal
