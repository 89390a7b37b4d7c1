// The estimator's state handed to a CANopen node: one writer (the axis' sample
// loop), any number of readers (the node's thread). A ring of sequence-locked slots
// over atomics: the writer never waits, a reader retries the few times a write
// overlapped it. No allocation, no system call.
#pragma once

#include <array>
#include <atomic>
#include <climits>
#include <cstdint>

namespace ve::canopen {

struct AxisSnapshot {
  bool present = false;        ///< false until the first estimate
  std::int64_t t_ns = 0;       ///< CLOCK_REALTIME instant the estimate stands for [ns]
  double position_m = 0.0;
  double velocity_mps = 0.0;
  double acceleration_mps2 = 0.0;
  std::uint32_t status = 0;    ///< the product's status word (core/status.hpp)
};

/// The last kHistory estimates, so that a reader late by up to kHistory sample periods
/// (a SYNC handled after newer estimates came in) still finds the estimate that was
/// current at a given instant.
class SnapshotBox {
 public:
  static constexpr std::uint64_t kHistory = 1024;

  /// Single writer: an estimate for the instant `t_ns` is being computed (its
  /// publish() follows). A reader answering a SYNC after `t_ns` may wait for it
  /// (settled()) rather than use the estimate before it.
  void begin(std::int64_t t_ns) { pending_.store(t_ns, std::memory_order_release); }
  /// Single writer, before reading the clock for begin(): an estimate of an instant
  /// not yet known is coming (a SYNC waits for it too).
  void claim() { pending_.store(kClaimed, std::memory_order_release); }
  /// False while an estimate for an instant at or before `t_ns` (or of an instant not
  /// yet stamped) is being computed.
  bool settled(std::int64_t t_ns) const {
    const std::int64_t p = pending_.load(std::memory_order_acquire);
    return p == 0 || (p != kClaimed && p > t_ns);
  }

  /// Single writer.
  void publish(const AxisSnapshot& s) {
    const std::uint64_t k = count_.load(std::memory_order_relaxed);
    Slot& slot = slots_[k % kHistory];
    const std::uint32_t q = slot.seq.load(std::memory_order_relaxed);
    slot.seq.store(q + 1, std::memory_order_relaxed);  // odd: write in progress
    std::atomic_thread_fence(std::memory_order_release);
    slot.index.store(k, std::memory_order_relaxed);
    slot.t_ns.store(s.t_ns, std::memory_order_relaxed);
    slot.x.store(s.position_m, std::memory_order_relaxed);
    slot.v.store(s.velocity_mps, std::memory_order_relaxed);
    slot.a.store(s.acceleration_mps2, std::memory_order_relaxed);
    slot.status.store(s.status, std::memory_order_relaxed);
    slot.seq.store(q + 2, std::memory_order_release);
    count_.store(k + 1, std::memory_order_release);
    pending_.store(0, std::memory_order_release);
  }

  /// The newest estimate. False when none was published yet (`out.present` false) or
  /// writes kept overlapping the read.
  bool read(AxisSnapshot& out) const { return read_at(INT64_MAX, out); }

  /// The newest estimate whose instant is at or before `t_ns`; when every estimate
  /// kept is newer, the oldest kept one. False (out.present false) when none was
  /// published yet or reads kept being overtaken.
  bool read_at(std::int64_t t_ns, AxisSnapshot& out) const {
    out = AxisSnapshot{};
    const std::uint64_t n = count_.load(std::memory_order_acquire);
    if (n == 0) return false;
    const std::uint64_t oldest = n > kHistory ? n - kHistory + 1 : 0;  // the slot being written next is skipped
    bool have = false;
    for (std::uint64_t i = n; i-- > oldest;) {
      AxisSnapshot s;
      if (!read_slot(i, s)) break;  // overwritten meanwhile: older ones are too
      out = s;
      have = true;
      if (s.t_ns <= t_ns) return true;
    }
    return have;
  }

  std::uint64_t writes() const { return count_.load(std::memory_order_acquire); }

 private:
  struct Slot {
    std::atomic<std::uint32_t> seq{0};
    std::atomic<std::uint64_t> index{0};
    std::atomic<std::int64_t> t_ns{0};
    std::atomic<double> x{0.0}, v{0.0}, a{0.0};
    std::atomic<std::uint32_t> status{0};
  };

  bool read_slot(std::uint64_t i, AxisSnapshot& out) const {
    const Slot& slot = slots_[i % kHistory];
    for (int attempt = 0; attempt < 16; ++attempt) {
      const std::uint32_t q0 = slot.seq.load(std::memory_order_acquire);
      if (q0 & 1u) continue;
      AxisSnapshot s;
      s.present = true;
      const std::uint64_t index = slot.index.load(std::memory_order_relaxed);
      s.t_ns = slot.t_ns.load(std::memory_order_relaxed);
      s.position_m = slot.x.load(std::memory_order_relaxed);
      s.velocity_mps = slot.v.load(std::memory_order_relaxed);
      s.acceleration_mps2 = slot.a.load(std::memory_order_relaxed);
      s.status = slot.status.load(std::memory_order_relaxed);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (slot.seq.load(std::memory_order_relaxed) != q0) continue;
      if (index != i) return false;
      out = s;
      return true;
    }
    return false;
  }

  static constexpr std::int64_t kClaimed = 1;
  std::atomic<std::uint64_t> count_{0};
  std::atomic<std::int64_t> pending_{0};
  std::array<Slot, kHistory> slots_{};
};

/// The estimate propagated to `t_ns` with the filter's velocity and acceleration
/// (constant-acceleration motion over the gap).
inline double propagate_position(const AxisSnapshot& s, std::int64_t t_ns) {
  const double dt = static_cast<double>(t_ns - s.t_ns) * 1e-9;
  return s.position_m + s.velocity_mps * dt + 0.5 * s.acceleration_mps2 * dt * dt;
}
inline double propagate_velocity(const AxisSnapshot& s, std::int64_t t_ns) {
  const double dt = static_cast<double>(t_ns - s.t_ns) * 1e-9;
  return s.velocity_mps + s.acceleration_mps2 * dt;
}

}  // namespace ve::canopen
