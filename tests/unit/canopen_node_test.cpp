// The CiA 301 / CiA 406 node's protocol logic without CAN: frames in, frames out.
// The SDO client, the EDS parser and the expected values here are the test's own
// (written from CiA 301 / 306 / 406), not the node's code.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <map>
#include <set>
#include <sstream>
#include <thread>

#include "../canopen_sdo_result.hpp"
#include "canopen/node.hpp"
#include "canopen/snapshot.hpp"
#include "core/status.hpp"

using namespace ve;
using canopen::Frame;
using canopen::Node;
using canopen::Outbox;

namespace {

constexpr std::uint8_t kId = 5;
constexpr std::int64_t kMs = 1000000;
constexpr std::int64_t kT0 = 1700000000LL * 1000000000LL;  // a CLOCK_REALTIME-like instant

Frame make(std::uint32_t id, std::initializer_list<std::uint8_t> bytes) {
  Frame f;
  f.id = id;
  f.len = static_cast<std::uint8_t>(bytes.size());
  std::size_t i = 0;
  for (auto b : bytes) f.data[i++] = b;
  return f;
}

std::uint32_t le32(const Frame& f, int at) {
  std::uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= static_cast<std::uint32_t>(f.data[static_cast<std::size_t>(at + i)]) << (8 * i);
  return v;
}

canopen::AxisSnapshot valid_state(double x, double v = 0.0, double a = 0.0, std::int64_t t = kT0) {
  canopen::AxisSnapshot s;
  s.present = true;
  s.t_ns = t;
  s.position_m = x;
  s.velocity_mps = v;
  s.acceleration_mps2 = a;
  s.status = core::status::kValid | core::status::kCalibrated | core::status::kHomed;
  return s;
}

/// A node with a harness: frames it sent are collected in `sent`.
struct Bench {
  canopen::SnapshotBox box;
  Node node;
  std::vector<Frame> sent;
  std::int64_t mono = 1000 * kMs;

  explicit Bench(canopen::NodeConfig cfg = config()) : node(std::move(cfg), &box) {
    Outbox out;
    node.start(mono, out);
    take(out);
  }
  static canopen::NodeConfig config() {
    canopen::NodeConfig c;
    c.node_id = kId;
    c.step_nm = 1000;
    c.transmission_type = 1;
    c.heartbeat_ms = 100;
    return c;
  }
  void take(Outbox& out) {
    for (int i = 0; i < out.count; ++i) sent.push_back(out.frames[static_cast<std::size_t>(i)]);
    out.clear();
  }
  std::vector<Frame> send(const Frame& f, std::int64_t rt = kT0) {
    Outbox out;
    node.on_frame(f, rt, mono, out);
    std::vector<Frame> r(out.frames.begin(), out.frames.begin() + out.count);
    take(out);
    return r;
  }
  void tick(std::int64_t rt = kT0) {
    Outbox out;
    node.on_tick(rt, mono, out);
    take(out);
  }
  void nmt(std::uint8_t cs, std::uint8_t node = kId) { send(make(0x000, {cs, node})); }

