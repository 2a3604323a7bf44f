// ISO 9283 figures (core/accuracy): a hand-computed cloud of known barycentre and spread; random clouds against a
// plain re-implementation of the standard's formulas written here; frame independence of AP_p, RP_l, AD, RD; bad
// input named. The test cube and poses on random robots (robot files and URDF-like joint layouts): every corner and
// test pose reached within the limits, the poses reached to 1e-6 mm; a simulated test of a robot with hidden errors
// gives the AP its truth says, and none against the true model.
#include <gtest/gtest.h>

#include <algorithm>

#include <cmath>
#include <map>
#include <random>

#include "cellcal/core/accuracy/iso9283.hpp"
#include "cellcal/core/accuracy/iso9283_plan.hpp"
#include "cellcal/core/accuracy/iso9283_test.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/sim/simulation.hpp"
#include "core/identification/hidden_effect.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

Pose rotX(double a) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX()).toRotationMatrix();
  return T;
}

// Four visits at barycentre b + (±s, 0, 0) and (0, ±s, 0), turned about x by phi ± theta, phi, phi: AP_p = |b|,
// every l_j = s so RP_l = s; AP_a = phi, S_a = theta sqrt(2/3), RP_a = 3 S_a.
TEST(Iso9283, AHandComputedCloud) {
  const Pose commanded = poseFromXyzRpy(0.5, -0.2, 0.8, 0, 0, 0);
  const Eigen::Vector3d b(0.3e-3, -0.4e-3, 0.0);  // |b| = 0.5 mm
  const double s = 0.02e-3, phi = 1e-4, theta = 2e-5;
  const Eigen::Vector3d offsets[4] = {{s, 0, 0}, {-s, 0, 0}, {0, s, 0}, {0, -s, 0}};
  const double angles[4] = {phi + theta, phi - theta, phi, phi};
  Iso9283PoseInput in{"P1", {}};
  for (int j = 0; j < 4; ++j) {
    Iso9283Visit v;
    v.commanded = commanded;
    v.attained = rotX(angles[j]) * commanded;
    v.attained.translation() = commanded.translation() + b + offsets[j];
    v.cycle = j + 1;
    in.visits.push_back(v);
  }
  const Iso9283Pose p = iso9283Pose(in);
  EXPECT_EQ(p.n, 4);
  EXPECT_TRUE(p.oriented);
  EXPECT_NEAR(p.AP_p_m, 0.5e-3, 1e-15);
  EXPECT_NEAR(p.AP_xyz_m.x(), 0.3e-3, 1e-15);
  EXPECT_NEAR(p.AP_xyz_m.y(), -0.4e-3, 1e-15);
  EXPECT_NEAR(p.l_mean_m, s, 1e-15);
  EXPECT_NEAR(p.S_l_m, 0, 1e-15);
  EXPECT_NEAR(p.RP_l_m, s, 1e-15);
  EXPECT_NEAR(p.AP_abc_rad.x(), phi, 1e-15);
  EXPECT_NEAR(p.AP_abc_rad.y(), 0, 1e-15);
  EXPECT_NEAR(p.S_abc_rad.x(), theta * std::sqrt(2.0 / 3.0), 1e-15);
  EXPECT_NEAR(p.RP_abc_rad.x(), 3 * theta * std::sqrt(2.0 / 3.0), 1e-15);
  EXPECT_FALSE(p.vAP_p_m.has_value());  // one direction

  // A second pose 100 mm along x, visited in the same cycles with deviations +-d along x: D_j = 100 mm + deviations.
  Iso9283PoseInput other{"P2", {}};
  const double d = 0.01e-3;
  for (int j = 0; j < 4; ++j) {
    Iso9283Visit v;
    v.commanded = commanded;
    v.commanded.translation().x() += 0.1;
    v.attained = v.commanded;
    v.attained.translation().x() += (j % 2 ? -d : d);
    v.cycle = j + 1;
    other.visits.push_back(v);
  }
  // D_j = |attained(P1) - attained(P2)|: P1's x deviations are 0.3 mm + (s, -s, 0, 0), P2's (d, -d, d, -d).
  std::vector<double> D;
  for (int j = 0; j < 4; ++j) D.push_back((in.visits[j].attained.translation() - other.visits[j].attained.translation()).norm());
  double mean = 0;
  for (double x : D) mean += x / 4;
  double ss = 0;
  for (double x : D) ss += (x - mean) * (x - mean);
  const Iso9283Distance dist = iso9283Distance(in, other);
  EXPECT_EQ(dist.n, 4);
  EXPECT_NEAR(dist.D_c_m, 0.1, 1e-15);
  EXPECT_NEAR(dist.AD_p_m, mean - 0.1, 1e-15);
  EXPECT_NEAR(dist.RD_m, 3 * std::sqrt(ss / 3), 1e-15);
  // AD_x = mean(x1 - x2) - (x1c - x2c) = b_x + mean(P1's x offsets) - mean(P2's) = 0.3 mm.
  EXPECT_NEAR(dist.AD_xyz_m.x(), 0.3e-3, 1e-15);
}

