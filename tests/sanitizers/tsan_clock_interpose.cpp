// ThreadSanitizer builds only (VE_SANITIZE=thread): CMakeLists.txt links this file into
// every executable of such a build, and into nothing else.
//
// Why: glibc 2.34+ has pthread_mutex_clocklock and pthread_rwlock_clock{rd,wr}lock, which
// libstdc++ uses for std::timed_mutex / std::recursive_timed_mutex::try_lock_until and
// std::shared_timed_mutex::try_lock{,_shared}_until on steady_clock. GCC 12's libtsan (and
// clang 14's) intercepts none of them (it does intercept pthread_cond_clockwait). Fast DDS
// takes its timed mutexes that way, from inside libfastrtps.so: TSan never sees those
// locks taken, so it reports bogus races on the data they protect and "unlock of an
// unlocked mutex" when they are released.
//
// How: the executable defines these functions. It comes first in the dynamic linker's
// lookup order, so the shared libraries' calls (libfastrtps.so's PLT) bind here rather
// than to glibc; CMakeLists.txt exports the symbols (--export-dynamic-symbol). Each turns
// its absolute deadline on the given clock into one on CLOCK_REALTIME and calls the
// CLOCK_REALTIME variant, which libtsan does intercept, so the lock is seen. The
// semantics are glibc's except that a step of the realtime clock while waiting moves the
// deadline, which does not matter to a test run.
#include <pthread.h>

#include <algorithm>
#include <cerrno>
#include <ctime>

namespace {

constexpr long kNsPerS = 1000000000L;

// abstime on `clock` -> the same instant on CLOCK_REALTIME, in *out. 0, or EINVAL as
// glibc's clock variants return it: for a clock other than these two, or a malformed time.
int to_realtime(clockid_t clock, const timespec* abstime, timespec* out) {
  if (clock == CLOCK_REALTIME) {
    *out = *abstime;  // checked by the timed variant, as by the clock variant
    return 0;
  }
  if (clock != CLOCK_MONOTONIC || abstime->tv_nsec < 0 || abstime->tv_nsec >= kNsPerS) return EINVAL;
  timespec now_clock{}, now_real{};
  clock_gettime(CLOCK_MONOTONIC, &now_clock);
  clock_gettime(CLOCK_REALTIME, &now_real);
  // now_real + (abstime - now_clock). A deadline already past stays in the past: the
  // timed variant then tries once and returns ETIMEDOUT, as the clock variant does. One
  // too far ahead to be represented (time_point::max()) saturates.
  const long long ahead_s = static_cast<long long>(abstime->tv_sec) - now_clock.tv_sec;
  constexpr long long kFar = 1LL << 40;  // some 35000 years
  if (ahead_s > kFar) {
    out->tv_sec = static_cast<time_t>(now_real.tv_sec + kFar);
    out->tv_nsec = 0;
    return 0;
  }
  long long sec = now_real.tv_sec + std::max(ahead_s, -kFar);
  long nsec = now_real.tv_nsec + (abstime->tv_nsec - now_clock.tv_nsec);  // in (-1 s, 2 s)
  if (nsec < 0) {
    nsec += kNsPerS;
    --sec;
  } else if (nsec >= kNsPerS) {
    nsec -= kNsPerS;
    ++sec;
  }
  if (sec < 0) {  // before the epoch: past all the same
    sec = 0;
    nsec = 0;
  }
  out->tv_sec = static_cast<time_t>(sec);
  out->tv_nsec = nsec;
  return 0;
}

}  // namespace

extern "C" {

int pthread_mutex_clocklock(pthread_mutex_t* mutex, clockid_t clock, const timespec* abstime) noexcept {
  timespec real{};
  if (const int rc = to_realtime(clock, abstime, &real)) return rc;
  return pthread_mutex_timedlock(mutex, &real);
}

int pthread_rwlock_clockrdlock(pthread_rwlock_t* rwlock, clockid_t clock, const timespec* abstime) noexcept {
  timespec real{};
  if (const int rc = to_realtime(clock, abstime, &real)) return rc;
  return pthread_rwlock_timedrdlock(rwlock, &real);
}

int pthread_rwlock_clockwrlock(pthread_rwlock_t* rwlock, clockid_t clock, const timespec* abstime) noexcept {
  timespec real{};
  if (const int rc = to_realtime(clock, abstime, &real)) return rc;
  return pthread_rwlock_timedwrlock(rwlock, &real);
}

}  // extern "C"
