#include "sim/population.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

namespace ve::sim {

namespace {

constexpr double kTwoPi = 6.283185307179586476925286766559;

/// Uniform draws that are the same on every standard library (the engine is fully
/// specified by the standard; its distributions are not, so none is used).
class Draw {
 public:
  explicit Draw(std::uint64_t seed) : engine_(seed ^ 0x5EED0F0D0A7C0DE5ull) {}
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  int integer(int lo, int hi) { return lo + static_cast<int>(uniform() * (hi - lo + 1)); }
  double sign() { return uniform() < 0.5 ? -1.0 : 1.0; }
  std::uint64_t bits() { return engine_(); }

 private:
  std::mt19937_64 engine_;
};

}  // namespace

void hall_coverage(const core::MotorConfig& motor, int& min_unsaturated, double& fraction_two_or_more) {
  const auto& h = motor.hall;
  const double lo = motor.adc.min_v + h.saturation_margin_v;
  const double hi = motor.adc.max_v - h.saturation_margin_v;
  constexpr int kPhases = 720;
  min_unsaturated = h.count;
  int two = 0;
  for (int k = 0; k < kPhases; ++k) {
    const double theta = kTwoPi * k / kPhases;
    int n = 0;
    for (int i = 0; i < h.count; ++i) {
      const double phi = theta + kTwoPi * h.offset_of(i) / motor.magnet_pitch_m;
      const double v = h.offset_v + h.amplitude_v * std::sin(phi);
      // Out of saturation, and steep enough to carry a position (not at a flat top).
      if (v > lo && v < hi && std::abs(std::cos(phi)) > 0.25) ++n;
    }
    min_unsaturated = std::min(min_unsaturated, n);
    if (n >= 2) ++two;
  }
  fraction_two_or_more = static_cast<double>(two) / kPhases;
}

PopulationMotor draw_population_motor(std::uint64_t seed, const core::FilterConfig& tuning,
                                      const PopulationRanges& r) {
  Draw d(seed);
  PopulationMotor p;
  p.seed = seed;
  core::MotorConfig& m = p.datasheet;
  char name[32];
  std::snprintf(name, sizeof name, "population-%llu", static_cast<unsigned long long>(seed));
  m.name = name;
  m.filter = tuning;
  // Catalogue values are round numbers.
  m.magnet_pitch_m = std::round(d.uniform(r.pitch_min_m, r.pitch_max_m) * 1e4) / 1e4;
  m.travel_m = std::round(d.uniform(r.travel_min_m, r.travel_max_m) * 100.0) / 100.0;
  m.sample_rate_hz = std::round(d.uniform(r.rate_min_hz, r.rate_max_hz) / 100.0) * 100.0;
  m.hall.count = d.integer(r.halls_min, r.halls_max);
  const int bits_choice = d.integer(0, 2);
  m.adc.bits = bits_choice == 0 ? 10 : bits_choice == 1 ? 12 : 16;
  m.adc.min_v = 0.0;
  m.adc.max_v = 5.0;
  m.hall.offset_v = 2.5;
  m.hall.noise_v = std::round(d.uniform(0.3e-3, 1.0e-3) * 1e5) / 1e5;
  m.hall.amplitude_v = std::round(d.uniform(1.8, 3.6) * 100.0) / 100.0;
  m.hall.saturation_margin_v = 0.05;
  m.accelerometer.noise_mps2 = std::round(d.uniform(0.01, 0.04) * 1000.0) / 1000.0;
  m.accelerometer.range_mps2 = 160.0;

  // Sensor spacing: an electrical step of 1/(2N) to 1/N of a period, sometimes a
  // whole period wider (sensors spread over the carriage); redrawn until the array
  // has no blind spot.
  const int n = m.hall.count;
  for (int attempt = 0;; ++attempt) {
    double fraction = d.uniform(0.5, 1.0) / n;
    if (attempt >= 40) fraction = 0.5 / n;  // always covers: kept as the fallback
    const double whole = (attempt < 40 && d.uniform() < 0.25) ? 1.0 : 0.0;
    m.hall.spacing_m = std::round((fraction + whole) * m.magnet_pitch_m * 1e6) / 1e6;
    m.hall.offsets_m.clear();
    int min_n = 0;
    double two = 0.0;
    hall_coverage(m, min_n, two);
    if (min_n >= 1) break;
  }

  // The motor as built.
  p.hardware = m;
  p.hardware.hall.amplitude_v =
      m.hall.amplitude_v * (1.0 + d.uniform(-r.amplitude_datasheet_error_max, r.amplitude_datasheet_error_max));
  p.hardware.hall.noise_v = m.hall.noise_v * d.uniform(0.8, 1.25);
  p.hardware.accelerometer.noise_mps2 = m.accelerometer.noise_mps2 * d.uniform(0.8, 1.25);

  ImperfectionConfig& im = p.sim.imperfections;
  im.track_seed = d.bits();
  im.magnet_strength_std = d.uniform(0.0, r.magnet_strength_max);
  im.magnet_placement_std_m = std::min(d.uniform(0.0, r.magnet_placement_max_m), 0.1 * m.magnet_pitch_m);
  im.field_third_harmonic = d.uniform(-r.third_harmonic_max, r.third_harmonic_max);
  im.sensor_placement_std_m = d.uniform(0.0, r.sensor_placement_max_m);
  im.sensor_gain_std = d.uniform(0.0, r.sensor_gain_max);
  im.sensor_offset_std_v = d.uniform(0.0, r.sensor_offset_max_v);
  im.hall_delay_s = std::round(d.uniform(0.0, r.hall_delay_max_s) * 1e7) / 1e7;
  im.coil_field_v_per_mps2 = d.sign() * d.uniform(0.0, r.coil_field_max_v_per_mps2);
  im.accel_bias_mps2 = d.uniform(-0.1, 0.1);
  im.accel_scale_error = d.uniform(-0.01, 0.01);
  im.accel_bias_random_walk_mps2_per_sqrt_s = d.uniform(0.0, 2e-4);
  im.accel_delay_s = d.uniform(0.0, r.accel_delay_max_s);
  im.frame_reaction_ratio = -d.uniform(0.0, 0.05);
  im.frame_vibration_mps2 = d.uniform(0.0, 0.05);
  im.frame_vibration_hz = d.uniform(20.0, 80.0);
  im.frame_accelerometer = false;
  p.sim.noise_seed = d.bits();
  p.sim.realtime = false;
  return p;
}

std::string PopulationMotor::summary() const {
  const auto& m = datasheet;
  const auto& im = sim.imperfections;
  char buf[512];
  std::snprintf(buf, sizeof buf,
                "motor %llu: pitch %.1f mm, %d Halls %.3f mm apart, %.0f Hz, travel %.2f m, %d-bit ADC, "
                "amplitude %.2f V (data sheet %.2f), Hall delay %.0f us, accel delay %.0f us, magnets %.0f um / %.1f %%, "
                "sensors %.0f um / gain %.1f %% / offset %.0f mV, coil %.2f mV/(m/s^2), h3 %+.3f",
                static_cast<unsigned long long>(seed), m.magnet_pitch_m * 1e3, m.hall.count, m.hall.spacing_m * 1e3,
                m.sample_rate_hz, m.travel_m, m.adc.bits, hardware.hall.amplitude_v, m.hall.amplitude_v,
                im.hall_delay_s * 1e6, im.accel_delay_s * 1e6, im.magnet_placement_std_m * 1e6,
                im.magnet_strength_std * 100.0, im.sensor_placement_std_m * 1e6, im.sensor_gain_std * 100.0,
                im.sensor_offset_std_v * 1e3, im.coil_field_v_per_mps2 * 1e3, im.field_third_harmonic);
  return buf;
}

}  // namespace ve::sim
