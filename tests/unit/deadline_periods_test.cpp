#include "app/deadline_periods.hpp"

#include <gtest/gtest.h>

using ve::app::DeadlinePeriods;

namespace {
constexpr std::int64_t ms = 1000000;
}

TEST(DeadlinePeriods, AReportBeforeAWholePeriodIsNotAMiss) {
  DeadlinePeriods d;
  // Fast DDS 2.9 reports a 5 ms deadline after ~4 ms of silence.
  EXPECT_EQ(d.on_report(100 * ms, 104 * ms + ms / 10, 5 * ms), 0u);
  EXPECT_EQ(d.on_report(100 * ms, 104 * ms + 999999, 5 * ms), 0u);
}

TEST(DeadlinePeriods, ALongSilenceCountsItsWholePeriodsOnce) {
  DeadlinePeriods d;
  const std::int64_t last = 100 * ms;
  // Reports every ~4 ms (Fast DDS re-arms for the truncated period) during a 1 s silence.
  std::uint64_t total = 0;
  for (std::int64_t t = last + 4 * ms; t <= last + 1000 * ms; t += 4 * ms) total += d.on_report(last, t, 5 * ms);
  EXPECT_EQ(total, 200u);
  // The same report again adds nothing.
  EXPECT_EQ(d.on_report(last, last + 1000 * ms, 5 * ms), 0u);
}

TEST(DeadlinePeriods, ALateReportCountsEveryPeriodItCovers) {
  DeadlinePeriods d;
  EXPECT_EQ(d.on_report(0, 23 * ms, 5 * ms), 4u);
  EXPECT_EQ(d.on_report(0, 24 * ms, 5 * ms), 0u);
  EXPECT_EQ(d.on_report(0, 25 * ms, 5 * ms), 1u);
}

TEST(DeadlinePeriods, ANewSampleStartsANewSilence) {
  DeadlinePeriods d;
  EXPECT_EQ(d.on_report(0, 12 * ms, 5 * ms), 2u);
  // A sample at 13 ms, then a report 5.5 ms later: one more period, counted from 13 ms.
  EXPECT_EQ(d.on_report(13 * ms, 18 * ms + ms / 2, 5 * ms), 1u);
  // A report for a sample older than now but within a period: nothing.
  EXPECT_EQ(d.on_report(20 * ms, 24 * ms, 5 * ms), 0u);
}

TEST(DeadlinePeriods, NoPeriodOrAClockThatWentBackCountsNothing) {
  DeadlinePeriods d;
  EXPECT_EQ(d.on_report(10 * ms, 100 * ms, 0), 0u);
  EXPECT_EQ(d.on_report(10 * ms, 5 * ms, 5 * ms), 0u);
}
