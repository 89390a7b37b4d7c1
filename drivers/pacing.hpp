// Real-time pacing shared by the sources that replay or simulate a clock: sample
// n is handed out no earlier than its offset after the first one, on
// CLOCK_MONOTONIC, without drift (a late caller catches up without sleeping).
#pragma once

#include <atomic>
#include <cstdint>
#include <string>

namespace ve::drivers {

/// CLOCK_MONOTONIC [ns].
std::int64_t monotonic_ns();

/// CLOCK_REALTIME [ns].
std::int64_t realtime_ns();

/// "HH:MM:SS.uuuuuu": the local time of day of a CLOCK_REALTIME instant, to the
/// microsecond. What logs of different processes are lined up on (the monitor's
/// gaps, the plant test's probes of the host's stalls).
std::string time_of_day_us(std::int64_t realtime_ns);

/// Sleeps until `due_ns` on CLOCK_MONOTONIC, in slices of at most 2 ms so that
/// `stop` is noticed promptly. False when stopped.
bool sleep_until(std::int64_t due_ns, const std::atomic<bool>& stop);

}  // namespace ve::drivers
