// When does Fast DDS 2.9 report an offered deadline, and what does the product count?
//
// The product's StateWriter (offered deadline D, default 5 ms) writes at 4 kHz, then goes
// quiet on purpose for a chosen time, N times per length, and writes on. Printed per
// length: the silence as measured, Fast DDS's reports that added no whole period (early
// reports) and the whole periods the product counted (app/deadline_periods.hpp). A host
// that stretches a silence past D makes a real miss; compare with the measured range.
// Not a ctest test; no assertions.
//
//   bench_deadline_reports [DEADLINE_MS] [REPEATS]      (DDS domain 95, no subscriber needed)
#include <time.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "VirtualEncoder.h"
#include "app/dds_io.hpp"

namespace {
std::int64_t mono_ns() {
  timespec t{};
  clock_gettime(CLOCK_MONOTONIC, &t);
  return static_cast<std::int64_t>(t.tv_sec) * 1000000000 + t.tv_nsec;
}
void sleep_until_ns(std::int64_t t) {
  timespec ts{static_cast<time_t>(t / 1000000000), static_cast<long>(t % 1000000000)};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) != 0) {
  }
}
}  // namespace

int main(int argc, char** argv) {
  const double deadline_ms = argc > 1 ? std::atof(argv[1]) : 5.0;
  const int repeats = argc > 2 ? std::max(1, std::atoi(argv[2])) : 20;
  ve::app::DdsOptions o;
  o.domain = 95;
  std::string error;
  auto ctx = ve::app::DdsContext::create(o, error);
  if (!ctx) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return 1;
  }
  ve::app::StateWriter writer(*ctx, deadline_ms);
  const int slot = writer.add_axis(1, "x");
  if (!writer.ok() || slot < 0) {
    std::fprintf(stderr, "cannot create the writer\n");
    return 1;
  }
  ve::dds::EncoderState s;
  s.axis_id(1);
  std::uint64_t seq = 0;
  auto write = [&] {
    s.sequence_number(++seq);
    writer.write(slot, s);
  };
  auto burst = [&](int n) {  // n samples at 4 kHz
    std::int64_t t = mono_ns();
    for (int i = 0; i < n; ++i) {
      t += 250000;
      sleep_until_ns(t);
      write();
    }
  };
  burst(400);
  std::printf("offered deadline %.1f ms, %d silences per length\n\n", deadline_ms, repeats);
  std::printf("| silence asked [ms] | measured min..max [ms] | early reports | periods counted |\n|---|---|---|---|\n");
  const double f = deadline_ms / 5.0;
  for (double silence : {2.5 * f, 3.5 * f, 3.9 * f, 4.1 * f, 4.3 * f, 4.6 * f, 4.9 * f, 5.2 * f, 5.6 * f, 6.5 * f}) {
    double lo = 1e9, hi = 0;
    const auto missed0 = writer.deadline_missed_total(), early0 = writer.deadline_early_reports();
    for (int k = 0; k < repeats; ++k) {
      burst(40);
      const std::int64_t t0 = mono_ns();
      sleep_until_ns(t0 + static_cast<std::int64_t>(silence * 1e6));
      write();
      const double measured = (mono_ns() - t0) * 1e-6;
      lo = std::min(lo, measured);
      hi = std::max(hi, measured);
    }
    burst(40);  // lets a late report arrive before the counts are read
    std::printf("| %.1f | %.2f..%.2f | %llu | %llu |\n", silence, lo, hi,
                static_cast<unsigned long long>(writer.deadline_early_reports() - early0),
                static_cast<unsigned long long>(writer.deadline_missed_total() - missed0));
  }
  return 0;
}
