// The CiA 406 node of `virtual-encoder run` on a real kernel CAN stack.
//
// CanopenVm.GuestSuite (the only test ctest lists) boots the SocketCAN VM
// (tests/vm/prepare.sh, run_in_vm.sh) and runs this binary inside it with VE_IN_VM=1,
// which runs CanopenGuest.*: `virtual-encoder run` with a simulated axis whose
// `canopen:` node is on vcan0, against a CANopen master written here (raw CAN_RAW
// socket, none of the node's code) and a DDS reader of the same axis' state.
// The master: NMT, SDO reads of the mandatory objects, SDO abort codes, writes of
// 1017h, 6200h and the TPDO transmission type, cyclic TPDOs, 10,000 SYNCs at 1 kHz
// (every one answered, every TPDO's position against the DDS stream at the SYNC
// instant), heartbeats, EMCY on a Hall sensor fault the simulator injects, NMT stop
// and reset communication. It prints the SYNC-to-TPDO delay (kernel time stamps of
// the SYNC and of the TPDO on vcan0, p50/p99): a measurement, not a pass criterion.
#include <gtest/gtest.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "../canopen_sdo_result.hpp"
#include "app/dds_io.hpp"
#include "socketcan/can_receive.hpp"
#include "../integration/process.hpp"
#include "../integration/temp_dir.hpp"
#include "../integration/test_domain.hpp"
#include "guest_suite.hpp"

using namespace ve;

