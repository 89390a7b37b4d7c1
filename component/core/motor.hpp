// Nominal description of a motor and its sensors, plus the estimator tuning.
// Plain structs with defaults in class; units in the names. Only the config
// loader (component/config) knows YAML.
#pragma once

#include <cmath>
#include <string>
#include <vector>

namespace ve::core {

struct HallConfig {
  int count = 4;
  /// Position of each sensor along the moving part relative to sensor 0 [m].
  /// Empty: sensors spaced by spacing_m (the paper: pitch / 8).
  std::vector<double> offsets_m;
  double spacing_m = 0.012 / 8.0;
  double offset_v = 2.5;                      ///< output at zero field [V]
  double amplitude_v = 2.5 * std::sqrt(2.0);  ///< unclamped peak about offset_v [V]
  double noise_v = 0.0006;                    ///< output noise, one sigma [V]
  /// Readings closer than this to an ADC rail count as saturated and carry no position [V].
  double saturation_margin_v = 0.05;

  double offset_of(int i) const {
    return offsets_m.empty() ? i * spacing_m : offsets_m[static_cast<std::size_t>(i)];
  }
};

struct AdcConfig {
  int bits = 12;
  double min_v = 0.0;
  double max_v = 5.0;
  double lsb_v() const { return (max_v - min_v) / static_cast<double>((1 << bits) - 1); }
};

struct AccelerometerConfig {
  double noise_mps2 = 0.02;   ///< white noise per sample, one sigma [m/s^2]
  double range_mps2 = 160.0;  ///< full scale; readings at or beyond it are saturated [m/s^2]
};

/// Block K tuning (the paper's Kalman filter on [x, v, a]).
struct FilterConfig {
  /// Process noise: white jerk driving the acceleration state, one sigma per
  /// sample expressed as a jerk [m/s^3]. Q(2,2) = (jerk_std_mps3 * Ts)^2.
  double jerk_std_mps3 = 60.0;
  /// Floor added to the Hall position variance computed from sensor slopes [m].
  double hall_position_floor_m = 0.2e-6;
  /// Innovation gate on the Hall position, in standard deviations.
  double gate_sigma = 6.0;
  /// Initial standard deviations of the state.
  double initial_position_std_m = 1e-3;
  double initial_velocity_std_mps = 1.0;
  double initial_acceleration_std_mps2 = 10.0;
};

struct MotorConfig {
  std::string name = "sim-12mm";
  double magnet_pitch_m = 0.012;
  double travel_m = 1.0;
  double sample_rate_hz = 4000.0;
  HallConfig hall;
  AdcConfig adc;
  AccelerometerConfig accelerometer;
  FilterConfig filter;

  double sample_period_s() const { return 1.0 / sample_rate_hz; }
};

}  // namespace ve::core
