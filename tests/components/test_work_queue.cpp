// WorkQueue (work_queue.hpp): what the calibration engine's DDS listeners hand their samples to.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <random>
#include <thread>

#include "test_support.hpp"
#include "cellcal/components/work_queue.hpp"

namespace cellcal::components {
namespace {

using namespace std::chrono_literals;

TEST(WorkQueue, ItemsAreHandledInPushOrderAndStopDrainsThem) {
  std::mt19937_64 rng(test::testSeed());
  const int n = 1000 + static_cast<int>(rng() % 20000);
  std::vector<int> seen;
  {
    WorkQueue<int> q(static_cast<size_t>(n), [&](std::vector<int>& b) { seen.insert(seen.end(), b.begin(), b.end()); },
                     5ms, nullptr);
    for (int i = 0; i < n; ++i) ASSERT_TRUE(q.push(i));
    q.stop();
    EXPECT_FALSE(q.push(-1));  // after stop: not taken, and not a refusal
    EXPECT_EQ(q.refused(), 0u);
  }
  ASSERT_EQ(seen.size(), static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) ASSERT_EQ(seen[static_cast<size_t>(i)], i);
}

TEST(WorkQueue, AStalledWorkerNeitherBlocksPushNorLosesAnythingUnderTheBound) {
  std::mt19937_64 rng(test::testSeed());
  const size_t bound = 100 + rng() % 900;
  std::atomic<bool> release{false};
  std::atomic<size_t> handled{0};
  WorkQueue<size_t> q(bound, [&](std::vector<size_t>& b) {
    while (!release) std::this_thread::sleep_for(1ms);  // a handler stuck on the disk
    handled += b.size();
  }, 5ms, nullptr);
  ASSERT_TRUE(q.push(0));  // the worker takes this one and stalls on it
  while (q.peak() == 0) std::this_thread::sleep_for(1ms);
  std::this_thread::sleep_for(20ms);
  // The stalled worker holds one item; `bound` more wait, the rest are refused, and no push waits for the worker.
  const size_t extra = 50 + rng() % 500;
  const auto t0 = std::chrono::steady_clock::now();
  size_t taken = 0;
  for (size_t i = 0; i < bound + extra; ++i) taken += q.push(i + 1) ? 1 : 0;
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 1s);
  EXPECT_EQ(taken, bound);
  EXPECT_EQ(q.refused(), extra);
  EXPECT_EQ(q.peak(), bound);
  release = true;
  q.stop();
  EXPECT_EQ(handled.load(), bound + 1);
}

TEST(WorkQueue, IdleIsCalledWhileNothingIsQueuedInTheWorkersThread) {
  std::atomic<int> idles{0};
  std::thread::id worker, idler;
  std::mutex m;
  WorkQueue<int> q(1000, [&](std::vector<int>&) {
    std::lock_guard<std::mutex> l(m);
    worker = std::this_thread::get_id();
  }, 2ms, [&] {
    std::lock_guard<std::mutex> l(m);
    idler = std::this_thread::get_id();
    ++idles;
  });
  q.push(1);
  std::this_thread::sleep_for(50ms);
  q.stop();
  EXPECT_GT(idles.load(), 2);
  EXPECT_EQ(worker, idler);  // the handler and idle() never run at once
  EXPECT_NE(worker, std::this_thread::get_id());
}

}  // namespace
}  // namespace cellcal::components