namespace {

using ve::test::in_vm;
using ve::test::slurp;

const std::string kSrc = VE_SOURCE_DIR;
const std::string kBin = VE_BINARY;
constexpr int kNode = 5;
constexpr double kStepM = 1e-6;  // measuring_step_nm: 1000

std::int64_t now_rt() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

struct Rx {
  can_frame f{};
  std::int64_t t_ns = 0;  ///< kernel time stamp (CLOCK_REALTIME)
};

/// A minimal CANopen master on a CAN_RAW socket: sends, and records every frame on
/// the bus (its own SYNCs too, for their kernel time stamps) from a thread of its own.
class TestMaster {
 public:
  explicit TestMaster(const std::string& iface) {
    fd_ = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
    if (fd_ < 0) return;
    const int one = 1;
    setsockopt(fd_, SOL_CAN_RAW, CAN_RAW_RECV_OWN_MSGS, &one, sizeof one);
    setsockopt(fd_, SOL_SOCKET, SO_TIMESTAMPNS, &one, sizeof one);
    // Room for seconds of bus traffic while this emulated guest is busy (root in the
    // guest: past net.core.rmem_max); the kernel's drop counter says if it was not enough.
    const int buf = 16 << 20;
    if (setsockopt(fd_, SOL_SOCKET, SO_RCVBUFFORCE, &buf, sizeof buf) < 0)
      setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &buf, sizeof buf);
    setsockopt(fd_, SOL_SOCKET, SO_RXQ_OVFL, &one, sizeof one);
    sockaddr_can addr{};
    addr.can_family = AF_CAN;
    addr.can_ifindex = static_cast<int>(if_nametoindex(iface.c_str()));
    if (::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
      ::close(fd_);
      fd_ = -1;
      return;
    }
    frames_.reserve(100000);
    thread_ = std::thread([this] { receive(); });
  }
  ~TestMaster() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
    if (fd_ >= 0) ::close(fd_);
  }
  bool ok() const { return fd_ >= 0; }
  /// Frames the kernel dropped because this socket's receive queue was full.
  std::uint32_t dropped() const { return dropped_.load(); }

  bool send(std::uint32_t id, std::vector<std::uint8_t> data) {
    can_frame f{};
    f.can_id = id;
    f.can_dlc = static_cast<std::uint8_t>(data.size());
    std::memcpy(f.data, data.data(), data.size());
    for (int attempt = 0; attempt < 100; ++attempt) {
      if (::write(fd_, &f, sizeof f) == static_cast<ssize_t>(sizeof f)) return true;
      if (errno != ENOBUFS) return false;
      ::usleep(200);
    }
    return false;
  }
  void nmt(std::uint8_t cs) { send(0x000, {cs, kNode}); }

  std::size_t count() {
    std::lock_guard<std::mutex> lock(m_);
    return frames_.size();
  }
  /// Frames recorded from index `from` on.
  std::vector<Rx> since(std::size_t from) {
    std::lock_guard<std::mutex> lock(m_);
    return std::vector<Rx>(frames_.begin() + static_cast<std::ptrdiff_t>(std::min(from, frames_.size())), frames_.end());
  }
  /// Waits for a frame with `id` from index `from` on; its index, or -1.
  long wait_for(std::uint32_t id, std::size_t from, double timeout_s) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (std::chrono::steady_clock::now() < until) {
      {
        std::lock_guard<std::mutex> lock(m_);
        for (std::size_t i = from; i < frames_.size(); ++i)
          if ((frames_[i].f.can_id & CAN_SFF_MASK) == id) return static_cast<long>(i);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    return -1;
  }
  Rx at(long i) {
    std::lock_guard<std::mutex> lock(m_);
    return frames_[static_cast<std::size_t>(i)];
  }

  // ---- SDO client (CiA 301), expedited and segmented upload, expedited download ----
  using Sdo = ve::test::SdoResult;
  Sdo exchange(const std::vector<std::uint8_t>& req, can_frame& reply) {
    Sdo r;
    const std::size_t from = count();
    send(0x600 + kNode, req);
    const long i = wait_for(0x580 + kNode, from, 5.0);
    if (i < 0) return r;
    reply = at(i).f;
    if (reply.data[0] == 0x80) {
      for (int b = 0; b < 4; ++b) r.abort |= static_cast<std::uint32_t>(reply.data[4 + b]) << (8 * b);
      return r;
    }
    r.ok = true;
    return r;
  }
  Sdo upload(std::uint16_t index, std::uint8_t sub) {
    can_frame f{};
    Sdo r = exchange({0x40, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub, 0, 0, 0, 0}, f);
    if (!r.ok) return r;
    r.ok = false;
    if ((f.data[0] & 0xE3) == 0x43) {
      const int n = 4 - ((f.data[0] >> 2) & 3);
      r.data.assign(f.data + 4, f.data + 4 + n);
      r.ok = true;
      return r;
    }
    if (f.data[0] != 0x41) return r;
    const std::uint32_t size = f.data[4] | f.data[5] << 8 | f.data[6] << 16 | static_cast<std::uint32_t>(f.data[7]) << 24;
    std::uint8_t t = 0;
    for (int guard = 0; guard < 64; ++guard) {
      Sdo s = exchange({static_cast<std::uint8_t>(0x60 | t << 4), 0, 0, 0, 0, 0, 0, 0}, f);
      if (!s.ok) return s;
      const int n = 7 - ((f.data[0] >> 1) & 7);
      r.data.insert(r.data.end(), f.data + 1, f.data + 1 + n);
      t ^= 1;
      if (f.data[0] & 1) break;
    }
    r.ok = r.data.size() == size;
    return r;
  }
  Sdo download(std::uint16_t index, std::uint8_t sub, std::uint32_t v, int size) {
    can_frame f{};
    Sdo r = exchange({static_cast<std::uint8_t>(0x23 | (4 - size) << 2), static_cast<std::uint8_t>(index),
                      static_cast<std::uint8_t>(index >> 8), sub, static_cast<std::uint8_t>(v),
                      static_cast<std::uint8_t>(v >> 8), static_cast<std::uint8_t>(v >> 16),
                      static_cast<std::uint8_t>(v >> 24)},
                     f);
    if (r.ok) r.ok = f.data[0] == 0x60;
    return r;
  }

 private:
  void receive() {
    while (!stop_) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      Rx rx;
      const socketcan::CanReceived got = socketcan::receive_can_frame(fd_, &rx.f, sizeof rx.f);
      if (got.bytes < static_cast<ssize_t>(sizeof rx.f)) continue;
      rx.t_ns = got.rx_realtime_ns;
      if (got.has_drops) dropped_.store(got.drops);
      std::lock_guard<std::mutex> lock(m_);
      frames_.push_back(rx);
    }
  }

  int fd_ = -1;
  std::atomic<std::uint32_t> dropped_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;
  std::mutex m_;
  std::vector<Rx> frames_;
};

