// SocketCAN driver on a real kernel CAN stack (issue 6).
//
// The build machines' kernel has no CAN, so SocketCanVm.GuestSuite (the only test
// ctest lists) boots a small VM (tests/vm/prepare.sh, run_in_vm.sh: Debian kernel with
// vcan, busybox initramfs, host root over 9p) and runs this same binary inside it
// with VE_IN_VM=1, which runs the SocketCanGuest.* tests against vcan0 with can-utils
// (cansend, cangen) and the sensor-node emulator as independent peers. It skips, saying
// why, only when qemu or the kernel package is unavailable.
#include <gtest/gtest.h>
#include <linux/can.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "app/axis.hpp"
#include "app/dds_io.hpp"
#include "core/status.hpp"
#include "config/loader.hpp"
#include "core/pipeline.hpp"
#include "sim/sim_source.hpp"
#include "config/can_layout_file.hpp"
#include "socketcan/socketcan_source.hpp"
#include "../integration/process.hpp"
#include "../integration/temp_dir.hpp"
#include "../integration/test_domain.hpp"
#include "../integration/threads.hpp"
#include "guest_suite.hpp"

extern char** environ;

using namespace ve;
using socketcan::SocketCanSource;

namespace {

using ve::test::in_vm;
using ve::test::slurp;

const std::string kSrc = VE_SOURCE_DIR;
const std::string kBin = VE_BINARY;

int sh(const std::string& cmd) {
  const int r = std::system(cmd.c_str());
  return WIFEXITED(r) ? WEXITSTATUS(r) : -1;
}

/// Starts a process (no shell); returns its pid.
pid_t spawn(const std::vector<std::string>& args) {
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  pid_t pid = -1;
  if (posix_spawn(&pid, argv[0], nullptr, nullptr, argv.data(), environ) != 0) return -1;
  return pid;
}

int wait_exit(pid_t pid) {
  int status = 0;
  if (waitpid(pid, &status, 0) < 0) return -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

socketcan::CanLayout layout(const std::string& rel) {
  socketcan::CanLayout l;
  std::vector<config::ConfigError> errors;
  EXPECT_TRUE(socketcan::load_can_layout_file(kSrc + "/" + rel, l, errors)) << config::to_string(errors);
  return l;
}

std::unique_ptr<SocketCanSource> open_source(const std::string& layout_rel, double timeout_ms = 200) {
  socketcan::SocketCanOptions opt;
  opt.interface = "vcan0";
  opt.layout = layout(layout_rel);
  opt.timeout_ms = timeout_ms;
  auto src = std::make_unique<SocketCanSource>(opt);
  EXPECT_TRUE(src->ok()) << src->last_error();
  return src;
}

#define GUEST_ONLY() \
  if (!in_vm()) GTEST_SKIP() << "runs inside the SocketCAN VM (started by SocketCanVm.GuestSuite)"

constexpr double kLsb = 5.0 / 4095.0;

}  // namespace

// ---------------------------------------------------------------------------
// Host side: boot the VM and run the guest tests there.

TEST(SocketCanVm, GuestSuite) {
  if (in_vm()) GTEST_SKIP() << "this is the guest";
  ve::test::run_guest_suite("ve_vm_guest", "SocketCanGuest.*",
                            std::to_string(ve::test::dds_domain(0)) + "," + std::to_string(ve::test::dds_domain(1)), 200);
}

// ---------------------------------------------------------------------------
// Guest side.

TEST(SocketCanGuest, SilentBusTimesOut) {
  GUEST_ONLY();
  auto src = open_source("config/can/classic-4hall.yaml", 30);
  core::RawSample s;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(src->read(s), drivers::ReadStatus::timeout);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_GE(ms, 25.0);
  EXPECT_LT(ms, 1000.0);
}

TEST(SocketCanGuest, CansendFramesDecode) {
  GUEST_ONLY();
  {
    auto src = open_source("config/can/classic-4hall.yaml");
    // Hall codes 0x123 0x456 0x789 0xABC, accel raw -2 (-0.01 m/s^2), counter 5 in the id.
    ASSERT_EQ(sh("cansend vcan0 405#23614589C7ABFEFF"), 0);
    core::RawSample s;
    ASSERT_EQ(src->read(s), drivers::ReadStatus::ok) << src->last_error();
    EXPECT_EQ(s.seq, 5u);
    EXPECT_EQ(s.hall_count, 4);
    EXPECT_DOUBLE_EQ(s.hall_v[0], 0x123 * kLsb);
    EXPECT_DOUBLE_EQ(s.hall_v[1], 0x456 * kLsb);
    EXPECT_DOUBLE_EQ(s.hall_v[2], 0x789 * kLsb);
    EXPECT_DOUBLE_EQ(s.hall_v[3], 0xABC * kLsb);
    EXPECT_NEAR(s.accel_mps2, -0.01, 1e-12);
    EXPECT_GT(s.t_ns, 1000000000LL);  // a kernel (CLOCK_REALTIME) time stamp
    ASSERT_EQ(sh("cansend vcan0 406#FF0F000000000080"), 0);  // hall_0 4095 -> 5 V, accel -32768
    ASSERT_EQ(src->read(s), drivers::ReadStatus::ok);
    EXPECT_EQ(s.seq, 6u);
    EXPECT_DOUBLE_EQ(s.hall_v[0], 5.0);
    EXPECT_NEAR(s.accel_mps2, -163.84, 1e-9);
    EXPECT_EQ(src->gaps(), 0u);
    std::printf("classic: %s\n", src->stats().c_str());
  }
  {
    auto src = open_source("config/can/fd-4hall-x8.yaml");
    std::string hex = "0201236145" "89C7ABFE3F";
    hex.append(2 * 54, '0');
    ASSERT_EQ(sh("cansend vcan0 500##0" + hex), 0);
    core::RawSample s;
    ASSERT_EQ(src->read(s), drivers::ReadStatus::ok) << src->last_error();
    EXPECT_EQ(s.seq, 0x0102u * 8);
    EXPECT_DOUBLE_EQ(s.hall_v[0], 0x123 * kLsb);
    EXPECT_DOUBLE_EQ(s.hall_v[1], 0x456 * kLsb);
    EXPECT_DOUBLE_EQ(s.hall_v[2], 0x789 * kLsb);
    EXPECT_DOUBLE_EQ(s.hall_v[3], 0xABC * kLsb);
    EXPECT_NEAR(s.accel_mps2, -0.04, 1e-12);
    const std::int64_t t0 = s.t_ns;
    for (int k = 1; k < 8; ++k) {
      ASSERT_EQ(src->read(s), drivers::ReadStatus::ok);
      EXPECT_EQ(s.seq, 0x0102u * 8 + k);
      EXPECT_EQ(s.t_ns - t0, k * 250000);  // 4 kHz
      EXPECT_DOUBLE_EQ(s.hall_v[0], 0.0);
    }
    // A classic frame on the FD id and a short FD frame are bad frames, not samples.
    ASSERT_EQ(sh("cansend vcan0 500#1122334455667788"), 0);
    ASSERT_EQ(sh("cansend vcan0 500##01122"), 0);
    EXPECT_EQ(src->read(s), drivers::ReadStatus::timeout);
    EXPECT_EQ(src->bad_frames(), 2u);
    std::printf("fd: %s\n", src->stats().c_str());
  }
}

TEST(SocketCanGuest, CangenNoiseIsCountedNotUsed) {
  GUEST_ONLY();
  auto src = open_source("config/can/classic-4hall.yaml", 100);
  // Noise on ids around the layout's range, extended ids and FD frames with the same low
  // bits, and remote requests. The socket has no kernel id filter: all of it reaches
  // the source, none of it is used, and it is counted as foreign (id or remote).
  ASSERT_EQ(sh("cangen vcan0 -g 0 -n 300 -I 3FF -L 8 && cangen vcan0 -g 0 -n 300 -I 500 -L 8 && "
               "cangen vcan0 -g 0 -n 300 -e -I 400 -L 8 && cangen vcan0 -g 0 -n 200 -I 123 && "
               "cangen vcan0 -g 0 -n 100 -I 7FF -R"),
            0);
  for (int i = 0; i < 10; ++i) {
    char cmd[64];
    std::snprintf(cmd, sizeof cmd, "cansend vcan0 %03X#0000000000000000", 0x410 + i);
    ASSERT_EQ(sh(cmd), 0);
  }
  ASSERT_EQ(sh("cansend vcan0 41A#1122"), 0);  // right id, wrong length
  int n = 0;
  core::RawSample s;
  while (src->read(s) == drivers::ReadStatus::ok) {
    EXPECT_EQ(s.seq, 0x10u + static_cast<unsigned>(n));
    ++n;
  }
  EXPECT_EQ(n, 10);
  const auto c = src->counters();
  EXPECT_EQ(c.frames, 10u);
  EXPECT_EQ(c.kernel_drops, 0u);  // the socket's queue held the whole burst
  EXPECT_EQ(c.foreign_id, 1100u);
  EXPECT_EQ(c.remote_frames, 100u);
  EXPECT_EQ(c.foreign_frames, 1200u);
  EXPECT_EQ(c.last_foreign_id, 0x123u);  // the last data frame of another id
  EXPECT_EQ(c.bad_frames, 1u);
  EXPECT_EQ(c.gaps, 0u);
  std::printf("after 1200 noise frames: %s\n", src->stats().c_str());
}

TEST(SocketCanGuest, NodeOnAWrongIdIsCountedAsForeignId) {
  GUEST_ONLY();
  // A node configured for another id (0x300 instead of the layout's 0x400-0x4FF): the
  // bus is not silent to the diagnostics, every frame is counted with its id.
  auto src = open_source("config/can/classic-4hall.yaml", 100);
  for (int i = 0; i < 5; ++i) {
    char cmd[64];
    std::snprintf(cmd, sizeof cmd, "cansend vcan0 %03X#23614589C7ABFEFF", 0x300 + i);
    ASSERT_EQ(sh(cmd), 0);
  }
  ASSERT_EQ(sh("cansend vcan0 00000405#23614589C7ABFEFF"), 0);  // the right bits as an extended id
  core::RawSample s;
  EXPECT_EQ(src->read(s), drivers::ReadStatus::timeout);
  const auto c = src->counters();
  EXPECT_EQ(c.frames, 0u);
  EXPECT_EQ(c.foreign_id, 6u);
  EXPECT_EQ(c.last_foreign_id, 0x405u | CAN_EFF_FLAG);
  const std::string line = src->stats();
  EXPECT_NE(line.find("foreign=6 (id=6 remote=0; last foreign id 0x00000405 (extended))"), std::string::npos) << line;
  std::printf("node on a wrong id: %s\n", line.c_str());
}

TEST(SocketCanGuest, ErrorFramesAreClassified) {
  GUEST_ONLY();
  auto src = open_source("config/can/classic-4hall.yaml", 100);
  // CAN_ERR_FLAG | CAN_ERR_CRTL, data[1] = RX_WARNING; then TX_PASSIVE; then BUSOFF; then a protocol error.
  ASSERT_EQ(sh("cansend vcan0 20000004#0004000000000000"), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(src->bus_state(), socketcan::BusState::warning);
  ASSERT_EQ(sh("cansend vcan0 20000004#0020000000000000"), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(src->bus_state(), socketcan::BusState::passive);
  ASSERT_EQ(sh("cansend vcan0 20000040#0000000000000000 && cansend vcan0 20000008#0000000000000000"), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(src->bus_state(), socketcan::BusState::bus_off);
  ASSERT_EQ(sh("cansend vcan0 20000100#0000000000000000"), 0);  // restarted
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  const auto c = src->counters();
  EXPECT_EQ(c.error_frames, 5u);
  EXPECT_EQ(c.bus_warnings, 1u);
  EXPECT_EQ(c.bus_passives, 1u);
  EXPECT_EQ(c.bus_offs, 1u);
  EXPECT_EQ(c.other_errors, 1u);
  EXPECT_EQ(src->bus_state(), socketcan::BusState::active);
  EXPECT_EQ(c.frames, 0u);
  std::printf("errors: %s\n", src->stats().c_str());
}

TEST(SocketCanGuest, InterfaceDownAndUpReconnects) {
  GUEST_ONLY();
  auto src = open_source("config/can/classic-4hall.yaml", 100);
  ASSERT_EQ(sh("cansend vcan0 401#0000000000000000"), 0);
  core::RawSample s;
  ASSERT_EQ(src->read(s), drivers::ReadStatus::ok);
  ASSERT_EQ(sh("ip link set vcan0 down"), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_EQ(src->read(s), drivers::ReadStatus::timeout);
  const bool was_connected = src->connected();
  ASSERT_EQ(sh("ip link set vcan0 up"), 0);
  for (int i = 0; i < 50 && !src->connected(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_EQ(sh("cansend vcan0 402#0000000000000000"), 0);
  ASSERT_EQ(src->read(s), drivers::ReadStatus::ok) << src->last_error();
  EXPECT_EQ(s.seq, 2u);
  EXPECT_FALSE(was_connected);
  EXPECT_EQ(src->reconnects(), 1u);
  std::printf("down/up: %s\n", src->stats().c_str());
}

namespace {

struct ChainResult {
  std::uint64_t samples = 0, gaps = 0, lost = 0, kernel_drops = 0;
  double rms_can_m = 0, rms_sim_m = 0, max_can_m = 0;
  std::string stats;
};

/// The emulator sends the constant-velocity run on vcan0; the machine file's axis
/// (socketcan driver) is built as `virtual-encoder run` builds it, its pipeline fed
/// from the CAN source, and compared with truth from the same simulation. The same
/// pipeline fed straight from the simulator is the reference.
ChainResult run_chain(const std::string& machine, const std::string& layout_rel, double seconds,
                      const std::vector<std::string>& extra = {}) {
  ChainResult r;
  auto loaded = config::load_machine_file(kSrc + "/" + machine);
  EXPECT_TRUE(loaded.ok()) << config::to_string(loaded.errors);
  if (!loaded.ok()) return r;
  app::AxisSetup axis;
  std::string error;
  const bool built = app::build_axis(loaded.config.axes[0], app::SourceTiming::as_configured, axis, error);
  EXPECT_TRUE(built) << error;
  if (!built) return r;
  auto* src = dynamic_cast<SocketCanSource*>(axis.source.get());
  EXPECT_NE(src, nullptr);

  auto node_cfg = config::load_machine_file(kSrc + "/config/machines/can-node-cv.yaml");
  EXPECT_TRUE(node_cfg.ok());
  sim::SimConfig sc = node_cfg.config.axes[0].driver.sim;
  sc.realtime = false;
  sim::SimSource truth_sim(node_cfg.config.axes[0].motor, sc);
  core::AxisPipeline reference(app::pipeline_config(axis.config, axis.calibration, axis.calibrated),
                               axis.calibration.table);

  char dur[32];
  std::snprintf(dur, sizeof dur, "%g", seconds + 0.3);
  std::vector<std::string> args = {kBin, "sensor-node", "--config", kSrc + "/config/machines/can-node-cv.yaml",
                                   "--axis", "x", "--can", "vcan0", "--layout", kSrc + "/" + layout_rel,
                                   "--duration", dur};
  args.insert(args.end(), extra.begin(), extra.end());
  const pid_t node = spawn(args);
  EXPECT_GT(node, 0);

  const std::uint64_t want = static_cast<std::uint64_t>(seconds * 4000);
  const std::uint64_t settle = 800;  // 0.2 s to converge
  double sum_can = 0, sum_sim = 0;
  std::uint64_t n = 0;
  core::RawSample s, t;
  int timeouts = 0;
  // The emulator takes a while to start under TCG: up to 15 s for the first sample,
  // then at most 1 s of silence.
  while (r.samples < want && timeouts < (r.samples == 0 ? 750 : 50)) {
    const auto st = axis.source->read(s);
    if (st == drivers::ReadStatus::timeout) {
      ++timeouts;
      continue;
    }
    if (st != drivers::ReadStatus::ok) {
      std::printf("chain: read() returned %d after %llu samples: %s\n", static_cast<int>(st),
                  (unsigned long long)r.samples, axis.source->last_error().c_str());
      break;
    }
    timeouts = 0;
    ++r.samples;
    const core::EncoderEstimate& est = axis.pipeline->step(s);
    // Advance the reference simulation to the same sample.
    bool have_truth = false;
    while (truth_sim.samples_read() == 0 || t.seq < s.seq) {
      if (truth_sim.read(t) != drivers::ReadStatus::ok) break;
      reference.step(t);
      if (t.seq == s.seq) have_truth = true;
    }
    if (!have_truth || s.seq < settle) continue;
    const double truth = truth_sim.truth()->position_m;
    const double e_can = est.position_m - truth;
    const double e_sim = reference.last().position_m - truth;
    sum_can += e_can * e_can;
    sum_sim += e_sim * e_sim;
    r.max_can_m = std::max(r.max_can_m, std::abs(e_can));
    ++n;
  }
  kill(node, SIGTERM);
  wait_exit(node);
  if (n > 0) {
    r.rms_can_m = std::sqrt(sum_can / static_cast<double>(n));
    r.rms_sim_m = std::sqrt(sum_sim / static_cast<double>(n));
  }
  r.gaps = src ? src->gaps() : 0;
  r.lost = src ? src->lost_samples() : 0;
  r.kernel_drops = src ? src->counters().kernel_drops : 0;
  r.stats = src ? src->stats() : "";
  return r;
}

}  // namespace

TEST(SocketCanGuest, EmulatorChainAccuracyClassic) {
  GUEST_ONLY();
  const ChainResult r = run_chain("config/machines/can-classic.yaml", "config/can/classic-4hall.yaml", 2.0);
  std::printf("classic chain: %llu samples, rms error %.3f um (sim driver %.3f um), max %.3f um; %s\n",
              (unsigned long long)r.samples, r.rms_can_m * 1e6, r.rms_sim_m * 1e6, r.max_can_m * 1e6, r.stats.c_str());
  EXPECT_GE(r.samples, 7000u);
  // A loaded CI host can make the guest's socket queue overflow: then every lost frame
  // must be accounted for as a gap (the kernel's own drop counter agrees).
  EXPECT_EQ(r.lost, r.kernel_drops);
  EXPECT_GT(r.rms_sim_m, 0.0);
  EXPECT_LE(r.rms_can_m, 1.1 * r.rms_sim_m + 0.05e-6);
}

TEST(SocketCanGuest, EmulatorChainAccuracyFd) {
  GUEST_ONLY();
  const ChainResult r = run_chain("config/machines/can-fd.yaml", "config/can/fd-4hall-x8.yaml", 2.0);
  std::printf("fd chain: %llu samples, rms error %.3f um (sim driver %.3f um), max %.3f um; %s\n",
              (unsigned long long)r.samples, r.rms_can_m * 1e6, r.rms_sim_m * 1e6, r.max_can_m * 1e6, r.stats.c_str());
  EXPECT_GE(r.samples, 7000u);
  // A loaded CI host can make the guest's socket queue overflow: then every lost frame
  // must be accounted for as a gap (the kernel's own drop counter agrees).
  EXPECT_EQ(r.lost, r.kernel_drops);
  EXPECT_GT(r.rms_sim_m, 0.0);
  EXPECT_LE(r.rms_can_m, 1.1 * r.rms_sim_m + 0.05e-6);
}

TEST(SocketCanGuest, BurstOfDroppedFramesIsDetected) {
  GUEST_ONLY();
  // Classic: frames 1000..1019 not sent (20 samples); FD: frames 100..102 (24 samples).
  const ChainResult c = run_chain("config/machines/can-classic.yaml", "config/can/classic-4hall.yaml", 0.6,
                                  {"--drop-at", "1000", "--drop-count", "20"});
  std::printf("classic with a burst dropped: %s\n", c.stats.c_str());
  EXPECT_EQ(c.gaps, 1u);
  EXPECT_EQ(c.lost, 20u);
  EXPECT_LE(c.rms_can_m, 2.0 * c.rms_sim_m + 0.5e-6);  // predicted through the gap
  const ChainResult f = run_chain("config/machines/can-fd.yaml", "config/can/fd-4hall-x8.yaml", 0.6,
                                  {"--drop-at", "100", "--drop-count", "3"});
  std::printf("fd with a burst dropped: %s\n", f.stats.c_str());
  EXPECT_EQ(f.gaps, 1u);
  EXPECT_EQ(f.lost, 24u);
}

TEST(SocketCanGuest, RecordCommandReadsTheBus) {
  GUEST_ONLY();
  const pid_t node = spawn({kBin, "sensor-node", "--config", kSrc + "/config/machines/can-node-cv.yaml", "--can",
                            "vcan0", "--layout", kSrc + "/config/can/fd-4hall-x8.yaml", "--duration", "5"});
  ASSERT_GT(node, 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(2500));  // the emulator is up (slow under TCG)
  // `record` gives up when its first read times out (20 ms): retry while the emulator warms up under TCG.
  int rc = 1;
  for (int attempt = 0; attempt < 5 && rc != 0; ++attempt)
    rc = sh(kBin + " record --config " + kSrc + "/config/machines/can-fd.yaml --duration 0.5 --out rec.csv");
  kill(node, SIGTERM);
  wait_exit(node);
  EXPECT_EQ(rc, 0);
  const std::string log = slurp("rec.csv");
  int rows = 0;
  for (char ch : log) rows += ch == '\n';
  std::printf("record over CAN FD: %d lines\n", rows);
  EXPECT_GT(rows, 500);  // record stops at its first read timeout; under TCG that can be early
}

namespace {

/// RMS of the positions about their least-squares line over time: at constant
/// velocity the truth is a line, so this is the estimate's error without needing
/// the emulator's clock (the time offset and the start drop out with the fit).
double line_fit_rms(const std::vector<std::pair<double, double>>& tx) {
  const double n = static_cast<double>(tx.size());
  double st = 0, sx = 0;
  for (const auto& [t, x] : tx) {
    st += t;
    sx += x;
  }
  const double mt = st / n, mx = sx / n;
  double stt = 0, stx = 0;
  for (const auto& [t, x] : tx) {
    stt += (t - mt) * (t - mt);
    stx += (t - mt) * (x - mx);
  }
  const double slope = stx / stt;
  double ss = 0;
  for (const auto& [t, x] : tx) {
    const double e = x - (mx + slope * (t - mt));
    ss += e * e;
  }
  return std::sqrt(ss / n);
}

}  // namespace

/// The whole product chain: sensor-node emulator -> vcan0 -> `virtual-encoder run`
/// (socketcan driver, estimator, DDS writer) -> a DDS subscriber in this process.
/// The published positions at constant velocity are as accurate as the same
/// estimator fed by the simulator driver directly.
// SocketCAN's receive thread is part of the sample path (the sample thread waits for
// its frames): `run` gives it the sample thread's real-time settings, and Fast DDS's
// threads run below both when realtime.dds_thread_priority asks for it.
TEST(SocketCanGuest, ReceiveThreadRunsWithTheSampleThreadsSettings) {
  GUEST_ONLY();
  std::string yaml = slurp(kSrc + "/config/machines/can-classic.yaml");
  for (std::size_t at = 0; (at = yaml.find("../", at)) != std::string::npos;) {
    yaml.replace(at, 3, kSrc + "/config/machines/../");
    at += kSrc.size() + 20;
  }
  const auto axes = yaml.find("\naxes:");
  ASSERT_NE(axes, std::string::npos);
  yaml.insert(axes + 1, "realtime:\n  sample_thread_priority: 30\n  dds_thread_priority: 25\n");
  const std::string machine = "realtime-can-classic.yaml";
  std::ofstream(machine) << yaml;
  const int domain = ve::test::dds_domain(0);  // the guest tests run one after the other
  const pid_t run = spawn({kBin, "run", "--config", machine, "--domain", std::to_string(domain), "--duration", "20"});
  ASSERT_GT(run, 0);
  // "comm policy/priority" of every thread of `run`.
  std::vector<std::string> threads;
  auto has = [&](const std::string& entry) { return std::find(threads.begin(), threads.end(), entry) != threads.end(); };
  for (int i = 0; i < 1500; ++i) {
    threads.clear();
    for (const auto& t : ve::test::tasks_of(run))
      threads.push_back(t.comm + " " + std::to_string(t.policy) + "/" + std::to_string(t.prio));
    if (has("ve-rx-x 1/30") && has("ve-x 1/30")) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  kill(run, SIGTERM);
  EXPECT_EQ(wait_exit(run), 0);
  std::string seen;
  int dds_at_25 = 0;
  for (const auto& t : threads) {
    seen += t + "; ";
    if (t == "virtual-encoder 1/25") ++dds_at_25;
  }
  EXPECT_TRUE(has("ve-rx-x 1/30")) << "the receive thread at SCHED_FIFO 30: " << seen;
  EXPECT_TRUE(has("ve-x 1/30")) << seen;
  EXPECT_GE(dds_at_25, 3) << "Fast DDS's threads at realtime.dds_thread_priority: " << seen;
  std::printf("threads of run: %s\n", seen.c_str());
}

TEST(SocketCanGuest, EmulatorToDdsChainAccuracy) {
  GUEST_ONLY();
  // Reference: the simulator driver straight into the pipeline, same motion.
  auto node_cfg = config::load_machine_file(kSrc + "/config/machines/can-node-cv.yaml");
  ASSERT_TRUE(node_cfg.ok());
  double rms_ref = 0.0;
  {
    sim::SimConfig sc = node_cfg.config.axes[0].driver.sim;
    sc.realtime = false;
    sim::SimSource sim(node_cfg.config.axes[0].motor, sc);
    app::AxisSetup axis;
    std::string error;
    ASSERT_TRUE(app::build_axis(node_cfg.config.axes[0], app::SourceTiming::as_fast_as_possible, axis, error)) << error;
    std::vector<std::pair<double, double>> tx;
    core::RawSample s;
    while (sim.read(s) == drivers::ReadStatus::ok && s.seq < 12000) {
      const auto& est = axis.pipeline->step(s);
      if (s.seq >= 800) tx.emplace_back(static_cast<double>(s.t_ns) * 1e-9, est.position_m);
    }
    rms_ref = line_fit_rms(tx);
  }

  struct Case {
    const char* machine;
    const char* layout;
    int domain;
  };
  // The guest is emulated (no KVM): DDS costs it far more per sample than a real
  // host, and `run` publishing all 4000 samples/s cannot keep up with the bus there
  // (about 300-1700 of them processed per second in our runs). So here the axis
  // publishes every 4th estimate (output.publish_divider), the estimator still
  // running on every sample: a copy of the machine file with that one setting.
  auto with_divider = [](const std::string& machine_rel) {
    std::ifstream in(kSrc + "/" + machine_rel);
    std::stringstream text;
    text << in.rdbuf();
    std::string yaml = text.str();
    const std::string dir = kSrc + "/" + machine_rel.substr(0, machine_rel.rfind('/')) + "/";
    for (std::size_t at = 0; (at = yaml.find("../", at)) != std::string::npos;) {
      yaml.replace(at, 3, dir + "../");
      at += dir.size() + 3;
    }
    const std::string key = "      preset_counts: 0\n";
    const auto at = yaml.find(key);
    EXPECT_NE(at, std::string::npos) << machine_rel;
    if (at != std::string::npos) yaml.insert(at + key.size(), "      publish_divider: 4\n");
    const std::string out = "divider4-" + machine_rel.substr(machine_rel.rfind('/') + 1);
    std::ofstream(out) << yaml;
    return out;
  };
  for (const Case c : {Case{"config/machines/can-classic.yaml", "config/can/classic-4hall.yaml", ve::test::dds_domain(0)},
                       Case{"config/machines/can-fd.yaml", "config/can/fd-4hall-x8.yaml", ve::test::dds_domain(1)}}) {
    app::DdsOptions o;
    o.domain = c.domain;
    std::string error;
    auto ctx = app::DdsContext::create(o, error);
    ASSERT_TRUE(ctx) << error;
    std::mutex m;
    std::vector<ve::dds::EncoderState> got;
    got.reserve(40000);
    {
      app::StateReader reader(*ctx, 0.0, [&](const ve::dds::EncoderState& s) {
        std::lock_guard<std::mutex> lock(m);
        got.push_back(s);
      });
      const pid_t run = spawn({kBin, "run", "--config", with_divider(c.machine), "--domain", std::to_string(c.domain),
                               "--duration", "6", "--wait-for-subscriber", "20", "--status-period", "5"});
      ASSERT_GT(run, 0);
      // The node starts once the encoder publishes to us.
      for (int i = 0; i < 2000 && reader.matched_writers() == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
      const pid_t node = spawn({kBin, "sensor-node", "--config", kSrc + "/config/machines/can-node-cv.yaml", "--axis",
                                "x", "--can", "vcan0", "--layout", kSrc + "/" + c.layout, "--duration", "3.5"});
      ASSERT_GT(node, 0);
      EXPECT_EQ(wait_exit(node), 0);
      kill(run, SIGTERM);
      EXPECT_EQ(wait_exit(run), 0);
    }
    ctx.reset();
    std::vector<std::pair<double, double>> tx;
    std::uint64_t valid = 0;
    for (const auto& s : got) {
      if (!(s.status() & core::status::kValid) || !(s.status() & core::status::kHomed)) continue;
      ++valid;
      tx.emplace_back(static_cast<double>(s.sample_time_ns()) * 1e-9, s.position_m());
    }
    // Skip the first 0.2 s of convergence.
    if (!tx.empty()) {
      const double t_settled = tx.front().first + 0.2;
      tx.erase(tx.begin(), std::find_if(tx.begin(), tx.end(), [&](const auto& p) { return p.first >= t_settled; }));
    }
    // Under software emulation the estimator falls behind the bus (about 2,600 of
    // 4,000 samples/s in our runs, the rest still queued in the driver's ring when the
    // node stops; no frame lost: the driver's counters are in the log), and best-effort
    // DDS between two emulated processes drops some of what is published (1,700 to
    // 1,900 of 2,000 to 2,300 arrived). What this test checks is that what arrives over
    // DDS is right.
    ASSERT_GT(tx.size(), 500u) << c.machine << ": " << got.size() << " samples received, " << valid << " VALID";
    const double rms = line_fit_rms(tx);
    std::printf("dds chain %s: %zu samples received, %llu VALID+HOMED; error about the constant-velocity line "
                "%.3f um RMS (simulator driver %.3f um)\n",
                c.layout, got.size(), static_cast<unsigned long long>(valid), rms * 1e6, rms_ref * 1e6);
    // Samples the guest could not keep up with are bridged by prediction, so a
    // loaded emulated guest may come out a little worse than the simulator driver
    // (0.085..0.13 um against 0.088 um in our runs); the bound is a tenth of the spec.
    EXPECT_LE(rms, 0.5e-6) << c.machine;
  }
}
