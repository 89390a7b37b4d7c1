// Whether this build runs the product at its real speed, for the integration tests
// that check real-time figures of the 4 kHz stream.
//
// Under a sanitizer every memory access is instrumented: ThreadSanitizer makes the
// product and the test process 5 to 15 times slower, AddressSanitizer about 2 times,
// and on a shared host (two test suites at once, a build beside them) that is enough
// for a 4 kHz axis to miss its rate now and then, so rates, losses, pauses and
// promptness would measure the sanitizer and the host, not the product. In those
// builds the same tests still run every step and check every behaviour (what arrives,
// in which order, with which values and flags; that a stall raises a deadline miss;
// that an abort stops a calibration; that the stream goes on), waiting up to
// kSlowdown times longer for each; the real-time figures are printed but not judged
// there. They are judged, with unchanged bounds, in the plain build.
#pragma once

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>

namespace ve::test {

#if defined(__SANITIZE_THREAD__)  // gcc
#define VE_TEST_UNDER_TSAN 1
#elif defined(__has_feature)  // clang
#if __has_feature(thread_sanitizer)
#define VE_TEST_UNDER_TSAN 1
#endif
#endif

#if defined(__SANITIZE_ADDRESS__)  // gcc
#define VE_TEST_UNDER_ASAN 1
#elif defined(__has_feature)  // clang
#if __has_feature(address_sanitizer)
#define VE_TEST_UNDER_ASAN 1
#endif
#endif

#if defined(VE_TEST_UNDER_TSAN)
inline constexpr bool kRealTimeFigures = false;
inline constexpr int kSlowdown = 10;
#elif defined(VE_TEST_UNDER_ASAN)
inline constexpr bool kRealTimeFigures = false;
inline constexpr int kSlowdown = 3;
#else
inline constexpr bool kRealTimeFigures = true;
inline constexpr int kSlowdown = 1;
#endif

/// A wait limit for this build: `t` at real speed, kSlowdown times `t` under a sanitizer.
constexpr std::chrono::milliseconds patience(std::chrono::milliseconds t) { return t * kSlowdown; }

/// Held by a test, from its start to its end, when what it judges depends on getting
/// the CPU it needs: the real-time figures of the 4 kHz stream (plain build), and the
/// comparisons between axes or windows of one stream (every build: a stalled axis against
/// its neighbours, which a starved host stalls too). Such tests take turns on this host,
/// across test runs and builds (ctest's RUN_SERIAL does it within one run), so that two
/// suites run at once do not starve each other's streams. An exclusive flock(2) on
/// /tmp/ve-test-real-time.lock, waited for; the test's children inherit it and the kernel
/// frees it when the last of them has ended.
class RealTimeSlot {
 public:
  RealTimeSlot() {
    fd_ = ::open("/tmp/ve-test-real-time.lock", O_RDONLY | O_CREAT, 0666);
    if (fd_ < 0) return;
    ::fchmod(fd_, 0666);
    if (::flock(fd_, LOCK_EX | LOCK_NB) == 0) return;
    std::printf("[ note     ] waiting for another test run's real-time test to end\n");
    std::fflush(stdout);
    while (::flock(fd_, LOCK_EX) != 0 && errno == EINTR) {
    }
  }
  ~RealTimeSlot() {
    if (fd_ >= 0) ::close(fd_);
  }
  RealTimeSlot(const RealTimeSlot&) = delete;
  RealTimeSlot& operator=(const RealTimeSlot&) = delete;

 private:
  int fd_ = -1;
};

}  // namespace ve::test
