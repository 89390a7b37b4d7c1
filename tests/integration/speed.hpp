// Whether this build runs the product at its real speed, for the integration tests
// that check real-time figures of the 4 kHz stream.
//
// Under ThreadSanitizer every memory access is instrumented: the product and the test
// process run 5 to 15 times slower, so a 4 kHz axis cannot keep its rate, subscribers
// fall behind it, and rates, losses, pauses and promptness measure TSan, not the
// product. In that build the same tests still run every step and check every
// behaviour (what arrives, in which order, with which values and flags; that a stall
// raises a deadline miss; that an abort stops a calibration; that the stream goes on),
// waiting up to kSlowdown times longer for each; the real-time figures are printed but
// not judged there. They are judged, with unchanged bounds, in the plain build and in
// the AddressSanitizer build (about 2x slower, where they hold).
#pragma once

#include <chrono>

namespace ve::test {

#if defined(__SANITIZE_THREAD__)  // gcc
#define VE_TEST_UNDER_TSAN 1
#elif defined(__has_feature)  // clang
#if __has_feature(thread_sanitizer)
#define VE_TEST_UNDER_TSAN 1
#endif
#endif

#if defined(VE_TEST_UNDER_TSAN)
inline constexpr bool kRealTimeFigures = false;
inline constexpr int kSlowdown = 10;
#else
inline constexpr bool kRealTimeFigures = true;
inline constexpr int kSlowdown = 1;
#endif

/// A wait limit for this build: `t` at real speed, kSlowdown times `t` under TSan.
constexpr std::chrono::milliseconds patience(std::chrono::milliseconds t) { return t * kSlowdown; }

}  // namespace ve::test