  // ---- a minimal SDO client (CiA 301 7.2.4) ----
  using Result = ve::test::SdoResult;
  Frame request(std::uint8_t cmd, std::uint16_t index, std::uint8_t sub, std::uint32_t payload = 0) {
    return make(0x600 + kId, {cmd, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub,
                              static_cast<std::uint8_t>(payload), static_cast<std::uint8_t>(payload >> 8),
                              static_cast<std::uint8_t>(payload >> 16), static_cast<std::uint8_t>(payload >> 24)});
  }
  Result upload(std::uint16_t index, std::uint8_t sub, std::int64_t rt = kT0) {
    Result r;
    auto reply = send(request(0x40, index, sub), rt);
    if (reply.size() != 1 || reply[0].id != 0x580u + kId) return r;
    const Frame& f = reply[0];
    if (f.data[0] == 0x80) {
      r.abort = le32(f, 4);
      return r;
    }
    if ((f.data[0] & 0xE3) == 0x43) {  // expedited, size indicated
      const int n = 4 - ((f.data[0] >> 2) & 3);
      r.data.assign(f.data.begin() + 4, f.data.begin() + 4 + n);
      r.ok = true;
      return r;
    }
    if (f.data[0] != 0x41) return r;
    const std::uint32_t size = le32(f, 4);
    std::uint8_t toggle = 0;
    for (int guard = 0; guard < 100; ++guard) {
      auto seg = send(make(0x600 + kId, {static_cast<std::uint8_t>(0x60 | (toggle << 4)), 0, 0, 0, 0, 0, 0, 0}), rt);
      if (seg.size() != 1) return r;
      if (seg[0].data[0] == 0x80) {
        r.abort = le32(seg[0], 4);
        return r;
      }
      if (((seg[0].data[0] >> 4) & 1) != toggle) return r;
      const int n = 7 - ((seg[0].data[0] >> 1) & 7);
      r.data.insert(r.data.end(), seg[0].data.begin() + 1, seg[0].data.begin() + 1 + n);
      toggle ^= 1;
      if (seg[0].data[0] & 1) break;
    }
    r.ok = r.data.size() == size;
    return r;
  }
  /// Expedited download of `size` bytes.
  Result download(std::uint16_t index, std::uint8_t sub, std::uint32_t value, int size) {
    Result r;
    const auto cmd = static_cast<std::uint8_t>(0x23 | ((4 - size) << 2));
    auto reply = send(request(cmd, index, sub, value));
    if (reply.size() != 1) return r;
    if (reply[0].data[0] == 0x80) {
      r.abort = le32(reply[0], 4);
      return r;
    }
    r.ok = reply[0].data[0] == 0x60 && reply[0].data[1] == static_cast<std::uint8_t>(index) && reply[0].data[3] == sub;
    return r;
  }
  /// Segmented download of `bytes`.
  Result download_segmented(std::uint16_t index, std::uint8_t sub, const std::vector<std::uint8_t>& bytes,
                            bool break_toggle = false) {
    Result r;
    auto reply = send(request(0x21, index, sub, static_cast<std::uint32_t>(bytes.size())));
    if (reply.size() != 1 || reply[0].data[0] != 0x60) {
      if (reply.size() == 1 && reply[0].data[0] == 0x80) r.abort = le32(reply[0], 4);
      return r;
    }
    std::uint8_t toggle = 0;
    for (std::size_t at = 0; at < bytes.size(); at += 7) {
      const std::size_t n = std::min<std::size_t>(7, bytes.size() - at);
      const bool last = at + n >= bytes.size();
      Frame f;
      f.id = 0x600 + kId;
      f.len = 8;
      const std::uint8_t t = break_toggle ? static_cast<std::uint8_t>(toggle ^ 1) : toggle;
      f.data[0] = static_cast<std::uint8_t>((t << 4) | ((7 - n) << 1) | (last ? 1 : 0));
      for (std::size_t i = 0; i < n; ++i) f.data[1 + i] = bytes[at + i];
      auto rep = send(f);
      if (rep.size() != 1) return r;
      if (rep[0].data[0] == 0x80) {
        r.abort = le32(rep[0], 4);
        return r;
      }
      if (rep[0].data[0] != (0x20 | (toggle << 4))) return r;
      toggle ^= 1;
    }
    r.ok = true;
    return r;
  }
  std::vector<Frame> sync(std::int64_t rt) { return send(make(0x080, {}), rt); }
};

std::int32_t as_i32(std::uint32_t v) { return static_cast<std::int32_t>(v); }

}  // namespace

TEST(CanopenNode, BootsIntoPreOperationalWithABootUpMessage) {
  Bench b;
  ASSERT_EQ(b.sent.size(), 1u);
  EXPECT_EQ(b.sent[0].id, 0x700u + kId);
  EXPECT_EQ(b.sent[0].len, 1);
  EXPECT_EQ(b.sent[0].data[0], 0x00);
  EXPECT_EQ(b.node.state(), canopen::NmtState::pre_operational);
}

