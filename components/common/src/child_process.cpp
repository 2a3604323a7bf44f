#include "cellcal/components/child_process.hpp"

#include <fcntl.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <thread>

namespace cellcal::components {

ChildProcess::ChildProcess(const std::string& exe, const std::vector<std::string>& args, const std::string& log_file,
                           bool append)
    : log_file_(log_file) {
  if (!std::filesystem::exists(exe)) throw std::runtime_error(exe + " not found (build all targets)");
  std::vector<std::string> full = {exe};
  full.insert(full.end(), args.begin(), args.end());
  const pid_t parent = ::getpid();
  pid_ = ::fork();
  if (pid_ < 0) throw std::runtime_error("fork failed for " + exe);
  if (pid_ == 0) {
    // Down with the parent, even when it is SIGKILLed (SIGTERM: a cellcal program's clean stop).
    ::prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (::getppid() != parent) ::_exit(1);  // the parent died before prctl
    const int fd = ::open(log_file_.c_str(), O_WRONLY | O_CREAT | (append ? O_APPEND : O_TRUNC), 0644);
    if (fd >= 0) {
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      ::close(fd);
    }
    std::vector<char*> argv;
    for (auto& a : full) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    std::perror("execv");
    ::_exit(127);
  }
}

ChildProcess::ChildProcess(ChildProcess&& other) noexcept
    : pid_(other.pid_), exit_code_(other.exit_code_), log_file_(std::move(other.log_file_)) {
  other.pid_ = -1;
}

ChildProcess::~ChildProcess() {
  if (pid_ > 0 && running()) {
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
  }
}

bool ChildProcess::running() {
  if (pid_ <= 0 || exit_code_ >= 0) return false;
  int st = 0;
  if (::waitpid(pid_, &st, WNOHANG) == pid_) {
    exit_code_ = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    return false;
  }
  return true;
}

int ChildProcess::wait(double timeout_s) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (running() && std::chrono::steady_clock::now() < end) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  return exitCode();
}

int ChildProcess::stop(int sig, double timeout_s) {
  if (!running()) return exit_code_;
  ::kill(pid_, sig);
  return wait(timeout_s);
}

int ChildProcess::stopOrKill(int sig, double timeout_s) {
  if (stop(sig, timeout_s) >= 0) return exit_code_;
  ::kill(pid_, SIGKILL);
  int st = 0;
  ::waitpid(pid_, &st, 0);
  exit_code_ = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  return exit_code_;
}

void stopAll(const std::vector<ChildProcess*>& children, int sig, double timeout_s) {
  for (ChildProcess* c : children)
    if (c->running()) ::kill(c->pid(), sig);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  for (ChildProcess* c : children) {
    const double left = std::chrono::duration<double>(deadline - std::chrono::steady_clock::now()).count();
    c->stopOrKill(0, std::max(0.0, left));  // signal 0: nothing more sent, only waited for
  }
}

std::string ipProgram() {
  for (const char* p : {"/usr/sbin/ip", "/usr/bin/ip", "/sbin/ip", "/bin/ip"})
    if (::access(p, X_OK) == 0) return p;
  return "";
}

}  // namespace cellcal::components
