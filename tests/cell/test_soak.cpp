// Soak: 8 robots with joint states and tracker readings at 1 kHz each (160,000 samples/s), targets at 100 Hz per
// robot, through the engine and compensation processes on loopback (`cellcal bench-cell`), for CELLCAL_SOAK_S
// seconds (60 in CI; a long soak: docs/RELIABILITY.md). The simulated robots' errors and the noise come from the test
// seed; the engine sees only the topics.
//   no growth in memory: the engine's and compensation publisher's RSS after the first third of the run (warm-up
//     done) grows by less than 1 MB/min (a leak of one joint state per sample would be ~50 MB/min);
//   no backlog: tracker->state p50 in the last third within 2x (+0.5 ms) of the first third, 99 % of the samples
//     received and 98 % of the stand-stills made an update (best effort: a stall of the machine drops samples);
//   still converging: the received calibrations' error against the truth at the end under 0.05 mm and no worse than
//     at the end of the first third (+0.005 mm).
#include <gtest/gtest.h>

#include <cstdlib>

#include "cell_test_support.hpp"

namespace cellcal {
namespace {

using namespace cellcal::test;

TEST(Soak, EightRobotsAt1kHzKeepMemoryLatencyAndAccuracy) {
  const std::string dir = testDir();
  const double seconds = std::getenv("CELLCAL_SOAK_S") ? std::atof(std::getenv("CELLCAL_SOAK_S")) : 60.0;
  Process bench(dir, "bench", {"cellcal", "bench-cell", "--robots", "8", "--rate-hz", "1000", "--targets-hz", "100",
                               "--duration-s", std::to_string(seconds), "--domain-id", std::to_string(domainForTest()),
                               "--seed", std::to_string(testSeed() % 1000000007ULL), "--json", dir + "/soak.json",
                               "--series-csv", dir + "/soak.csv"});
  ASSERT_EQ(bench.wait(seconds + 60), 0) << bench.log();
  const auto j = readJson(dir + "/soak.json");
  ASSERT_FALSE(j.is_discarded()) << bench.log();
  std::printf("%s", bench.log().c_str());
  const auto& s = j["soak"];
  EXPECT_GE(s["minutes_compared"].get<double>(), seconds / 60.0 * 0.6);
  for (const char* p : {"engine", "compensation_publisher"})
    EXPECT_LT(s["rss_growth_mb_per_min_after_first_third"][p].get<double>(), 1.0) << p << "\n" << s.dump(1);
  // Best effort, KEEP_LAST 100 per robot: a stall of the whole machine over ~100 ms (a shared 2-core CI runner) drops
  // samples without any backlog forming; 1 % is allowed for that (the 300 s run in docs/RELIABILITY.md lost none).
  const double published = j["joint_states"]["published"];
  EXPECT_GE(j["joint_states"]["received_by_engine"].get<double>(), 0.99 * published);
  EXPECT_GE(j["tracker_readings"]["received_by_engine"].get<double>(), 0.99 * published);
  EXPECT_GE(j["calibration_updates"].get<double>(), 0.98 * j["standstills"].get<double>());
  const double first = j["tracker_to_state_us"]["p50_first_third"], last = j["tracker_to_state_us"]["p50_last_third"];
  EXPECT_LT(last, 2 * first + 500) << "the engine falls behind";
  EXPECT_EQ(s["bad_calibration_states"], 0);
  const double uncalibrated = s["uncalibrated_error_mm"], third = s["error_mm_first_third"], end = s["error_mm_end"];
  EXPECT_GT(uncalibrated, 0.3);
  EXPECT_LT(end, 0.05);
  EXPECT_LE(end, third + 0.005);
}

}  // namespace
}  // namespace cellcal