TEST(CanopenNode, NmtCommandsChangeTheStateForThisNodeOrAll) {
  Bench b;
  b.nmt(0x01, kId + 1);  // another node
  EXPECT_EQ(b.node.state(), canopen::NmtState::pre_operational);
  b.nmt(0x01);
  EXPECT_EQ(b.node.state(), canopen::NmtState::operational);
  b.nmt(0x02, 0);  // all nodes
  EXPECT_EQ(b.node.state(), canopen::NmtState::stopped);
  // Stopped: no SDO answer.
  EXPECT_TRUE(b.send(b.request(0x40, 0x1000, 0)).empty());
  b.nmt(0x80);
  EXPECT_EQ(b.node.state(), canopen::NmtState::pre_operational);
  EXPECT_TRUE(b.upload(0x1000, 0).ok);
}

TEST(CanopenNode, ResetCommunicationRestoresOnlyCommunicationObjects) {
  Bench b;
  ASSERT_TRUE(b.download(0x1017, 0, 250, 2).ok);
  ASSERT_TRUE(b.download(0x6200, 0, 7, 2).ok);
  b.sent.clear();
  b.nmt(0x82);
  ASSERT_EQ(b.sent.size(), 1u);
  EXPECT_EQ(b.sent[0].id, 0x700u + kId);  // boot-up again
  EXPECT_EQ(b.sent[0].data[0], 0x00);
  EXPECT_EQ(b.upload(0x1017, 0).u32(), 100u);
  EXPECT_EQ(b.upload(0x6200, 0).u32(), 7u);
  b.nmt(0x81);  // reset node: the application objects too
  EXPECT_EQ(b.upload(0x6200, 0).u32(), 0u);
  EXPECT_EQ(b.node.state(), canopen::NmtState::pre_operational);
}

TEST(CanopenNode, HeartbeatsCarryTheStateAtTheProducerPeriod) {
  Bench b;
  b.sent.clear();
  const std::int64_t start = b.mono;
  for (std::int64_t t = 0; t <= 1000 * kMs; t += kMs) {  // 1 s ticked every ms
    b.mono = start + t;
    b.tick();
  }
  int beats = 0;
  for (const auto& f : b.sent)
    if (f.id == 0x700u + kId) {
      ++beats;
      EXPECT_EQ(f.data[0], 0x7F);  // pre-operational
    }
  EXPECT_EQ(beats, 10);  // 100 ms period over 1 s (the first at 100 ms)
  b.nmt(0x01);
  b.sent.clear();
  b.mono += 100 * kMs;
  b.tick();
  ASSERT_FALSE(b.sent.empty());
  EXPECT_EQ(b.sent.back().data[0], 0x05);
  ASSERT_TRUE(b.download(0x1017, 0, 0, 2).ok);  // heartbeat off
  b.sent.clear();
  b.mono += 1000 * kMs;
  b.tick();
  for (const auto& f : b.sent) EXPECT_NE(f.id, 0x700u + kId);
}

TEST(CanopenNode, MandatoryObjectsReadBack) {
  Bench b;
  EXPECT_EQ(b.upload(0x1000, 0).u32(), 0x00080196u);  // CiA 406, absolute linear encoder
  EXPECT_TRUE(b.upload(0x1001, 0).ok);
  EXPECT_EQ(b.upload(0x1018, 0).u32(), 4u);
  EXPECT_TRUE(b.upload(0x1018, 1).ok);
  EXPECT_EQ(b.upload(0x1017, 0).u32(), 100u);
  EXPECT_EQ(b.upload(0x1800, 1).u32(), 0x180u + kId);
  EXPECT_EQ(b.upload(0x1A00, 1).u32(), 0x60040020u);
  EXPECT_EQ(b.upload(0x6501, 0).u32(), 1000u);
  EXPECT_EQ(b.upload(0x6005, 1).u32(), 1000u);
  EXPECT_EQ(b.upload(0x6504, 0).u32() & 1u, 1u);  // position error is supported
  // Long strings come by segmented upload.
  const auto name = b.upload(0x1008, 0);
  ASSERT_TRUE(name.ok) << std::hex << name.abort;
  EXPECT_EQ(name.text(), "virtual-encoder");
  EXPECT_GT(name.data.size(), 4u);
}

