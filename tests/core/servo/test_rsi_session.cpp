// One RSI connection in memory (rsi_session.hpp): a controller's <Rob> packets at 250 Hz along a random joint path,
// each answered with AK equal to the compensator's correction given the same setpoint directly (to the last bit of
// the degrees written); faults interleaved at random cycles (a packet cut short, a NaN axis, seven axes for a
// six-axis robot, a repeated IPOC, a jump of several cycles, a packet without a readable IPOC) answered with the
// correction last sent or not at all, counted by kind, and without a trace in the answers that follow; nothing
// allocated while answering.
#include <gtest/gtest.h>

#include <functional>
#include <random>
#include <string>

#include "cellcal/core/model/kinematics.hpp"
#include "cellcal/core/servo/rsi_session.hpp"
#include "test_support.hpp"

namespace cellcal {
long allocationsInRsi(const std::function<void()>& f);  // test_realtime_compensator.cpp
namespace {

TEST(RsiSession, EveryCycleIsAnsweredWithTheCompensatorsCorrectionAndFaultsWithTheLastOne) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(-1, 1);
  const RobotModel m = test::robot("staubli_tx60");
  Eigen::VectorXd p = m.nominal;
  for (int j = 0; j < m.numJoints(); ++j) p[m.jointParam(j, JointParam::kThetaOffset)] += degToRad(0.03 * u(rng));
  RealtimeSettings rs;
  rs.blend_s = 0.5;
  RealtimeCompensator rt(m, rs), direct(m, rs);
  std::string why;
  for (RealtimeCompensator* c : {&rt, &direct})
    ASSERT_TRUE(c->publish(ServoVersion::prepare(m, 1, IdentifiedModel(CalibratedModel::geometric(p)), &why))) << why;
  RsiSettings settings;
  RsiSession session(rt, m.numJoints(), settings);
  // A path through the middle of the workspace, 4 s at 250 Hz; a fault in each of 40 stretches of 24 cycles, at a random
  // cycle of it.
  Eigen::VectorXd a(m.numJoints()), b(m.numJoints());
  for (int j = 0; j < m.numJoints(); ++j) {
    const double mid = 0.5 * (m.limits[j].lower_rad + m.limits[j].upper_rad),
                 half = 0.5 * (m.limits[j].upper_rad - m.limits[j].lower_rad);
    a[j] = mid + 0.4 * half * u(rng);
    b[j] = mid + 0.4 * half * u(rng);
  }
  const int cycles = 1000;
  std::vector<int> fault(cycles, -1);
  for (int k = 0; k < 40; ++k) fault[static_cast<size_t>(20 + 24 * k + rng() % 20)] = static_cast<int>(rng() % 6);
  std::uint64_t ipoc = 1'000'000;
  char in[kMaxRsiPacketBytes], out[kMaxRsiPacketBytes];
  std::array<double, kMaxServoJoints> last_sent{};
  int compared = 0, faults = 0, mismatched = 0, held_right = 0;
  long allocations = 0;
  int expected_missed = 0;
  for (int k = 0; k < cycles; ++k) {
    const Eigen::VectorXd q = a + (0.5 - 0.5 * std::cos(kPi * k / (cycles - 1))) * (b - a);
    double set_deg[kMaxServoJoints], act_deg[kMaxServoJoints];
    for (int j = 0; j < m.numJoints(); ++j) set_deg[j] = act_deg[j] = radToDeg(q[j]);
    ipoc += 4;
    std::size_t n = writeRsiRob(in, sizeof in, act_deg, set_deg, m.numJoints(), ipoc);
    std::string packet(in, n);
    const int f = fault[static_cast<size_t>(k)];
    bool answered_by_compensator = true;
    if (f >= 0) {
      ++faults;
      answered_by_compensator = false;
      switch (f) {
        case 0: packet.resize(packet.size() / 2); ++expected_missed; break;  // cut: no IPOC, no answer, a cycle missed
        case 1: {  // joint 2's setpoint not a number
          const std::size_t v = packet.find("A2=\"", packet.find("ASPos")) + 4;
          packet.replace(v, packet.find('"', v) - v, "nan");
          break;
        }
        case 2: packet = std::string(in, writeRsiRob(in, sizeof in, act_deg, set_deg, 7, ipoc)); break;
        case 3: {  // the previous cycle's IPOC again
          packet = std::string(in, writeRsiRob(in, sizeof in, act_deg, set_deg, m.numJoints(), ipoc - 4));
          ipoc -= 4;  // this cycle did not happen for the controller's clock
          break;
        }
        case 4: {  // a jump of 3 cycles: answered normally
          ipoc += 12;
          expected_missed += 3;
          packet = std::string(in, writeRsiRob(in, sizeof in, act_deg, set_deg, m.numJoints(), ipoc));
          answered_by_compensator = true;
          --faults;
          break;
        }
        default: packet.replace(packet.find("<IPOC>") + 6, 1, "x"); ++expected_missed; break;  // unreadable IPOC
      }
    }
    std::size_t answer = 0;
    allocations += allocationsInRsi([&] { answer = session.onPacket(packet.data(), packet.size(), out, sizeof out); });
    const bool readable_ipoc = f != 0 && f != 5;
    if (!answered_by_compensator) {
      if (!readable_ipoc) {
        EXPECT_EQ(answer, 0u) << f;
        continue;
      }
      RsiSen sen;
      ASSERT_EQ(parseRsiSen(out, answer, sen), RsiError::kNone) << f;
      held_right += sen.correction_deg == last_sent;
      continue;
    }
    RsiSen sen;
    ASSERT_EQ(parseRsiSen(out, answer, sen), RsiError::kNone);
    EXPECT_EQ(sen.ipoc, ipoc);
    // The compensator given the same setpoint at the same stamp directly.
    double q_rad[kMaxServoJoints];
    for (int j = 0; j < m.numJoints(); ++j) q_rad[j] = degToRad(set_deg[j]);
    const RealtimeAnswer want = direct.correct(static_cast<std::int64_t>(ipoc) * 1'000'000, q_rad, m.numJoints());
    ++compared;
    for (int j = 0; j < m.numJoints(); ++j) mismatched += sen.correction_deg[static_cast<size_t>(j)] != radToDeg(want.correction_rad[j]);
    last_sent = sen.correction_deg;
  }
  const RsiCounters& c = session.counters();
  std::printf("  %d cycles answered by the compensator, %d faults (%llu cut, %llu NaN, %llu seven axes, %llu repeated "
              "IPOC, %llu unreadable IPOC; %llu cycles missed): %d axis values differing, %d held answers right; %ld "
              "allocations\n",
              compared, faults, (unsigned long long)c.refused[static_cast<size_t>(RsiError::kTruncated)],
              (unsigned long long)c.refused[static_cast<size_t>(RsiError::kNotFinite)], (unsigned long long)c.wrong_axes,
              (unsigned long long)c.stale_ipoc, (unsigned long long)c.refused[static_cast<size_t>(RsiError::kBadIpoc)],
              (unsigned long long)c.missed_cycles, mismatched, held_right, allocations);
  EXPECT_EQ(mismatched, 0);
  EXPECT_EQ(allocations, 0);
  EXPECT_EQ(c.packets, static_cast<std::uint64_t>(cycles));
  EXPECT_EQ(c.missed_cycles, static_cast<std::uint64_t>(expected_missed));
  EXPECT_EQ(static_cast<int>(c.refused[static_cast<size_t>(RsiError::kTruncated)] +
                             c.refused[static_cast<size_t>(RsiError::kNotFinite)] + c.wrong_axes + c.stale_ipoc +
                             c.refused[static_cast<size_t>(RsiError::kBadIpoc)]),
            faults);
  EXPECT_EQ(held_right, static_cast<int>(c.refused[static_cast<size_t>(RsiError::kNotFinite)] + c.wrong_axes + c.stale_ipoc));
  EXPECT_GT(c.applied, static_cast<std::uint64_t>(cycles / 2));
}

TEST(RsiSession, ACorrectionOverTheLimitIsNotSent) {
  const RobotModel m = test::robot("staubli_tx60");
  Eigen::VectorXd p = m.nominal;
  p[m.jointParam(1, JointParam::kThetaOffset)] += degToRad(0.3);  // joint 2's correction about -0.3 deg
  RealtimeSettings rs;
  rs.blend_s = 0;
  RealtimeCompensator rt(m, rs);
  std::string why;
  ASSERT_TRUE(rt.publish(ServoVersion::prepare(m, 1, IdentifiedModel(CalibratedModel::geometric(p)), &why)));
  RsiSettings settings;
  settings.max_correction_deg = 0.2;
  RsiSession session(rt, m.numJoints(), settings);
  const double q[6] = {10, -30, 100, 5, 40, -20};
  char in[kMaxRsiPacketBytes], out[kMaxRsiPacketBytes];
  const std::size_t n = writeRsiRob(in, sizeof in, q, q, 6, 4);
  RsiSen sen;
  ASSERT_EQ(parseRsiSen(out, session.onPacket(in, n, out, sizeof out), sen), RsiError::kNone);
  EXPECT_EQ(session.counters().over_limit, 1u);
  for (int k = 0; k < 6; ++k) EXPECT_EQ(sen.correction_deg[static_cast<size_t>(k)], 0.0);  // nothing sent before
  EXPECT_NEAR(radToDeg(session.lastAnswer().correction_rad[1]), -0.3, 0.01);
  EXPECT_THROW(RsiSession(rt, 8, settings), std::invalid_argument);
}

}  // namespace
}  // namespace cellcal
