// The pacing floor: threads that only wake at a fixed rate, paced exactly as the
// product's sample threads are (ve::drivers::sleep_until on CLOCK_MONOTONIC, from
// drivers/pacing.hpp), doing nothing else. What waking up costs on this host before any
// work is done. Used by the scale benchmark (tests/plant/scale_bench.cpp).
//
//   ve_pace_floor [--rate HZ] [--threads N] [--duration S] [--stall-ms MS]
//
// Defaults: 4000 Hz, 1 thread, until SIGINT/SIGTERM (duration 0), stalls of 4 ms.
// Prints "READY" once the threads run, and at the end
//   END wakeups=W late=L stalls=S max_late_us=M
// preceded by one line per stall (the first 4096 of each thread), in the order found:
//   STALL HH:MM:SS.uuuuuu LATE_US
// the local time of day at which the thread was due, and how late it woke: the interval
// the host held it, to line up with other logs (the monitor's gaps) in time.
// L: wake-ups that found their next due time already past; S: wake-ups at least MS after
// their due time (the thread was kept from running that long: as a probe run at a real-time
// priority, the host's stalls; tests/plant/discovery_server_test.sh); M: the latest one.
#include <csignal>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "pacing.hpp"  // drivers/pacing.hpp

namespace {
std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop.store(true); }
}  // namespace

int main(int argc, char** argv) {
  double rate = 4000.0, duration = 0.0;
  int threads = 1;
  double stall_ms = 4.0;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    if (k == "--rate") rate = std::atof(argv[i + 1]);
    else if (k == "--threads") threads = std::atoi(argv[i + 1]);
    else if (k == "--duration") duration = std::atof(argv[i + 1]);
    else if (k == "--stall-ms") stall_ms = std::atof(argv[i + 1]);
    else {
      std::fprintf(stderr, "usage: ve_pace_floor [--rate HZ] [--threads N] [--duration S] [--stall-ms MS]\n");
      return 2;
    }
  }
  if (rate <= 0 || threads < 1) return 2;
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  const auto period_ns = static_cast<std::int64_t>(1e9 / rate);
  const auto stall_ns = static_cast<std::int64_t>(stall_ms * 1e6);
  std::atomic<std::uint64_t> wakeups{0}, late{0}, stalls{0};
  std::atomic<std::int64_t> max_late_ns{0};
  struct Stall {
    std::int64_t due_realtime_ns;
    std::int64_t late_ns;
  };
  constexpr std::size_t kStallsKept = 4096;
  std::vector<std::vector<Stall>> stall_log(static_cast<std::size_t>(threads));
  for (auto& l : stall_log) l.reserve(kStallsKept);  // nothing allocated while pacing
  std::vector<std::thread> pool;
  for (int t = 0; t < threads; ++t)
    pool.emplace_back([&, t] {
      auto& log = stall_log[static_cast<std::size_t>(t)];
      std::int64_t due = ve::drivers::monotonic_ns();
      std::uint64_t n = 0, l = 0, st = 0;
      std::int64_t worst = 0;
      while (!g_stop.load(std::memory_order_relaxed)) {
        due += period_ns;
        if (!ve::drivers::sleep_until(due, g_stop)) break;
        ++n;
        const std::int64_t lateness = ve::drivers::monotonic_ns() - due;
        if (lateness > period_ns) ++l;
        if (lateness >= stall_ns) {
          ++st;
          if (log.size() < kStallsKept) log.push_back({ve::drivers::realtime_ns() - lateness, lateness});
        }
        if (lateness > worst) worst = lateness;
      }
      wakeups += n;
      late += l;
      stalls += st;
      std::int64_t m = max_late_ns.load();
      while (worst > m && !max_late_ns.compare_exchange_weak(m, worst)) {
      }
    });
  std::printf("READY\n");
  std::fflush(stdout);
  const std::int64_t end = duration > 0 ? ve::drivers::monotonic_ns() + static_cast<std::int64_t>(duration * 1e9) : 0;
  while (!g_stop.load()) {
    if (end != 0 && ve::drivers::monotonic_ns() >= end) g_stop.store(true);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  for (auto& t : pool) t.join();
  for (const auto& l : stall_log)
    for (const auto& st : l)
      std::printf("STALL %s %lld\n", ve::drivers::time_of_day_us(st.due_realtime_ns).c_str(),
                  static_cast<long long>(st.late_ns / 1000));
  std::printf("END wakeups=%llu late=%llu stalls=%llu max_late_us=%lld\n",
              static_cast<unsigned long long>(wakeups.load()), static_cast<unsigned long long>(late.load()),
              static_cast<unsigned long long>(stalls.load()), static_cast<long long>(max_late_ns.load() / 1000));
  return 0;
}
