// The controller-side compensator (realtime_compensator.hpp) against the plain reference, compensate() of each
// version: its answers, its predicted error, its blends; a refusal held and faded without a step; versions handed over
// from another thread; and no heap allocation inside correct(), counted by this binary's own malloc.
//
// The robot (TX60, UR10, or the UR5 from its URDF where ../shared has it), the versions' errors, the path, the blend
// time and the moments versions arrive are drawn from the test seed.
#include <gtest/gtest.h>

#include <malloc.h>

#include <atomic>
#include <functional>
#include <cerrno>
#include <cstdlib>
#include <random>
#include <thread>

#include "cellcal/core/engine/compensation.hpp"
#include "cellcal/core/engine/servo.hpp"
#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/servo/realtime_compensator.hpp"
#include "test_support.hpp"

// ---- Every heap allocation of this process goes through here: glibc's own allocator, counted while a thread asks.
extern "C" {
void* __libc_malloc(size_t);
void* __libc_calloc(size_t, size_t);
void* __libc_realloc(void*, size_t);
void* __libc_memalign(size_t, size_t);
void __libc_free(void*);
}
namespace {
thread_local bool g_counting = false;
std::atomic<long> g_allocations{0};
void counted() {
  if (g_counting) g_allocations.fetch_add(1, std::memory_order_relaxed);
}
}  // namespace
extern "C" {
void* malloc(size_t n) {
  counted();
  return __libc_malloc(n);
}
void* calloc(size_t n, size_t size) {
  counted();
  return __libc_calloc(n, size);
}
void* realloc(void* p, size_t n) {
  counted();
  return __libc_realloc(p, n);
}
void* memalign(size_t alignment, size_t n) {
  counted();
  return __libc_memalign(alignment, n);
}
void* aligned_alloc(size_t alignment, size_t n) {
  counted();
  return __libc_memalign(alignment, n);
}
int posix_memalign(void** out, size_t alignment, size_t n) {
  counted();
  void* p = __libc_memalign(alignment, n);
  if (!p) return ENOMEM;
  *out = p;
  return 0;
}
void free(void* p) { __libc_free(p); }
}

namespace cellcal {
namespace {

// Allocations made by f on this thread.
template <class F>
long allocationsIn(F&& f) {
  const long before = g_allocations.load();
  g_counting = true;
  f();
  g_counting = false;
  return g_allocations.load() - before;
}

}  // namespace

// For the other test files of this binary (test_rsi_xml.cpp).
long allocationsInRsi(const std::function<void()>& f) { return allocationsIn(f); }

namespace {

struct RealtimeFixture : ::testing::Test {
  std::uint64_t seed = test::testSeed();
  std::mt19937_64 rng{seed};
  std::uniform_real_distribution<double> u{0, 1};
  std::vector<RobotModel> robots = test::robotsWithUr5();
  const RobotModel* m = nullptr;
  CompensationSettings settings;
  void SetUp() override { m = &robots[static_cast<size_t>(rng() % robots.size())]; }

