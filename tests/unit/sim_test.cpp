// Simulator: motion profiles (exact kinematics, limits) and the simulated sensors
// (paper's Hall model, noise, ADC grid, determinism, real-time pacing).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>
#include <vector>

#include "core/motor.hpp"
#include "sim/motion_profile.hpp"
#include "sim/sim_source.hpp"

namespace {

using ve::core::MotorConfig;
using ve::core::RawSample;
using ve::drivers::ReadStatus;
using ve::sim::Kinematics;
using ve::sim::MotionProfile;
using ve::sim::MotionProfileConfig;
using ve::sim::SimConfig;
using ve::sim::SimSource;
using Kind = MotionProfileConfig::Kind;

MotionProfile make(const MotionProfileConfig& cfg, double travel_m = 1.0) {
  std::string error;
  auto p = MotionProfile::create(cfg, travel_m, &error);
  EXPECT_TRUE(p.has_value()) << error;
  return p.value_or(MotionProfile{});
}

MotionProfileConfig profile_of(Kind kind) {
  MotionProfileConfig c;
  c.kind = kind;
  return c;
}

SimConfig offline(Kind kind) {
  SimConfig c;
  c.profile.kind = kind;
  c.realtime = false;
  return c;
}

struct ProfileCase {
  const char* name;
  MotionProfileConfig cfg;
  double horizon_s;
};

std::vector<ProfileCase> profile_cases() {
  std::vector<ProfileCase> cases;
  cases.push_back({"standstill", profile_of(Kind::standstill), 5.0});
  {
    auto c = profile_of(Kind::constant_velocity);
    cases.push_back({"cv+", c, 2.0});
    c.velocity_mps = -0.5;
    c.start_m = 0.3;
    cases.push_back({"cv-", c, 2.0});
  }
  {
    auto c = profile_of(Kind::constant_acceleration);
    c.velocity_mps = 0.0;
    cases.push_back({"ca from rest", c, 2.0});
    c.velocity_mps = -1.0;  // reverses, then runs to max_m
    cases.push_back({"ca reversing", c, 3.0});
    c.velocity_mps = 0.2;
    c.acceleration_mps2 = -3.0;
    cases.push_back({"ca negative", c, 3.0});
    c.velocity_mps = 3.0;  // cannot stop at max_acceleration_mps2: brakes harder at once
    c.acceleration_mps2 = 5.0;
    c.start_m = 0.8;
    cases.push_back({"ca hard brake", c, 2.0});
  }
  cases.push_back({"multisine", profile_of(Kind::multisine), 20.0});
  {
    auto c = profile_of(Kind::shuttle);
    cases.push_back({"shuttle", c, 10.0});
    c.start_m = 0.9;
    c.max_velocity_mps = 0.5;
    cases.push_back({"shuttle from near max", c, 10.0});
    c.start_m = c.min_m;
    c.max_velocity_mps = 0.02;
    cases.push_back({"shuttle slow sweep", c, 200.0});
  }
  return cases;
}

TEST(SimProfile, DerivativesMatchAndStayInTravel) {
  for (const ProfileCase& pc : profile_cases()) {
    SCOPED_TRACE(pc.name);
    const MotionProfile p = make(pc.cfg);
    const double h = 1e-6;
    // A time grid that does not line up with any segment boundary.
    const double dt = pc.horizon_s / 2000.0 * 1.0137;
    int jumps = 0;
    for (double t = 0.0; t < pc.horizon_s; t += dt) {
      const Kinematics k = p.at(t), before = p.at(t - h), after = p.at(t + h);
      // Position and velocity are continuous and smooth enough for central differences.
      // (A step in acceleration inside [t - h, t + h] costs up to h * step / 4.)
      const double a_step = std::abs(after.acceleration_mps2 - before.acceleration_mps2);
      EXPECT_NEAR((after.position_m - before.position_m) / (2 * h), k.velocity_mps, 1e-6 + h * a_step)
          << "t=" << t;
      const double a_diff = (after.velocity_mps - before.velocity_mps) / (2 * h);
      if (before.acceleration_mps2 == after.acceleration_mps2 || std::abs(a_diff - k.acceleration_mps2) < 1e-5) {
        EXPECT_NEAR(a_diff, k.acceleration_mps2, 1e-5) << "t=" << t;
      } else {
        ++jumps;  // a segment boundary within h: acceleration steps there
      }
      EXPECT_GE(k.position_m, pc.cfg.min_m - 1e-12) << "t=" << t;
      EXPECT_LE(k.position_m, pc.cfg.max_m + 1e-12) << "t=" << t;
    }
    EXPECT_LE(jumps, 2);
    EXPECT_NEAR(p.at(0.0).position_m, pc.cfg.start_m, 1e-12);
  }
}

TEST(SimProfile, MultisineBoundsReachedNotExceeded) {
  const MotionProfileConfig cfg = profile_of(Kind::multisine);  // 2 m/s, 10 m/s^2, 0.5 in [0.05, 0.95]
  const MotionProfile p = make(cfg);
  double vpk = 0.0, apk = 0.0, xmin = 1e9, xmax = -1e9;
  for (int i = 0; i <= 240000; ++i) {  // 60 s at 4 kHz
    const Kinematics k = p.at(i / 4000.0);
    vpk = std::max(vpk, std::abs(k.velocity_mps));
    apk = std::max(apk, std::abs(k.acceleration_mps2));
    xmin = std::min(xmin, k.position_m);
    xmax = std::max(xmax, k.position_m);
  }
  EXPECT_LE(vpk, 2.0 + 1e-9);
  EXPECT_GE(vpk, 0.8 * 2.0);
  EXPECT_LE(apk, 10.0 + 1e-9);
  EXPECT_GE(apk, 0.8 * 10.0);
  EXPECT_GE(xmin, 0.05);
  EXPECT_LE(xmax, 0.95);
  // Worst case over all time, not just 60 s: the amplitudes' sum fits.
  double amp = 0.0, vsum = 0.0, asum = 0.0;
  ASSERT_GE(p.sine_count(), 3);
  for (int k = 0; k < p.sine_count(); ++k) {
    amp += p.sine_amplitude_m(k);
    vsum += p.sine_amplitude_m(k) * p.sine_omega_rps(k);
    asum += p.sine_amplitude_m(k) * p.sine_omega_rps(k) * p.sine_omega_rps(k);
  }
  EXPECT_LE(amp, 0.45 + 1e-12);
  EXPECT_NEAR(vsum, 2.0, 1e-12);
  EXPECT_NEAR(asum, 10.0, 1e-12);
  EXPECT_EQ(p.steady_duration_s(), std::numeric_limits<double>::infinity());
}

TEST(SimProfile, MultisineNarrowsOnShortTravelAndRejectsTooShort) {
  auto cfg = profile_of(Kind::multisine);
  cfg.min_m = 0.09;  // 0.41 m either side: just above the 0.4 m minimum
  cfg.max_m = 0.91;
  const MotionProfile p = make(cfg);
  double amp = 0.0;
  for (int k = 0; k < p.sine_count(); ++k) amp += p.sine_amplitude_m(k);
  EXPECT_LE(amp, 0.41 + 1e-12);

  cfg.min_m = 0.4;
  cfg.max_m = 0.6;
  std::string error;
  EXPECT_FALSE(MotionProfile::create(cfg, 1.0, &error));
  EXPECT_NE(error.find("multisine"), std::string::npos) << error;
}

TEST(SimProfile, ConstantVelocityWindow) {
  auto cfg = profile_of(Kind::constant_velocity);  // 1 m/s from 0.5, brakes at 10 m/s^2 to 0.95
  const MotionProfile p = make(cfg);
  EXPECT_NEAR(p.steady_duration_s(), 0.4, 1e-12);  // 0.95 - 0.05 braking distance - 0.5
  for (double t = 0.0; t < p.steady_duration_s(); t += 0.01) {
    const Kinematics k = p.at(t);
    EXPECT_NEAR(k.position_m, 0.5 + t, 1e-12);
    EXPECT_EQ(k.velocity_mps, 1.0);
    EXPECT_EQ(k.acceleration_mps2, 0.0);
  }
  EXPECT_EQ(p.at(0.45).acceleration_mps2, -10.0);
  const Kinematics end = p.at(0.5 + 1e-9), later = p.at(100.0);
  EXPECT_NEAR(end.position_m, 0.95, 1e-12);
  EXPECT_EQ(later.position_m, 0.95);
  EXPECT_EQ(later.velocity_mps, 0.0);

  cfg.velocity_mps = -2.0;
  cfg.start_m = 0.6;
  const MotionProfile back = make(cfg);
  EXPECT_NEAR(back.steady_duration_s(), (0.55 - 0.2) / 2.0, 1e-12);
  EXPECT_EQ(back.at(10.0).position_m, 0.05);
}

TEST(SimProfile, ConstantAccelerationWindow) {
  auto cfg = profile_of(Kind::constant_acceleration);
  cfg.velocity_mps = 0.0;
  cfg.acceleration_mps2 = 5.0;  // from 0.5; brakes at 10 m/s^2 to 0.95
  const MotionProfile p = make(cfg);
  // x = 0.5 + 2.5 t^2 and the braking distance (5t)^2 / 20 add to 0.45 m.
  EXPECT_NEAR(p.steady_duration_s(), std::sqrt(0.45 / 3.75), 1e-12);
  for (double t = 0.0; t < p.steady_duration_s(); t += 0.01) {
    const Kinematics k = p.at(t);
    EXPECT_NEAR(k.position_m, 0.5 + 2.5 * t * t, 1e-12);
    EXPECT_NEAR(k.velocity_mps, 5.0 * t, 1e-12);
    EXPECT_EQ(k.acceleration_mps2, 5.0);
  }
  EXPECT_EQ(p.at(p.steady_duration_s() + 0.01).acceleration_mps2, -10.0);
  EXPECT_EQ(p.at(10.0).position_m, 0.95);
  EXPECT_EQ(p.at(10.0).velocity_mps, 0.0);

  cfg.velocity_mps = -1.0;  // decelerates, reverses and runs to the far end
  const MotionProfile rev = make(cfg);
  EXPECT_GT(rev.steady_duration_s(), 0.2);
  EXPECT_EQ(rev.at(10.0).position_m, 0.95);

  cfg.velocity_mps = 3.0;  // 0.45 m to stop at 10 m/s^2, only 0.15 m left
  cfg.start_m = 0.8;
  const MotionProfile hard = make(cfg);
  EXPECT_EQ(hard.steady_duration_s(), 0.0);
  EXPECT_NEAR(hard.at(0.01).acceleration_mps2, -9.0 / 0.3, 1e-9);
  EXPECT_EQ(hard.at(10.0).position_m, 0.95);
}

TEST(SimProfile, ShuttlePeriodicBetweenEnds) {
  auto cfg = profile_of(Kind::shuttle);  // starts at 0.5: goes to 0.05 first
  const MotionProfile p = make(cfg);
  // Each 0.9 m move: 0.2 s ramps each side (0.2 m each), 0.5 m cruise at 2 m/s.
  EXPECT_NEAR(p.period_s(), 2.0 * (0.4 + 0.25), 1e-12);
  EXPECT_GT(p.lead_in_s(), 0.0);
  EXPECT_NEAR(p.at(p.lead_in_s()).position_m, 0.05, 1e-12);
  EXPECT_NEAR(p.at(p.lead_in_s() + p.period_s() / 2).position_m, 0.95, 1e-12);
  double vpk = 0.0, apk = 0.0;
  for (double t = p.lead_in_s(); t < p.lead_in_s() + 3 * p.period_s(); t += 0.00173) {
    const Kinematics a = p.at(t), b = p.at(t + 7 * p.period_s());
    EXPECT_NEAR(a.position_m, b.position_m, 1e-9);
    EXPECT_NEAR(a.velocity_mps, b.velocity_mps, 1e-9);
    vpk = std::max(vpk, std::abs(a.velocity_mps));
    apk = std::max(apk, std::abs(a.acceleration_mps2));
  }
  EXPECT_NEAR(vpk, 2.0, 1e-12);
  EXPECT_NEAR(apk, 10.0, 1e-12);

  cfg.start_m = cfg.min_m;  // calibration sweep at 20 mm/s: no lead-in
  cfg.max_velocity_mps = 0.02;
  const MotionProfile sweep = make(cfg);
  EXPECT_EQ(sweep.lead_in_s(), 0.0);
  EXPECT_NEAR(sweep.at(10.0).velocity_mps, 0.02, 1e-12);
  EXPECT_NEAR(sweep.period_s(), 2.0 * (0.9 / 0.02 + 0.02 / 10.0), 1e-9);
}

TEST(SimProfile, FactoryRejectsInvalidParameters) {
  struct Bad {
    const char* name;
    MotionProfileConfig cfg;
  };
  std::vector<Bad> bad;
  auto c = profile_of(Kind::constant_velocity);
  c.velocity_mps = 0.0;
  bad.push_back({"zero velocity", c});
  c = profile_of(Kind::constant_velocity);
  c.velocity_mps = 5.0;  // 1.25 m to stop
  bad.push_back({"cannot stop", c});
  c = profile_of(Kind::standstill);
  c.start_m = 0.99;
  bad.push_back({"start outside", c});
  c = profile_of(Kind::shuttle);
  c.max_m = 1.5;
  bad.push_back({"beyond travel", c});
  c = profile_of(Kind::shuttle);
  c.min_m = 0.6;
  c.max_m = 0.4;
  bad.push_back({"min above max", c});
  c = profile_of(Kind::shuttle);
  c.max_velocity_mps = 0.0;
  bad.push_back({"zero speed", c});
  c = profile_of(Kind::constant_acceleration);
  c.acceleration_mps2 = 0.0;
  bad.push_back({"zero acceleration", c});
  c = profile_of(Kind::multisine);
  c.max_acceleration_mps2 = std::nan("");
  bad.push_back({"nan", c});
  for (const Bad& b : bad) {
    std::string error;
    EXPECT_FALSE(MotionProfile::create(b.cfg, 1.0, &error)) << b.name;
    EXPECT_FALSE(error.empty()) << b.name;
  }
  for (Kind k : {Kind::standstill, Kind::constant_velocity, Kind::constant_acceleration, Kind::multisine,
                 Kind::shuttle}) {
    std::string error;
    EXPECT_TRUE(MotionProfile::create(profile_of(k), 1.0, &error)) << ve::sim::kind_name(k) << ": " << error;
  }
}

// ---- sensors ------------------------------------------------------------------

double paper_hall(double x_m, int sensor) {
  const double p = 0.012;
  return std::clamp(2.5 + 2.5 * std::sqrt(2.0) * std::sin(2 * M_PI * (x_m + sensor * p / 8) / p), 0.0, 5.0);
}

TEST(SimSource, IdealMotorMatchesPaperModel) {
  MotorConfig motor;
  auto cfg = offline(Kind::constant_velocity);
  cfg.profile.velocity_mps = 0.3;
  SimSource src(motor, cfg);
  ASSERT_TRUE(src.ok()) << src.last_error();
  RawSample s;
  const double tol = 6 * motor.hall.noise_v + motor.adc.lsb_v();
  for (int n = 0; n < 4000; ++n) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    ASSERT_NE(src.truth(), nullptr);
    const double x = src.truth()->position_m;
    ASSERT_EQ(s.hall_count, 4);
    EXPECT_EQ(s.hall_valid_mask, 0xFu);
    for (int i = 0; i < 4; ++i) EXPECT_NEAR(s.hall_v[static_cast<std::size_t>(i)], paper_hall(x, i), tol) << n;
    EXPECT_TRUE(s.accel_valid);
    EXPECT_FALSE(s.accel_base_valid);
  }
}

