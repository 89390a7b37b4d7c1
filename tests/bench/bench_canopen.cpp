// The CiA 406 node's share of the SYNC-to-TPDO delay: Node::on_frame for a SYNC up to
// the TPDO in its outbox (estimate lookup in the ring, propagation, packing), and an
// SDO upload. The kernel's and the scheduler's share is measured by the SocketCAN VM
// test (tests/vm/canopen_vm_test.cpp), which prints p50/p99 from kernel time stamps.
#include <benchmark/benchmark.h>

#include "canopen/node.hpp"
#include "core/status.hpp"

using namespace ve;

namespace {

constexpr std::int64_t kT0 = 1700000000LL * 1000000000LL;

struct Fixture {
  canopen::SnapshotBox box;
  canopen::Node node;
  canopen::Outbox out;
  explicit Fixture(bool map_speed) : node(config(map_speed), &box) {
    node.start(0, out);
    canopen::Frame start;
    start.id = 0;
    start.len = 2;
    start.data[0] = 0x01;
    start.data[1] = 5;
    node.on_frame(start, kT0, 0, out);
    // A full ring, 4 kHz estimates.
    for (std::uint64_t i = 0; i < canopen::SnapshotBox::kHistory; ++i) {
      canopen::AxisSnapshot s;
      s.present = true;
      s.t_ns = kT0 + static_cast<std::int64_t>(i) * 250000;
      s.position_m = 0.5 + 1e-5 * static_cast<double>(i);
      s.velocity_mps = 0.04;
      s.acceleration_mps2 = 0.5;
      s.status = core::status::kValid | core::status::kHomed;
      box.publish(s);
    }
    out.clear();
  }
  static canopen::NodeConfig config(bool map_speed) {
    canopen::NodeConfig c;
    c.node_id = 5;
    c.transmission_type = 1;
    if (map_speed) c.tpdo_mapping.push_back(canopen::Mapped::speed);
    return c;
  }
};

/// `back`: how many estimates newer than the SYNC arrived before it was handled.
void sync_to_tpdo(benchmark::State& state) {
  Fixture f(state.range(1) != 0);
  canopen::Frame sync;
  sync.id = 0x080;
  const std::int64_t newest = kT0 + static_cast<std::int64_t>(canopen::SnapshotBox::kHistory - 1) * 250000;
  const std::int64_t t_sync = newest - state.range(0) * 250000 + 100000;
  for (auto _ : state) {
    f.node.on_frame(sync, t_sync, 1, f.out);
    benchmark::DoNotOptimize(f.out.frames[0]);
    f.out.clear();
  }
}
BENCHMARK(sync_to_tpdo)->ArgsProduct({{0, 4, 40}, {0, 1}})->ArgNames({"estimates_newer", "speed_mapped"});

void sdo_upload_position(benchmark::State& state) {
  Fixture f(false);
  canopen::Frame req;
  req.id = 0x605;
  req.len = 8;
  req.data = {0x40, 0x04, 0x60, 0x00, 0, 0, 0, 0};
  const std::int64_t now = kT0 + static_cast<std::int64_t>(canopen::SnapshotBox::kHistory) * 250000;
  for (auto _ : state) {
    f.node.on_frame(req, now, 1, f.out);
    benchmark::DoNotOptimize(f.out.frames[0]);
    f.out.clear();
  }
}
BENCHMARK(sdo_upload_position);

}  // namespace

BENCHMARK_MAIN();
