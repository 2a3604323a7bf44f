// A one-line progress bar on stderr for long work (replay, validate). Drawn only when stderr is a terminal (logs and
// CI output stay clean); at most 10 redraws per second.
#pragma once

#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>

namespace cellcal::cli {

class ProgressBar {
 public:
  explicit ProgressBar(std::string label, bool enabled = true) : label_(std::move(label)), on_(enabled && ::isatty(2)) {}
  ~ProgressBar() { done(); }
  // fraction in [0, 1]; `detail` follows the bar ("1234/5678 messages").
  void update(double fraction, const std::string& detail) {
    if (!on_) return;
    const auto now = std::chrono::steady_clock::now();
    if (drawn_ && now - last_ < std::chrono::milliseconds(100) && fraction < 1) return;
    last_ = now;
    drawn_ = true;
    const int width = 30;
    const int fill = static_cast<int>(std::min(1.0, std::max(0.0, fraction)) * width + 0.5);
    std::fprintf(stderr, "\r%s [%s%s] %3.0f%% %s\033[K", label_.c_str(), std::string(fill, '#').c_str(),
                 std::string(width - fill, '.').c_str(), 100 * fraction, detail.c_str());
    std::fflush(stderr);
  }
  void done() {
    if (on_ && drawn_) std::fprintf(stderr, "\n");
    drawn_ = false;
    on_ = false;
  }

 private:
  std::string label_;
  bool on_;
  bool drawn_ = false;
  std::chrono::steady_clock::time_point last_{};
};

}  // namespace cellcal::cli