TEST(SimSource, SensorsShiftedByEighthPitchAndIdealIsExact) {
  MotorConfig motor;
  SimSource src(motor, offline(Kind::standstill));
  ASSERT_TRUE(src.ok());
  const double p = motor.magnet_pitch_m;
  for (double x = 0.1; x < 0.2; x += 0.000731) {
    for (int i = 0; i < 4; ++i) {
      EXPECT_NEAR(src.hall_voltage_noiseless(i, x), src.hall_voltage_noiseless(0, x + i * p / 8), 1e-12);
      // Zero imperfections are no imperfections at all.
      EXPECT_DOUBLE_EQ(src.hall_voltage_noiseless(i, x),
                       2.5 + 2.5 * std::sqrt(2.0) * std::sin(2 * M_PI / p * (x + i * p / 8)));
    }
  }
}

TEST(SimSource, NoiseStdAtStandstill) {
  MotorConfig motor;
  motor.adc.bits = 22;  // quantization (12 bit: 0.35 mV rms) would otherwise add to the 0.6 mV
  SimSource src(motor, offline(Kind::standstill));
  ASSERT_TRUE(src.ok());
  const int n = 40000;
  std::vector<double> sum(4, 0.0), sum2(4, 0.0);
  double asum = 0.0, asum2 = 0.0;
  RawSample s;
  for (int k = 0; k < n; ++k) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    for (std::size_t i = 0; i < 4; ++i) {
      sum[i] += s.hall_v[i];
      sum2[i] += s.hall_v[i] * s.hall_v[i];
    }
    asum += s.accel_mps2;
    asum2 += s.accel_mps2 * s.accel_mps2;
  }
  int checked = 0;
  for (int i = 0; i < 4; ++i) {
    const double v = src.hall_voltage_noiseless(i, 0.5);
    if (v < 0.3 || v > 4.7) continue;  // saturated: the ADC clamps the noise away
    const auto u = static_cast<std::size_t>(i);
    const double mean = sum[u] / n;
    const double sd = std::sqrt(std::max(0.0, sum2[u] / n - mean * mean));
    EXPECT_NEAR(mean, v, 3e-5) << i;
    EXPECT_NEAR(sd, 0.0006, 0.00006) << i;
    ++checked;
  }
  EXPECT_GE(checked, 1);
  const double amean = asum / n;
  EXPECT_NEAR(std::sqrt(asum2 / n - amean * amean), 0.02, 0.002);
  EXPECT_NEAR(amean, 0.0, 0.001);
}

