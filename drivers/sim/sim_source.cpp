#include "sim/sim_source.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/identification.hpp"
#include "pacing.hpp"

namespace ve::sim {

namespace {

constexpr double kTwoPi = 6.283185307179586476925286766559;

std::uint64_t splitmix(std::uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// Counter-based generator: a stream of uniforms determined by (seed, key) alone, so a
/// sample's noise or a magnet's tolerance does not depend on what was drawn before it.
class Stream {
 public:
  Stream(std::uint64_t seed, std::uint64_t key) : state_(splitmix(seed ^ splitmix(key))) {}

  /// Uniform in [0, 1).
  double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }

  /// Standard normal; Box-Muller, both outputs used.
  double normal() {
    if (have_spare_) {
      have_spare_ = false;
      return spare_;
    }
    const double u1 = (static_cast<double>(next() >> 11) + 1.0) * 0x1.0p-53;  // (0, 1]: log is finite
    const double u2 = static_cast<double>(next() >> 11) * 0x1.0p-53;
    const double r = std::sqrt(-2.0 * std::log(u1));
    spare_ = r * std::sin(kTwoPi * u2);
    have_spare_ = true;
    return r * std::cos(kTwoPi * u2);
  }

 private:
  std::uint64_t next() { return splitmix(state_ += 0x9E3779B97F4A7C15ull); }
  std::uint64_t state_;
  double spare_ = 0.0;
  bool have_spare_ = false;
};

// Keys of the track draws (from track_seed); the index goes in the low bits.
constexpr std::uint64_t kKeyBoundary = 1ull << 60;
constexpr std::uint64_t kKeyStrength = 2ull << 60;
constexpr std::uint64_t kKeySensor = 3ull << 60;
constexpr std::uint64_t kKeySensorTemperature = 4ull << 60;  // per-sensor temperature coefficients
// Keys of per-sample streams besides the Hall + accelerometer noise (from noise_seed;
// the sample index goes in the low bits): independent of that noise and of each other.
constexpr std::uint64_t kKeyBiasWalk = 5ull << 60;
constexpr std::uint64_t kKeyBaseAccel = 6ull << 60;
constexpr std::uint64_t kKeyFault = 7ull << 60;
constexpr std::uint64_t kKeyTemperatureReport = 8ull << 60;
constexpr std::uint64_t kKeySilence = 9ull << 60;  // the bias walk over the samples a silent node lost

double track_normal(std::uint64_t seed, std::uint64_t key, std::int64_t index) {
  return Stream(seed, key ^ (static_cast<std::uint64_t>(index) & ((1ull << 60) - 1))).normal();
}

bool finite_nonneg(double x) { return std::isfinite(x) && x >= 0.0; }

}  // namespace

std::string SimSource::check(const core::MotorConfig& motor, const SimConfig& cfg) {
  auto say = [](const char* format, double a = 0.0, double b = 0.0) {
    char buf[256];
    std::snprintf(buf, sizeof buf, format, a, b);
    return std::string("sim: ") + buf;
  };
  if (!(std::isfinite(motor.sample_rate_hz) && motor.sample_rate_hz > 0.0))
    return say("sample_rate_hz %g must be positive", motor.sample_rate_hz);
  if (!(std::isfinite(motor.magnet_pitch_m) && motor.magnet_pitch_m > 0.0))
    return say("magnet_pitch_m %g must be positive", motor.magnet_pitch_m);
  if (motor.hall.count < 1 || motor.hall.count > core::kMaxHalls)
    return say("hall count %g must be 1..%g", motor.hall.count, core::kMaxHalls);
  if (!motor.hall.offsets_m.empty() && motor.hall.offsets_m.size() < static_cast<std::size_t>(motor.hall.count))
    return say("%g hall offsets given for %g sensors", static_cast<double>(motor.hall.offsets_m.size()),
               motor.hall.count);
  for (int i = 0; i < motor.hall.count; ++i)
    if (!std::isfinite(motor.hall.offset_of(i))) return say("hall offset %g is not finite", i);
  if (!std::isfinite(motor.hall.offset_v) || !std::isfinite(motor.hall.amplitude_v) ||
      !finite_nonneg(motor.hall.noise_v))
    return say("hall offset_v, amplitude_v and noise_v (>= 0) must be finite");
  if (motor.adc.bits < 1 || motor.adc.bits > 30) return say("adc bits %g must be 1..30", motor.adc.bits);
  if (!(std::isfinite(motor.adc.min_v) && std::isfinite(motor.adc.max_v) && motor.adc.min_v < motor.adc.max_v))
    return say("adc range [%g, %g] V is empty", motor.adc.min_v, motor.adc.max_v);
  if (!finite_nonneg(motor.accelerometer.noise_mps2) || !(motor.accelerometer.range_mps2 > 0.0) ||
      !std::isfinite(motor.accelerometer.range_mps2))
    return say("accelerometer noise must be >= 0 and range > 0");

  const ImperfectionConfig& im = cfg.imperfections;
  if (!finite_nonneg(im.magnet_strength_std) || !finite_nonneg(im.magnet_placement_std_m) ||
      !finite_nonneg(im.sensor_placement_std_m) || !finite_nonneg(im.sensor_gain_std) ||
      !finite_nonneg(im.sensor_offset_std_v))
    return say("imperfection standard deviations must be finite and >= 0");
  if (im.magnet_placement_std_m > 0.1 * motor.magnet_pitch_m)
    return say("magnet_placement_std_m %g m is more than a tenth of the pitch (%g m)", im.magnet_placement_std_m,
               motor.magnet_pitch_m);
  if (!std::isfinite(im.hall_delay_s) || !std::isfinite(im.accel_bias_mps2) || !std::isfinite(im.accel_scale_error))
    return say("hall_delay_s, accel_bias_mps2 and accel_scale_error must be finite");
  if (!(std::abs(im.field_third_harmonic) <= kMaxThirdHarmonic))
    return say("field_third_harmonic %g must be within +-%g", im.field_third_harmonic, kMaxThirdHarmonic);
  if (!std::isfinite(im.coil_field_v_per_mps2)) return say("coil_field_v_per_mps2 must be finite");
  if (!finite_nonneg(im.accel_bias_random_walk_mps2_per_sqrt_s) || !finite_nonneg(im.accel_delay_s))
    return say("accel_bias_random_walk_mps2_per_sqrt_s and accel_delay_s must be finite and >= 0");
  if (!std::isfinite(im.frame_reaction_ratio) || !finite_nonneg(im.frame_vibration_mps2) ||
      !finite_nonneg(im.frame_vibration_hz))
    return say("frame_reaction_ratio must be finite, frame_vibration_mps2 and frame_vibration_hz finite and >= 0");
  const TemperatureConfig& tc = cfg.temperature;
  if (!std::isfinite(tc.delta_k) || !std::isfinite(tc.offset_k) ||
      !(std::abs(tc.delta_k) + std::abs(tc.offset_k) <= kMaxTemperatureRiseK))
    return say("temperature offset_k and delta_k must be finite, |offset_k| + |delta_k| <= %g K", kMaxTemperatureRiseK);
  if (!finite_nonneg(tc.start_s)) return say("temperature start_s %g must be >= 0", tc.start_s);
  if (!finite_nonneg(tc.duration_s) ||
      ((tc.profile == TemperatureConfig::Profile::ramp || tc.profile == TemperatureConfig::Profile::warmup) &&
       !(tc.duration_s > 0.0)))
    return say("temperature duration_s %g must be > 0 for a ramp or warmup profile", tc.duration_s);
  if (!(std::abs(tc.magnet_remanence_per_k) <= kMaxTemperatureCoefficientPerK) ||
      !(std::abs(tc.hall_gain_tc_per_k) <= kMaxTemperatureCoefficientPerK))
    return say("temperature magnet_remanence_per_k and hall_gain_tc_per_k must be within +-%g per K",
               kMaxTemperatureCoefficientPerK);
  if (!finite_nonneg(tc.hall_gain_tc_std_per_k) || tc.hall_gain_tc_std_per_k > kMaxTemperatureCoefficientStdPerK)
    return say("temperature hall_gain_tc_std_per_k %g must be in [0, %g] per K", tc.hall_gain_tc_std_per_k,
               kMaxTemperatureCoefficientStdPerK);
  if (!finite_nonneg(tc.hall_offset_tc_std_v_per_k) || tc.hall_offset_tc_std_v_per_k > kMaxHallOffsetDriftStdVPerK)
    return say("temperature hall_offset_tc_std_v_per_k %g must be in [0, %g] V/K", tc.hall_offset_tc_std_v_per_k,
               kMaxHallOffsetDriftStdVPerK);
  if (!std::isfinite(tc.reference_c)) return say("temperature reference_c must be finite");
  if (!finite_nonneg(tc.report_noise_k) || !finite_nonneg(tc.report_resolution_k))
    return say("temperature report_noise_k and report_resolution_k must be finite and >= 0");
  if (!finite_nonneg(cfg.duration_s)) return say("duration_s %g must be >= 0 (0: unlimited)", cfg.duration_s);

  std::string why;
  if (!MotionProfile::create(cfg.profile, motor.travel_m, &why)) return "sim: " + why;
  return {};
}

SimSource::SimSource(const core::MotorConfig& motor, const SimConfig& cfg, double start_time_s)
    : motor_(motor), cfg_(cfg) {
  error_ = check(motor, cfg);
  if (error_.empty() && !(std::isfinite(start_time_s) && start_time_s >= 0.0))
    error_ = "sim: start time must be >= 0";
  if (!error_.empty()) return;
  profile_ = *MotionProfile::create(cfg.profile, motor.travel_m);

  wavenumber_rad_per_m_ = kTwoPi / motor.magnet_pitch_m;
  lsb_v_ = motor.adc.lsb_v();
  max_code_ = (1 << motor.adc.bits) - 1;
  first_index_ = static_cast<std::uint64_t>(std::llround(start_time_s * motor.sample_rate_hz));
  {
    const ImperfectionConfig& im = cfg.imperfections;
    third_harmonic_ = im.field_third_harmonic;
    frame_moves_ = im.frame_reaction_ratio != 0.0 || im.frame_vibration_mps2 != 0.0;
    frame_omega_rps_ = kTwoPi * im.frame_vibration_hz;
    bias_step_mps2_ = im.accel_bias_random_walk_mps2_per_sqrt_s * std::sqrt(motor.sample_period_s());
  }
  for (int f = 0; f < cfg.fault_count && f < kMaxFaults; ++f)
    if (cfg.faults[f].kind == FaultConfig::Kind::no_samples) has_silence_ = true;
  if (cfg.duration_s > 0.0)
    max_samples_ = static_cast<std::uint64_t>(std::ceil(cfg.duration_s * motor.sample_rate_hz - 1e-6));

  const ImperfectionConfig& im = cfg.imperfections;
  sensors_.resize(static_cast<std::size_t>(motor.hall.count));
  for (int i = 0; i < motor.hall.count; ++i) {
    Stream draw(im.track_seed, kKeySensor ^ static_cast<std::uint64_t>(i));
    Sensor& s = sensors_[static_cast<std::size_t>(i)];
    // Multiplying a finite draw by a zero std gives exactly 0: no effect when disabled.
    s.gain = 1.0 + im.sensor_gain_std * draw.normal();
    s.offset_v = im.sensor_offset_std_v * draw.normal();
    s.position_m = motor.hall.offset_of(i) + im.sensor_placement_std_m * draw.normal();
    // Its own stream: the draws above stay what they were before the temperature model.
    Stream tc_draw(im.track_seed, kKeySensorTemperature ^ static_cast<std::uint64_t>(i));
    s.gain_tc_per_k = cfg.temperature.hall_gain_tc_per_k + cfg.temperature.hall_gain_tc_std_per_k * tc_draw.normal();
    s.offset_tc_v_per_k = cfg.temperature.hall_offset_tc_std_v_per_k * tc_draw.normal();
  }
  build_track();
}

void SimSource::build_track() {
  const ImperfectionConfig& im = cfg_.imperfections;
  ideal_track_ = im.magnet_strength_std == 0.0 && im.magnet_placement_std_m == 0.0;
  if (ideal_track_) return;
  // Cover every track position a sensor can face while the carriage is on the travel,
  // plus a few periods; beyond that the track is ideal.
  const double pitch = motor_.magnet_pitch_m;
  double lo = 0.0, hi = motor_.travel_m;
  double off_lo = 0.0, off_hi = 0.0;
  for (const Sensor& s : sensors_) {
    off_lo = std::min(off_lo, s.position_m);
    off_hi = std::max(off_hi, s.position_m);
  }
  j_first_ = static_cast<std::int64_t>(std::floor((lo + off_lo) / pitch)) - 4;
  const auto j_end = static_cast<std::int64_t>(std::ceil((hi + off_hi) / pitch)) + 4;
  const auto periods = static_cast<std::size_t>(j_end - j_first_);
  boundary_m_.resize(periods + 1);
  strength_.resize(periods);
  // Clamped to a quarter pitch so that boundaries stay ordered whatever the draw.
  const double max_shift = 0.25 * pitch;
  for (std::size_t n = 0; n <= periods; ++n) {
    const std::int64_t j = j_first_ + static_cast<std::int64_t>(n);
    double shift = im.magnet_placement_std_m * track_normal(im.track_seed, kKeyBoundary, j);
    if (n == 0 || n == periods) shift = 0.0;  // meets the ideal track continuously
    boundary_m_[n] = static_cast<double>(j) * pitch + std::clamp(shift, -max_shift, max_shift);
  }
  for (std::size_t n = 0; n < periods; ++n) {
    const std::int64_t j = j_first_ + static_cast<std::int64_t>(n);
    strength_[n] = std::max(0.0, 1.0 + im.magnet_strength_std * track_normal(im.track_seed, kKeyStrength, j));
  }
}

double SimSource::track_scale_error(double lo_m, double hi_m) const {
  core::Regression r;  // boundary against its nominal place
  for (std::size_t k = 0; k < boundary_m_.size(); ++k)
    if (boundary_m_[k] >= lo_m && boundary_m_[k] <= hi_m)
      r.add(static_cast<double>(j_first_ + static_cast<std::int64_t>(k)) * motor_.magnet_pitch_m, boundary_m_[k]);
  double slope, intercept, rms;
  return r.solve(slope, intercept, rms) ? slope - 1.0 : 0.0;
}

double SimSource::field_shape(double theta) const {
  // The branch keeps h3 = 0 bit for bit the pure sine.
  return third_harmonic_ == 0.0 ? std::sin(theta) : std::sin(theta) + third_harmonic_ * std::sin(3.0 * theta);
}

double SimSource::track_field(double x_m) const {
  if (ideal_track_) return field_shape(wavenumber_rad_per_m_ * x_m);
  const double pitch = motor_.magnet_pitch_m;
  const auto periods = static_cast<std::int64_t>(strength_.size());
  std::int64_t n = static_cast<std::int64_t>(std::floor(x_m / pitch)) - j_first_;
  // Boundaries move by at most a quarter pitch: one step corrects the nominal guess.
  if (n >= 0 && n <= periods && x_m < boundary_m_[static_cast<std::size_t>(n)]) --n;
  if (n >= 0 && n < periods && x_m >= boundary_m_[static_cast<std::size_t>(n + 1)]) ++n;
  if (n < 0 || n >= periods) return field_shape(wavenumber_rad_per_m_ * x_m);

  const auto u = static_cast<std::size_t>(n);
  const double b0 = boundary_m_[u], b1 = boundary_m_[u + 1];
  const double phase = kTwoPi * (x_m - b0) / (b1 - b0);
  // Strength interpolated linearly between period centres, so the field is continuous
  // and its envelope has no steps; neighbours outside the table have strength 1.
  const double centre = 0.5 * (b0 + b1);
  double s_other, c_other;
  if (x_m < centre) {
    s_other = u > 0 ? strength_[u - 1] : 1.0;
    c_other = u > 0 ? 0.5 * (boundary_m_[u - 1] + b0) : b0 - 0.5 * pitch;
  } else {
    s_other = u + 1 < strength_.size() ? strength_[u + 1] : 1.0;
    c_other = u + 1 < strength_.size() ? 0.5 * (b1 + boundary_m_[u + 2]) : b1 + 0.5 * pitch;
  }
  const double w = (x_m - centre) / (c_other - centre);
  const double strength = strength_[u] + (s_other - strength_[u]) * w;
  return strength * field_shape(phase);
}

double SimSource::frame_acceleration(double t_s, double carriage_acceleration_mps2) const {
  if (!frame_moves_) return 0.0;
  const ImperfectionConfig& im = cfg_.imperfections;
  return im.frame_reaction_ratio * carriage_acceleration_mps2 + im.frame_vibration_mps2 * std::sin(frame_omega_rps_ * t_s);
}

double SimSource::hall_voltage_noiseless(int sensor, double carriage_x_m) const {
  const Sensor& s = sensors_[static_cast<std::size_t>(sensor)];
  return motor_.hall.offset_v + s.offset_v + motor_.hall.amplitude_v * s.gain * track_field(carriage_x_m + s.position_m);
}

double SimSource::hall_voltage_noiseless(int sensor, double carriage_x_m, double temperature_rise_k) const {
  // The branch keeps dT = 0 bit for bit the model without temperature.
  if (temperature_rise_k == 0.0) return hall_voltage_noiseless(sensor, carriage_x_m);
  const Sensor& s = sensors_[static_cast<std::size_t>(sensor)];
  const double dt = temperature_rise_k;
  return motor_.hall.offset_v + s.offset_v + s.offset_tc_v_per_k * dt +
         motor_.hall.amplitude_v * s.gain * (1.0 + s.gain_tc_per_k * dt) *
             (1.0 + cfg_.temperature.magnet_remanence_per_k * dt) * track_field(carriage_x_m + s.position_m);
}

double SimSource::temperature_at(double t_s) const {
  const TemperatureConfig& tc = cfg_.temperature;
  using P = TemperatureConfig::Profile;
  double part = 0.0;
  if (tc.profile == P::constant) {
    part = tc.delta_k;
  } else if (t_s >= tc.start_s && tc.delta_k != 0.0) {
    const double since = t_s - tc.start_s;
    switch (tc.profile) {
      case P::step: part = tc.delta_k; break;
      case P::ramp: part = since >= tc.duration_s ? tc.delta_k : tc.delta_k * (since / tc.duration_s); break;
      case P::warmup: part = tc.delta_k * -std::expm1(-since / tc.duration_s); break;
      case P::constant: break;
    }
  }
  return tc.offset_k + part;
}

std::int64_t SimSource::sample_time_ns(std::uint64_t k) const {
  // 64-bit mantissa: k * 1e9 is exact below 1.8e10 samples, so t_ns is the exact
  // rounding of k / rate and never drifts.
  return static_cast<std::int64_t>(
      std::llround(static_cast<long double>(k) * 1e9L / static_cast<long double>(motor_.sample_rate_hz)));
}

void SimSource::start_clock() {
  if (clock_started_) return;
  clock_started_ = true;
  clock_start_ns_ = drivers::monotonic_ns();
}

bool SimSource::wait_until_due(std::uint64_t n) {
  if (!clock_started_) {
    start_clock();
    if (n == 0) return !stop_.load(std::memory_order_relaxed);
  }
  return drivers::sleep_until(clock_start_ns_ + sample_time_ns(n), stop_);
}

bool SimSource::share_clock(std::int64_t start_ns) {
  if (!cfg_.realtime || !error_.empty() || clock_started_) return false;
  clock_started_ = true;
  clock_shared_ = true;
  clock_start_ns_ = start_ns;
  return true;
}

std::int64_t SimSource::next_due_ns() const {
  if (!clock_shared_ || !error_.empty() || stop_.load(std::memory_order_relaxed)) return 0;
  const std::uint64_t n = next_index_;
  if (max_samples_ != 0 && n >= max_samples_) return 0;
  if (has_silence_ && next_sent(n) != n) return silent_due_ns_;  // 0 on entering the silence: at once
  return clock_start_ns_ + sample_time_ns(n);
}

std::uint64_t SimSource::next_sent(std::uint64_t n) const {
  const double rate = motor_.sample_rate_hz;
  for (bool moved = true; moved;) {
    moved = false;
    for (int f = 0; f < cfg_.fault_count && f < kMaxFaults; ++f) {
      const FaultConfig& fault = cfg_.faults[f];
      if (fault.kind != FaultConfig::Kind::no_samples) continue;
      const double t_s = static_cast<double>(first_index_ + n) / rate;
      if (t_s < fault.start_s || t_s >= fault.end_s) continue;
      // The first sample index k with k / rate >= end_s (as inject_faults compares).
      const double k_end = std::ceil(fault.end_s * rate);
      if (!(k_end < 1e18)) return kNeverSent;
      auto k = static_cast<std::uint64_t>(k_end);
      while (k > 0 && static_cast<double>(k - 1) / rate >= fault.end_s) --k;
      while (static_cast<double>(k) / rate < fault.end_s) ++k;
      n = k - first_index_;  // > n: t_s < end_s
      moved = true;
    }
  }
  return n;
}

drivers::ReadStatus SimSource::read(core::RawSample& out) {
  if (!error_.empty()) return drivers::ReadStatus::error;
  if (stop_.load(std::memory_order_relaxed)) return drivers::ReadStatus::stopped;
  std::uint64_t n = next_index_;
  if (max_samples_ != 0 && n >= max_samples_) return drivers::ReadStatus::end_of_stream;
  if (has_silence_) {
    const std::uint64_t sent = next_sent(n);
    if (sent != n) {
      // A silent node (no_samples): samples n .. sent - 1 are never sent. In real time
      // the caller hears nothing until `sent` is due (or the duration ends), and gets a
      // timeout every kSilentReadTimeoutNs meanwhile, as from a silent CAN bus.
      const std::uint64_t last = max_samples_ != 0 ? std::min(sent, max_samples_) : sent;
      if (cfg_.realtime) {
        start_clock();
        const std::int64_t now = drivers::monotonic_ns();
        if (clock_shared_) {
          // The caller waited until next_due_ns(): a timeout now, the next one a
          // period later or when `last` is due, whichever comes first.
          const std::int64_t due = last == kNeverSent ? INT64_MAX : clock_start_ns_ + sample_time_ns(last);
          if (now < due) {
            silent_due_ns_ = due - now > kSilentReadTimeoutNs ? now + kSilentReadTimeoutNs : due;
            return drivers::ReadStatus::timeout;
          }
        } else if (last == kNeverSent || clock_start_ns_ + sample_time_ns(last) - now > kSilentReadTimeoutNs) {
          if (!drivers::sleep_until(now + kSilentReadTimeoutNs, stop_)) return drivers::ReadStatus::stopped;
          return drivers::ReadStatus::timeout;
        }
      }
      if (last == kNeverSent || (max_samples_ != 0 && last >= max_samples_)) {
        next_index_ = last == kNeverSent ? n : last;
        return drivers::ReadStatus::end_of_stream;
      }
      // The accelerometer's bias walks on while nothing is sent: the sum of the lost
      // samples' steps (one normal draw, scaled; its own stream).
      if (bias_step_mps2_ > 0.0 && samples_read_ > 0)
        bias_walk_mps2_ += bias_step_mps2_ * std::sqrt(static_cast<double>(sent - n)) *
                           Stream(cfg_.noise_seed, kKeySilence ^ (first_index_ + sent)).normal();
      n = sent;
      next_index_ = sent;
    }
  }
  if (cfg_.realtime && !wait_until_due(n)) return drivers::ReadStatus::stopped;

  const std::uint64_t k = first_index_ + n;
  const double t_s = static_cast<double>(k) / motor_.sample_rate_hz;
  const Kinematics now = profile_.at(t_s);
  const ImperfectionConfig& im = cfg_.imperfections;
  // What the Halls see: the carriage (relative to the frame, which carries the magnets)
  // at their delayed instant, plus the coil field at that same instant.
  const Kinematics at_halls = im.hall_delay_s == 0.0 ? now : profile_.at(t_s - im.hall_delay_s);
  const double hall_x = at_halls.position_m;
  const bool coil = im.coil_field_v_per_mps2 != 0.0;
  const double coil_v = im.coil_field_v_per_mps2 * at_halls.acceleration_mps2;

  const double dT = temperature_at(t_s);
  temperature_rise_k_ = dT;

  Stream noise(cfg_.noise_seed, k);
  out.t_ns = sample_time_ns(k);
  out.seq = k;
  out.hall_count = motor_.hall.count;
  out.hall_valid_mask = (1u << motor_.hall.count) - 1u;
  out.hall_v.fill(0.0);
  for (int i = 0; i < motor_.hall.count; ++i) {
    double v = hall_voltage_noiseless(i, hall_x, dT);
    if (coil) v += coil_v;
    v += motor_.hall.noise_v * noise.normal();
    v = std::clamp(v, motor_.adc.min_v, motor_.adc.max_v);
    const double code = std::clamp(std::round((v - motor_.adc.min_v) / lsb_v_), 0.0, static_cast<double>(max_code_));
    out.hall_v[static_cast<std::size_t>(i)] = motor_.adc.min_v + code * lsb_v_;
  }
  // Accelerometers: the motion at their delayed instant. The moving one is inertial, so
  // it feels the frame's acceleration on top of the carriage's relative one.
  const double t_acc_s = t_s - im.accel_delay_s;
  const double a_carriage = im.accel_delay_s == 0.0 ? now.acceleration_mps2 : profile_.at(t_acc_s).acceleration_mps2;
  const double a_frame = frame_acceleration(t_acc_s, a_carriage);
  const double a_inertial = frame_moves_ ? a_carriage + a_frame : a_carriage;
  if (bias_step_mps2_ > 0.0) {
    // Sequential: the walk starts at the first sample read; each later one adds its
    // own step, drawn from (noise_seed, sample index) so a re-read stream repeats it.
    if (samples_read_ > 0) bias_walk_mps2_ += bias_step_mps2_ * Stream(cfg_.noise_seed, kKeyBiasWalk ^ k).normal();
    bias_now_mps2_ = im.accel_bias_mps2 + bias_walk_mps2_;
  } else {
    bias_now_mps2_ = im.accel_bias_mps2;
  }
  const double range = motor_.accelerometer.range_mps2;
  const double a = (1.0 + im.accel_scale_error) * a_inertial + bias_now_mps2_ +
                   motor_.accelerometer.noise_mps2 * noise.normal();
  out.accel_mps2 = std::clamp(a, -range, range);
  out.accel_valid = true;
  if (im.frame_accelerometer) {
    const double base = a_frame + motor_.accelerometer.noise_mps2 * Stream(cfg_.noise_seed, kKeyBaseAccel ^ k).normal();
    out.accel_base_mps2 = std::clamp(base, -range, range);
    out.accel_base_valid = true;
  } else {
    out.accel_base_mps2 = 0.0;
    out.accel_base_valid = false;
  }

  if (cfg_.temperature.report) {
    const TemperatureConfig& tc = cfg_.temperature;
    double c = tc.reference_c + dT + tc.report_noise_k * Stream(cfg_.noise_seed, kKeyTemperatureReport ^ k).normal();
    if (tc.report_resolution_k > 0.0) c = std::round(c / tc.report_resolution_k) * tc.report_resolution_k;
    out.temperature_c = c;
    out.temperature_valid = true;
  } else {
    out.temperature_c = 0.0;
    out.temperature_valid = false;
  }

  if (cfg_.fault_count > 0) inject_faults(t_s, k, out);

  truth_ = {now.position_m, now.velocity_mps, now.acceleration_mps2};
  next_index_ = n + 1;
  ++samples_read_;
  return drivers::ReadStatus::ok;
}

void SimSource::inject_faults(double t_s, std::uint64_t k, core::RawSample& out) const {
  Stream draw(cfg_.noise_seed, kKeyFault ^ k);
  for (int f = 0; f < cfg_.fault_count && f < kMaxFaults; ++f) {
    const FaultConfig& fault = cfg_.faults[f];
    if (t_s < fault.start_s || t_s >= fault.end_s) continue;
    const auto i = static_cast<std::size_t>(std::clamp(fault.sensor, 0, motor_.hall.count - 1));
    using K = FaultConfig::Kind;
    switch (fault.kind) {
      case K::hall_stuck_high:
        out.hall_v[i] = motor_.adc.max_v;
        break;
      case K::hall_stuck_low:
        out.hall_v[i] = motor_.adc.min_v;
        break;
      case K::hall_stuck_mid:
        out.hall_v[i] = motor_.hall.offset_v;
        break;
      case K::hall_noisy:
        out.hall_v[i] = std::clamp(out.hall_v[i] + fault.magnitude * draw.normal(), motor_.adc.min_v, motor_.adc.max_v);
        break;
      case K::hall_intermittent:
        if (draw.uniform() < fault.magnitude) out.hall_valid_mask &= ~(1u << i);
        break;
      case K::hall_spikes:
        if (draw.uniform() < 0.01)
          out.hall_v[i] = std::clamp(out.hall_v[i] + fault.magnitude, motor_.adc.min_v, motor_.adc.max_v);
        break;
      case K::accel_dead:
        out.accel_mps2 = 0.0;
        break;
      case K::accel_saturated:
        out.accel_mps2 = motor_.accelerometer.range_mps2;
        break;
      case K::accel_bias:
        out.accel_mps2 += fault.magnitude;
        break;
      case K::accel_missing:
        out.accel_valid = false;
        break;
      case K::no_samples:  // read() sends no sample in the window
        break;
    }
  }
}

std::string SimSource::describe() const {
  char buf[160];
  std::snprintf(buf, sizeof buf, "sim(%s, %d Halls, %g Hz%s)", kind_name(cfg_.profile.kind), motor_.hall.count,
                motor_.sample_rate_hz, cfg_.realtime ? "" : ", as fast as possible");
  return buf;
}

}  // namespace ve::sim
