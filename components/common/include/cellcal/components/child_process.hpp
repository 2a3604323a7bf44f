// Another program started as a child, as the launcher (`cellcal cell`), `bench-cell` and the multi-process tests do:
// its stdout and stderr in a log file, and it dies with its parent (the death signal is SIGTERM, every cellcal
// program's clean stop), even when the parent is SIGKILLed.
#pragma once

#include <sys/types.h>

#include <csignal>
#include <string>
#include <vector>

namespace cellcal::components {

class ChildProcess {
 public:
  // Starts `exe` with `args`. `append`: add to the log instead of replacing it. Throws std::runtime_error when the
  // program does not exist or fork fails (a failed exec exits the child with 127).
  ChildProcess(const std::string& exe, const std::vector<std::string>& args, const std::string& log_file,
               bool append = false);
  // A child still running is killed (SIGKILL) and reaped.
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  ChildProcess(ChildProcess&& other) noexcept;
  ChildProcess& operator=(ChildProcess&&) = delete;

  pid_t pid() const { return pid_; }
  const std::string& logFile() const { return log_file_; }
  // Reaps it if it has exited.
  bool running();
  // Its exit code (128 + the signal when a signal ended it); -1 while it runs.
  int exitCode() { return running() ? -1 : exit_code_; }
  // Waits up to timeout_s; the exit code, or -1 when it still runs.
  int wait(double timeout_s);
  // Sends `sig` and waits up to timeout_s; the exit code, or -1 when it still runs.
  int stop(int sig = SIGINT, double timeout_s = 15);
  // stop(sig, timeout_s), then SIGKILL if it had not ended.
  int stopOrKill(int sig = SIGINT, double timeout_s = 15);

 private:
  pid_t pid_ = -1;
  int exit_code_ = -1;
  std::string log_file_;
};

// Sends `sig` to every running child, then waits for them all (at most timeout_s in all), SIGKILLing those left.
void stopAll(const std::vector<ChildProcess*>& children, int sig = SIGINT, double timeout_s = 15);

// The iproute2 `ip` program, for a child run in a network namespace (`ip netns exec NS PROGRAM ...` execs the program
// in place: same pid, same death signal); empty when it is not installed.
std::string ipProgram();

}  // namespace cellcal::components