TEST(SimSource, OutputsOnTheAdcGrid) {
  MotorConfig motor;
  SimSource src(motor, offline(Kind::multisine));
  const double lsb = motor.adc.lsb_v();
  RawSample s;
  int at_rails = 0;
  for (int k = 0; k < 8000; ++k) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    for (int i = 0; i < 4; ++i) {
      const double v = s.hall_v[static_cast<std::size_t>(i)];
      const double code = v / lsb;
      EXPECT_NEAR(code, std::round(code), 1e-6);
      EXPECT_GE(v, 0.0);
      EXPECT_LE(v, 5.0 + 1e-12);
      at_rails += v == 0.0 || std::round(code) == 4095.0;
    }
  }
  EXPECT_GT(at_rails, 0);  // the paper's sensors saturate much of the time
}

std::vector<RawSample> run(const MotorConfig& motor, const SimConfig& cfg, int n) {
  SimSource src(motor, cfg);
  std::vector<RawSample> out(static_cast<std::size_t>(n));
  for (auto& s : out) EXPECT_EQ(src.read(s), ReadStatus::ok);
  return out;
}

bool same(const std::vector<RawSample>& a, const std::vector<RawSample>& b) {
  for (std::size_t k = 0; k < a.size(); ++k) {
    if (a[k].t_ns != b[k].t_ns || a[k].accel_mps2 != b[k].accel_mps2) return false;
    for (std::size_t i = 0; i < 4; ++i)
      if (a[k].hall_v[i] != b[k].hall_v[i]) return false;
  }
  return true;
}

