// Soak: 8 robots with joint states and tracker readings at 1 kHz each (160,000 samples/s), targets at 100 Hz per
// robot, through the engine and compensation processes on loopback (`cellcal bench-cell`), for CELLCAL_SOAK_S
// seconds (60 in CI; a long soak: docs/RELIABILITY.md). The simulated robots' errors and the noise come from the test
// seed; the engine sees only the topics.
//   no growth in memory: the engine's and compensation publisher's RSS after the first third of the run (warm-up
//     done) grows by less than 1 MB/min (a leak of one joint state per sample would be ~50 MB/min);
//   no backlog: tracker->state p50 in the last third within 2x (+0.5 ms) of the first third; no sample lost other
//     than by the kernel for a full socket buffer; where the host lets the profile have its 4 MiB buffers, 99 % of
//     the samples received and 98 % of the stand-stills made an update (90 % where the kernel caps the buffers;
//     best effort: a stall of the machine drops samples);
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
  // Best effort: a sample is lost only where a stall of the host outlasts a socket buffer, and the kernel counts
  // those drops. Nothing may be lost anywhere else (the engine takes every sample in its listener). Where the host's
  // net.core.rmem_max is at least what the profile asks for (`make test` raises it, tools/tune_host.sh), the buffer
  // holds ~0.4 s and 1 % is allowed for a shared 2-core runner (the 300 s run in docs/RELIABILITY.md lost none);
  // where the kernel caps it (~20 ms; each process warns at start), the kernel's drops are reported, not judged, and
  // the stand-stills they cost are allowed up to 10 %.
  const double published = j["joint_states"]["published"];
  const double js_rx = j["joint_states"]["received_by_engine"], tp_rx = j["tracker_readings"]["received_by_engine"];
  const auto& host = j["host"];
  ASSERT_FALSE(host["udp_datagrams_dropped_by_kernel"].is_null()) << "/proc/net/snmp unreadable";
  const double kernel_drops = host["udp_datagrams_dropped_by_kernel"];
  EXPECT_LE(2 * published - js_rx - tp_rx - kernel_drops, 0.001 * published) << "lost other than by the kernel";
  const bool buffers_capped = host["net_core_rmem_max_bytes"].is_null() ||
                              host["net_core_rmem_max_bytes"].get<double>() < host["profile_udp_receive_buffer_bytes"].get<double>();
  if (buffers_capped) {
    std::printf("NOTE: net.core.rmem_max caps the UDP receive buffer the profile asks for; %.0f datagrams the kernel "
                "dropped are not judged (sysctl -p config/sysctl/60-cellcal.conf)\n", kernel_drops);
  } else {
    EXPECT_GE(js_rx, 0.99 * published);
    EXPECT_GE(tp_rx, 0.99 * published);
  }
  EXPECT_GE(j["calibration_updates"].get<double>(), (buffers_capped ? 0.90 : 0.98) * j["standstills"].get<double>());
  const double first = j["tracker_to_state_us"]["p50_first_third"], last = j["tracker_to_state_us"]["p50_last_third"];
  EXPECT_LT(last, 2 * first + 500) << "the engine falls behind";
  EXPECT_EQ(s["bad_calibration_states"], 0);
  // The compensation publisher answered the targets it took (its callback timed each) and says per outcome what
  // became of those it solved: most applied (the robots' random poses include a few its solver does not reach from
  // the seed near a wrist singularity, a few % in bench-cell).
  ASSERT_TRUE(j.contains("compensation")) << j.dump(1);
  const auto& comp = j["compensation"];
  const double sent = j["target_to_compensated_us"]["sent"];
  // (the publisher stops 0.5 s after the last target: on a stalled machine the last ones may still be queued)
  EXPECT_LE(comp["target_callback_cpu_us"]["samples"].get<double>(), sent);
  EXPECT_GE(comp["target_callback_cpu_us"]["samples"].get<double>(), 0.95 * sent);
  double solved = 0;
  for (const auto& [outcome, n] : comp["outcomes"].items()) solved += n.get<double>();
  EXPECT_LE(solved, sent);
  EXPECT_GE(comp["outcomes"].value("applied", 0.0), 0.8 * sent) << comp.dump(1);
  EXPECT_GT(comp["target_callback_cpu_us"]["mean"].get<double>(), 0.0);
  const double uncalibrated = s["uncalibrated_error_mm"], third = s["error_mm_first_third"], end = s["error_mm_end"];
  EXPECT_GT(uncalibrated, 0.3);
  EXPECT_LT(end, 0.05);
  EXPECT_LE(end, third + 0.005);
}

}  // namespace
}  // namespace cellcal
