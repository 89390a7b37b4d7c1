// Per-sensor Hall output versus carriage position over the whole travel. Every
// magnet period keeps its own entries: with magnet tolerances of tens of um a
// single folded period would already exceed the 5 um budget.
#pragma once

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "motor.hpp"

namespace ve::core {

struct HallTable {
  double start_m = 0.0;  ///< carriage position of grid point 0 [m]
  double step_m = 0.0;   ///< grid spacing [m]
  int points = 0;        ///< grid points per sensor
  int sensors = 0;
  /// sensors * points values, sensor-major: v[s * points + k] is sensor s at start_m + k * step_m [V].
  std::vector<double> v;

  double end_m() const { return start_m + step_m * (points - 1); }
  bool contains(double x_m) const { return x_m >= start_m && x_m <= end_m(); }
  bool valid() const {
    return points >= 4 && sensors > 0 && step_m > 0.0 &&
           v.size() == static_cast<std::size_t>(points) * static_cast<std::size_t>(sensors);
  }

  /// Output of `sensor` at `x_m` and its slope dV/dx [V/m]: cubic (Catmull-Rom)
  /// interpolation; positions outside the grid are clamped to it. (Inline: it runs
  /// for every sensor several times per sample.)
  void evaluate(int sensor, double x_m, double& value_v, double& slope_v_per_m) const {
    int k;
    double t;
    locate(x_m, k, t);
    interpolate(sensor, k, t, value_v, slope_v_per_m);
  }
  /// evaluate() for sensors 0 .. count - 1 at one position (the grid cell found once).
  void evaluate_sensors(int count, double x_m, double* value_v, double* slope_v_per_m) const {
    int k;
    double t;
    locate(x_m, k, t);
    for (int s = 0; s < count; ++s) interpolate(s, k, t, value_v[s], slope_v_per_m[s]);
  }
  /// The grid interval [k, k + 1] holding `x_m` (clamped to the grid) and the
  /// position's fraction `t` of it.
  void locate(double x_m, int& k, double& t) const {
    double u = (x_m - start_m) / step_m;
    u = std::clamp(u, 0.0, static_cast<double>(points - 1));
    k = static_cast<int>(u);
    if (k > points - 2) k = points - 2;
    t = u - k;
  }
  void interpolate(int sensor, int k, double t, double& value_v, double& slope_v_per_m) const {
    const double* row = v.data() + static_cast<std::size_t>(sensor) * static_cast<std::size_t>(points);
    // Catmull-Rom through p0..p3 around the interval [k, k+1]; ends mirror linearly.
    const double p1 = row[k];
    const double p2 = row[k + 1];
    const double p0 = k > 0 ? row[k - 1] : 2.0 * p1 - p2;
    const double p3 = k + 2 < points ? row[k + 2] : 2.0 * p2 - p1;
    const double a = -0.5 * p0 + 1.5 * p1 - 1.5 * p2 + 0.5 * p3;
    const double b = p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3;
    const double c = -0.5 * p0 + 0.5 * p2;
    value_v = ((a * t + b) * t + c) * t + p1;
    slope_v_per_m = ((3.0 * a * t + 2.0 * b) * t + c) / step_m;
  }
  double value(int sensor, double x_m) const {
    double val, slope;
    evaluate(sensor, x_m, val, slope);
    return val;
  }
};

/// The table a perfect motor of this description would have (no calibration).
/// Grid: the whole travel at pitch / points_per_pitch.
HallTable nominal_hall_table(const MotorConfig& motor, int points_per_pitch = 256);

/// What identifies a calibration and what it must match to be used.
struct CalibrationInfo {
  std::string motor;         ///< MotorConfig::name it was made for
  int hall_count = 0;
  double magnet_pitch_m = 0.0;
  std::string method;        ///< e.g. "reference"
  std::string created_utc;   ///< ISO 8601
  std::string id;            ///< checksum of the table, hex; names this calibration
};

struct Calibration {
  CalibrationInfo info;
  HallTable table;
  SensorModel model;  ///< delays, coil field, accelerometer bias and scale
};

/// FNV-1a 64 of the table's numbers and grid and of the sensor model, as 16 hex
/// digits. Values are rounded (1 uV, 1 nm, 1 ns, ...) before hashing, so a decimal
/// text round trip at that precision reproduces it.
std::string calibration_checksum(const HallTable& table, const SensorModel& model);
inline std::string calibration_checksum(const Calibration& cal) { return calibration_checksum(cal.table, cal.model); }

}  // namespace ve::core