TEST(SimSource, SeedsDetermineTheStream) {
  MotorConfig motor;
  auto cfg = offline(Kind::multisine);
  cfg.noise_seed = 42;
  const auto a = run(motor, cfg, 2000), b = run(motor, cfg, 2000);
  EXPECT_TRUE(same(a, b));
  cfg.noise_seed = 43;
  EXPECT_FALSE(same(a, run(motor, cfg, 2000)));
}

TEST(SimSource, TrackSeedFixesTheImperfectTrack) {
  MotorConfig motor;
  auto cfg = offline(Kind::standstill);
  auto& im = cfg.imperfections;
  im.magnet_strength_std = 0.02;
  im.magnet_placement_std_m = 30e-6;
  im.sensor_placement_std_m = 50e-6;
  im.sensor_gain_std = 0.01;
  im.sensor_offset_std_v = 0.005;
  cfg.noise_seed = 1;
  SimSource a(motor, cfg);
  cfg.noise_seed = 2;
  SimSource b(motor, cfg);
  cfg.imperfections.track_seed += 1;
  SimSource c(motor, cfg);
  SimSource ideal(motor, offline(Kind::standstill));
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  double max_ab = 0.0, max_ac = 0.0, max_ideal = 0.0, max_step = 0.0;
  const double dx = 1e-6;
  for (double x = 0.0; x < 1.0; x += 0.0001237) {
    for (int i = 0; i < 4; ++i) {
      max_ab = std::max(max_ab, std::abs(a.hall_voltage_noiseless(i, x) - b.hall_voltage_noiseless(i, x)));
      max_ac = std::max(max_ac, std::abs(a.hall_voltage_noiseless(i, x) - c.hall_voltage_noiseless(i, x)));
      max_ideal = std::max(max_ideal, std::abs(a.hall_voltage_noiseless(i, x) - ideal.hall_voltage_noiseless(i, x)));
    }
    // Continuous: the steepest ideal slope is 2.5 sqrt(2) * 2 pi / 12 mm = 1.85 V/mm.
    max_step = std::max(max_step, std::abs(a.track_field(x + dx) - a.track_field(x)));
  }
  EXPECT_EQ(max_ab, 0.0);
  EXPECT_GT(max_ac, 1e-3);
  EXPECT_GT(max_ideal, 1e-3);
  EXPECT_LT(max_step, 2 * M_PI / 0.012 * dx * 1.2);
  // Magnet boundaries still lie (near) zero crossings; the field stays in its envelope.
  for (double x = 0.0; x < 1.0; x += 0.0000931) EXPECT_LE(std::abs(a.track_field(x)), 1.2);
}

