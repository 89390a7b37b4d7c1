#include "signals.hpp"

#include <pthread.h>
#include <signal.h>
#include <string.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <ctime>
#include <mutex>
#include <string>
#include <thread>

#include "config/atomic_file.hpp"

namespace ve::app {

namespace {

/// How long a subcommand may go without taking notice of a signal.
constexpr double kGraceS = 0.5;
/// How long a clean stop that took notice may take.
constexpr double kCleanStopS = 10.0;

sigset_t termination_set() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  return set;
}

timespec to_timespec(double s) {
  if (!(s > 0.0)) s = 0.0;
  timespec ts;
  ts.tv_sec = static_cast<time_t>(std::floor(s));
  ts.tv_nsec = static_cast<long>((s - std::floor(s)) * 1e9);
  return ts;
}

std::atomic<int> g_signal{0};
std::atomic<bool> g_noticed{false};
std::atomic<bool> g_flag{false};
std::atomic<bool> g_watcher{false};

// Never destroyed: the watcher may still use them while the main thread exits.
std::mutex& wake_mutex() {
  static auto* m = new std::mutex;
  return *m;
}
std::condition_variable& wake_cv() {
  static auto* cv = new std::condition_variable;
  return *cv;
}

std::mutex& callback_mutex() {
  static auto* m = new std::mutex;
  return *m;
}
std::function<void()>& callback() {
  static auto* f = new std::function<void()>;
  return *f;
}

/// Ends the process now: temporaries removed, the signal named, 128 + signal.
[[noreturn]] void force_exit(int sig) {
  const std::size_t removed = config::remove_scratch_files_for_exit();
  std::string msg = std::string("virtual-encoder: ") + (sig == SIGINT ? "SIGINT" : "SIGTERM") +
                    ": interrupted; unfinished output removed (" + std::to_string(removed) + " temporary file(s))\n";
  if (::write(STDERR_FILENO, msg.data(), msg.size()) < 0) {
    // nothing more to say
  }
  ::_exit(128 + sig);
}

/// Waits up to `s` seconds for another termination signal; true when one came.
bool another_signal_within(const sigset_t& set, double s) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(s);
  for (;;) {
    const double left = std::chrono::duration<double>(until - std::chrono::steady_clock::now()).count();
    if (left <= 0.0) return false;
    const timespec ts = to_timespec(left);
    const int sig = sigtimedwait(&set, nullptr, &ts);
    if (sig == SIGINT || sig == SIGTERM) return true;
    if (sig < 0 && errno != EINTR && errno != EAGAIN) return false;
  }
}

void watch() {
  const sigset_t set = termination_set();
  int sig = 0;
  while (sigwait(&set, &sig) != 0 || (sig != SIGINT && sig != SIGTERM)) {
  }
  {
    std::lock_guard<std::mutex> lock(wake_mutex());
    g_signal.store(sig);
    g_flag.store(true);
  }
  wake_cv().notify_all();
  {
    std::lock_guard<std::mutex> lock(callback_mutex());
    if (callback()) callback()();
  }
  // A second signal ends the process at once; so does silence past the grace period.
  if (another_signal_within(set, kGraceS)) force_exit(sig);
  if (!g_noticed.load()) force_exit(sig);
  another_signal_within(set, kCleanStopS);
  force_exit(sig);
}

}  // namespace

void block_termination_signals() {
  const sigset_t set = termination_set();
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
}

void start_termination_watcher() {
  bool expected = false;
  if (!g_watcher.compare_exchange_strong(expected, true)) return;
  std::thread(watch).detach();
}

bool termination_requested() {
  if (g_signal.load(std::memory_order_relaxed) == 0) return false;
  g_noticed.store(true);
  return true;
}

const std::atomic<bool>& termination_flag() { return g_flag; }

TerminationCallback::TerminationCallback(std::function<void()> wake) {
  std::lock_guard<std::mutex> lock(callback_mutex());
  callback() = std::move(wake);
  if (g_flag.load() && callback()) callback()();  // the signal came first
}

TerminationCallback::~TerminationCallback() {
  std::lock_guard<std::mutex> lock(callback_mutex());
  callback() = nullptr;
}

int termination_signal() { return g_signal.load(); }

int interrupted_exit_code() {
  const int sig = g_signal.load();
  return 128 + (sig != 0 ? sig : SIGINT);
}

bool wait_for_termination(double timeout_s) {
  if (g_watcher.load()) {
    if (termination_requested()) return true;
    if (!(timeout_s > 0.0)) return false;
    std::unique_lock<std::mutex> lock(wake_mutex());
    wake_cv().wait_for(lock, std::chrono::duration<double>(std::min(timeout_s, 1e6)),
                       [] { return g_signal.load() != 0; });
    lock.unlock();
    return termination_requested();
  }
  if (termination_requested()) return true;
  const sigset_t set = termination_set();
  const timespec ts = to_timespec(timeout_s);
  for (;;) {
    const int sig = sigtimedwait(&set, nullptr, &ts);
    if (sig == SIGINT || sig == SIGTERM) {
      g_signal.store(sig);
      g_flag.store(true);
      g_noticed.store(true);
      return true;
    }
    if (sig < 0 && errno == EINTR) continue;
    return false;
  }
}

}  // namespace ve::app
