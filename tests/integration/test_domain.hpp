// DDS domain ids for tests: one no other test process on this host holds.
//
// No test uses a fixed domain. Each takes its ids from ve::test::dds_domain(), which
// reserves them in a pool shared by every test run on the host (two build trees, the
// sanitizer builds and the plain one, two people's suites started at once), so two
// runs never meet on a domain however their tests interleave:
//  - a domain d is held by an exclusive flock(2) on /tmp/ve-test-dds-domains/d.lock,
//    taken without waiting on the first free one from a random starting point in the
//    pool (spreading use over the pool);
//  - the lock is on a file description the test's child processes inherit (it is not
//    close-on-exec), so d stays taken while any process a test started may still be
//    on it, and the kernel frees it when the last of them has gone: also when the test
//    crashes, aborts or is killed by ctest's timeout;
//  - the lock is released when a later test of the same process asks for a domain
//    (running the test binary directly runs many tests in one process), and a domain
//    is never handed out twice within one test;
//  - whoever takes d next finds no process of an earlier holder alive, so the Fast
//    DDS shared-memory port files of d's ports left in /dev/shm by a killed process
//    (fastrtps_portP, its _el/_sl locks, sem.fastrtps_portP_mutex) are stale by
//    construction and removed before d is used: a crash in one run cannot trouble
//    the next one that draws the same domain.
// The pool is 1-60: domain 0 is the product's default (an encoder started by hand),
// and a domain's ports (7400 + 250 d + ...) stay below Linux's ephemeral port range
// (32768-) up to d = 101; 61-101 is left to benchmarks and hand-run experiments.
// VE_TEST_DDS_DOMAINS="FIRST-LAST" (0 <= FIRST <= LAST <= 232) names another pool.
// Programs that run outside a test process take part through the same lock files
// (tests/dds_domain.sh for shell scripts; `flock -n /tmp/ve-test-dds-domains/D.lock CMD`
// keeps a domain for a command run by hand). Tests set no explicit ports: every port is
// derived from the domain, so distinct domains mean distinct ports.
#pragma once

#include <dirent.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace ve::test {

inline constexpr const char* kDomainLockDir = "/tmp/ve-test-dds-domains";