  double sign() { return u(rng) < 0.5 ? -1.0 : 1.0; }
  // A calibration of the robot: each joint's zero moved by 0.005-0.05 deg, its d and a by 20-200 um, its alpha by up
  // to 0.01 deg, either way; with `covariance`, a random one over the canonical parameters (1-sigma 2-20 um / urad).
  IdentifiedModel draw(const Eigen::VectorXd& from, bool covariance) {
    Eigen::VectorXd p = from;
    for (int j = 0; j < m->numJoints(); ++j) {
      p[m->jointParam(j, JointParam::kThetaOffset)] += sign() * degToRad(0.005 + 0.045 * u(rng));
      p[m->jointParam(j, JointParam::kA)] += sign() * (20 + 180 * u(rng)) * 1e-6;
      if (!m->parallel_to_next[static_cast<size_t>(j)]) p[m->jointParam(j, JointParam::kD)] += sign() * (20 + 180 * u(rng)) * 1e-6;
      p[m->jointParam(j, JointParam::kAlpha)] += sign() * degToRad(0.01 * u(rng));
    }
    if (!covariance) return IdentifiedModel(CalibratedModel::geometric(p));
    const std::vector<int> est = m->canonicalParams();
    const auto n = static_cast<Eigen::Index>(est.size());
    Eigen::MatrixXd A(n, n);
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index k = 0; k < n; ++k) A(i, k) = std::normal_distribution<double>(0, 1)(rng);
    const double scale = (2 + 18 * u(rng)) * 1e-6;
    const Eigen::MatrixXd P = scale * scale * (A * A.transpose()) / static_cast<double>(n);
    return IdentifiedModel(CalibratedModel::geometric(p, est, P));
  }
  Eigen::VectorXd randomConfiguration() {
    Eigen::VectorXd q(m->numJoints());
    for (int j = 0; j < m->numJoints(); ++j) {
      const double lo = std::max(m->limits[j].lower_rad, -kPi), hi = std::min(m->limits[j].upper_rad, kPi);
      q[j] = lo + (0.1 + 0.8 * u(rng)) * (hi - lo);
    }
    return q;
  }
  // A smooth joint path between two random configurations, one setpoint per cycle.
  std::vector<Eigen::VectorXd> path(int cycles) {
    const Eigen::VectorXd a = randomConfiguration(), b = randomConfiguration();
    std::vector<Eigen::VectorXd> qs;
    for (int k = 0; k < cycles; ++k) qs.push_back(a + (0.5 - 0.5 * std::cos(kPi * k / (cycles - 1))) * (b - a));
    return qs;
  }
  RealtimeAnswer correct(RealtimeCompensator& rt, std::int64_t t, const Eigen::VectorXd& q) {
    return rt.correct(t, q.data(), static_cast<int>(q.size()));
  }
  std::unique_ptr<const ServoVersion> prepared(std::uint64_t version, const IdentifiedModel& model) {
    std::string why;
    auto v = ServoVersion::prepare(*m, version, model, &why);
    EXPECT_TRUE(v) << why;
    return v;
  }
};

// 500 Hz joint setpoints for 3 s: version 1 before the stream, version 2 at a random cycle, version 3 (in half the
// runs) during the blend. Every answer against the plain reference: each version's compensate() of the setpoint's
// nominal pose seeded at the setpoint, blended as servo.hpp's ServoCompensator blends them (which answers the same
// stream beside it); the predicted error against compensate()'s. Setpoints a version refuses are left to the next
// test (the reference passes them through, this one holds).
TEST_F(RealtimeFixture, AnswersAsTheReferenceAndBlendsVersionsIn) {
  const IdentifiedModel v[3] = {draw(m->nominal, true), draw(m->nominal, true), draw(m->nominal, true)};
  const double blend_s = 0.2 + 0.8 * u(rng);
  const int cycles = 1500, switch_at = 100 + static_cast<int>(u(rng) * 400);
  const bool third = u(rng) < 0.5;
  const int third_at = switch_at + 1 + static_cast<int>(u(rng) * blend_s * 500 * 0.8);
  const std::int64_t t0 = 1'700'000'000'000'000'000, dt = 2'000'000;
  RealtimeSettings rs{settings, blend_s};
  RealtimeCompensator rt(*m, rs);
  ServoCompensator reference(*m, settings, blend_s);
  ASSERT_TRUE(rt.publish(prepared(1, v[0])));
  reference.setCalibration(1, v[0]);
  // A path every version answers (every tenth setpoint checked with the reference): the test is of the answers and
  // the blend; refusals are the next test's.
  auto answered = [&](const std::vector<Eigen::VectorXd>& qs) {
    for (size_t k = 0; k < qs.size(); k += 10)
      for (const IdentifiedModel& vk : v) {
        const CompensationResult c = compensate(*m, vk, forwardKinematics(*m, m->nominal, qs[k]), qs[k], settings);
        if (!c.applied || (c.q_rad - qs[k]).cwiseAbs().maxCoeff() > settings.max_joint_correction_rad) return false;
      }
    return true;
  };
  std::vector<Eigen::VectorXd> qs = path(cycles);
  for (int tries = 1; tries < 30 && !answered(qs); ++tries) qs = path(cycles);
  double worst_q = 0, worst_sigma = 0;
  int compared = 0, refused = -1, max_evaluations = 0;
  std::string stopped = "no refusal";
  for (int k = 0; k < cycles; ++k) {
    const std::int64_t t = t0 + k * dt;
    if (k == switch_at || (third && k == third_at)) {
      const std::uint64_t id = k == switch_at ? 2 : 3;
      ASSERT_TRUE(rt.publish(prepared(id, v[id - 1])));
      reference.setCalibration(id, v[id - 1]);
    }
    const RealtimeAnswer a = correct(rt, t, qs[k]);
    const ServoAnswer r = reference.answerJoints(t, qs[k]);
    max_evaluations = std::max(max_evaluations, a.ik_evaluations);
    ASSERT_LE(a.ik_evaluations, RealtimeCompensator::evaluationBound(rs));
    if (!r.applied || a.status != ServoStatus::kApplied || a.from_refused) {
      refused = k;
      stopped = !r.applied ? "the reference refused: " + describe(r)
                : a.from_refused ? "the previous version refused within this one's budget"
                                 : "refused within this one's budget: " + describe(a);
      break;
    }
    ++compared;
    EXPECT_EQ(a.version, r.version);
    EXPECT_EQ(a.from_version, r.from_version);
    EXPECT_NEAR(a.weight, r.weight, 1e-12);
    worst_q = std::max(worst_q, (Eigen::VectorXd(a.q_rad) - r.q_rad).cwiseAbs().maxCoeff());
    const CompensationResult c =
        compensate(*m, v[a.version - 1], forwardKinematics(*m, m->nominal, qs[k]), qs[k], settings);
    worst_sigma = std::max(worst_sigma, std::abs(a.predicted_sigma_m - c.predicted_sigma_position_m) /
                                            c.predicted_sigma_position_m);
  }
  std::printf("  %d joints, blend %.2f s, versions at %d%s: %d of %d cycles compared before any refusal; worst joint "
              "difference %.3g rad, predicted sigma %.3g relative; at most %d evaluations a cycle; %s\n",
              m->numJoints(), blend_s, switch_at, third ? (" and " + std::to_string(third_at)).c_str() : "", compared,
              cycles, worst_q, worst_sigma, max_evaluations, stopped.c_str());
  EXPECT_LT(worst_q, 1e-10);
  EXPECT_LT(worst_sigma, 1e-9);
  // A path between random configurations may reach a limit or a singularity; the comparison needs a long stretch.
  if (compared < switch_at + 50) GTEST_SKIP() << "the path met a refusal at cycle " << refused;
  if (refused < 0) {
    EXPECT_EQ(rt.version(), third ? 3u : 2u);
    EXPECT_FALSE(rt.blending());
  }
}

// A version that arrives during a blend waits for it; when refusals restart the blend from the correction last
// commanded, the waiting version becomes the blend's target at once (at weight 0: no step) instead of waiting for a
// blend that refusals can keep restarting. The recovery then takes |jump| / recovery_rate_rad_s, not blend_s.
TEST_F(RealtimeFixture, ARecoveryTakesTheWaitingVersionAndEndsAtTheRecoveryRate) {
  const int j = static_cast<int>(rng() % static_cast<unsigned>(m->numJoints()));
  const double delta = degToRad(0.02 + 0.08 * u(rng));
  Eigen::VectorXd p1 = m->nominal, p2 = m->nominal;
  p2[m->jointParam(j, JointParam::kThetaOffset)] -= delta;  // v2, v3: q* = q_s + delta on joint j
  RealtimeSettings rs{settings, 30.0};                       // a blend longer than the whole path
  RealtimeCompensator rt(*m, rs);
  ASSERT_TRUE(rt.publish(prepared(1, IdentifiedModel(CalibratedModel::geometric(p1)))));
  const double upper = m->limits[j].upper_rad;
  const IdentifiedModel v2(CalibratedModel::geometric(p2));
  Eigen::VectorXd base = randomConfiguration();
  for (int tries = 0; tries < 50; ++tries) {  // a configuration v2 answers away from the limit
    base[j] = upper - 3 * delta;
    const CompensationResult c = compensate(*m, v2, forwardKinematics(*m, m->nominal, base), base, settings);
    if (c.applied && (c.q_rad - base).cwiseAbs().maxCoeff() < settings.max_joint_correction_rad) break;
    base = randomConfiguration();
  }
  const std::int64_t dt = 4'000'000;
  const int cycles = 1000;
  int recovered_at = -1, settled_at = -1;
  for (int k = 0; k < cycles; ++k) {
    if (k == 10) {
      ASSERT_TRUE(rt.publish(prepared(2, v2)));  // a blend from v1 (30 s long)
    }
    if (k == 20) {
      ASSERT_TRUE(rt.publish(prepared(3, v2)));  // waits for it
    }
    Eigen::VectorXd q = base;
    q[j] = upper - delta * (3.0 - 3.0 * std::sin(kPi * k / (cycles - 1)));  // to the limit, where v2 refuses, and back
    const RealtimeAnswer a = correct(rt, k * dt, q);
    if (k > 20 && recovered_at < 0) {
      if (a.status == ServoStatus::kApplied && rt.version() == 3) recovered_at = k;
      else ASSERT_NE(rt.version(), 3u) << "v3 taken before the recovery, at cycle " << k;
    }
    if (recovered_at >= 0 && settled_at < 0 && a.weight >= 1.0) settled_at = k;
  }
  ASSERT_GE(recovered_at, 0) << "v3 was never taken";
  ASSERT_GE(settled_at, 0) << "the recovery never ended";
  // The jump at the recovery is at most the held correction (v1's zero blended a little towards delta) plus delta.
  const double bound_s = 2 * delta / rs.recovery_rate_rad_s + 2 * dt * 1e-9;
  std::printf("  joint %d, delta %.4f deg: v3 taken at the recovery (cycle %d), blend ended %.3f s later (bound %.3f s, "
              "blend_s %.0f s)\n", j + 1, radToDeg(delta), recovered_at, (settled_at - recovered_at) * dt * 1e-9, bound_s,
              rs.blend_s);
  EXPECT_LE((settled_at - recovered_at) * dt * 1e-9, bound_s);
}

// A joint driven to its upper limit and back, with a version whose zero of that joint puts the answer beyond the
// limit for the last stretch: the version refuses there. The stream holds the correction last commanded, fades it to
// zero over blend_s, and blends back to the version's answer when it answers again: no cycle steps the correction by
// more than the fade's rate or the recovery's (recovery_rate_rad_s, or the jump over blend_s where that is faster). The reference (ServoCompensator) passes those setpoints through: a step
// of the whole correction.
TEST_F(RealtimeFixture, ARefusalHoldsTheLastCorrectionAndFadesIt) {
  const int j = static_cast<int>(rng() % static_cast<unsigned>(m->numJoints()));
  const double delta = degToRad(0.02 + 0.08 * u(rng)), blend_s = 0.1 + 0.3 * u(rng);
  Eigen::VectorXd p = m->nominal;
  p[m->jointParam(j, JointParam::kThetaOffset)] -= delta;  // q* = q_s + delta on joint j
  const IdentifiedModel v(CalibratedModel::geometric(p));
  RealtimeCompensator rt(*m, RealtimeSettings{settings, blend_s});
  ServoCompensator reference(*m, settings, blend_s);
  ASSERT_TRUE(rt.publish(prepared(4, v)));
  reference.setCalibration(4, v);
  const double upper = m->limits[j].upper_rad;
  Eigen::VectorXd base = randomConfiguration();
  for (int tries = 0; tries < 50; ++tries) {  // a configuration the version answers away from the limit
    base[j] = upper - 3 * delta;
    const CompensationResult c = compensate(*m, v, forwardKinematics(*m, m->nominal, base), base, settings);
    if (c.applied && (c.q_rad - base).cwiseAbs().maxCoeff() < settings.max_joint_correction_rad) break;
    base = randomConfiguration();
  }
  const std::int64_t dt = 4'000'000;  // 250 Hz
  const int cycles = 1000;
  double worst_excess = 0, reference_step = 0, last_hold = 1, spread = 0;
  std::vector<double> steps;
  int held = 0, recovered = 0;
  Eigen::VectorXd last_dq = Eigen::VectorXd::Zero(m->numJoints()), last_ref = last_dq;
  ServoStatus last_status = ServoStatus::kApplied;
  for (int k = 0; k < cycles; ++k) {
    Eigen::VectorXd q = base;
    q[j] = upper - delta * (3.0 - 3.0 * std::sin(kPi * k / (cycles - 1)));  // to the limit and back
    const RealtimeAnswer a = correct(rt, k * dt, q);
    const ServoAnswer r = reference.answerJoints(k * dt, q);
    const Eigen::VectorXd dq = a.correction_rad, ref = r.q_rad - q;
    ASSERT_NE(a.status, ServoStatus::kNoCalibration);
    if (a.status == ServoStatus::kHeld) {
      ++held;
      EXPECT_EQ(a.outcome, CompensationOutcome::kUnreachable) << describe(a);
      EXPECT_LE(a.hold_fraction, last_hold + 1e-12);
      last_hold = a.hold_fraction;
      EXPECT_NE(describe(a).find("holding"), std::string::npos) << describe(a);
    } else {
      if (last_status == ServoStatus::kHeld) ++recovered;
      last_hold = 1;
    }
    // The correction is delta on joint j where the version answers, to within `spread` (the solve's tolerance through
    // the arm's conditioning: what the reference's answers show): the fade and the blend move it at most
    // (delta + spread) dt / blend_s a cycle, and the version's own answers by up to 2 spread.
    if (r.applied) {
      Eigen::VectorXd ideal = Eigen::VectorXd::Zero(m->numJoints());
      ideal[j] = delta;
      spread = std::max(spread, (ref - ideal).cwiseAbs().maxCoeff());
    }
    if (k > 0) steps.push_back((dq - last_dq).cwiseAbs().maxCoeff());
    if (k > 0) reference_step = std::max(reference_step, (ref - last_ref).cwiseAbs().maxCoeff());
    last_dq = dq;
    last_ref = ref;
    last_status = a.status;
  }
  // The blend back from the held correction moves at recovery_rate_rad_s, or over blend_s where that is faster.
  const double rate = std::max((delta + spread) / blend_s, RealtimeSettings{}.recovery_rate_rad_s);
  const double allowed = rate * dt * 1e-9 + 2 * spread;
  for (double step : steps) worst_excess = std::max(worst_excess, step - allowed);
  std::printf("  joint %d, delta %.4f deg (answers within %.2g rad of it), blend %.2f s: %d cycles held, %d recoveries; "
              "largest step beyond the rate %.3g rad; the reference's largest step %.3g rad\n",
              j + 1, radToDeg(delta), spread, blend_s, held, recovered, worst_excess, reference_step);
  ASSERT_GT(held, 0) << "the path never reached the refused stretch";
  EXPECT_EQ(recovered, 1);
  EXPECT_LE(worst_excess, 0.0);
  EXPECT_LT(spread, 0.1 * delta);  // the scenario is what it says: the answers move joint j by delta
  EXPECT_GT(reference_step, 0.9 * delta);
  EXPECT_LT((last_dq - last_ref).cwiseAbs().maxCoeff(), 1e-10);  // back to the version's answer at the end
}

// Everything correct() does in one stream, counted: cycles before any version, the first version, switches with
// blends (two solves a cycle), a version waiting for a blend, refusals held and faded, recoveries, clamped
// corrections, bad setpoints. Not one allocation inside correct(); the counter itself counts an Eigen vector.
TEST_F(RealtimeFixture, CorrectAllocatesNothing) {
  ASSERT_GT(allocationsIn([] { Eigen::VectorXd x(100); x.setZero(); }), 0) << "the counter sees no allocation";
  CompensationSettings clamp = settings;
  clamp.on_exceed = ExceedAction::kClamp;
  clamp.max_correction_m = 0.2e-3;  // most corrections clamped
  RealtimeCompensator rt(*m, RealtimeSettings{clamp, 0.05});
  const std::vector<Eigen::VectorXd> qs = path(600);
  const Eigen::VectorXd bad = Eigen::VectorXd::Constant(m->numJoints(), std::nan(""));
  long inside = 0;
  int statuses[4] = {0, 0, 0, 0}, clamped = 0, blending = 0;
  // Versions at these cycles (81 waits for 80's blend; 320 with a covariance); the one at 380 has a covariance whose
  // predicted error exceeds the guard everywhere: refused, held and faded until 440's recovers.
  const std::vector<int> arrivals = {20, 80, 81, 140, 200, 260, 320, 380, 440};
  for (int k = 0; k < 600; ++k) {
    if (std::find(arrivals.begin(), arrivals.end(), k) != arrivals.end()) {
      IdentifiedModel v = draw(m->nominal, k == 320 || k == 380);
      if (k == 380) v.covariance *= 1e8;  // 1-sigma 2-20 cm
      ASSERT_TRUE(rt.publish(prepared(static_cast<std::uint64_t>(k + 1), v)));
    }
    const Eigen::VectorXd& q = k % 97 == 50 ? bad : qs[static_cast<size_t>(k)];
    RealtimeAnswer a;
    inside += allocationsIn([&] { a = correct(rt, k * 2'000'000LL, q); });
    ++statuses[static_cast<int>(a.status)];
    clamped += a.outcome == CompensationOutcome::kClamped;
    blending += a.weight < 1;
  }
  std::printf("  %d applied (%d clamped, %d blending), %d held, %d before any version, %d bad setpoints: %ld "
              "allocations inside correct()\n",
              statuses[0], clamped, blending, statuses[1], statuses[2], statuses[3], inside);
  EXPECT_EQ(inside, 0);
  EXPECT_GT(statuses[0], 100);
  EXPECT_GT(clamped, 0);
  EXPECT_GT(blending, 0);
  EXPECT_GT(statuses[1], 0);
  EXPECT_EQ(statuses[2], 20);
  EXPECT_EQ(statuses[3], 6);
}

// A feed thread prepares and publishes 300 versions while the controller's thread corrects 20,000 setpoints, switching
// at once (blend 0): each version differs in joint j's zero by its own amount (0.01-0.06 deg), so every answer must
// carry the correction of the version it names (the reference's, to 1e-10 rad); versions never go back, and the last one is answered at the end.
TEST_F(RealtimeFixture, VersionsHandedOverFromAnotherThread) {
  const int j = static_cast<int>(rng() % static_cast<unsigned>(m->numJoints()));
  RealtimeCompensator rt(*m, RealtimeSettings{settings, 0.0});
  const int versions = 300;
  std::vector<double> delta(versions + 1);
  for (double& d : delta) d = degToRad(0.01 + 0.05 * u(rng));
  Eigen::VectorXd q = randomConfiguration();
  for (int tries = 0; tries < 50; ++tries) {  // a configuration the versions answer (they differ by hundredths of a degree)
    Eigen::VectorXd p = m->nominal;
    p[m->jointParam(j, JointParam::kThetaOffset)] -= degToRad(0.035);
    const CompensationResult c = compensate(*m, p, forwardKinematics(*m, m->nominal, q), q, settings);
    if (c.applied && (c.q_rad - q).cwiseAbs().maxCoeff() < settings.max_joint_correction_rad) break;
    q = randomConfiguration();
  }
  // Each version's answer at q, from the reference: the same for every cycle that names the version.
  std::vector<Eigen::VectorXd> expected(versions + 1);
  for (int k = 1; k <= versions; ++k) {
    Eigen::VectorXd p = m->nominal;
    p[m->jointParam(j, JointParam::kThetaOffset)] -= delta[static_cast<size_t>(k)];
    const CompensationResult c = compensate(*m, p, forwardKinematics(*m, m->nominal, q), q, settings);
    ASSERT_TRUE(c.applied) << describe(c);
    expected[static_cast<size_t>(k)] = c.q_rad - q;
  }
  std::atomic<bool> done{false};
  std::thread feed([&] {
    for (int k = 1; k <= versions; ++k) {
      Eigen::VectorXd p = m->nominal;
      p[m->jointParam(j, JointParam::kThetaOffset)] -= delta[static_cast<size_t>(k)];
      std::string why;
      auto v = ServoVersion::prepare(*m, static_cast<std::uint64_t>(k), IdentifiedModel(CalibratedModel::geometric(p)),
                                     &why);
      rt.publish(std::move(v));
      std::this_thread::sleep_for(std::chrono::microseconds(50));
    }
    done = true;
  });
  std::uint64_t last = 0;
  int wrong = 0, back = 0, answered = 0;
  for (int k = 0; (answered < 20000 || !done) && k < 10'000'000; ++k) {
    const RealtimeAnswer a = correct(rt, k * 2'000'000LL, q);
    if (a.version < last) ++back;
    last = a.version;
    if (a.status != ServoStatus::kApplied) continue;
    ++answered;
    if ((Eigen::VectorXd(a.correction_rad) - expected[a.version]).cwiseAbs().maxCoeff() > 1e-10) ++wrong;
  }
  feed.join();
  const RealtimeAnswer end = correct(rt, 0, q);
  rt.collectRetired();
  std::printf("  joint %d: %d answers applied, %d with another version's correction, %d going back\n", j + 1, answered,
              wrong, back);
  EXPECT_EQ(wrong, 0);
  EXPECT_EQ(back, 0);
  EXPECT_GE(answered, 20000);
  EXPECT_EQ(end.version, static_cast<std::uint64_t>(versions));
}

// What is refused before the stream: a model with extensions, one of the wrong size, a covariance that is not one;
// bad settings. A bad setpoint changes nothing: the next cycle answers as if it had not come.
TEST_F(RealtimeFixture, RefusalsByNameAndBadSetpoints) {
  std::string why;
  IdentifiedModel extended(CalibratedModel::geometric(m->nominal));
  extended.extensions = {Extension{Cause::kJointScale, 1}};
  extended.extension_params = Eigen::VectorXd::Zero(numExtensionParams(*m, extended.extensions));
  EXPECT_FALSE(ServoVersion::prepare(*m, 1, extended, &why));
  EXPECT_NE(why.find("joint_scale:2"), std::string::npos) << why;
  EXPECT_FALSE(ServoVersion::prepare(*m, 1, IdentifiedModel(CalibratedModel::geometric(m->nominal.head(5))), &why));
  EXPECT_NE(why.find("calibration version 1"), std::string::npos) << why;
  const std::vector<int> est = {0, 1};
  EXPECT_FALSE(ServoVersion::prepare(
      *m, 1, IdentifiedModel(CalibratedModel::geometric(m->nominal, est, Eigen::Matrix2d{{1e-8, 2e-8}, {2e-8, 1e-8}})), &why));
  EXPECT_NE(why.find("positive semi-definite"), std::string::npos) << why;
  EXPECT_THROW(RealtimeCompensator(*m, RealtimeSettings{settings, -1.0}), std::invalid_argument);

  RealtimeCompensator rt(*m, RealtimeSettings{settings, 0.5}), same(*m, RealtimeSettings{settings, 0.5});
  const IdentifiedModel v = draw(m->nominal, false);
  rt.publish(prepared(2, v));
  same.publish(prepared(2, v));
  EXPECT_FALSE(rt.publish(prepared(2, v))) << "a version not newer than the last is dropped";
  const std::vector<Eigen::VectorXd> qs = path(50);
  for (int k = 0; k < 50; ++k) {
    if (k == 20) {
      const Eigen::VectorXd longer = Eigen::VectorXd::Zero(m->numJoints() + 1);
      const RealtimeAnswer b = correct(rt, k * 4'000'000LL, longer);
      EXPECT_EQ(b.status, ServoStatus::kBadSetpoint);
      EXPECT_EQ(b.outcome, CompensationOutcome::kBadInput);
      EXPECT_NE(describe(b).find(std::to_string(m->numJoints() + 1) + " joint values (the robot has " +
                                 std::to_string(m->numJoints()) + ")"),
                std::string::npos)
          << describe(b);
      EXPECT_EQ(rt.correct(k, nullptr, m->numJoints()).status, ServoStatus::kBadSetpoint);
    }
    const RealtimeAnswer a = correct(rt, k * 4'000'000LL, qs[static_cast<size_t>(k)]);
    const RealtimeAnswer b = correct(same, k * 4'000'000LL, qs[static_cast<size_t>(k)]);
    EXPECT_EQ(a.status, b.status);
    EXPECT_EQ(a.q_rad, b.q_rad);
  }
}

}  // namespace
}  // namespace cellcal
