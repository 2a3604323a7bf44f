// Hands work from DDS listener threads to one worker thread, so that a listener never waits on the disk or on a long
// computation. Fast DDS reads a transport's socket in the thread that runs the listener: while the listener waits
// (a state file written under disk pressure can block for a second), the socket buffer fills and the kernel drops
// datagrams. Here the wait moves to the worker and the items wait in memory instead.
//
// Contract:
//  - push() never blocks on the worker: it appends, and wakes the worker if it is waiting. Items are handled in push
//    order, in batches (everything queued when the worker looks), by one thread. A backlog's memory is given back
//    once it has been handled.
//  - At most max_items wait; push() refuses more (returns false) and counts them in refused(): the caller's bound on
//    memory when the worker is stalled for long.
//  - Every idle_period with nothing queued, the worker calls idle() (timeouts that need no input).
//  - stop() (and the destructor) stops taking items (push() returns false, uncounted), lets the worker handle
//    everything already queued, and joins it.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace cellcal::components {

template <class T>
class WorkQueue {
 public:
  WorkQueue(size_t max_items, std::function<void(std::vector<T>&)> handle, std::chrono::milliseconds idle_period,
            std::function<void()> idle)
      : max_items_(max_items), handle_(std::move(handle)), idle_period_(idle_period), idle_(std::move(idle)) {
    worker_ = std::thread([this] { run(); });
  }
  WorkQueue(const WorkQueue&) = delete;
  WorkQueue& operator=(const WorkQueue&) = delete;
  ~WorkQueue() { stop(); }

  bool push(T item) {
    {
      std::lock_guard<std::mutex> l(mutex_);
      if (stopping_) return false;  // shutting down: not a refusal
      if (items_.size() >= max_items_) {
        ++refused_;
        return false;
      }
      items_.push_back(std::move(item));
      peak_ = std::max(peak_, items_.size());
      if (!worker_waiting_) return true;  // busy: it takes this one with its next batch, no wake-up needed
    }
    wake_.notify_one();
    return true;
  }

  void stop() {
    {
      std::lock_guard<std::mutex> l(mutex_);
      if (stopping_) return;
      stopping_ = true;
    }
    wake_.notify_one();
    if (worker_.joinable()) worker_.join();
  }

  std::uint64_t refused() const {
    std::lock_guard<std::mutex> l(mutex_);
    return refused_;
  }
  // The most items that waited at once.
  size_t peak() const {
    std::lock_guard<std::mutex> l(mutex_);
    return peak_;
  }

 private:
  void run() {
    std::vector<T> batch;
    for (;;) {
      bool timed_out = false;
      {
        std::unique_lock<std::mutex> l(mutex_);
        worker_waiting_ = true;
        timed_out = !wake_.wait_for(l, idle_period_, [&] { return stopping_ || !items_.empty(); });
        worker_waiting_ = false;
        if (stopping_ && items_.empty()) return;
        batch.swap(items_);
      }
      if (timed_out) {
        if (idle_) idle_();
        continue;
      }
      handle_(batch);
      batch.clear();
      // After a stall's backlog, give its memory back (the next swap hands push() this small vector).
      if (batch.capacity() > kKeepCapacity) std::vector<T>().swap(batch);
    }
  }

  static constexpr size_t kKeepCapacity = 1024;
  const size_t max_items_;
  std::function<void(std::vector<T>&)> handle_;
  const std::chrono::milliseconds idle_period_;
  std::function<void()> idle_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::vector<T> items_;
  bool stopping_ = false;
  bool worker_waiting_ = false;
  std::uint64_t refused_ = 0;
  size_t peak_ = 0;
  std::thread worker_;  // last: started once everything above exists
};

}  // namespace cellcal::components
