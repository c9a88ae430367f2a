// Real processes in the service tests: a scratch directory per test, and a child process (the
// daemon binary or another one) whose stdout and stderr go to a log file.
#pragma once

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "service_test_support.h"
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

namespace bp::test {

/// A directory of its own for this test (prefix + the test's partition), removed at the end.
class ScratchDir {
 public:
  explicit ScratchDir(const std::string& prefix = "bp-proc-")
      : path_((std::filesystem::temp_directory_path() / (prefix + TestPartition())).string()) {
    std::filesystem::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
  }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

/// A running binary (broadphased by default); its stdout and stderr are appended to log_path.
/// Killed (SIGKILL) and reaped on destruction if it has not exited.
class Process {
 public:
  Process(const std::vector<std::string>& args, const std::string& log_path,
          std::string binary = BROADPHASED) {
    pid_ = fork();
    if (pid_ == 0) {
      const int fd = open(log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      dup2(fd, 2);
      dup2(fd, 1);
      std::vector<char*> argv;
      argv.push_back(binary.data());
      for (auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
      argv.push_back(nullptr);
      execv(binary.c_str(), argv.data());
      _exit(127);
    }
  }
  ~Process() { Kill(); }
  void Signal(int sig) { kill(pid_, sig); }
  /// SIGKILL, and reap it.
  void Kill() {
    if (pid_ > 0 && !exited_) {
      kill(pid_, SIGKILL);
      int status = 0;
      waitpid(pid_, &status, 0);
      exited_ = true;
    }
  }
  /// Waits for exit; the exit status, or -1 on timeout or a death by signal.
  int Wait(std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        exited_ = true;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return -1;
  }

 private:
  pid_t pid_ = -1;
  bool exited_ = false;
};

/// A whole file as text ("" if it cannot be read).
inline std::string ReadFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace bp::test
