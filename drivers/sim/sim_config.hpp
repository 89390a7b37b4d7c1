// Configuration of the simulated motor: motion profile, imperfections, timing.
// The nominal motor (pitch, sensors, ADC) comes from core::MotorConfig; this adds
// what only a simulator has.
#pragma once

#include <cstdint>

namespace ve::sim {

struct MotionProfileConfig {
  enum class Kind { standstill, constant_velocity, constant_acceleration, multisine, shuttle };
  Kind kind = Kind::multisine;
  double start_m = 0.5;               ///< position at t = 0 [m]
  double velocity_mps = 1.0;          ///< constant_velocity: speed; constant_acceleration: initial speed
  double acceleration_mps2 = 5.0;     ///< constant_acceleration
  double max_velocity_mps = 2.0;      ///< multisine, shuttle: peak speed
  double max_acceleration_mps2 = 10.0;///< multisine, shuttle: peak acceleration
  double min_m = 0.05;                ///< shuttle: lower turning point; all profiles stay above it
  double max_m = 0.95;                ///< shuttle: upper turning point; all profiles stay below it
};

/// Deviations of the simulated hardware from the nominal motor. All zero: the
/// ideal motor of the paper. (The accuracy work turns them on.)
struct ImperfectionConfig {
  std::uint64_t track_seed = 7;             ///< fixes magnet tolerances so calibration and run see one track
  double magnet_strength_std = 0.0;         ///< relative, per magnet period
  double magnet_placement_std_m = 0.0;      ///< per magnet boundary
  double sensor_placement_std_m = 0.0;
  double sensor_gain_std = 0.0;             ///< relative
  double sensor_offset_std_v = 0.0;
  double hall_delay_s = 0.0;
  double accel_bias_mps2 = 0.0;
  double accel_scale_error = 0.0;           ///< relative, +0.005 reads 0.5 % high
};

struct SimConfig {
  MotionProfileConfig profile;
  ImperfectionConfig imperfections;
  std::uint64_t noise_seed = 1;  ///< seeds the per-sample sensor noise
  bool realtime = true;          ///< true: one sample per period of wall time; false: as fast as possible
  double duration_s = 0.0;       ///< > 0: the source ends (end_of_stream) after this much simulated time [s]
};

}  // namespace ve::sim
