#include "pacing.hpp"

#include <time.h>

#include <algorithm>
#include <cstdio>
#include <ctime>

namespace ve::drivers {

std::int64_t monotonic_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

std::int64_t realtime_ns() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

std::string time_of_day_us(std::int64_t realtime_ns) {
  const std::time_t secs = static_cast<std::time_t>(realtime_ns / 1000000000LL);
  std::tm tm{};
  localtime_r(&secs, &tm);
  char text[32];
  std::snprintf(text, sizeof text, "%02d:%02d:%02d.%06lld", tm.tm_hour, tm.tm_min, tm.tm_sec,
                static_cast<long long>(realtime_ns % 1000000000LL / 1000));
  return text;
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
