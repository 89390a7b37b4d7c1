// systemd supervision without systemd: a datagram socket stands in for
// NOTIFY_SOCKET. `run` must say READY=1 only once it publishes, pet the watchdog
// only while its sample loop makes progress, and say STOPPING=1 on SIGTERM.
#include <gtest/gtest.h>

#include <sys/socket.h>
#include <sys/un.h>

#include <chrono>
#include <string>
#include <vector>

#include "process.hpp"

namespace {

using namespace std::chrono_literals;

struct Message {
  double t_s;
  std::string text;
};

TEST(Service, ReadyWatchdogWhileHealthyAndStopping) {
  const std::string path = "/tmp/ve_it_notify_" + std::to_string(getpid()) + ".sock";
  unlink(path.c_str());
  const int fd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::snprintf(addr.sun_path, sizeof addr.sun_path, "%s", path.c_str());
  ASSERT_EQ(bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  timeval tv{0, 50000};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);

  // Watchdog every 0.25 s (half of 0.5 s); the sample loop stalls 1.5 s after start for 1 s.
  setenv("NOTIFY_SOCKET", path.c_str(), 1);
  setenv("WATCHDOG_USEC", "500000", 1);
  setenv("VE_TEST_STALL_AXIS", "x:1.5:1.0", 1);
  ve::test::ChildProcess run({VE_BINARY, "run", "--domain", "75", "--duration", "30"}, "/tmp/ve_it_service.log");
  unsetenv("NOTIFY_SOCKET");
  unsetenv("WATCHDOG_USEC");
  unsetenv("VE_TEST_STALL_AXIS");
  ASSERT_TRUE(run.started());

  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Message> got;
  bool terminated = false;
  while (std::chrono::steady_clock::now() - t0 < 15s) {
    char buf[512];
    const ssize_t n = recv(fd, buf, sizeof buf - 1, 0);
    const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (n > 0) {
      buf[n] = '\0';
      got.push_back({t, buf});
      if (std::string(buf).find("STOPPING=1") != std::string::npos) break;
    }
    if (!terminated && t > 4.5) {
      run.signal(SIGTERM);
      terminated = true;
    }
  }
  EXPECT_EQ(run.wait_exit(10s), 0) << run.log();
  close(fd);
  unlink(path.c_str());

  ASSERT_FALSE(got.empty()) << run.log();
  EXPECT_EQ(got.front().text.rfind("READY=1", 0), 0u) << "the first message is READY=1: " << got.front().text;
  // When did the stall happen, by the process' own log?
  const std::string log = run.log();
  ASSERT_NE(log.find("stall over"), std::string::npos) << log;
  int before = 0, largest_gap_ms = 0;
  double last = -1.0;
  for (const auto& m : got) {
    if (m.text != "WATCHDOG=1") continue;
    if (m.t_s < 1.4) ++before;
    if (last >= 0) largest_gap_ms = std::max(largest_gap_ms, static_cast<int>((m.t_s - last) * 1000));
    last = m.t_s;
  }
  int after = 0;
  for (const auto& m : got)
    if (m.text == "WATCHDOG=1" && m.t_s > 3.0) ++after;
  std::printf("[ figures  ] %zu messages; watchdog before the stall %d, after it %d; largest gap between pets %d ms\n",
              got.size(), before, after, largest_gap_ms);
  EXPECT_GE(before, 2) << "the watchdog is petted while healthy";
  EXPECT_GE(after, 2) << "and again once the loop runs again";
  // During the 1 s stall nothing pets it: a gap of most of a second.
  EXPECT_GE(largest_gap_ms, 700) << "the watchdog was petted while the sample loop was stalled";
  EXPECT_NE(got.back().text.find("STOPPING=1"), std::string::npos) << got.back().text;
}

}  // namespace
