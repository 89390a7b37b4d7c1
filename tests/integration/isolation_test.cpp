// What keeps the integration tests apart (docs/testing.md), checked: a test's DDS
// domains are its own on this host, its children hold them with it, and every process
// it starts ends with it: with the ChildProcess, with what the child started, and
// with the test process when that dies without running a destructor.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
using ve::test::ChildProcess;
using ve::test::patience;
using ve::test::TempDir;
using ve::test::wait_until;

std::string lock_path(int domain) { return std::string(ve::test::kDomainLockDir) + "/" + std::to_string(domain) + ".lock"; }

/// Whether another open file description can take the domain's lock now.
bool lock_free(int domain) {
  const int fd = ::open(lock_path(domain).c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return true;
  const bool got = ::flock(fd, LOCK_EX | LOCK_NB) == 0;
  ::close(fd);
  return got;
}

/// Whether a process with this pid exists and is not a zombie.
bool alive(pid_t pid) {
  const std::string stat = ve::test::read_file("/proc/" + std::to_string(pid) + "/stat");
  if (stat.empty()) return false;
  const auto p = stat.rfind(')');
  return p != std::string::npos && p + 2 < stat.size() && stat[p + 2] != 'Z';
}

pid_t read_pid(const std::string& path) {
  const std::string text = ve::test::read_file(path);
  return text.empty() ? -1 : static_cast<pid_t>(std::atol(text.c_str()));
}

/// The first domain of the first test, when the tests run in one process.
int g_first_test_domain = -1;

/// How many of this process' descriptors are open on the domain's lock file.
int open_lock_descriptors(int domain) {
  int n = 0;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator("/proc/self/fd", ec)) {
    std::error_code ec2;
    n += std::filesystem::read_symlink(e.path(), ec2).string() == lock_path(domain);
  }
  return n;
}

TEST(TestIsolation, DomainsAreHeldForTheTestAndItsChildren) {
  const int a = ve::test::dds_domain();
  g_first_test_domain = a;
  const int b = ve::test::dds_domain(1);
  EXPECT_NE(a, b);
  EXPECT_EQ(ve::test::dds_domain(), a) << "the same domain on every call in one test";
  for (int d : {a, b}) {
    EXPECT_GE(d, 0);
    EXPECT_LE(d, 232);
    EXPECT_FALSE(lock_free(d)) << "domain " << d << " is not reserved";
  }
  // A child holds the lock with the test: flock(1) in it cannot take it either.
  TempDir dir;
  ChildProcess probe({"/usr/bin/flock", "-n", lock_path(a), "true"}, (dir.path / "flock.log").string());
  ASSERT_TRUE(probe.started());
  EXPECT_EQ(probe.wait_exit(patience(10s)), 1) << "another process took domain " << a << "'s lock: " << probe.log();
}

TEST(TestIsolation, ALaterTestGetsItsOwnDomainAndTheEarlierOnesAreFreed) {
  // When the binary runs the tests one after the other in one process, the test before
  // this one gave its domains back: this process keeps no descriptor of their locks.
  const int d = ve::test::dds_domain();
  EXPECT_FALSE(lock_free(d));
  if (g_first_test_domain < 0) return;  // run in a process of its own: nothing earlier to give back
  EXPECT_EQ(open_lock_descriptors(g_first_test_domain), 0) << "domain " << g_first_test_domain << " still held";
  EXPECT_EQ(open_lock_descriptors(d), 1);
}

TEST(TestIsolation, TheChildsProcessGroupEndsWithIt) {
  TempDir dir;
  const std::string pid_file = (dir.path / "grandchild.pid").string();
  pid_t grandchild = -1;
  {
    ChildProcess sh({"/bin/sh", "-c", "sleep 300 & echo $! > '" + pid_file + "'; wait"},
                    (dir.path / "sh.log").string());
    ASSERT_TRUE(sh.started());
    ASSERT_TRUE(wait_until([&] { return read_pid(pid_file) > 0; }, patience(10s)));
    grandchild = read_pid(pid_file);
    ASSERT_TRUE(alive(grandchild));
    EXPECT_EQ(getpgid(grandchild), sh.pid()) << "the child leads a process group of its own, with what it starts";
  }  // the destructor
  EXPECT_TRUE(wait_until([&] { return !alive(grandchild); }, patience(10s)))
      << "a process the child started outlived it: " << grandchild;
}

TEST(TestIsolation, WhatAnExitedChildLeftBehindIsEndedWhenItIsReaped) {
  TempDir dir;
  const std::string pid_file = (dir.path / "grandchild.pid").string();
  ChildProcess sh({"/bin/sh", "-c", "sleep 300 & echo $! > '" + pid_file + "'; exit 3"}, (dir.path / "sh.log").string());
  ASSERT_TRUE(sh.started());
  EXPECT_EQ(sh.wait_exit(patience(10s)), 3);
  const pid_t grandchild = read_pid(pid_file);
  ASSERT_GT(grandchild, 0);
  EXPECT_TRUE(wait_until([&] { return !alive(grandchild); }, patience(10s)))
      << "a process the child started outlived it: " << grandchild;
}

TEST(TestIsolation, ChildrenDieWithATestProcessThatDiesWithoutCleaningUp) {
  TempDir dir;
  const std::string pid_file = (dir.path / "child.pid").string();
  // A stand-in for a test process that crashes: it starts a child, then ends at once
  // without running a destructor (as after SIGKILL, SIGSEGV or abort()).
  const pid_t test_process = fork();
  ASSERT_GE(test_process, 0);
  if (test_process == 0) {
    ChildProcess* child = new ChildProcess({"/bin/sleep", "300"}, "/dev/null");
    FILE* f = std::fopen(pid_file.c_str(), "w");
    if (f != nullptr) {
      std::fprintf(f, "%d\n", static_cast<int>(child->pid()));
      std::fclose(f);
    }
    _exit(0);
  }
  int st = 0;
  ASSERT_EQ(waitpid(test_process, &st, 0), test_process);
  const pid_t child = read_pid(pid_file);
  ASSERT_GT(child, 0);
  EXPECT_TRUE(wait_until([&] { return !alive(child); }, patience(10s)))
      << "the child of a dead test process is still running: " << child;
  if (alive(child)) kill(child, SIGKILL);
}

TEST(TestIsolation, AProgramThatCannotBeStartedIsNotStarted) {
  TempDir dir;
  ChildProcess p({(dir.path / "no-such-program").string()}, (dir.path / "log").string());
  EXPECT_FALSE(p.started());
  EXPECT_EQ(p.wait_exit(1s), -1);
}

}  // namespace
