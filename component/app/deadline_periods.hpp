// Counting deadline misses the way the QoS defines them.
//
// Fast DDS 2.9 arms a writer's or reader's deadline timer for the whole milliseconds
// left until the instance's next deadline, and re-arms it for another period (again
// truncated) each time it fires. So a 5 ms deadline is reported after a little over
// 4 ms without a sample (measured: silences of 3.5 ms never, 3.9 ms half the time,
// 4.1 ms and more always), and during a long silence every ~4 ms instead of every 5.
// Fast DDS's own status counts those reports. The product counts what a deadline
// means: whole periods that passed without a sample on the instance, looked at when
// Fast DDS reports. Reports that add no whole period (the first one after ~4 ms, and
// during a long silence the one in five that falls in a period already counted) are
// counted apart as early reports, so nothing is hidden.
#pragma once

#include <cstdint>
#include <limits>

namespace ve::app {

/// For one instance; used only from the thread that delivers the deadline reports.
class DeadlinePeriods {
 public:
  /// A report at now_ns (steady clock) for an instance whose last sample was at
  /// last_sample_ns: returns the whole periods newly missed since that sample (0: an
  /// early report, or one whose periods were already counted).
  std::uint64_t on_report(std::int64_t last_sample_ns, std::int64_t now_ns, std::int64_t period_ns) {
    if (last_sample_ns != silence_of_) {
      silence_of_ = last_sample_ns;
      counted_ = 0;
    }
    if (period_ns <= 0 || now_ns <= last_sample_ns) return 0;
    const auto periods = static_cast<std::uint64_t>((now_ns - last_sample_ns) / period_ns);
    if (periods <= counted_) return 0;
    const std::uint64_t added = periods - counted_;
    counted_ = periods;
    return added;
  }

 private:
  std::int64_t silence_of_ = std::numeric_limits<std::int64_t>::min();
  std::uint64_t counted_ = 0;
};

}  // namespace ve::app