TEST(SimSource, AccelerometerBiasScaleAndHallDelay) {
  MotorConfig motor;
  motor.accelerometer.noise_mps2 = 0.0;
  motor.hall.noise_v = 0.0;
  motor.adc.bits = 24;
  auto cfg = offline(Kind::multisine);
  cfg.imperfections.accel_bias_mps2 = 0.05;
  cfg.imperfections.accel_scale_error = 0.005;
  cfg.imperfections.hall_delay_s = 100e-6;
  SimSource src(motor, cfg);
  RawSample s;
  for (int k = 0; k < 4000; ++k) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    const double t = k / 4000.0;
    EXPECT_NEAR(s.accel_mps2, 1.005 * src.truth()->acceleration_mps2 + 0.05, 1e-12);
    EXPECT_EQ(src.truth()->position_m, src.profile().at(t).position_m);
    const double x_delayed = src.profile().at(t - 100e-6).position_m;
    for (int i = 0; i < 4; ++i) {
      const double expect = std::clamp(src.hall_voltage_noiseless(i, x_delayed), 0.0, 5.0);
      EXPECT_NEAR(s.hall_v[static_cast<std::size_t>(i)], expect, motor.adc.lsb_v());
    }
  }
}

TEST(SimSource, TimestampsSequenceAndDuration) {
  MotorConfig motor;
  motor.sample_rate_hz = 3000.0;  // 333333.33 ns: must not drift
  auto cfg = offline(Kind::standstill);
  cfg.duration_s = 2.0;
  SimSource src(motor, cfg);
  RawSample s;
  std::int64_t n = 0;
  while (src.read(s) == ReadStatus::ok) {
    EXPECT_EQ(s.seq, static_cast<std::uint64_t>(n));
    EXPECT_EQ(s.t_ns, std::llround(n * 1e9 / 3000.0));
    ++n;
  }
  EXPECT_EQ(n, 6000);
  EXPECT_EQ(src.read(s), ReadStatus::end_of_stream);
  EXPECT_EQ(src.sample_time_ns(3000 * 1000000ull), 1000000ll * 1000000000ll);

  SimSource later(motor, offline(Kind::multisine), 1.5);
  ASSERT_EQ(later.read(s), ReadStatus::ok);
  EXPECT_EQ(s.seq, 4500u);
  EXPECT_EQ(s.t_ns, 1500000000);
  EXPECT_EQ(later.truth()->position_m, later.profile().at(1.5).position_m);
}

