// InputWatch against the script that drove it: random programs of moves and stand-stills (some read by the tracker,
// with encoder jitter below the settle tolerance), random rates. The count of stand-stills in a row without a reading,
// whether a time span holds a move, and the staleness of each stream are known from the script, not recomputed.
#include <gtest/gtest.h>

#include "cellcal/core/engine/input_watch.hpp"
#include "test_support.hpp"

namespace cellcal {
namespace {

TEST(InputWatch, StandStillsMovesAndStaleStreamsAreWhatTheProgramDid) {
  std::mt19937_64 rng(test::testSeed());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    EngineSettings settings;
    settings.stale_stand_stills = 1 + static_cast<int>(u(rng) * 5);
    settings.stale_input_s = 1.0 + 4.0 * u(rng);
    InputWatch watch(settings);
    const std::int64_t period_ns = static_cast<std::int64_t>(1e9 / (50 + 950 * u(rng)));
    std::int64_t t = 1'000'000'000;
    std::uint64_t seq = 0;
    Eigen::VectorXd q = Eigen::VectorXd::Zero(6);
    int unread_in_a_row = 0;  // the script's count: stand-stills ended without a reading since the last reading
    bool any_reading = false;
    struct Span {
      std::int64_t from_ns, to_ns;
      bool moving;
    };
    std::vector<Span> spans;
    const int segments = 4 + static_cast<int>(u(rng) * 12);
    for (int s = 0; s < segments; ++s) {
      // A move to a new configuration.
      const Eigen::VectorXd target = q + Eigen::VectorXd::NullaryExpr(6, [&] { return 0.05 + 0.3 * u(rng); });
      const int steps = 3 + static_cast<int>(u(rng) * 20);
      const std::int64_t move_from = t;
      for (int k = 1; k <= steps; ++k) {
        t += period_ns;
        watch.jointReceived(t);
        watch.jointAdmitted({t, ++seq, q + (target - q) * k / steps, false});
      }
      q = target;
      spans.push_back({move_from, t, true});
      // A stand-still, with jitter well inside the settle tolerance; the tracker reads it or not.
      const bool read = u(rng) < 0.4;
      const int still = 5 + static_cast<int>(u(rng) * 30);
      const std::int64_t still_from = t;
      for (int k = 0; k < still; ++k) {
        t += period_ns;
        const Eigen::VectorXd jitter =
            Eigen::VectorXd::NullaryExpr(6, [&] { return (u(rng) - 0.5) * 0.4 * settings.settle_tolerance_rad; });
        watch.jointReceived(t);
        watch.jointAdmitted({t, ++seq, q + jitter * (k % 2), true});
        if (read && k == still / 2) watch.trackerReceived(t);
      }
      spans.push_back({still_from, t, false});
      if (read) {
        any_reading = true;
        unread_in_a_row = 0;
      }
      // The stand-still ends with the next move's first sample; count it then (below, for all but the last).
      if (s + 1 < segments && !read) ++unread_in_a_row;
    }
    // The last stand-still has not ended: it does not count yet.
    const std::string stale = watch.staleInputs(t);
    const bool tracker_stale = unread_in_a_row >= settings.stale_stand_stills;
    EXPECT_EQ(stale.find("tracker_pose") != std::string::npos, tracker_stale)
        << stale << " | unread in a row " << unread_in_a_row << " of " << settings.stale_stand_stills;
    if (tracker_stale) {
      EXPECT_NE(stale.find("last " + std::to_string(unread_in_a_row) + " stand-stills"), std::string::npos) << stale;
    }
    if (tracker_stale && !any_reading) {
      EXPECT_NE(stale.find("nothing received yet"), std::string::npos) << stale;
    }
    EXPECT_EQ(stale.find("joint_state"), std::string::npos) << stale;
    const auto later = t + static_cast<std::int64_t>((settings.stale_input_s + 0.1) * 1e9);
    EXPECT_NE(watch.staleInputs(later).find("joint_state: nothing for"), std::string::npos);
    // Moves: a span that holds a move's samples shows motion; one inside a stand-still does not (the moves of the
    // last InputWatch::kMotionKept samples are kept).
    for (const Span& sp : spans) {
      if (sp.to_ns < t - static_cast<std::int64_t>(InputWatch::kMotionKept / 2) * period_ns) continue;
      EXPECT_EQ(watch.movedBetween(sp.from_ns, sp.to_ns), sp.moving) << (sp.moving ? "move" : "stand-still");
    }
  }
}

TEST(InputWatch, NothingReceivedIsStaleOnBothStreamsOnlyByTheirOwnRules) {
  EngineSettings settings;
  InputWatch watch(settings);
  EXPECT_NE(watch.staleInputs(5'000'000'000).find("joint_state: nothing received yet"), std::string::npos);
  EXPECT_EQ(watch.staleInputs(5'000'000'000).find("tracker_pose"), std::string::npos);  // no stand-still yet
  settings.tracker_silence_s = 10;
  watch.trackerReceived(1'000'000'000);
  EXPECT_EQ(watch.staleInputs(10'000'000'000).find("tracker_pose"), std::string::npos);
  EXPECT_NE(watch.staleInputs(12'000'000'000).find("tracker_pose: nothing for 11.0 s (engine.tracker_silence_s)"),
            std::string::npos)
      << watch.staleInputs(12'000'000'000);
}

}  // namespace
}  // namespace cellcal
