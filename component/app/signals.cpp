#include "signals.hpp"

#include <pthread.h>
#include <signal.h>

#include <cerrno>
#include <cmath>
#include <ctime>

namespace ve::app {

namespace {
sigset_t termination_set() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGTERM);
  return set;
}
}  // namespace

void block_termination_signals() {
  const sigset_t set = termination_set();
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
}

bool wait_for_termination(double timeout_s) {
  const sigset_t set = termination_set();
  timespec ts;
  ts.tv_sec = static_cast<time_t>(std::floor(timeout_s));
  ts.tv_nsec = static_cast<long>((timeout_s - std::floor(timeout_s)) * 1e9);
  for (;;) {
    const int sig = sigtimedwait(&set, nullptr, &ts);
    if (sig == SIGINT || sig == SIGTERM) return true;
    if (sig < 0 && errno == EINTR) continue;
    return false;
  }
}

}  // namespace ve::app