TEST(CanopenNode, SdoAbortCodes) {
  Bench b;
  EXPECT_EQ(b.upload(0x2000, 0).abort, 0x06020000u);          // object does not exist
  EXPECT_EQ(b.upload(0x1018, 9).abort, 0x06090011u);          // sub-index does not exist
  EXPECT_EQ(b.download(0x1000, 0, 1, 4).abort, 0x06010002u);  // read-only
  EXPECT_EQ(b.download(0x6004, 0, 1, 4).abort, 0x06010002u);
  EXPECT_EQ(b.download(0x1800, 2, 245, 1).abort, 0x06090030u);  // reserved transmission type
  EXPECT_EQ(b.download(0x1800, 2, 0, 1).abort, 0x06090030u);
  EXPECT_EQ(b.download(0x6000, 0, 0x8000, 2).abort, 0x06090030u);  // unsupported operating parameter
  EXPECT_EQ(b.download(0x6200, 0, 10, 4).abort, 0x06070012u);       // 4 bytes into a 16-bit object
  EXPECT_EQ(b.download(0x6200, 0, 10, 1).abort, 0x06070013u);
  EXPECT_EQ(b.download(0x2000, 0, 1, 4).abort, 0x06020000u);
  // The value was not written by any of these.
  EXPECT_EQ(b.upload(0x1800, 2).u32(), 1u);
  EXPECT_EQ(b.upload(0x6200, 0).u32(), 0u);
}

TEST(CanopenNode, SegmentedDownloadWritesAndChecksTheToggleBit) {
  Bench b;
  auto r = b.download_segmented(0x6200, 0, {0x34, 0x12});
  ASSERT_TRUE(r.ok) << std::hex << r.abort;
  EXPECT_EQ(b.upload(0x6200, 0).u32(), 0x1234u);
  r = b.download_segmented(0x1017, 0, {0x10, 0x00}, /*break_toggle=*/true);
  EXPECT_EQ(r.abort, 0x05030000u);
  EXPECT_EQ(b.upload(0x1017, 0).u32(), 100u);
  r = b.download_segmented(0x1000, 0, {1, 2, 3, 4});
  EXPECT_EQ(r.abort, 0x06010002u);
}

TEST(CanopenNode, SyncTpdoCarriesThePositionPropagatedToTheSyncInstant) {
  Bench b;
  // Estimate at kT0: 0.5 m, 0.2 m/s, 3 m/s^2; the SYNC arrives 1.5 ms later.
  b.box.publish(valid_state(0.5, 0.2, 3.0));
  b.nmt(0x01);
  const std::int64_t t_sync = kT0 + 1500000;
  auto r = b.sync(t_sync);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].id, 0x180u + kId);
  ASSERT_EQ(r[0].len, 4);
  const double dt = 1.5e-3;
  const double x = 0.5 + 0.2 * dt + 0.5 * 3.0 * dt * dt;  // metres at the SYNC instant
  EXPECT_EQ(as_i32(le32(r[0], 0)), static_cast<std::int32_t>(std::llround(x * 1e6)));  // 1 um steps
  // Not the last sample's position (300 steps away at this speed).
  EXPECT_GT(std::abs(as_i32(le32(r[0], 0)) - 500000), 250);
}

