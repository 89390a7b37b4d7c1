// systemd supervision without systemd: a datagram socket stands in for
// NOTIFY_SOCKET. `run` must say READY=1 only once it publishes, pet the watchdog
// only while its sample loop makes progress (not while its sensor node is silent),
// and say STOPPING=1 on SIGTERM.
#include <gtest/gtest.h>

#include <sys/socket.h>
#include <sys/un.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <string>
#include <vector>

#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;

struct Message {
  double t_s;
  std::string text;
};

TEST(Service, ReadyWatchdogWhileHealthyAndStopping) {
  ve::test::TempDir dir;
  const std::string path = (dir.path / "notify.sock").string();
  const int fd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  ASSERT_LT(path.size(), sizeof addr.sun_path) << path;
  std::snprintf(addr.sun_path, sizeof addr.sun_path, "%s", path.c_str());
  ASSERT_EQ(bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0) << std::strerror(errno);
  timeval tv{0, 50000};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);

  // Watchdog every 0.25 s (half of 0.5 s); the axis' sensor node (the simulator with a
  // no_samples fault) sends nothing from 1.5 s after its first sample for 1 s, so the
  // sample loop makes no progress.
  const double stall_s = 1.0;
  setenv("NOTIFY_SOCKET", path.c_str(), 1);
  setenv("WATCHDOG_USEC", "500000", 1);
  ve::test::ChildProcess run({VE_BINARY, "run", "--config",
                              std::string(VE_SOURCE_DIR) + "/tests/integration/data/silent_node.yaml", "--domain",
                              std::to_string(ve::test::dds_domain()), "--duration", "60"},
                             (dir.path / "run.log").string());
  unsetenv("NOTIFY_SOCKET");
  unsetenv("WATCHDOG_USEC");
  ASSERT_TRUE(run.started());

  // Each message is put in the phase of the process' own log when it arrived: before
  // the stall began (the loop logs a source silent for 100 ms), during it, after it. What is checked is the order of events, not
  // when they happened: a slower build (a sanitizer) or a loaded host moves them all.
  enum Phase { kBefore, kDuring, kAfter };
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Message> got;
  std::vector<Phase> phase;
  int pets_after = 0;
  bool terminated = false;
  while (std::chrono::steady_clock::now() - t0 < ve::test::patience(60s)) {
    char buf[512];
    const ssize_t n = recv(fd, buf, sizeof buf - 1, 0);
    const std::string log = run.log();
    const Phase now = log.find("samples again after") != std::string::npos           ? kAfter
                      : log.find("the sensor source is silent") != std::string::npos ? kDuring
                                                                                     : kBefore;
    if (n > 0) {
      buf[n] = '\0';
      got.push_back({std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), buf});
      phase.push_back(now);
      if (got.back().text.find("STOPPING=1") != std::string::npos) break;
      if (got.back().text == "WATCHDOG=1" && now == kAfter) ++pets_after;
    }
    // Stopped once the loop has run again long enough to pet the watchdog twice.
    if (!terminated && pets_after >= 2) {
      run.signal(SIGTERM);
      terminated = true;
    }
  }
  EXPECT_TRUE(terminated) << "no two watchdog messages after the stall\n" << run.log();
  EXPECT_EQ(run.wait_exit(ve::test::patience(10s)), 0) << run.log();
  close(fd);

  ASSERT_FALSE(got.empty()) << run.log();
  EXPECT_EQ(got.front().text.rfind("READY=1", 0), 0u) << "the first message is READY=1: " << got.front().text;
  ASSERT_NE(run.log().find("samples again after"), std::string::npos) << run.log();
  int before = 0, during = 0, largest_gap_ms = 0;
  double last = -1.0;
  for (std::size_t i = 0; i < got.size(); ++i) {
    if (got[i].text != "WATCHDOG=1") continue;
    if (phase[i] == kBefore) ++before;
    if (phase[i] == kDuring) ++during;
    if (last >= 0) largest_gap_ms = std::max(largest_gap_ms, static_cast<int>((got[i].t_s - last) * 1000));
    last = got[i].t_s;
  }
  std::printf("[ figures  ] %zu messages; watchdog before the stall %d, during it %d, after it %d; largest gap "
              "between pets %d ms\n",
              got.size(), before, during, pets_after, largest_gap_ms);
  EXPECT_GE(before, 2) << "the watchdog is petted while healthy";
  EXPECT_GE(pets_after, 2) << "and again once the loop runs again";
  // Nothing pets it while the loop is stalled. Seen in the stall's phase can be only
  // what the progress made before it allows: the check after the stall began (the
  // samples since the check before), and one sent before the log line but received
  // after it. The stall lasts four watchdog periods.
  EXPECT_LE(during, 2) << "the watchdog was petted while the sample loop was stalled";
  // And two pets are at least the stall apart, less the one watchdog period (0.25 s)
  // a pet sent just after the stall began can take from it. A slower host only
  // widens the gap.
  EXPECT_GE(largest_gap_ms, static_cast<int>((stall_s - 0.25) * 1000) - 50)
      << "the watchdog was petted while the sample loop was stalled";
  EXPECT_NE(got.back().text.find("STOPPING=1"), std::string::npos) << got.back().text;
}

}  // namespace