namespace detail {

struct DomainPool {
  int first = 1, last = 60;
};

inline DomainPool domain_pool() {
  DomainPool p;
  const char* env = std::getenv("VE_TEST_DDS_DOMAINS");
  if (env == nullptr || *env == '\0') return p;
  int a = -1, b = -1;
  char tail = 0;
  if (std::sscanf(env, "%d-%d%c", &a, &b, &tail) != 2 || a < 0 || b < a || b > 232)
    throw std::runtime_error(std::string("VE_TEST_DDS_DOMAINS='") + env +
                             "': expected FIRST-LAST with 0 <= FIRST <= LAST <= 232");
  p.first = a;
  p.last = b;
  return p;
}

/// Removes the shared-memory port files of domain `d`'s ports (7400 + 250 d ...
/// 7649 + 250 d) from /dev/shm. Only called with d's lock held: no process that
/// could use them is alive.
inline void remove_stale_shm_ports(int d) {
  const long lo = 7400L + 250L * d, hi = lo + 250;
  DIR* dir = opendir("/dev/shm");
  if (dir == nullptr) return;
  std::vector<std::string> stale;
  while (const dirent* e = readdir(dir)) {
    std::string name = e->d_name;
    std::string rest;
    if (name.rfind("fastrtps_port", 0) == 0)
      rest = name.substr(13);
    else if (name.rfind("sem.fastrtps_port", 0) == 0)
      rest = name.substr(17);
    else
      continue;
    std::size_t digits = 0;
    while (digits < rest.size() && digits < 6 && rest[digits] >= '0' && rest[digits] <= '9') ++digits;
    if (digits == 0) continue;
    const std::string suffix = rest.substr(digits);
    if (!(suffix.empty() || suffix == "_el" || suffix == "_sl" || suffix == "_mutex")) continue;
    const long port = std::stol(rest.substr(0, digits));
    if (port >= lo && port < hi) stale.push_back("/dev/shm/" + name);
  }
  closedir(dir);
  for (const auto& f : stale) ::unlink(f.c_str());
}

/// Takes the lock of a free domain in the pool, waiting up to `patience` for one;
/// returns the domain and the lock's descriptor, or throws saying why not.
inline std::pair<int, int> reserve_domain(const std::vector<int>& not_these, std::chrono::seconds patience) {
  const DomainPool pool = domain_pool();
  if (::mkdir(kDomainLockDir, 01777) == 0) ::chmod(kDomainLockDir, 01777);  // every user's tests share it
  const int size = pool.last - pool.first + 1;
  const unsigned seed = static_cast<unsigned>(::getpid()) * 2654435761u ^
                        static_cast<unsigned>(std::chrono::steady_clock::now().time_since_epoch().count());
  const auto give_up = std::chrono::steady_clock::now() + patience;
  std::string last_error;
  for (;;) {
    const int start = static_cast<int>(seed % static_cast<unsigned>(size));
    for (int i = 0; i < size; ++i) {
      const int d = pool.first + (start + i) % size;
      bool mine = false;
      for (int n : not_these) mine = mine || n == d;
      if (mine) continue;
      const std::string path = std::string(kDomainLockDir) + "/" + std::to_string(d) + ".lock";
      // Not O_CLOEXEC: the test's children inherit the lock (see the header comment).
      const int fd = ::open(path.c_str(), O_RDONLY | O_CREAT, 0666);
      if (fd < 0) {
        last_error = path + ": " + std::strerror(errno);
        continue;
      }
      if (::flock(fd, LOCK_EX | LOCK_NB) == 0) {
        ::fchmod(fd, 0666);  // another user's tests may take it later (fails harmlessly if not ours)
        remove_stale_shm_ports(d);
        std::printf("[ domain   ] DDS domain %d (pool %d-%d, %s)\n", d, pool.first, pool.last, path.c_str());
        std::fflush(stdout);
        return {d, fd};
      }
      ::close(fd);
    }
    if (std::chrono::steady_clock::now() >= give_up) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  throw std::runtime_error("no free DDS domain for this test in " + std::to_string(pool.first) + "-" +
                           std::to_string(pool.last) + " (locks in " + kDomainLockDir + ")" +
                           (last_error.empty() ? std::string() : ": " + last_error));
}

struct HeldDomains {
  std::string test;                     ///< the test they were taken for
  std::vector<std::pair<int, int>> held;  ///< (domain, lock descriptor), in order of index
  ~HeldDomains() { release(); }
  void release() {
    for (const auto& h : held) ::close(h.second);
    held.clear();
  }
};

inline HeldDomains& held_domains() {
  static HeldDomains h;
  return h;
}

inline std::string current_test_name() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  return info == nullptr ? std::string("(no test)") : std::string(info->test_suite_name()) + "." + info->name();
}

}  // namespace detail

/// The `index`-th DDS domain of the running test (0, 1, ...): reserved for it on
/// this host on first use, the same id on every later call in the same test.
/// A test process started by another one that holds its domains for it (the SocketCAN
/// VM's guest, whose /tmp and /dev/shm are not the host's) is given them in
/// VE_TEST_DDS_DOMAINS_HELD="D0,D1,...".
inline int dds_domain(int index = 0) {
  if (const char* given = std::getenv("VE_TEST_DDS_DOMAINS_HELD")) {
    std::vector<int> ids;
    for (const char* p = given; *p != '\0';) {
      char* end = nullptr;
      const long v = std::strtol(p, &end, 10);
      if (end == p || v < 0 || v > 232) break;
      ids.push_back(static_cast<int>(v));
      p = *end == ',' ? end + 1 : end;
    }
    if (index >= static_cast<int>(ids.size()))
      throw std::runtime_error(std::string("VE_TEST_DDS_DOMAINS_HELD='") + given + "' names no domain " +
                               std::to_string(index));
    return ids[static_cast<std::size_t>(index)];
  }
  auto& h = detail::held_domains();
  const std::string test = detail::current_test_name();
  if (h.test != test) {
    h.release();
    h.test = test;
  }
  while (static_cast<int>(h.held.size()) <= index) {
    std::vector<int> taken;
    for (const auto& d : h.held) taken.push_back(d.first);
    h.held.push_back(detail::reserve_domain(taken, std::chrono::seconds(120)));
  }
  return h.held[static_cast<std::size_t>(index)].first;
}

}  // namespace ve::test