TEST(CanopenNode, ALateSyncUsesTheEstimateCurrentAtItsReception) {
  Bench b;
  b.nmt(0x01);
  // Three estimates 1 ms apart, each with its own motion; the SYNC came in at
  // +1.5 ms but is handled after the third.
  b.box.publish(valid_state(0.100, 0.0, 0.0, kT0));
  b.box.publish(valid_state(0.200, 1.0, 10.0, kT0 + kMs));
  b.box.publish(valid_state(0.300, -1.0, 0.0, kT0 + 2 * kMs));
  auto r = b.sync(kT0 + 1500000);
  ASSERT_EQ(r.size(), 1u);
  const double dt = 0.5e-3;
  EXPECT_EQ(as_i32(le32(r[0], 0)), std::llround((0.200 + 1.0 * dt + 0.5 * 10.0 * dt * dt) * 1e6));
  // Older than every estimate kept: the oldest, propagated back (counted).
  for (std::uint64_t i = 0; i < canopen::SnapshotBox::kHistory; ++i)
    b.box.publish(valid_state(0.4, 0.0, 0.0, kT0 + 10 * kMs + static_cast<std::int64_t>(i)));
  r = b.sync(kT0);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(as_i32(le32(r[0], 0)), 400000);
  EXPECT_EQ(b.node.counters().stale_reads, 1u);
}

TEST(CanopenNode, TransmissionTypeNSendsOnEveryNthSync) {
  Bench b;
  b.box.publish(valid_state(0.25));
  ASSERT_TRUE(b.download(0x1800, 2, 3, 1).ok);
  // Pre-operational: SYNCs are counted, no PDO.
  for (int i = 0; i < 5; ++i) EXPECT_TRUE(b.sync(kT0).empty());
  b.nmt(0x01);
  int tpdos = 0;
  for (int i = 0; i < 30; ++i) tpdos += static_cast<int>(b.sync(kT0 + i * kMs).size());
  EXPECT_EQ(tpdos, 10);
  EXPECT_EQ(b.node.counters().syncs, 35u);
}

TEST(CanopenNode, CyclicTimerSendsTpdosInOperationalOnly) {
  Bench b;
  b.box.publish(valid_state(0.25));
  ASSERT_TRUE(b.download(0x1800, 2, 254, 1).ok);
  ASSERT_TRUE(b.download(0x6200, 0, 10, 2).ok);
  ASSERT_TRUE(b.download(0x1017, 0, 0, 2).ok);
  auto run_ms = [&](int ms) {
    int n = 0;
    for (int i = 0; i < ms; ++i) {
      b.mono += kMs;
      const std::size_t before = b.sent.size();
      b.tick();
      for (std::size_t k = before; k < b.sent.size(); ++k) n += b.sent[k].id == 0x180u + kId;
    }
    return n;
  };
  EXPECT_EQ(run_ms(100), 0);
  b.nmt(0x01);
  // The first at the first tick in operational, then every 10 ms: 0, 10, ..., 100.
  EXPECT_EQ(run_ms(100), 11);
  EXPECT_EQ(run_ms(1000), 100);
  EXPECT_LE(b.node.next_due_ns() - b.mono, 10 * kMs);
  b.nmt(0x02);
  EXPECT_EQ(run_ms(100), 0);
}

TEST(CanopenNode, PdoMappingChangesInPreOperationalOnly) {
  Bench b;
  b.box.publish(valid_state(0.1, -0.05));
  b.nmt(0x01);
  EXPECT_EQ(b.download(0x1A00, 0, 0, 1).abort, 0x08000022u);
  b.nmt(0x80);
  EXPECT_EQ(b.download(0x1A00, 2, 0x60300120, 4).abort, 0x08000022u);  // sub 0 must be 0 first
  ASSERT_TRUE(b.download(0x1A00, 0, 0, 1).ok);
  EXPECT_EQ(b.download(0x1A00, 2, 0x60000010, 4).abort, 0x06040041u);  // 6000h cannot be mapped
  EXPECT_EQ(b.download(0x1A00, 2, 0x70000020, 4).abort, 0x06020000u);
  ASSERT_TRUE(b.download(0x1A00, 2, 0x60300120, 4).ok);
  EXPECT_EQ(b.download(0x1A00, 0, 3, 1).abort, 0x06090030u);
  ASSERT_TRUE(b.download(0x1A00, 0, 2, 1).ok);
  b.nmt(0x01);
  auto r = b.sync(kT0);
  ASSERT_EQ(r.size(), 1u);
  ASSERT_EQ(r[0].len, 8);
  EXPECT_EQ(as_i32(le32(r[0], 0)), 100000);
  EXPECT_EQ(as_i32(le32(r[0], 4)), -50000);  // steps per second
}

