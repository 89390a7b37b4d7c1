#include "pacing.hpp"

#include <time.h>

#include <algorithm>

namespace ve::drivers {

std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

bool sleep_until(std::int64_t due_ns, const std::atomic<bool>& stop) {
  constexpr std::int64_t kSlice = 2000000;  // [ns]
  for (;;) {
    if (stop.load(std::memory_order_relaxed)) return false;
    const std::int64_t now = monotonic_ns();
    if (now >= due_ns) return true;
    const std::int64_t until = std::min(due_ns, now + kSlice);
    timespec ts{};
    ts.tv_sec = static_cast<time_t>(until / 1000000000LL);
    ts.tv_nsec = static_cast<long>(until % 1000000000LL);
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr);  // EINTR: the loop re-checks
  }
}

}  // namespace ve::drivers
