// Samples that flow from a sensor source into the estimation core.
#pragma once

#include <array>
#include <cstdint>

namespace ve::core {

/// Most Hall sensors one axis can carry; fixed so that samples never allocate.
inline constexpr int kMaxHalls = 8;

/// One synchronous reading of an axis' sensors, as a driver delivers it.
struct RawSample {
  std::int64_t t_ns = 0;     ///< sample instant on the source's clock [ns]
  std::uint64_t seq = 0;     ///< source sequence number, +1 per sample
  int hall_count = 0;        ///< entries of hall_v in use
  std::array<double, kMaxHalls> hall_v{};  ///< Hall outputs as read [V]
  std::uint32_t hall_valid_mask = 0;       ///< bit i set: hall_v[i] was received
  double accel_mps2 = 0.0;                 ///< accelerometer on the moving part [m/s^2]
  bool accel_valid = false;
  double accel_base_mps2 = 0.0;            ///< optional accelerometer on the frame [m/s^2]
  bool accel_base_valid = false;
  double temperature_c = 0.0;              ///< optional temperature reported by the sensor node [deg C]
  bool temperature_valid = false;
};

/// Ground truth that only a simulator (or a recorded reference) can provide.
struct Truth {
  double position_m = 0.0;
  double velocity_mps = 0.0;
  double acceleration_mps2 = 0.0;
};

}  // namespace ve::core