std::int32_t le_i32(const can_frame& f, int at) {
  std::uint32_t v = 0;
  for (int b = 0; b < 4; ++b) v |= static_cast<std::uint32_t>(f.data[at + b]) << (8 * b);
  return static_cast<std::int32_t>(v);
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(p * static_cast<double>(v.size() - 1) + 0.5))];
}

/// The test's reader's socket buffer [bytes]; the kernel accounts twice that: about 13 s
/// of the stream.
constexpr int kTestReceiveBuffer = 32 << 20;

/// The shipped profiles (deploy/dds-profiles.xml) with the test's state reader keeping
/// 8192 samples (2 s at 4 kHz) instead of 256 for each of up to 16 axes (Fast DDS wants
/// max_samples >= max_instances * max_samples_per_instance), and its sockets receiving into
/// kTestReceiveBuffer bytes instead of 4 MiB, written to `path`; empty when the shipped file
/// has not the shape expected. The writer (`run`) is as shipped: best effort, history of
/// one. The emulated guest stalls the test's receive thread for longer than 256 samples
/// take, and a reader history that overwrites what it has not handed over loses estimates
/// the TPDOs are compared with. On a slow host the guest's reader also falls behind the
/// stream for longer than the shipped 4 MiB hold (about 1.6 s of it): in one CI run it was
/// 1.47 s behind after the SYNC phase and 2,881 estimates had been dropped at its socket.
std::string deep_reader_profiles(const std::string& path) {
  std::ifstream in(kSrc + "/deploy/dds-profiles.xml");
  std::stringstream text;
  text << in.rdbuf();
  std::string x = text.str();
  const auto at = x.find("profile_name=\"ve_state_reader\"");
  if (at == std::string::npos) return {};
  const auto end = x.find("</data_reader>", at);
  for (const auto& [from, to] : {std::pair<std::string, std::string>{"<depth>256</depth>", "<depth>8192</depth>"},
                                 {"<max_instances>1024<", "<max_instances>16<"},
                                 {"<max_samples_per_instance>256<", "<max_samples_per_instance>8192<"}}) {
    const auto k = x.find(from, at);
    if (k == std::string::npos || k > end) return {};
    x.replace(k, from.size(), to);
  }
  const std::string shipped_buffer = "<receiveBufferSize>4194304</receiveBufferSize>";
  const auto b = x.find(shipped_buffer);
  if (b == std::string::npos) return {};
  x.replace(b, shipped_buffer.size(), "<receiveBufferSize>" + std::to_string(kTestReceiveBuffer) + "</receiveBufferSize>");
  std::ofstream(path) << x;
  return path;
}

#define GUEST_ONLY() \
  if (!in_vm()) GTEST_SKIP() << "runs inside the SocketCAN VM (started by CanopenVm.GuestSuite)"

}  // namespace

// ---------------------------------------------------------------------------
// Host side: boot the VM and run the guest tests there.

TEST(CanopenVm, GuestSuite) {
  if (in_vm()) GTEST_SKIP() << "this is the guest";
  ve::test::run_guest_suite("ve_canopen_vm", "CanopenGuest.*", std::to_string(ve::test::dds_domain(0)), 330);
}

// ---------------------------------------------------------------------------
// Guest side.