// The standard's formulas written plainly (loops over the visits, one figure at a time), on random clouds: random
// commanded pose, 2-40 visits, a barycentre offset and spread of random size, orientation deviations about random
// axes, approach directions at random.
struct Plain {
  double AP_p, RP_l, AP_a[3], RP_a[3], vAP_p;
};
Plain plainIso(const Iso9283PoseInput& in) {
  const int n = static_cast<int>(in.visits.size());
  double xc = 0, yc = 0, zc = 0, xb = 0, yb = 0, zb = 0;
  for (const auto& v : in.visits) {
    xb += v.attained.translation().x() / n;
    yb += v.attained.translation().y() / n;
    zb += v.attained.translation().z() / n;
    xc += v.commanded.translation().x() / n;
    yc += v.commanded.translation().y() / n;
    zc += v.commanded.translation().z() / n;
  }
  Plain r{};
  r.AP_p = std::sqrt((xb - xc) * (xb - xc) + (yb - yc) * (yb - yc) + (zb - zc) * (zb - zc));
  double lbar = 0;
  std::vector<double> l;
  for (const auto& v : in.visits) {
    const double dx = v.attained.translation().x() - xb, dy = v.attained.translation().y() - yb,
                 dz = v.attained.translation().z() - zb;
    l.push_back(std::sqrt(dx * dx + dy * dy + dz * dz));
    lbar += l.back() / n;
  }
  double sl = 0;
  for (double x : l) sl += (x - lbar) * (x - lbar);
  r.RP_l = lbar + 3 * std::sqrt(sl / (n - 1));
  for (int k = 0; k < 3; ++k) {
    std::vector<double> a;
    double abar = 0;
    for (const auto& v : in.visits) {
      a.push_back(orientationDeviation(v.attained, v.commanded)[k]);
      abar += a.back() / n;
    }
    double sa = 0;
    for (double x : a) sa += (x - abar) * (x - abar);
    r.AP_a[k] = abar;
    r.RP_a[k] = 3 * std::sqrt(sa / (n - 1));
  }
  std::map<std::string, std::vector<Eigen::Vector3d>> dirs;
  for (const auto& v : in.visits)
    if (!v.approach.empty()) dirs[v.approach].push_back(v.attained.translation());
  r.vAP_p = -1;
  if (dirs.size() >= 2) {
    r.vAP_p = 0;
    for (const auto& [h, ph] : dirs)
      for (const auto& [k, pk] : dirs) {
        Eigen::Vector3d bh = Eigen::Vector3d::Zero(), bk = Eigen::Vector3d::Zero();
        for (const auto& p : ph) bh += p / static_cast<double>(ph.size());
        for (const auto& p : pk) bk += p / static_cast<double>(pk.size());
        r.vAP_p = std::max(r.vAP_p, (bh - bk).norm());
      }
  }
  return r;
}