TEST(CanopenNode, CodeSequenceReversesPositionAndSpeed) {
  Bench b;
  b.box.publish(valid_state(0.1, 0.02));
  ASSERT_TRUE(b.download(0x6000, 0, 1, 2).ok);
  EXPECT_EQ(as_i32(b.upload(0x6004, 0).u32()), -100000);
  EXPECT_EQ(as_i32(b.upload(0x6030, 1).u32()), -20000);
  EXPECT_EQ(b.upload(0x6500, 0).u32(), 1u);
}

TEST(CanopenNode, AlarmsWarningsAndEmcyFollowTheStatus) {
  Bench b;
  // No estimate yet: position error.
  EXPECT_EQ(b.upload(0x6503, 0).u32() & canopen::alarm::kPositionError, canopen::alarm::kPositionError);
  auto emcys = [&] {
    std::vector<Frame> r;
    for (const auto& f : b.sent)
      if (f.id == 0x80u + kId) r.push_back(f);
    b.sent.clear();
    return r;
  };
  b.tick();
  auto e = emcys();
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].data[0] | e[0].data[1] << 8, 0x1000);
  b.box.publish(valid_state(0.3));
  b.mono += 200 * kMs;  // past the EMCY inhibit time
  b.tick();
  e = emcys();
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].data[0] | e[0].data[1] << 8, 0x0000);  // error reset
  EXPECT_EQ(e[0].data[2], 0);
  EXPECT_EQ(b.upload(0x6503, 0).u32(), 0u);
  EXPECT_EQ(b.upload(0x1001, 0).u32(), 0u);
  // Hall sensor 2 flagged: sensor EMCY with the sensor in the manufacturer bytes.
  auto s = valid_state(0.3);
  s.status |= core::status::kSensorFault | core::status::kDegraded | core::status::hall_fault(2);
  b.box.publish(s);
  b.mono += 200 * kMs;
  b.tick();
  e = emcys();
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].data[0] | e[0].data[1] << 8, 0x7300);
  EXPECT_NE(e[0].data[2], 0);
  EXPECT_EQ(e[0].data[5], 1u << 2);
  EXPECT_EQ(b.upload(0x6503, 0).u32(), canopen::alarm::kHallFault);
  EXPECT_EQ(b.upload(0x6505, 0).u32(), canopen::warning::kDegraded);
  // Unchanged: no new EMCY.
  b.mono += 200 * kMs;
  b.tick();
  EXPECT_TRUE(emcys().empty());
  // A change within the EMCY inhibit time (1015h: 100 ms) waits for it to end.
  b.box.publish(valid_state(0.3));
  b.tick();
  e = emcys();
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].data[0] | e[0].data[1] << 8, 0x0000);
  s.status |= core::status::hall_fault(3);
  b.box.publish(s);
  b.mono += 10 * kMs;
  b.tick();
  EXPECT_TRUE(emcys().empty());
  b.mono += 95 * kMs;
  b.tick();
  e = emcys();
  ASSERT_EQ(e.size(), 1u);
  EXPECT_EQ(e[0].data[0] | e[0].data[1] << 8, 0x7300);
  EXPECT_EQ(e[0].data[5], (1u << 2) | (1u << 3));
}