TEST(CanopenGuest, MasterDrivesTheNodeOfARunningEncoder) {
  GUEST_ONLY();
  const int domain = ve::test::dds_domain(0);
  // A slow shuttle (velocity and acceleration both non-zero most of the time); Hall
  // sensor 1 sticks high at 35 s of simulated time, after the SYNC phase. Every
  // estimate is published (publish_divider 1), so that the DDS stream's sequence
  // numbers tell which estimate the node had at each SYNC.
  const std::string machine = std::filesystem::absolute("canopen-vm.yaml").string();
  std::ofstream(machine) << "machine: canopen-vm\n"
                         << "dds: {domain: " << domain << ", deadline_ms: 50}\n"
                         << "axes:\n"
                         << "  - name: x\n"
                         << "    motor: " << kSrc << "/config/motors/sim-12mm.yaml\n"
                         << "    driver:\n"
                         << "      type: sim\n"
                         << "      profile: {type: shuttle, start_m: 0.5, max_velocity_mps: 0.05, "
                            "max_acceleration_mps2: 0.5, min_m: 0.3, max_m: 0.7}\n"
                         << "      faults: [{kind: hall_stuck_high, sensor: 1, start_s: 35}]\n"
                         << "    output: {publish_divider: 1}\n"
                         << "    homing: {mode: startup_position, position_m: 0.5}\n"
                         << "    canopen:\n"
                         << "      interface: vcan0\n"
                         << "      node_id: " << kNode << "\n"
                         << "      measuring_step_nm: 1000\n"
                         << "      heartbeat_ms: 50\n"
                         << "      transmission_type: 1\n";

  TestMaster master("vcan0");
  ASSERT_TRUE(master.ok()) << std::strerror(errno);

  // The guest's cap on socket buffers, raised for the test's reader (deep_reader_profiles);
  // the kernel caps SO_RCVBUF at it without an error.
  std::ofstream("/proc/sys/net/core/rmem_max") << 2 * kTestReceiveBuffer << "\n";
  ASSERT_GE(std::stol(slurp("/proc/sys/net/core/rmem_max")), 2L * kTestReceiveBuffer) << "net.core.rmem_max not raised";
  app::DdsOptions o;
  o.domain = domain;
  o.profiles_file = deep_reader_profiles(std::filesystem::absolute("deep-reader.xml").string());
  ASSERT_FALSE(o.profiles_file.empty()) << "deploy/dds-profiles.xml: no state reader profile to deepen";
  std::string error;
  auto ctx = app::DdsContext::create(o, error);
  ASSERT_TRUE(ctx) << error;
  struct DdsSample {
    std::int64_t t_ns;
    std::uint64_t seq;
    double x, v, a;
  };
  std::mutex m;
  std::vector<DdsSample> dds;
  dds.reserve(400000);
  {
    app::StateReader reader(*ctx, 0.0, [&](const ve::dds::EncoderState& s) {
      std::lock_guard<std::mutex> lock(m);
      dds.push_back({s.source_time_ns(), s.sequence_number(), s.position_m(), s.velocity_mps(), s.acceleration_mps2()});
    });
    ASSERT_TRUE(reader.ok()) << "the test's DDS reader (deep-reader.xml) was not created";
    ve::test::ChildProcess run({kBin, "run", "--config", machine, "--duration", "240", "--wait-for-subscriber", "30",
                                "--status-period", "5"},
                               "run.log");
    ASSERT_TRUE(run.started());

    // ---- boot-up, then pre-operational heartbeats
    const long boot = master.wait_for(0x700 + kNode, 0, 60.0);
    ASSERT_GE(boot, 0) << "no boot-up message\n" << slurp("run.log");
    EXPECT_EQ(master.at(boot).f.can_dlc, 1);
    EXPECT_EQ(master.at(boot).f.data[0], 0x00);
    // Wait until the estimator hands over its first estimate (DDS flowing).
    for (int i = 0; i < 3000; ++i) {
      {
        std::lock_guard<std::mutex> lock(m);
        if (dds.size() > 50) break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    {
      const std::size_t from = master.count();
      const auto t0 = now_rt();
      std::this_thread::sleep_for(std::chrono::seconds(2));
      const double window_s = static_cast<double>(now_rt() - t0) * 1e-9;
      std::vector<std::int64_t> beats;
      for (const auto& rx : master.since(from))
        if ((rx.f.can_id & CAN_SFF_MASK) == 0x700u + kNode) {
          EXPECT_EQ(rx.f.data[0], 0x7F) << "heartbeat state: pre-operational";
          beats.push_back(rx.t_ns);
        }
      std::vector<double> gaps;
      for (std::size_t i = 1; i < beats.size(); ++i) gaps.push_back(static_cast<double>(beats[i] - beats[i - 1]) * 1e-6);
      const double expected = window_s / 0.050;
      std::printf("heartbeats: %zu in %.2f s (%.1f expected at 50 ms); intervals p50 %.1f ms, max %.1f ms\n",
                  beats.size(), window_s, expected, percentile(gaps, 0.5), percentile(gaps, 1.0));
      // A count over the window, not a timing bound: the producer keeps its schedule.
      EXPECT_GE(static_cast<double>(beats.size()), 0.7 * expected);
      EXPECT_LE(static_cast<double>(beats.size()), 1.3 * expected + 1);
    }

    // ---- SDO: every mandatory object, and what this node promises
    EXPECT_EQ(master.upload(0x1000, 0).u32(), 0x00080196u);  // CiA 406, absolute linear encoder
    const auto err = master.upload(0x1001, 0);
    EXPECT_TRUE(err.ok);
    EXPECT_EQ(err.data.size(), 1u);
    EXPECT_EQ(master.upload(0x1017, 0).u32(), 50u);
    EXPECT_EQ(master.upload(0x1018, 0).u32(), 4u);
    for (std::uint8_t sub = 1; sub <= 4; ++sub) EXPECT_TRUE(master.upload(0x1018, sub).ok) << "1018h:" << int(sub);
    EXPECT_EQ(master.upload(0x1018, 4).u32(), 1u);  // serial number: the axis id
    const auto name = master.upload(0x1008, 0);     // segmented
    EXPECT_TRUE(name.ok);
    EXPECT_EQ(name.text(), "virtual-encoder x");
    EXPECT_TRUE(master.upload(0x1009, 0).ok);
    EXPECT_EQ(master.upload(0x100A, 0).text(), VE_VERSION);
    EXPECT_EQ(master.upload(0x6000, 0).u32(), 0u);
    EXPECT_EQ(master.upload(0x6005, 1).u32(), 1000u);
    EXPECT_EQ(master.upload(0x6501, 0).u32(), 1000u);
    EXPECT_EQ(master.upload(0x6500, 0).u32(), 0u);
    EXPECT_EQ(master.upload(0x6504, 0).u32(), 0x3001u);
    EXPECT_EQ(master.upload(0x6506, 0).u32(), 0x7020u);
    EXPECT_EQ(master.upload(0x6503, 0).u32(), 0u) << "no alarm while the estimate is VALID";
    EXPECT_EQ(master.upload(0x6505, 0).u32() & 0x1000u, 0x1000u) << "warning: not calibrated (nominal table)";
    const auto pos = master.upload(0x6004, 0);
    ASSERT_TRUE(pos.ok);
    EXPECT_NEAR(static_cast<std::int32_t>(pos.u32()) * kStepM, 0.5, 0.25);
    EXPECT_EQ(master.upload(0x1800, 2).u32(), 1u);
    EXPECT_EQ(master.upload(0x1A00, 1).u32(), 0x60040020u);

    // ---- SDO abort codes
    EXPECT_EQ(master.upload(0x2000, 0).abort, 0x06020000u);            // object does not exist
    EXPECT_EQ(master.download(0x1000, 0, 0, 4).abort, 0x06010002u);    // read-only
    EXPECT_EQ(master.download(0x6004, 0, 0, 4).abort, 0x06010002u);
    EXPECT_EQ(master.download(0x1800, 2, 245, 1).abort, 0x06090030u);  // value range exceeded
    EXPECT_EQ(master.upload(0x1800, 2).u32(), 1u);

    // ---- cyclic TPDO: 6200h = 10 ms, transmission type 254, 1 s operational
    ASSERT_TRUE(master.download(0x6200, 0, 10, 2).ok);
    ASSERT_TRUE(master.download(0x1800, 2, 254, 1).ok);
    EXPECT_EQ(master.upload(0x6200, 0).u32(), 10u);
    {
      const std::size_t from = master.count();
      const auto t0 = now_rt();
      master.nmt(0x01);
      std::this_thread::sleep_for(std::chrono::seconds(1));
      master.nmt(0x80);
      const double window_s = static_cast<double>(now_rt() - t0) * 1e-9;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
      int tpdos = 0, op_beats = 0;
      for (const auto& rx : master.since(from)) {
        tpdos += (rx.f.can_id & CAN_SFF_MASK) == 0x180u + kNode;
        op_beats += (rx.f.can_id & CAN_SFF_MASK) == 0x700u + kNode && rx.f.data[0] == 0x05;
      }
      std::printf("cyclic: %d TPDOs in %.2f s at 10 ms\n", tpdos, window_s);
      EXPECT_GE(tpdos, static_cast<int>(0.7 * window_s / 0.010));
      EXPECT_LE(tpdos, static_cast<int>(1.3 * window_s / 0.010) + 2);
      EXPECT_GT(op_beats, 0) << "heartbeats say operational";
    }

    // ---- SYNC-triggered TPDOs: type 1, 10,000 SYNCs at 1 kHz
    ASSERT_TRUE(master.download(0x6200, 0, 0, 2).ok);
    ASSERT_TRUE(master.download(0x1800, 2, 1, 1).ok);
    master.nmt(0x01);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    constexpr int kSyncs = 10000;
    const std::size_t sync_from = master.count();
    {
      timespec next{};
      clock_gettime(CLOCK_MONOTONIC, &next);
      for (int i = 0; i < kSyncs; ++i) {
        next.tv_nsec += 1000000;
        if (next.tv_nsec >= 1000000000) {
          next.tv_nsec -= 1000000000;
          ++next.tv_sec;
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, nullptr);
        ASSERT_TRUE(master.send(0x080, {})) << std::strerror(errno);
      }
    }
    // Every SYNC answered: wait for the last TPDO (the emulated guest may lag).
    for (int i = 0; i < 3000; ++i) {
      int n = 0;
      for (const auto& rx : master.since(sync_from)) n += (rx.f.can_id & CAN_SFF_MASK) == 0x180u + kNode;
      if (n >= kSyncs) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    master.nmt(0x80);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    std::vector<Rx> syncs, tpdos;
    for (const auto& rx : master.since(sync_from)) {
      const auto id = rx.f.can_id & CAN_SFF_MASK;
      if (id == 0x080) syncs.push_back(rx);
      if (id == 0x180u + kNode) tpdos.push_back(rx);
    }
    ASSERT_EQ(master.dropped(), 0u) << "the test master's receive queue overflowed";
    ASSERT_EQ(syncs.size(), static_cast<std::size_t>(kSyncs));
    EXPECT_EQ(tpdos.size(), syncs.size()) << "SYNCs not answered: " << static_cast<long>(syncs.size()) - static_cast<long>(tpdos.size());
    // The DDS stream is delivered on its own thread and may lag the CAN bus in the
    // emulated guest: the comparison needs the estimate after the last SYNC's instant,
    // so the stream is taken once it holds one (it lagged by about 0.28 s once, and
    // the last 278 SYNCs found no estimate after them).
    std::vector<DdsSample> stream;
    const std::int64_t last_sync_ns = syncs.back().t_ns;
    for (int i = 0; i < 1000; ++i) {
      {
        std::lock_guard<std::mutex> lock(m);
        bool after = false;
        for (auto r = dds.rbegin(); r != dds.rend() && !after; ++r) after = r->t_ns > last_sync_ns;
        if (after || i == 999) {
          stream = dds;
          if (i > 0) std::printf("DDS stream: waited %d ms for the estimate after the last SYNC\n", i * 10);
          break;
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    {
      // Where the stream lost estimates: between received samples (sequence numbers).
      auto by_seq = stream;
      std::sort(by_seq.begin(), by_seq.end(), [](const DdsSample& a, const DdsSample& b) { return a.seq < b.seq; });
      std::uint64_t missing = 0;
      for (std::size_t i = 1; i < by_seq.size(); ++i) missing += by_seq[i].seq - by_seq[i - 1].seq - 1;
      std::printf("DDS stream: %zu estimates received, %llu missing between them\n", by_seq.size(),
                  static_cast<unsigned long long>(missing));
    }
    std::sort(stream.begin(), stream.end(), [](const DdsSample& a, const DdsSample& b) { return a.t_ns < b.t_ns; });
    // Each TPDO answers the SYNC of the same rank (one TPDO per SYNC, in order): its
    // position is compared with the DDS stream's estimate propagated to that SYNC's
    // kernel time stamp (x + v dt + a dt^2 / 2 from the last estimate handed over
    // before it; also from the one before, which the node may still have had while
    // the last one was being computed). The stream must hold that estimate and the
    // next (consecutive sequence numbers): every one of the 10,000 SYNCs is compared.
    std::size_t compared = 0, within = 0, out_of_order = 0, no_dds = 0, no_dds_before_stream = 0, no_dds_after_stream = 0;
    double worst_steps = 0.0;
    std::vector<double> delay_us;
    const std::size_t n = std::min(syncs.size(), tpdos.size());
    for (std::size_t k = 0; k < n; ++k) {
      const std::int64_t ts = syncs[k].t_ns;
      if (tpdos[k].t_ns < ts) ++out_of_order;
      delay_us.push_back(static_cast<double>(tpdos[k].t_ns - ts) * 1e-3);
      ASSERT_EQ(tpdos[k].f.can_dlc, 4);
      const double got = le_i32(tpdos[k].f, 0);
      auto it = std::upper_bound(stream.begin(), stream.end(), ts, [](std::int64_t t, const DdsSample& s) { return t < s.t_ns; });
      if (it == stream.begin() || it == stream.end() || it->seq != std::prev(it)->seq + 1) {
        ++no_dds;  // the estimate current at the SYNC did not arrive over DDS
        no_dds_before_stream += it == stream.begin();
        no_dds_after_stream += it == stream.end();
        continue;
      }
      double best = 1e300;
      for (int back = 1; back <= 2 && it - back >= stream.begin(); ++back) {
        const DdsSample& s = *(it - back);
        const double dt = static_cast<double>(ts - s.t_ns) * 1e-9;
        const double x = s.x + s.v * dt + 0.5 * s.a * dt * dt;
        best = std::min(best, std::abs(got - x / kStepM));
      }
      ++compared;
      worst_steps = std::max(worst_steps, best);
      within += best <= 1.0;
    }
    std::printf("SYNC phase: %zu SYNCs sent at 1 kHz, %zu TPDOs (%zu missed), %zu after their SYNC out of order\n",
                syncs.size(), tpdos.size(), syncs.size() - std::min(syncs.size(), tpdos.size()), out_of_order);
    std::printf("position vs DDS at the SYNC instant: %zu compared (%zu whose estimate DDS did not deliver), %zu within "
                "one measuring step (1 um), worst %.3f steps\n",
                compared, no_dds, within, worst_steps);
    std::printf("SYNC -> TPDO delay on vcan0 in the emulated guest (kernel time stamps), %zu pairs:\n"
                "| p50 | p90 | p99 | max |\n|---|---|---|---|\n| %.0f us | %.0f us | %.0f us | %.0f us |\n",
                delay_us.size(), percentile(delay_us, 0.5), percentile(delay_us, 0.9), percentile(delay_us, 0.99),
                percentile(delay_us, 1.0));
    EXPECT_EQ(out_of_order, 0u);
    // Checked once `run` has said how many SYNCs it answered without the estimate in
    // progress at their instant (its sample thread descheduled for over 2 ms: the
    // TPDO then carries the estimate before it).
    // The test's reader keeps 2 s of the stream (deep_reader_profiles): with the
    // shipped 256 samples, 194-809 of 10,000 estimates were lost in the emulated guest.
    EXPECT_EQ(no_dds, 0u) << "SYNCs whose estimate the DDS stream did not deliver (" << no_dds_before_stream
                          << " before its first estimate, " << no_dds_after_stream << " after its last)";
    EXPECT_EQ(compared, n);

    // ---- EMCY on the injected Hall fault (sensor 1 sticks high at 35 s simulated)
    {
      bool seen = false;
      can_frame emcy{};
      std::size_t from = sync_from;
      for (int i = 0; i < 1500 && !seen; ++i) {
        const auto frames = master.since(from);
        from += frames.size();
        for (const auto& rx : frames)
          if ((rx.f.can_id & CAN_SFF_MASK) == 0x80u + kNode && (rx.f.data[0] | rx.f.data[1] << 8) == 0x7300) {
            emcy = rx.f;
            seen = true;
          }
        if (!seen) std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
      ASSERT_TRUE(seen) << "no sensor EMCY (7300h) after the Hall fault\n" << slurp("run.log");
      EXPECT_EQ(emcy.can_dlc, 8);
      EXPECT_NE(emcy.data[2] & 0x01, 0) << "error register: generic error";
      EXPECT_NE(emcy.data[3] | emcy.data[4] << 8, 0) << "6503h alarms in the EMCY";
      EXPECT_NE(emcy.data[5] & 0x02, 0) << "Hall sensor 1 named";
      EXPECT_NE(master.upload(0x6503, 0).u32() & 0x1000u, 0u) << "6503h: Hall sensor fault alarm";
      EXPECT_NE(master.upload(0x1001, 0).u32(), 0u);
    }

    // ---- NMT stop: heartbeats say stopped, SYNCs are not answered, SDO is silent
    {
      master.nmt(0x02);
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
      const std::size_t from = master.count();
      for (int i = 0; i < 20; ++i) {
        master.send(0x080, {});
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(300));
      int tp = 0, stopped_beats = 0;
      for (const auto& rx : master.since(from)) {
        tp += (rx.f.can_id & CAN_SFF_MASK) == 0x180u + kNode;
        stopped_beats += (rx.f.can_id & CAN_SFF_MASK) == 0x700u + kNode && rx.f.data[0] == 0x04;
      }
      EXPECT_EQ(tp, 0);
      EXPECT_GT(stopped_beats, 0);
    }
    // ---- reset communication: boot-up again, 1017h back to the machine file's value
    {
      master.nmt(0x80);
      ASSERT_TRUE(master.download(0x1017, 0, 200, 2).ok);
      const std::size_t from = master.count();
      master.nmt(0x82);
      const long b = master.wait_for(0x700 + kNode, from, 5.0);
      ASSERT_GE(b, 0);
      EXPECT_EQ(master.at(b).f.data[0], 0x00) << "boot-up";
      EXPECT_EQ(master.upload(0x1017, 0).u32(), 50u);
    }
    run.signal(SIGTERM);
    EXPECT_EQ(run.wait_exit(std::chrono::seconds(60)), 0) << slurp("run.log");
    const std::string log = slurp("run.log");
    const auto at = log.find("canopen: ");
    ASSERT_NE(at, std::string::npos) << log;
    std::printf("run: %s\n", log.substr(at, log.find('\n', at) - at).c_str());
    const auto w = log.find(" SYNCs answered before the estimate in progress", at);
    ASSERT_NE(w, std::string::npos) << log;
    const auto digits = log.rfind(' ', w - 1) + 1;
    const std::size_t expired = std::stoul(log.substr(digits, w - digits));
    EXPECT_LE(compared - within, expired) << "TPDOs off the DDS stream by more than one measuring step";
    EXPECT_LE(expired, compared / 10) << "the node had to answer many SYNCs without their estimate";
  }
  ctx.reset();
}