TEST(Iso9283, RandomCloudsAgreeWithThePlainFormulas) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> g(0, 1);
  for (int draw = 0; draw < 200; ++draw) {
    const Pose commanded = poseFromXyzRpy(u(rng), u(rng), u(rng), 3 * u(rng), 1.5 * u(rng), 3 * u(rng));
    const int n = 2 + static_cast<int>(rng() % 39);
    const double spread = std::pow(10, -5 + 2 * (u(rng) + 1) / 2), offset = std::pow(10, -5 + 2 * (u(rng) + 1) / 2);
    const Eigen::Vector3d b = offset * Eigen::Vector3d(u(rng), u(rng), u(rng));
    const Eigen::Vector3d w0 = 1e-4 * Eigen::Vector3d(u(rng), u(rng), u(rng));
    const int directions = 1 + static_cast<int>(rng() % 3);
    Iso9283PoseInput in{"P" + std::to_string(draw), {}};
    for (int j = 0; j < n; ++j) {
      Iso9283Visit v;
      v.commanded = commanded;
      v.attained = commanded;
      v.attained.linear() = expSO3(w0 + 3e-5 * Eigen::Vector3d(g(rng), g(rng), g(rng))) * commanded.linear();
      v.attained.translation() += b + spread * Eigen::Vector3d(g(rng), g(rng), g(rng));
      v.cycle = j;
      v.approach = directions > 1 ? "from" + std::to_string(j % directions) : "";
      in.visits.push_back(v);
    }
    SCOPED_TRACE("draw " + std::to_string(draw) + ", n " + std::to_string(n));
    const Iso9283Pose p = iso9283Pose(in);
    const Plain r = plainIso(in);
    EXPECT_NEAR(p.AP_p_m, r.AP_p, 1e-12);
    EXPECT_NEAR(p.RP_l_m, r.RP_l, 1e-12);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(p.AP_abc_rad[k], r.AP_a[k], 1e-13);
      EXPECT_NEAR(p.RP_abc_rad[k], r.RP_a[k], 1e-13);
    }
    if (directions > 1 && n >= directions) {
      ASSERT_TRUE(p.vAP_p_m.has_value());
      EXPECT_NEAR(*p.vAP_p_m, r.vAP_p, 1e-12);
    }
    // A rigid move of the whole test (another frame) keeps AP_p, RP_l and the distances.
    const Pose X = poseFromXyzRpy(u(rng), u(rng), u(rng), 3 * u(rng), 1.5 * u(rng), 3 * u(rng));
    Iso9283PoseInput moved = in;
    for (auto& v : moved.visits) {
      v.commanded = X * v.commanded;
      v.attained = X * v.attained;
    }
    const Iso9283Pose q = iso9283Pose(moved);
    EXPECT_NEAR(q.AP_p_m, p.AP_p_m, 1e-12);
    EXPECT_NEAR(q.RP_l_m, p.RP_l_m, 1e-12);
    Iso9283PoseInput second = in;
    for (auto& v : second.visits) {
      v.commanded.translation() += Eigen::Vector3d(0.2, 0, 0);
      v.attained.translation() += Eigen::Vector3d(0.2, 0, 0) + spread * Eigen::Vector3d(g(rng), g(rng), g(rng));
    }
    Iso9283PoseInput second_moved = second;
    for (auto& v : second_moved.visits) {
      v.commanded = X * v.commanded;
      v.attained = X * v.attained;
    }
    const Iso9283Distance d1 = iso9283Distance(in, second), d2 = iso9283Distance(moved, second_moved);
    EXPECT_NEAR(d1.AD_p_m, d2.AD_p_m, 1e-12);
    EXPECT_NEAR(d1.RD_m, d2.RD_m, 1e-12);
  }
}

TEST(Iso9283, BadInputIsNamed) {
  Iso9283PoseInput one{"P3", {Iso9283Visit{}}};
  try {
    iso9283Pose(one);
    ADD_FAILURE() << "one visit accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("test pose P3: 1 visit"), std::string::npos) << e.what();
  }
  Iso9283PoseInput nan{"P4", {Iso9283Visit{}, Iso9283Visit{}}};
  nan.visits[1].attained.translation().x() = std::nan("");
  try {
    iso9283Pose(nan);
    ADD_FAILURE() << "NaN accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("test pose P4: a visit with a non-finite pose"), std::string::npos) << e.what();
  }
  Iso9283PoseInput a{"P2", {Iso9283Visit{}, Iso9283Visit{}}}, b{"P4", {Iso9283Visit{}, Iso9283Visit{}}};
  a.visits[1].cycle = 1;
  b.visits[0].cycle = 5;
  b.visits[1].cycle = 6;
  try {
    iso9283Distance(a, b);
    ADD_FAILURE() << "no common cycle accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("distance P2-P4: 0 cycle(s)"), std::string::npos) << e.what();
  }
}