TEST(SimSource, InvalidConfigurationIsReported) {
  MotorConfig motor;
  auto cfg = offline(Kind::constant_velocity);
  cfg.profile.velocity_mps = 0.0;
  SimSource src(motor, cfg);
  EXPECT_FALSE(src.ok());
  EXPECT_FALSE(src.last_error().empty());
  EXPECT_FALSE(SimSource::check(motor, cfg).empty());
  RawSample s;
  EXPECT_EQ(src.read(s), ReadStatus::error);

  motor.hall.count = 9;
  EXPECT_FALSE(SimSource::check(motor, offline(Kind::standstill)).empty());
  EXPECT_TRUE(SimSource::check(MotorConfig{}, SimConfig{}).empty());
}

TEST(SimSource, Describe) {
  SimConfig cfg;
  SimSource src(MotorConfig{}, cfg);
  EXPECT_EQ(src.describe(), "sim(multisine, 4 Halls, 4000 Hz)");
}

TEST(SimSource, RealtimePacing) {
  SimSource src(MotorConfig{}, SimConfig{});  // realtime by default
  RawSample s;
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < 400; ++k) ASSERT_EQ(src.read(s), ReadStatus::ok);
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_GT(elapsed, 0.05);  // nominal 399 periods = 0.09975 s
  EXPECT_LT(elapsed, 1.0);
}

TEST(SimSource, StopWakesBlockedRead) {
  MotorConfig motor;
  motor.sample_rate_hz = 0.5;  // the second read would block for 2 s
  SimSource src(motor, SimConfig{});
  RawSample s;
  ASSERT_EQ(src.read(s), ReadStatus::ok);
  std::thread stopper([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    src.stop();
  });
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(src.read(s), ReadStatus::stopped);
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  stopper.join();
  EXPECT_LT(elapsed, 1.0);
  EXPECT_EQ(src.read(s), ReadStatus::stopped);
}

}  // namespace
