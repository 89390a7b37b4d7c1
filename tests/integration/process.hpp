// A child process for integration tests: the real `virtual-encoder` binary (or
// another program), its output captured to a file, ended with its test.
//
// Every process a test starts ends with it, also when the test fails or aborts:
//  - the child runs in a process group of its own, and the destructor kills the whole
//    group (SIGKILL), so whatever the child started goes too; a child that has exited
//    is reaped only after its group was killed, so the group id is never one the
//    system has given to another process;
//  - the child asks the kernel for SIGKILL when the thread that started it dies
//    (PR_SET_PDEATHSIG), and exits at once if that thread was already gone when it
//    asked: a test process that crashes, aborts or is killed (ctest's timeout)
//    takes its children with it, though no destructor runs. Start children from the
//    test's own thread, not from a thread that ends before them.
// The child inherits the test's DDS domain locks (test_domain.hpp).
#pragma once

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace ve::test {

/// The whole content of a text file ("" if it cannot be read).
inline std::string read_file(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class ChildProcess {
 public:
  /// Runs in the child between fork and exec: async-signal-safe calls only.
  using Prepare = void (*)();

  /// stdout and stderr both go to `log_path`, or stderr to `stderr_path` if one is given.
  ChildProcess(const std::vector<std::string>& args, const std::string& log_path, const std::string& stderr_path = "",
               Prepare prepare = nullptr)
      : log_path_(log_path) {
    // Everything the child needs is made before fork: it only makes system calls.
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    const char* out = log_path.c_str();
    const char* err = stderr_path.empty() ? nullptr : stderr_path.c_str();
    int report[2];  // the child's exec error, if any; closed by a successful exec
    if (pipe2(report, O_CLOEXEC) != 0) return;
    const pid_t parent = getpid();
    const pid_t pid = fork();
    if (pid == 0) {
      close(report[0]);
      setpgid(0, 0);
      if (prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || getppid() != parent) _exit(127);
      int e = 0;
      const int fd = open(out, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
      if (fd < 0 || dup2(fd, STDOUT_FILENO) < 0) e = errno;
      const int efd = err != nullptr ? open(err, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644) : fd;
      if (e == 0 && (efd < 0 || dup2(efd, STDERR_FILENO) < 0)) e = errno;
      // No terminal input: a background process group reading it would be stopped.
      const int in = open("/dev/null", O_RDONLY | O_CLOEXEC);
      if (e == 0 && (in < 0 || dup2(in, STDIN_FILENO) < 0)) e = errno;
      if (e == 0) {
        if (prepare != nullptr) prepare();
        execve(argv[0], argv.data(), environ);
        e = errno;
      }
      while (write(report[1], &e, sizeof e) < 0 && errno == EINTR) {
      }
      _exit(127);
    }
    close(report[1]);
    if (pid < 0) {
      close(report[0]);
      return;
    }
    setpgid(pid, pid);  // also here: the group exists before either side goes on
    int child_errno = 0;
    ssize_t n;
    while ((n = read(report[0], &child_errno, sizeof child_errno)) < 0 && errno == EINTR) {
    }
    close(report[0]);
    pid_ = pid;
    if (n > 0) {  // it could not exec: not started
      end_group();
      pid_ = -1;
    }
  }
  ~ChildProcess() {
    if (pid_ > 0 && !exited_) end_group();
  }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  bool started() const { return pid_ > 0; }
  pid_t pid() const { return pid_; }
  /// To the child itself, not its group. Never with pid -1 (a failed spawn): that
  /// would signal every process we may signal; never to a child already reaped.
  void signal(int sig) const {
    if (pid_ > 0 && !exited_) kill(pid_, sig);
  }

  /// Waits up to timeout for the exit; returns the exit code, or -1 on timeout or a
  /// signal death. Once it has exited, the rest of its group is killed and it is reaped.
  int wait_exit(std::chrono::milliseconds timeout) {
    if (pid_ <= 0) return -1;
    if (exited_) return code_;
    const auto end = std::chrono::steady_clock::now() + timeout;
    for (;;) {
      siginfo_t info{};
      // WNOWAIT: seen, not reaped, so that its group id stays ours until end_group().
      if (waitid(P_PID, static_cast<id_t>(pid_), &info, WEXITED | WNOHANG | WNOWAIT) == 0 && info.si_pid == pid_) {
        code_ = info.si_code == CLD_EXITED ? info.si_status : -1;
        end_group();
        return code_;
      }
      if (std::chrono::steady_clock::now() >= end) return -1;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }

  std::string log() const { return read_file(log_path_); }

 private:
  /// Kills the child's process group (the child and all it started) and reaps the child.
  void end_group() {
    kill(-pid_, SIGKILL);
    kill(pid_, SIGKILL);  // in case it had not joined its group yet
    int st = 0;
    while (waitpid(pid_, &st, 0) < 0 && errno == EINTR) {
    }
    exited_ = true;
  }

  pid_t pid_ = -1;
  bool exited_ = false;
  int code_ = -1;
  std::string log_path_;
};

/// Polls `done` every 10 ms until it holds or the timeout passes.
template <class F>
bool wait_until(F done, std::chrono::milliseconds timeout) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return done();
}

}  // namespace ve::test