// The cube on random robots: the TX60 and UR10 robot files with random errors on their parameters; every corner,
// the centre and P2..P5 reached with one orientation; the planned joints within the limits and giving the test poses
// to 1e-6 mm; the poses where the standard puts them.
TEST(Iso9283, TheCubeAndItsPosesAreReachedOnRandomRobots) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1, 1);
  for (int draw = 0; draw < 6; ++draw) {
    const RobotModel m = test::robot(draw % 2 ? "ur10" : "staubli_tx60");
    Eigen::VectorXd p = m.nominal;
    for (int i : m.canonicalParams()) p[i] += m.isLength(i) ? 5e-4 * u(rng) : degToRad(0.05) * u(rng);
    IsoPlanOptions o;
    o.plane = 1 + static_cast<int>(rng() % 4);
    o.seed = rng();
    // Fewer candidates than the default 200, for time: with 20 the TX60's cube came out at 95-260 mm, below 100 mm in
    // about 1 draw of 80 (seed 14597059565872942252: 97 mm); with 60 the smallest of 120 TX60 draws (seeds 1-40) was
    // 138 mm, and the test takes 1.6 s.
    o.candidates = 60;
    SCOPED_TRACE(m.name + " plane " + std::to_string(o.plane));
    const IsoPlan plan = planIso9283(m, p, o);
    EXPECT_GT(plan.cube.edge_m, 0.1) << "a cube of at least 100 mm for a 600 mm-class arm";
    EXPECT_LT(plan.worst_position_error_m, 1e-9);  // 1e-6 mm
    EXPECT_LT(plan.worst_orientation_error_rad, 1e-9);
    for (const auto& q : plan.q_rad)
      for (int j = 0; j < m.numJoints(); ++j) {
        EXPECT_GE(q[j], m.limits[static_cast<size_t>(j)].lower_rad);
        EXPECT_LE(q[j], m.limits[static_cast<size_t>(j)].upper_rad);
      }
    // P1 the centre; P2..P5 on the plane's diagonals 10 % of the diagonal from its corners; all in the plane.
    const auto corners = isoCubeCorners(plan.cube);
    EXPECT_LT((plan.poses[0].translation() - plan.cube.centre_m).norm(), 1e-15);
    const double diagonal = std::sqrt(2.0) * plan.cube.edge_m * std::sqrt(1.5);  // of a plane through two edges
    double nearest_sum = 0;
    for (int k = 1; k < 5; ++k) {
      double nearest = 1e9;
      for (const auto& c : corners) nearest = std::min(nearest, (plan.poses[static_cast<size_t>(k)].translation() - c).norm());
      nearest_sum += nearest;
      EXPECT_NEAR(nearest, 0.1 * diagonal, 1e-12);
    }
    std::printf("  %s plane %d: cube edge %.0f mm at (%.0f, %.0f, %.0f) mm, poses reached to %.1g mm\n", m.name.c_str(),
                o.plane, plan.cube.edge_m * 1e3, plan.cube.centre_m.x() * 1e3, plan.cube.centre_m.y() * 1e3,
                plan.cube.centre_m.z() * 1e3, plan.worst_position_error_m * 1e3);
  }
  // Out of reach: a centre 5 m away is named with how close the robot came.
  IsoPlanOptions far;
  far.centre_m = Eigen::Vector3d(5, 0, 0.5);
  far.candidates = 3;
  try {
    planIso9283(test::robot("staubli_tx60"), test::robot("staubli_tx60").nominal, far);
    ADD_FAILURE() << "a cube 5 m away planned";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("P1 (the centre)"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("closest pose found is"), std::string::npos) << e.what();
  }
}

