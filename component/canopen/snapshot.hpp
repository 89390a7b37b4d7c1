// The estimator's state handed to a CANopen node: one writer (the axis' sample
// loop), any number of readers (the node's thread). A sequence lock over atomics:
// the writer never waits, a reader retries the few times a write overlapped it.
// No allocation, no system call.
#pragma once

#include <atomic>
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

class SnapshotBox {
 public:
  /// Single writer.
  void publish(const AxisSnapshot& s) {
    const std::uint32_t q = seq_.load(std::memory_order_relaxed);
    seq_.store(q + 1, std::memory_order_relaxed);  // odd: write in progress
    std::atomic_thread_fence(std::memory_order_release);
    t_ns_.store(s.t_ns, std::memory_order_relaxed);
    x_.store(s.position_m, std::memory_order_relaxed);
    v_.store(s.velocity_mps, std::memory_order_relaxed);
    a_.store(s.acceleration_mps2, std::memory_order_relaxed);
    status_.store(s.status, std::memory_order_relaxed);
    present_.store(s.present, std::memory_order_relaxed);
    seq_.store(q + 2, std::memory_order_release);
  }

  /// A consistent copy; false only when writes kept overlapping (then `out` is unchanged).
  bool read(AxisSnapshot& out) const {
    for (int attempt = 0; attempt < 64; ++attempt) {
      const std::uint32_t q0 = seq_.load(std::memory_order_acquire);
      if (q0 & 1u) continue;
      AxisSnapshot s;
      s.t_ns = t_ns_.load(std::memory_order_relaxed);
      s.position_m = x_.load(std::memory_order_relaxed);
      s.velocity_mps = v_.load(std::memory_order_relaxed);
      s.acceleration_mps2 = a_.load(std::memory_order_relaxed);
      s.status = status_.load(std::memory_order_relaxed);
      s.present = present_.load(std::memory_order_relaxed);
      std::atomic_thread_fence(std::memory_order_acquire);
      if (seq_.load(std::memory_order_relaxed) == q0) {
        out = s;
        return true;
      }
    }
    return false;
  }

  std::uint32_t writes() const { return seq_.load(std::memory_order_acquire) / 2; }

 private:
  std::atomic<std::uint32_t> seq_{0};
  std::atomic<std::int64_t> t_ns_{0};
  std::atomic<double> x_{0.0}, v_{0.0}, a_{0.0};
  std::atomic<std::uint32_t> status_{0};
  std::atomic<bool> present_{false};
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