TEST(CanopenSnapshot, ReadersNeverSeeATornState) {
  canopen::SnapshotBox box;
  std::atomic<bool> done{false};
  std::thread writer([&] {
    for (int k = 1; k <= 200000; ++k) {
      canopen::AxisSnapshot s;
      s.present = true;
      s.t_ns = k;
      s.position_m = k;
      s.velocity_mps = 2.0 * k;
      s.acceleration_mps2 = 3.0 * k;
      s.status = static_cast<std::uint32_t>(k);
      box.publish(s);
    }
    done = true;
  });
  std::uint64_t reads = 0, torn = 0;
  while (!done.load()) {
    canopen::AxisSnapshot s;
    if (!box.read(s) || !s.present) continue;
    ++reads;
    const double k = static_cast<double>(s.t_ns);
    torn += s.position_m != k || s.velocity_mps != 2 * k || s.acceleration_mps2 != 3 * k ||
            s.status != static_cast<std::uint32_t>(s.t_ns);
  }
  writer.join();
  EXPECT_EQ(torn, 0u) << "of " << reads << " reads";
  canopen::AxisSnapshot last;
  ASSERT_TRUE(box.read(last));
  EXPECT_EQ(last.t_ns, 200000);
}

TEST(CanopenSnapshot, SettledTellsWhetherAnEstimateBeforeAnInstantIsInProgress) {
  canopen::SnapshotBox box;
  EXPECT_TRUE(box.settled(kT0));
  box.claim();  // an estimate is coming, its instant not stamped yet
  EXPECT_FALSE(box.settled(kT0));
  box.begin(kT0 + 10);
  EXPECT_FALSE(box.settled(kT0 + 10));  // a SYNC at or after its instant waits for it
  EXPECT_TRUE(box.settled(kT0 + 9));    // one before it does not
  box.publish(valid_state(0.1, 0.0, 0.0, kT0 + 10));
  EXPECT_TRUE(box.settled(kT0 + 10));
  canopen::AxisSnapshot s;
  ASSERT_TRUE(box.read_at(kT0 + 10, s));
  EXPECT_EQ(s.t_ns, kT0 + 10);
}

// ---------------------------------------------------------------------------
// EDS: parsed back (an INI reader of the test's own) and compared with what the
// node serves over SDO.

namespace {

using Sections = std::map<std::string, std::map<std::string, std::string>>;

Sections parse_ini(const std::string& text) {
  Sections s;
  std::istringstream in(text);
  std::string line, current;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == ';') continue;
    if (line[0] == '[') {
      current = line.substr(1, line.find(']') - 1);
      s[current];
      continue;
    }
    const auto eq = line.find('=');
    if (eq != std::string::npos) s[current][line.substr(0, eq)] = line.substr(eq + 1);
  }
  return s;
}

std::uint32_t eds_number(std::string v, std::uint32_t node_id) {
  std::uint32_t add = 0;
  if (v.rfind("$NODEID+", 0) == 0) {
    add = node_id;
    v = v.substr(8);
  }
  return add + static_cast<std::uint32_t>(std::stoll(v, nullptr, 0));
}

}  // namespace