// A simulated ISO test: a robot with hidden errors runs the planned program (30 cycles of P1, P5, P4, P3, P2) under a
// tracker with its noise and the robot's repeatability; against the nominal model each pose's AP is the truth's
// error at its joints (within the noise's share, 3 sigma / sqrt(30)); against the true model it is that share only.
// RP is the repeatability and noise the simulator draws (2 sigma 0.02 mm plus the tracker): within 0.02-0.1 mm.
TEST(Iso9283, ASimulatedTestGivesTheAccuracyItsTruthSays) {
  std::mt19937_64 rng(test::testSeed());
  std::vector<double> rp_over_sigma;
  for (int draw = 0; draw < 4; ++draw) {
    test::RandomDraw d = test::randomDraw(rng);
    const RobotModel nominal = test::robot(d.name);
    const SimulatedCell cell(nominal, d.sc);
    const RobotModel& m = cell.model();
    IsoPlanOptions o;
    o.seed = rng();
    // Fewer random configurations than the planner's 200, for time; 10 was too few: at seed 6041561711101938314 none
    // of a UR10's 10 held a cube above its floor (found by a sweep, docs/testing.md).
    o.candidates = 40;
    const IsoPlan plan = planIso9283(m, m.nominal, o);
    MeasurementFile f;
    f.source = "simulated.csv";
    for (int c = 1; c <= 30; ++c)
      for (int k : kIsoCycleOrder) {
        const Observation obs = cell.measure(plan.q_rad[static_cast<size_t>(k)], 0.0, rng, d.kind);
        MeasurementRow r;
        r.line = static_cast<int>(f.rows.size()) + 2;
        r.q_rad = plan.q_rad[static_cast<size_t>(k)];
        r.position_m = obs.measured_in_tracker.translation();
        if (d.kind == MeasurementKind::kPose6D) r.orientation = Eigen::Quaterniond(obs.measured_in_tracker.linear());
        r.pose = "P" + std::to_string(k + 1);
        r.cycle = c;
        f.rows.push_back(r);
      }
    SCOPED_TRACE(d.name + (d.kind == MeasurementKind::kPose6D ? " 6D" : " points"));
    const Iso9283Model nominal_model{CalibratedModel::geometric(m.nominal), &m};
    const Iso9283Model true_model{CalibratedModel::geometric(cell.trueParams(0.0)), &m};
    const Iso9283Report before = iso9283Report(iso9283Visits(f, nominal_model, true));
    const Iso9283Report after = iso9283Report(iso9283Visits(f, true_model, true));
    ASSERT_EQ(before.poses.size(), 5u);
    ASSERT_EQ(before.distances.size(), 1u);
    EXPECT_EQ(before.distances[0].from, "P2");
    EXPECT_EQ(before.distances[0].to, "P4");
    KinematicsData data(m);
    const int b = m.baseParam(FrameParam::kX);
    const Eigen::VectorXd truth = cell.trueParams(0.0);
    const Pose base_nominal = poseFromXyzRpy(m.nominal[b], m.nominal[b + 1], m.nominal[b + 2], m.nominal[b + 3],
                                             m.nominal[b + 4], m.nominal[b + 5]);
    for (int k = 0; k < 5; ++k) {
      const Iso9283Pose& p = before.poses[static_cast<size_t>(k)];
      const int idx = std::stoi(p.name.substr(1)) - 1;
      const Eigen::VectorXd& q = plan.q_rad[static_cast<size_t>(idx)];
      // What noise leaves in a 30-visit barycentre: 6 sigma (of each axis: the tracker's at this distance and the
      // robot's repeatability, 2 sigma in the config); a 3D normal vector goes beyond 6 sigma with p < 1e-7.
      const double sigma = std::hypot(d.sc.tracker.sigmaPosition(forwardKinematics(m, data, truth, q).translation().norm()),
                                      d.sc.repeatability_m / 2);
      const double share = 6 * sigma / std::sqrt(30.0);
      // The truth's error at these joints, in the nominal base frame (where the test reads it).
      const Eigen::Vector3d want = base_nominal.inverse() * (forwardKinematics(m, data, truth, q).translation()) -
                                   base_nominal.inverse() * forwardKinematics(m, data, m.nominal, q).translation();
      EXPECT_EQ(p.n, 30);
      EXPECT_NEAR(p.AP_p_m, want.norm(), share) << p.name;
      EXPECT_LT(after.poses[static_cast<size_t>(k)].AP_p_m, share) << p.name;
      EXPECT_NEAR(after.poses[static_cast<size_t>(k)].RP_l_m, p.RP_l_m, 1e-12) << "repeatability is the robot's";
      // RP_l = mean + 3 S of the distances to the barycentre: for a 3D normal of sigma per axis, a Maxwell distance
      // (mean 1.60 sigma, S 0.67 sigma): about 3.6 sigma, within 10 % over 30 visits (the tracker's noise is not the
      // same along its beam and across it). Measured over 41 seeds x 20 poses: 2.48-4.58 sigma. The bounds, 2 and 5.5
      // sigma, fail a mean distance alone (1.6); they replace 0.01-0.1 mm, which one seed's 0.104 mm exceeded.
      EXPECT_GT(p.RP_l_m, 2.0 * sigma);
      EXPECT_LT(p.RP_l_m, 5.5 * sigma);
      rp_over_sigma.push_back(p.RP_l_m / sigma);
    }
    std::printf("  %s %s: AP_p against the nominal model %.3f-%.3f mm, against the truth %.4f mm at most; RP_l %.4f mm; "
                "AD %.4f mm, RD %.4f mm\n",
                d.name.c_str(), d.kind == MeasurementKind::kPose6D ? "6D" : "points",
                std::min_element(before.poses.begin(), before.poses.end(), [](auto& a, auto& c) { return a.AP_p_m < c.AP_p_m; })->AP_p_m * 1e3,
                std::max_element(before.poses.begin(), before.poses.end(), [](auto& a, auto& c) { return a.AP_p_m < c.AP_p_m; })->AP_p_m * 1e3,
                std::max_element(after.poses.begin(), after.poses.end(), [](auto& a, auto& c) { return a.AP_p_m < c.AP_p_m; })->AP_p_m * 1e3,
                before.poses[0].RP_l_m * 1e3, before.distances[0].AD_p_m * 1e3, before.distances[0].RD_m * 1e3);
  }
  std::sort(rp_over_sigma.begin(), rp_over_sigma.end());
  std::printf("  RP_l / sigma: %.2f-%.2f\n", rp_over_sigma.front(), rp_over_sigma.back());
}

}  // namespace
}  // namespace cellcal
