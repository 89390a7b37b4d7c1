#include "hall_table.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace ve::core {

HallTable nominal_hall_table(const MotorConfig& motor, int points_per_pitch) {
  HallTable table;
  table.step_m = motor.magnet_pitch_m / points_per_pitch;
  table.start_m = 0.0;
  table.points = static_cast<int>(std::ceil(motor.travel_m / table.step_m)) + 1;
  table.sensors = motor.hall.count;
  table.v.resize(static_cast<std::size_t>(table.points) * static_cast<std::size_t>(table.sensors));
  const double k = 2.0 * M_PI / motor.magnet_pitch_m;
  for (int s = 0; s < table.sensors; ++s) {
    const double offset = motor.hall.offset_of(s);
    for (int i = 0; i < table.points; ++i) {
      const double x = table.start_m + i * table.step_m;
      const double y = motor.hall.offset_v + motor.hall.amplitude_v * std::sin(k * (x + offset));
      table.v[static_cast<std::size_t>(s) * table.points + i] = std::clamp(y, motor.adc.min_v, motor.adc.max_v);
    }
  }
  return table;
}

std::string calibration_checksum(const HallTable& table, const SensorModel& model) {
  std::uint64_t h = 1469598103934665603ull;
  auto mix = [&h](const void* data, std::size_t n) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) {
      h ^= p[i];
      h *= 1099511628211ull;
    }
  };
  // Hash values rounded to 1 uV and 1 nm so that a decimal text round trip is stable.
  auto mix_rounded = [&mix](double x, double unit) {
    const auto q = static_cast<std::int64_t>(std::llround(x / unit));
    mix(&q, sizeof q);
  };
  mix_rounded(table.start_m, 1e-9);
  mix_rounded(table.step_m, 1e-12);
  mix(&table.points, sizeof table.points);
  mix(&table.sensors, sizeof table.sensors);
  for (double x : table.v) mix_rounded(x, 1e-6);
  mix_rounded(model.hall_delay_s, 1e-9);
  mix_rounded(model.coil_field_v_per_mps2, 1e-9);
  mix_rounded(model.accel_delay_s, 1e-9);
  mix_rounded(model.accel_bias_mps2, 1e-7);
  mix_rounded(model.accel_scale, 1e-9);
  mix_rounded(model.frame_vibration_hz, 1e-6);
  mix_rounded(model.frame_vibration_mps2, 1e-7);
  // Only when recorded, so that files without it keep their checksum.
  if (std::isfinite(model.temperature_c)) mix_rounded(model.temperature_c, 1e-3);
  if (model.track_scale_std > 0.0) mix_rounded(model.track_scale_std, 1e-10);
  if (model.accel_delay_std_s > 0.0) mix_rounded(model.accel_delay_std_s, 1e-9);
  if (model.hall_fix_excess_std_m > 0.0) mix_rounded(model.hall_fix_excess_std_m, 1e-9);
  if (model.coil_field_std_v_per_mps2 > 0.0) mix_rounded(model.coil_field_std_v_per_mps2, 1e-9);
  if (model.table_noise_v > 0.0) mix_rounded(model.table_noise_v, 1e-9);
  if (model.trusted_span_known()) {
    mix_rounded(model.table_trusted_from_m, 1e-9);
    mix_rounded(model.table_trusted_to_m, 1e-9);
    mix_rounded(model.table_outside_std_m, 1e-10);
  }
  if (model.thermal_known) {
    mix_rounded(model.thermal_rise_k, 1e-6);
    if (std::isfinite(model.common_tc_per_k)) mix_rounded(model.common_tc_per_k, 1e-12);
    if (std::isfinite(model.common_tc_rel_std)) mix_rounded(model.common_tc_rel_std, 1e-9);
    for (int i = 0; i < kMaxHalls; ++i) {
      const auto k = static_cast<std::size_t>(i);
      mix_rounded(model.hall_gain_tc_per_k[k], 1e-12);
      mix_rounded(model.hall_gain_tc_std_per_k[k], 1e-12);
      mix_rounded(model.hall_offset_tc_v_per_k[k], 1e-12);
      mix_rounded(model.hall_offset_tc_std_v_per_k[k], 1e-12);
    }
  }
  static const char* kHex = "0123456789abcdef";
  std::string out(16, '0');
  for (int i = 15; i >= 0; --i) {
    out[static_cast<std::size_t>(i)] = kHex[h & 0xF];
    h >>= 4;
  }
  return out;
}

}  // namespace ve::core