TEST(CanopenEds, RoundTripMatchesTheServedDictionary) {
  canopen::NodeConfig cfg = Bench::config();
  cfg.tpdo_mapping = {canopen::Mapped::position, canopen::Mapped::speed};
  cfg.cyclic_timer_ms = 20;
  const Sections eds = parse_ini(canopen::write_eds(cfg, "x.eds", "test"));
  Bench b(cfg);
  ASSERT_TRUE(eds.count("DeviceInfo"));
  EXPECT_EQ(eds.at("DeviceInfo").at("NrOfTXPDO"), "1");
  EXPECT_EQ(eds.at("DeviceInfo").at("BaudRate_1000"), "1");

  // Every object listed is described, and the lists hold what the node answers for.
  std::set<std::uint16_t> listed;
  for (const char* list : {"MandatoryObjects", "OptionalObjects", "ManufacturerObjects"}) {
    ASSERT_TRUE(eds.count(list)) << list;
    const auto& l = eds.at(list);
    const int n = std::stoi(l.at("SupportedObjects"));
    for (int i = 1; i <= n; ++i) listed.insert(static_cast<std::uint16_t>(std::stoul(l.at(std::to_string(i)), nullptr, 0)));
  }
  for (std::uint16_t m : {0x1000, 0x1001, 0x1018}) EXPECT_TRUE(listed.count(m)) << std::hex << m;
  std::set<std::uint16_t> served;
  for (std::uint32_t index = 0x1000; index <= 0x6FFF; ++index) {
    const auto r = b.upload(static_cast<std::uint16_t>(index), 0);
    if (r.abort != 0x06020000u) served.insert(static_cast<std::uint16_t>(index));
  }
  EXPECT_EQ(listed, served);

  int compared = 0;
  for (const std::uint16_t index : listed) {
    char sec[8];
    std::snprintf(sec, sizeof sec, "%04X", index);
    ASSERT_TRUE(eds.count(sec)) << sec;
    const auto& obj = eds.at(sec);
    std::vector<std::pair<std::string, std::uint8_t>> vars;
    if (std::stoul(obj.at("ObjectType"), nullptr, 0) == 0x7) {
      vars.emplace_back(sec, 0);
    } else {
      const int subs = std::stoi(obj.at("SubNumber"));
      int found = 0;
      for (int sub = 0; sub < 256 && found < subs; ++sub) {
        char name[16];
        std::snprintf(name, sizeof name, "%ssub%X", sec, sub);
        if (!eds.count(name)) {
          EXPECT_EQ(b.upload(index, static_cast<std::uint8_t>(sub)).abort, 0x06090011u) << name;
          continue;
        }
        ++found;
        vars.emplace_back(name, static_cast<std::uint8_t>(sub));
      }
      EXPECT_EQ(found, subs) << sec;
    }
    for (const auto& [name, sub] : vars) {
      const auto& v = eds.at(name);
      const auto served_value = b.upload(index, sub);
      ASSERT_TRUE(served_value.ok) << name;
      const auto type = std::stoul(v.at("DataType"), nullptr, 0);
      const std::string access = v.at("AccessType");
      const bool live = v.at("PDOMapping") == "1" || index == 0x1001 || index == 0x6500;
      if (type == 0x0009) {
        EXPECT_EQ(served_value.text(), v.at("DefaultValue")) << name;
      } else {
        const std::size_t bytes = type == 0x0005 ? 1 : type == 0x0006 ? 2 : 4;
        EXPECT_EQ(served_value.data.size(), bytes) << name;
        if (!live) {
          EXPECT_EQ(served_value.u32(), eds_number(v.at("DefaultValue"), kId)) << name;
        }
      }
      // The access type is the one the node enforces.
      if (access == "ro" || access == "const") {
        EXPECT_EQ(b.download(index, sub, served_value.u32(), static_cast<int>(std::min<std::size_t>(4, served_value.data.size()))).abort,
                  0x06010002u)
            << name;
      } else {
        EXPECT_EQ(access, "rw") << name;
        // Mapping entries change only while 1A00h:00 is 0 (CiA 301's mapping procedure).
        const bool mapping_entry = index == 0x1A00 && sub > 0;
        const std::uint32_t mapped = b.upload(0x1A00, 0).u32();
        if (mapping_entry) {
          EXPECT_EQ(b.download(index, sub, served_value.u32(), 4).abort, 0x08000022u) << name;
          ASSERT_TRUE(b.download(0x1A00, 0, 0, 1).ok);
        }
        EXPECT_TRUE(b.download(index, sub, served_value.u32(), static_cast<int>(served_value.data.size())).ok) << name;
        if (mapping_entry) {
          ASSERT_TRUE(b.download(0x1A00, 0, mapped, 1).ok);
        }
      }
      ++compared;
    }
  }
  EXPECT_GE(compared, 30);
}
