// Simulator: motion profiles (exact kinematics, limits) and the simulated sensors
// (paper's Hall model, noise, ADC grid, determinism, real-time pacing).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "core/motor.hpp"
#include "sim/motion_profile.hpp"
#include "pacing.hpp"
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
  {
    auto c = profile_of(Kind::point_to_point);
    cases.push_back({"point_to_point", c, 10.0});
    c.start_m = 0.2;  // goes to max_m first
    c.dwell_s = 0.0;
    cases.push_back({"point_to_point no dwell", c, 10.0});
    c.min_m = 0.45;  // 0.1 m: amax reached, vmax not
    c.max_m = 0.55;
    c.start_m = 0.5;
    c.dwell_s = 0.05;
    cases.push_back({"point_to_point short", c, 5.0});
    c.min_m = 0.49;  // 0.02 m: neither
    c.max_m = 0.51;
    cases.push_back({"point_to_point tiny", c, 5.0});
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

/// Samples `p` over [t0, t1) every dt and records peaks and whether the jerk agrees
/// with the acceleration's finite difference (away from jerk steps).
struct Peaks {
  double v = 0.0, a = 0.0, j = 0.0, xmin = 1e9, xmax = -1e9;
  int bad_jerk = 0;
};

Peaks scan(const MotionProfile& p, double t0, double t1, double dt) {
  Peaks pk;
  const double h = 1e-6;
  for (double t = t0; t < t1; t += dt) {
    const Kinematics k = p.at(t), before = p.at(t - h), after = p.at(t + h);
    pk.v = std::max(pk.v, std::abs(k.velocity_mps));
    pk.a = std::max(pk.a, std::abs(k.acceleration_mps2));
    pk.j = std::max(pk.j, std::abs(k.jerk_mps3));
    pk.xmin = std::min(pk.xmin, k.position_m);
    pk.xmax = std::max(pk.xmax, k.position_m);
    if (before.jerk_mps3 == after.jerk_mps3 &&
        std::abs((after.acceleration_mps2 - before.acceleration_mps2) / (2 * h) - k.jerk_mps3) > 1e-4)
      ++pk.bad_jerk;
  }
  return pk;
}

TEST(SimProfile, PointToPointReachesButNeverExceedsLimits) {
  auto cfg = profile_of(Kind::point_to_point);
  cfg.max_velocity_mps = 1.5;
  cfg.max_acceleration_mps2 = 10.0;
  cfg.max_jerk_mps3 = 250.0;
  cfg.dwell_s = 0.1;  // start 0.5 in [0.05, 0.95]: a tie, so max_m first
  const MotionProfile p = make(cfg);
  // A 0.9 m move: jerk phases 10 / 250 = 0.04 s, constant acceleration 1.5 / 10 - 0.04
  // = 0.11 s, so 0.19 s and 0.1425 m to reach 1.5 m/s; cruise (0.9 - 0.285) / 1.5 s.
  const double move = 4 * 0.04 + 2 * 0.11 + (0.9 - 0.285) / 1.5;
  EXPECT_NEAR(p.period_s(), 2 * (move + 0.1), 1e-12);
  EXPECT_NEAR(p.lead_in_s(), 4 * 0.04 + 2 * 0.11 + (0.45 - 0.285) / 1.5, 1e-12);
  EXPECT_GT(p.at(0.1).velocity_mps, 0.0);  // towards max_m

  const Peaks pk = scan(p, 0.0, p.lead_in_s() + 3 * p.period_s(), 1.0 / 4000.0 * 1.013);
  EXPECT_LE(pk.v, 1.5 * (1 + 1e-12));
  EXPECT_GE(pk.v, 1.5 * 0.99);
  EXPECT_LE(pk.a, 10.0 * (1 + 1e-12));
  EXPECT_GE(pk.a, 10.0 * 0.99);
  EXPECT_EQ(pk.j, 250.0);
  EXPECT_EQ(pk.bad_jerk, 0);
  EXPECT_GE(pk.xmin, 0.05 - 1e-12);
  EXPECT_LE(pk.xmax, 0.95 + 1e-12);
  EXPECT_NEAR(pk.xmin, 0.05, 1e-12);
  EXPECT_NEAR(pk.xmax, 0.95, 1e-12);

  // Dwell at each end, exactly at rest.
  const double t_top = p.lead_in_s(), t_bottom = p.lead_in_s() + 0.1 + move;
  for (double t : {t_top, t_bottom}) {
    const double end = t == t_top ? 0.95 : 0.05;
    for (double tau = 1e-9; tau < 0.1 - 1e-9; tau += 0.01) {
      const Kinematics k = p.at(t + tau);
      EXPECT_EQ(k.position_m, end) << t << " + " << tau;
      EXPECT_EQ(k.velocity_mps, 0.0);
      EXPECT_EQ(k.acceleration_mps2, 0.0);
      EXPECT_EQ(k.jerk_mps3, 0.0);
    }
    EXPECT_NE(p.at(t + 0.1 + 0.001).velocity_mps, 0.0);  // moving again after the dwell
  }
  // Periodic.
  for (double t = p.lead_in_s(); t < p.lead_in_s() + p.period_s(); t += 0.00237) {
    const Kinematics a = p.at(t), b = p.at(t + 5 * p.period_s());
    EXPECT_NEAR(a.position_m, b.position_m, 1e-9);
    EXPECT_NEAR(a.velocity_mps, b.velocity_mps, 1e-9);
    EXPECT_NEAR(a.acceleration_mps2, b.acceleration_mps2, 1e-6);
  }
  // Before t = 0: at rest at start_m.
  EXPECT_EQ(p.at(-0.01).position_m, 0.5);
  EXPECT_EQ(p.at(-0.01).velocity_mps, 0.0);

  cfg.start_m = 0.7;  // farther end is min_m
  const MotionProfile down = make(cfg);
  EXPECT_LT(down.at(0.1).velocity_mps, 0.0);
  EXPECT_NEAR(down.at(down.lead_in_s()).position_m, 0.05, 1e-12);
}

TEST(SimProfile, PointToPointShortMovesDropPlateaus) {
  auto cfg = profile_of(Kind::point_to_point);  // vmax 2, amax 10, jmax 250
  cfg.dwell_s = 0.2;
  // 0.1 m: amax is reached (needs 2 amax^3 / j^2 = 0.032 m) but not vmax.
  cfg.min_m = 0.45;
  cfg.max_m = 0.55;
  const MotionProfile mid = make(cfg);
  const Peaks a = scan(mid, mid.lead_in_s(), mid.lead_in_s() + 2 * mid.period_s(), 1e-4);
  // v^2 + (amax^2 / j) v = amax d.
  const double v = (-0.4 + std::sqrt(0.16 + 4.0 * 10.0 * 0.1)) / 2.0;
  EXPECT_NEAR(a.v, v, 1e-6);
  EXPECT_NEAR(a.a, 10.0, 1e-12);
  EXPECT_EQ(a.j, 250.0);
  EXPECT_EQ(a.bad_jerk, 0);
  // No cruise: move time 4 Tj + 2 Ta = 2 (v / amax + amax / j).
  EXPECT_NEAR(mid.period_s(), 2 * (2 * (v / 10.0 + 10.0 / 250.0) + 0.2), 1e-12);
  EXPECT_NEAR(a.xmin, 0.45, 1e-12);
  EXPECT_NEAR(a.xmax, 0.55, 1e-12);

  // 0.02 m: neither plateau; four jerk phases of (d / 2j)^(1/3).
  cfg.min_m = 0.49;
  cfg.max_m = 0.51;
  const MotionProfile tiny = make(cfg);
  const Peaks b = scan(tiny, tiny.lead_in_s(), tiny.lead_in_s() + 2 * tiny.period_s(), 1e-5);
  const double tj = std::cbrt(0.02 / 500.0);
  EXPECT_NEAR(b.a, 250.0 * tj, 1e-3 * 250.0 * tj);  // sampled peak of a triangle: within one step
  EXPECT_LT(b.a, 10.0);
  EXPECT_NEAR(b.v, 250.0 * tj * tj, 1e-7);
  EXPECT_EQ(b.j, 250.0);
  EXPECT_NEAR(tiny.period_s(), 2 * (4 * tj + 0.2), 1e-12);
  EXPECT_NEAR(b.xmin, 0.49, 1e-12);
  EXPECT_NEAR(b.xmax, 0.51, 1e-12);
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
  c = profile_of(Kind::point_to_point);
  c.max_jerk_mps3 = 0.0;
  bad.push_back({"zero jerk", c});
  c = profile_of(Kind::point_to_point);
  c.dwell_s = -0.1;
  bad.push_back({"negative dwell", c});
  c = profile_of(Kind::point_to_point);
  c.dwell_s = std::numeric_limits<double>::infinity();
  bad.push_back({"infinite dwell", c});
  for (const Bad& b : bad) {
    std::string error;
    EXPECT_FALSE(MotionProfile::create(b.cfg, 1.0, &error)) << b.name;
    EXPECT_FALSE(error.empty()) << b.name;
  }
  for (Kind k : {Kind::standstill, Kind::constant_velocity, Kind::constant_acceleration, Kind::multisine,
                 Kind::shuttle, Kind::point_to_point}) {
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

// ---- imperfections beyond the paper ------------------------------------------

/// Noise-free sensors on a 24-bit ADC: readings are the model to within 0.3 uV.
MotorConfig exact_motor() {
  MotorConfig m;
  m.hall.noise_v = 0.0;
  m.accelerometer.noise_mps2 = 0.0;
  m.adc.bits = 24;
  return m;
}

TEST(SimSource, ThirdHarmonicShapesTheField) {
  MotorConfig motor;
  auto cfg = offline(Kind::standstill);
  cfg.imperfections.field_third_harmonic = 0.03;
  SimSource src(motor, cfg);
  ASSERT_TRUE(src.ok()) << src.last_error();
  const double p = motor.magnet_pitch_m, k = 2 * M_PI / p;
  double peak = 0.0;
  for (double x = 0.1; x < 0.2; x += 0.0000731) {
    const double th = k * x;
    EXPECT_NEAR(src.track_field(x), std::sin(th) + 0.03 * std::sin(3 * th), 1e-12);
    const double th1 = k * (x + p / 8);
    EXPECT_NEAR(src.hall_voltage_noiseless(1, x), 2.5 + 2.5 * std::sqrt(2.0) * (std::sin(th1) + 0.03 * std::sin(3 * th1)),
                1e-12);
    peak = std::max(peak, src.track_field(x));
  }
  EXPECT_NEAR(peak, 0.97, 1e-4);  // +h3 flattens the tops: sin(3 theta) = -1 at theta = pi / 2

  // On an imperfect track the harmonic follows the local magnet phase: the zero
  // crossings stay at the magnet boundaries and the field is sin(theta) (1 + h3 (3 -
  // 4 sin^2 theta)) times the local strength, so its ratio to the plain one is in [1 - h3, 1 + 3 h3].
  cfg.imperfections.magnet_strength_std = 0.015;
  cfg.imperfections.magnet_placement_std_m = 20e-6;
  SimSource warped(motor, cfg);
  cfg.imperfections.field_third_harmonic = 0.0;
  SimSource plain(motor, cfg);
  int checked = 0;
  for (double x = 0.0; x < 1.0; x += 0.0000937) {
    const double a = warped.track_field(x), b = plain.track_field(x);
    if (std::abs(b) < 1e-3) continue;
    EXPECT_GE(a / b, 0.97 - 1e-9) << x;
    EXPECT_LE(a / b, 1.09 + 1e-9) << x;
    ++checked;
  }
  EXPECT_GT(checked, 10000);
}

TEST(SimSource, CoilFieldOffsetsEveryHallByKTimesAcceleration) {
  const MotorConfig motor = exact_motor();
  const double lsb = motor.adc.lsb_v();
  auto cfg = offline(Kind::constant_acceleration);  // from rest at 0.5, 5 m/s^2 for 0.346 s
  cfg.profile.velocity_mps = 0.0;
  cfg.imperfections.hall_delay_s = 20e-6;
  cfg.imperfections.coil_field_v_per_mps2 = 0.001;
  SimSource src(motor, cfg);
  cfg.imperfections.coil_field_v_per_mps2 = 0.0;
  SimSource none(motor, cfg);
  ASSERT_TRUE(src.ok() && none.ok()) << src.last_error();
  RawSample s, q;
  int checked = 0;
  for (int n = 0; n < 1300; ++n) {  // 0.325 s: inside the constant-acceleration window
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    ASSERT_EQ(none.read(q), ReadStatus::ok);
    if (n == 0) continue;  // the Halls' instant is before t = 0, where the carriage is at rest
    const double x = src.profile().at(n / 4000.0 - 20e-6).position_m;
    for (int i = 0; i < 4; ++i) {
      const double v = src.hall_voltage_noiseless(i, x);
      if (v < 0.1 || v > 4.9) continue;
      const auto u = static_cast<std::size_t>(i);
      EXPECT_NEAR(s.hall_v[u], v + 0.001 * 5.0, lsb) << n << " " << i;
      EXPECT_NEAR(q.hall_v[u], v, lsb) << n << " " << i;  // zero: no offset
      ++checked;
    }
  }
  EXPECT_GT(checked, 1000);

  // Varying acceleration: the offset follows a at the Halls' (delayed) instant.
  cfg = offline(Kind::multisine);
  cfg.imperfections.hall_delay_s = 500e-6;
  cfg.imperfections.coil_field_v_per_mps2 = 0.001;
  SimSource ms(motor, cfg);
  double max_if_undelayed = 0.0;
  checked = 0;
  for (int n = 0; n < 8000; ++n) {
    ASSERT_EQ(ms.read(s), ReadStatus::ok);
    const double t = n / 4000.0;
    const Kinematics d = ms.profile().at(t - 500e-6), now = ms.profile().at(t);
    for (int i = 0; i < 4; ++i) {
      const double v = ms.hall_voltage_noiseless(i, d.position_m);
      if (v < 0.1 || v > 4.9) continue;
      const auto u = static_cast<std::size_t>(i);
      EXPECT_NEAR(s.hall_v[u], v + 0.001 * d.acceleration_mps2, lsb) << n << " " << i;
      max_if_undelayed = std::max(max_if_undelayed, std::abs(s.hall_v[u] - (v + 0.001 * now.acceleration_mps2)));
      ++checked;
    }
  }
  EXPECT_GT(checked, 4000);
  EXPECT_GT(max_if_undelayed, 10 * lsb);  // the instant matters, and the test can tell
}

TEST(SimSource, AccelerometerReadsTheDelayedAcceleration) {
  MotorConfig motor = exact_motor();
  auto cfg = offline(Kind::multisine);
  cfg.imperfections.accel_delay_s = 250e-6;
  cfg.imperfections.accel_scale_error = 0.005;
  cfg.imperfections.accel_bias_mps2 = 0.05;
  SimSource src(motor, cfg);
  ASSERT_TRUE(src.ok()) << src.last_error();
  RawSample s;
  double max_if_undelayed = 0.0;
  for (int n = 0; n < 8000; ++n) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    const double t = n / 4000.0;
    EXPECT_NEAR(s.accel_mps2, 1.005 * src.profile().at(t - 250e-6).acceleration_mps2 + 0.05, 1e-12) << n;
    max_if_undelayed = std::max(max_if_undelayed, std::abs(s.accel_mps2 - (1.005 * src.truth()->acceleration_mps2 + 0.05)));
    EXPECT_EQ(src.truth()->position_m, src.profile().at(t).position_m);  // the truth is not delayed
  }
  EXPECT_GT(max_if_undelayed, 5e-3);  // ~ peak jerk x 250 us

  // With the white noise back: the residual is that noise, nothing more.
  motor.accelerometer.noise_mps2 = 0.02;
  SimSource noisy(motor, cfg);
  double sum = 0.0, sum2 = 0.0;
  const int n_samples = 20000;
  for (int n = 0; n < n_samples; ++n) {
    ASSERT_EQ(noisy.read(s), ReadStatus::ok);
    const double r = s.accel_mps2 - (1.005 * noisy.profile().at(n / 4000.0 - 250e-6).acceleration_mps2 + 0.05);
    sum += r;
    sum2 += r * r;
  }
  EXPECT_NEAR(sum / n_samples, 0.0, 5 * 0.02 / std::sqrt(n_samples));
  EXPECT_NEAR(std::sqrt(sum2 / n_samples), 0.02, 0.002);
}

/// Moving-accelerometer readings at standstill with no white noise: the bias alone.
std::vector<double> bias_path(std::uint64_t seed, double rw, int n, std::vector<double>* halls = nullptr) {
  MotorConfig motor;
  motor.accelerometer.noise_mps2 = 0.0;
  auto cfg = offline(Kind::standstill);
  cfg.noise_seed = seed;
  cfg.imperfections.accel_bias_mps2 = 0.05;
  cfg.imperfections.accel_scale_error = 0.005;
  cfg.imperfections.accel_bias_random_walk_mps2_per_sqrt_s = rw;
  SimSource src(motor, cfg);
  std::vector<double> out(static_cast<std::size_t>(n));
  RawSample s;
  for (auto& b : out) {
    EXPECT_EQ(src.read(s), ReadStatus::ok);
    b = s.accel_mps2;
    EXPECT_EQ(src.accel_bias_now_mps2(), b);
    if (halls) halls->insert(halls->end(), s.hall_v.begin(), s.hall_v.begin() + 4);
  }
  return out;
}

TEST(SimSource, AccelerometerBiasRandomWalk) {
  const double rw = 1e-4;
  const int n = 4000;  // 1 s
  // Over many seeds the bias after T seconds spreads as rw sqrt(T) about accel_bias_mps2.
  const int seeds = 300;
  double s_q = 0.0, s_e = 0.0, m_e = 0.0;
  for (int k = 0; k < seeds; ++k) {
    const auto path = bias_path(1000 + static_cast<std::uint64_t>(k), rw, n);
    ASSERT_EQ(path[0], 0.05);  // the walk starts at the first sample
    const double q = path[1000] - 0.05, e = path[n - 1] - 0.05;
    s_q += q * q;
    s_e += e * e;
    m_e += e;
  }
  EXPECT_NEAR(std::sqrt(s_q / seeds), rw * std::sqrt(1000 / 4000.0), 0.2 * rw * std::sqrt(0.25));
  EXPECT_NEAR(std::sqrt(s_e / seeds), rw * std::sqrt((n - 1) / 4000.0), 0.2 * rw);
  EXPECT_NEAR(m_e / seeds, 0.0, 5 * rw / std::sqrt(seeds));

  // Per sample, a white step of rw sqrt(Ts).
  std::vector<double> halls_walk, halls_still;
  const auto a = bias_path(5, rw, 20000, &halls_walk);
  double s_d = 0.0;
  for (std::size_t i = 1; i < a.size(); ++i) s_d += (a[i] - a[i - 1]) * (a[i] - a[i - 1]);
  EXPECT_NEAR(std::sqrt(s_d / (a.size() - 1)), rw * std::sqrt(1 / 4000.0), 0.05 * rw * std::sqrt(1 / 4000.0));

  // Deterministic: reading the stream again from the start repeats it exactly; another seed does not.
  EXPECT_EQ(a, bias_path(5, rw, 20000));
  EXPECT_NE(a, bias_path(6, rw, 20000));
  // Zero: no walk at all; and the walk has its own random stream (the Halls do not change).
  const auto still = bias_path(5, 0.0, 20000, &halls_still);
  for (double b : still) ASSERT_EQ(b, 0.05);
  EXPECT_EQ(halls_walk, halls_still);

  // The white noise stream is untouched too: with noise on, the two readings differ by the walk alone.
  MotorConfig motor;
  auto cfg = offline(Kind::standstill);
  cfg.noise_seed = 5;
  cfg.imperfections.accel_bias_mps2 = 0.05;
  SimSource white(motor, cfg);
  cfg.imperfections.accel_bias_random_walk_mps2_per_sqrt_s = rw;
  SimSource walking(motor, cfg);
  RawSample s, w;
  for (int k = 0; k < 4000; ++k) {
    ASSERT_EQ(white.read(s), ReadStatus::ok);
    ASSERT_EQ(walking.read(w), ReadStatus::ok);
    EXPECT_NEAR(w.accel_mps2 - s.accel_mps2, walking.accel_bias_now_mps2() - 0.05, 1e-15);
  }
  // A source that starts later starts its walk at its own first sample.
  SimSource later(motor, cfg, 1.0);
  ASSERT_EQ(later.read(s), ReadStatus::ok);
  EXPECT_EQ(later.accel_bias_now_mps2(), 0.05);
}

TEST(SimSource, FrameMotionSeenByTheAccelerometersNotTheHalls) {
  const MotorConfig motor = exact_motor();
  auto cfg = offline(Kind::multisine);
  cfg.imperfections.accel_delay_s = 250e-6;
  SimSource still(motor, cfg);  // frame at rest, no frame accelerometer
  auto& im = cfg.imperfections;
  im.frame_reaction_ratio = -0.02;
  im.frame_vibration_mps2 = 0.03;
  im.frame_vibration_hz = 35.0;
  im.frame_accelerometer = true;
  SimSource src(motor, cfg);
  ASSERT_TRUE(src.ok() && still.ok()) << src.last_error();
  RawSample s, q;
  for (int n = 0; n < 8000; ++n) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    ASSERT_EQ(still.read(q), ReadStatus::ok);
    const double td = n / 4000.0 - 250e-6;
    const double a = src.profile().at(td).acceleration_mps2;
    const double frame = -0.02 * a + 0.03 * std::sin(2 * M_PI * 35.0 * td);
    EXPECT_NEAR(src.frame_acceleration(td), frame, 1e-12);
    // The moving accelerometer is inertial: carriage (relative) plus frame.
    EXPECT_NEAR(s.accel_mps2, a + frame, 1e-12) << n;
    ASSERT_TRUE(s.accel_base_valid);
    EXPECT_NEAR(s.accel_base_mps2, frame, 1e-12) << n;
    // Zero: the frame is still and there is no second accelerometer.
    EXPECT_EQ(q.accel_mps2, a);
    EXPECT_FALSE(q.accel_base_valid);
    EXPECT_EQ(still.frame_acceleration(td), 0.0);
    // The Halls and the truth are relative to the frame, which carries the magnets.
    EXPECT_EQ(s.hall_v, q.hall_v);
    EXPECT_EQ(src.truth()->position_m, still.truth()->position_m);
    EXPECT_EQ(src.truth()->acceleration_mps2, still.truth()->acceleration_mps2);
  }
}

/// Least-squares fit of y = m + c sin(w t) + d cos(w t) over whole periods (the basis is
/// then orthogonal), and the residual std.
struct SineFit {
  double mean = 0.0, sin_amp = 0.0, cos_amp = 0.0, resid_std = 0.0;
};
SineFit fit_sine(const std::vector<double>& y, double w, double rate) {
  SineFit f;
  const double n = static_cast<double>(y.size());
  for (std::size_t k = 0; k < y.size(); ++k) {
    const double t = k / rate;
    f.mean += y[k] / n;
    f.sin_amp += 2.0 * y[k] * std::sin(w * t) / n;
    f.cos_amp += 2.0 * y[k] * std::cos(w * t) / n;
  }
  double r2 = 0.0;
  for (std::size_t k = 0; k < y.size(); ++k) {
    const double t = k / rate;
    const double r = y[k] - f.mean - f.sin_amp * std::sin(w * t) - f.cos_amp * std::cos(w * t);
    r2 += r * r;
  }
  f.resid_std = std::sqrt(r2 / n);
  return f;
}

TEST(SimSource, FrameVibrationVisibleThroughTheNoise) {
  MotorConfig motor;  // 0.02 m/s^2 white noise on both accelerometers
  auto cfg = offline(Kind::standstill);
  auto& im = cfg.imperfections;
  im.accel_bias_mps2 = 0.05;
  im.frame_vibration_mps2 = 0.03;
  im.frame_vibration_hz = 35.0;
  im.frame_accelerometer = true;
  SimSource src(motor, cfg);
  ASSERT_TRUE(src.ok()) << src.last_error();
  const int n = 8000;  // 2 s: 70 whole periods
  std::vector<double> moving(n), base(n);
  RawSample s;
  for (int k = 0; k < n; ++k) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    moving[static_cast<std::size_t>(k)] = s.accel_mps2;
    base[static_cast<std::size_t>(k)] = s.accel_base_mps2;
  }
  const double w = 2 * M_PI * 35.0, se = 0.02 * std::sqrt(2.0 / n);
  const SineFit fm = fit_sine(moving, w, 4000.0), fb = fit_sine(base, w, 4000.0);
  EXPECT_NEAR(fm.sin_amp, 0.03, 5 * se);
  EXPECT_NEAR(fm.cos_amp, 0.0, 5 * se);
  EXPECT_NEAR(fm.mean, 0.05, 5 * 0.02 / std::sqrt(n));  // the moving one has the bias ...
  EXPECT_NEAR(fb.sin_amp, 0.03, 5 * se);
  EXPECT_NEAR(fb.cos_amp, 0.0, 5 * se);
  EXPECT_NEAR(fb.mean, 0.0, 5 * 0.02 / std::sqrt(n));   // ... the frame one has none
  EXPECT_NEAR(fm.resid_std, 0.02, 0.002);
  EXPECT_NEAR(fb.resid_std, 0.02, 0.002);
  // Independent noise: the residuals are uncorrelated.
  double cross = 0.0;
  for (int k = 0; k < n; ++k) {
    const double t = k / 4000.0;
    const auto u = static_cast<std::size_t>(k);
    cross += (moving[u] - fm.mean - fm.sin_amp * std::sin(w * t) - fm.cos_amp * std::cos(w * t)) *
             (base[u] - fb.mean - fb.sin_amp * std::sin(w * t) - fb.cos_amp * std::cos(w * t));
  }
  EXPECT_LT(std::abs(cross / n / (fm.resid_std * fb.resid_std)), 5.0 / std::sqrt(n));
}

/// SimSource::check() of the default motor and a standstill configuration whose `part`
/// (imperfections, temperature) `set` changed.
template <class Part, class Set>
std::string check_with(Part SimConfig::*part, Set set) {
  SimConfig cfg = offline(Kind::standstill);
  set(cfg.*part);
  return SimSource::check(MotorConfig{}, cfg);
}

TEST(SimSource, InvalidImperfectionsAreReported) {
  auto bad = [](auto set) { return check_with(&SimConfig::imperfections, set); };
  using IC = ve::sim::ImperfectionConfig;
  EXPECT_NE(bad([](IC& i) { i.field_third_harmonic = 0.5; }).find("field_third_harmonic"), std::string::npos);
  EXPECT_NE(bad([](IC& i) { i.coil_field_v_per_mps2 = std::nan(""); }).find("coil_field"), std::string::npos);
  EXPECT_NE(bad([](IC& i) { i.accel_delay_s = -1e-4; }).find("accel_delay_s"), std::string::npos);
  EXPECT_NE(bad([](IC& i) { i.accel_bias_random_walk_mps2_per_sqrt_s = -1.0; }).find("random_walk"),
            std::string::npos);
  EXPECT_NE(bad([](IC& i) { i.frame_vibration_hz = -35.0; }).find("frame_vibration_hz"), std::string::npos);
  EXPECT_NE(bad([](IC& i) { i.frame_reaction_ratio = INFINITY; }).find("frame_reaction_ratio"), std::string::npos);
  EXPECT_EQ(bad([](IC& i) {
              i.field_third_harmonic = -0.3;
              i.coil_field_v_per_mps2 = -0.002;
              i.frame_reaction_ratio = 0.5;
              i.frame_accelerometer = true;
            }),
            "");
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
  // Paced: not faster than 399 periods (0.09975 s). No upper bound: a loaded machine
  // only makes it slower.
  EXPECT_GT(elapsed, 0.05);
}

TEST(SimSource, StopWakesBlockedRead) {
  MotorConfig motor;
  motor.sample_rate_hz = 0.05;  // the second read would block for 20 s
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
  EXPECT_LT(elapsed, 10.0);  // woken by stop(), not by the next sample
  EXPECT_EQ(src.read(s), ReadStatus::stopped);
}

// ---- a silent node (fault kind no_samples)

SimConfig with_silence(SimConfig cfg, double start_s, double end_s) {
  ve::sim::FaultConfig f;
  f.kind = ve::sim::FaultConfig::Kind::no_samples;
  f.start_s = start_s;
  f.end_s = end_s;
  cfg.faults[cfg.fault_count++] = f;
  return cfg;
}

// ---- a shared clock (several sources read from one sample thread)

TEST(SimSource, SharedClockSaysWhenEachSampleIsDueAndReadDoesNotWait) {
  MotorConfig motor;  // 4000 Hz
  auto cfg = offline(Kind::multisine);
  cfg.realtime = true;
  SimSource a(motor, cfg), b(motor, cfg);
  // Started 1 s ago: the first 4000 samples are due already; none is waited for.
  const std::int64_t start = ve::drivers::monotonic_ns() - 1000000000LL;
  ASSERT_TRUE(a.share_clock(start));
  ASSERT_TRUE(b.share_clock(start));
  EXPECT_FALSE(a.share_clock(start)) << "a clock is started once";
  RawSample s;
  for (std::uint64_t k = 0; k < 100; ++k) {
    EXPECT_EQ(a.next_due_ns(), start + a.sample_time_ns(k));
    EXPECT_EQ(b.next_due_ns(), a.next_due_ns()) << "one tick for both";
    ASSERT_EQ(a.read(s), ReadStatus::ok);
    EXPECT_EQ(s.t_ns, static_cast<std::int64_t>(k) * 250000);
    ASSERT_EQ(b.read(s), ReadStatus::ok);
  }
  // Not real time, or started already: the source paces itself (or not at all).
  SimSource offline_source(motor, offline(Kind::multisine));
  EXPECT_FALSE(offline_source.share_clock(start));
  EXPECT_EQ(offline_source.next_due_ns(), 0);
  a.stop();
  EXPECT_EQ(a.next_due_ns(), 0) << "stopped: read() returns at once";
  EXPECT_EQ(a.read(s), ReadStatus::stopped);
}

TEST(SimSource, SharedClockSilentNodeTimesOutWithoutWaiting) {
  MotorConfig motor;  // 4000 Hz
  auto cfg = offline(Kind::multisine);
  cfg.realtime = true;
  ve::sim::FaultConfig f;
  f.kind = ve::sim::FaultConfig::Kind::no_samples;
  f.start_s = 0.001;  // samples 4 .. 39999 are never sent
  f.end_s = 10.0;
  cfg.faults[cfg.fault_count++] = f;
  SimSource src(motor, cfg);
  const std::int64_t start = ve::drivers::monotonic_ns() - 1500000;  // samples 0..6 due
  ASSERT_TRUE(src.share_clock(start));
  RawSample s;
  for (int k = 0; k < 4; ++k) ASSERT_EQ(src.read(s), ReadStatus::ok);
  // The silence: a timeout at once, the next one a read timeout later (the sample after
  // the silence is due much later), as a silent CAN node's driver would report it.
  const std::int64_t before = ve::drivers::monotonic_ns();
  EXPECT_EQ(src.read(s), ReadStatus::timeout);
  const std::int64_t next = src.next_due_ns();
  EXPECT_GT(next, before);
  EXPECT_LE(next - before, ve::sim::kSilentReadTimeoutNs + (ve::drivers::monotonic_ns() - before));
  EXPECT_EQ(src.samples_read(), 4u);
}

TEST(SimSource, SilentNodeLosesTheSamplesOfItsWindow) {
  MotorConfig motor;  // 4000 Hz
  auto cfg = offline(Kind::multisine);
  cfg.duration_s = 1.0;
  SimSource plain(motor, cfg);
  SimSource silent(motor, with_silence(cfg, 0.5, 0.75));
  RawSample a, b;
  std::uint64_t read = 0;
  while (silent.read(b) == ReadStatus::ok) {
    // The same stream, less the window [0.5 s, 0.75 s): seq and t_ns jump over it.
    ASSERT_EQ(plain.read(a), ReadStatus::ok);
    while (a.seq < b.seq) ASSERT_EQ(plain.read(a), ReadStatus::ok);
    EXPECT_FALSE(b.seq >= 2000 && b.seq < 3000) << b.seq;
    EXPECT_EQ(a.t_ns, b.t_ns);
    EXPECT_EQ(a.hall_v, b.hall_v);
    EXPECT_EQ(a.accel_mps2, b.accel_mps2);
    EXPECT_EQ(silent.truth()->position_m, plain.truth()->position_m);
    ++read;
  }
  EXPECT_EQ(read, 3000u);
  EXPECT_EQ(silent.samples_read(), 3000u);
  EXPECT_EQ(silent.read(b), ReadStatus::end_of_stream);

  // From the first sample on, and for good: the stream starts late, or ends.
  SimSource late(motor, with_silence(offline(Kind::standstill), 0.0, 0.25));
  ASSERT_EQ(late.read(b), ReadStatus::ok);
  EXPECT_EQ(b.seq, 1000u);
  EXPECT_EQ(b.t_ns, 250000000);
  ve::sim::FaultConfig forever;
  SimSource dead(motor, with_silence(offline(Kind::standstill), 0.1, forever.end_s));
  read = 0;
  while (dead.read(b) == ReadStatus::ok) ++read;
  EXPECT_EQ(read, 400u);
  EXPECT_EQ(dead.read(b), ReadStatus::end_of_stream);
}

TEST(SimSource, SilentNodeInRealTimeTimesOutUntilItsNextSample) {
  MotorConfig motor;  // 4000 Hz
  SimConfig cfg;      // real time
  cfg.profile.kind = Kind::standstill;
  SimSource src(motor, with_silence(cfg, 0.0, 0.1));
  RawSample s;
  int timeouts = 0;
  ReadStatus st;
  while ((st = src.read(s)) == ReadStatus::timeout) ++timeouts;
  ASSERT_EQ(st, ReadStatus::ok);
  // Silent from the start (the first read starts the clock) for 0.1 s: at least one
  // timeout, each after 20 ms without a sample, none once the next one is due within 20 ms.
  EXPECT_GE(timeouts, 1);
  EXPECT_LE(timeouts, 4);
  EXPECT_EQ(s.seq, 400u);
  ASSERT_EQ(src.read(s), ReadStatus::ok);
  EXPECT_EQ(s.seq, 401u);

  // stop() ends a silence for good.
  SimSource dead(motor, with_silence(cfg, 0.0, ve::sim::FaultConfig{}.end_s));
  EXPECT_EQ(dead.read(s), ReadStatus::timeout);
  dead.stop();
  EXPECT_EQ(dead.read(s), ReadStatus::stopped);
}

// ---- temperature model

using TProfile = ve::sim::TemperatureConfig::Profile;

SimConfig realistic_offline() {
  SimConfig cfg = offline(Kind::multisine);
  auto& im = cfg.imperfections;
  im.magnet_strength_std = 0.015;
  im.magnet_placement_std_m = 20e-6;
  im.field_third_harmonic = 0.03;
  im.sensor_placement_std_m = 50e-6;
  im.sensor_gain_std = 0.03;
  im.sensor_offset_std_v = 0.02;
  im.hall_delay_s = 20e-6;
  im.coil_field_v_per_mps2 = 0.001;
  im.frame_accelerometer = true;
  return cfg;
}

bool same_with_base(const std::vector<RawSample>& a, const std::vector<RawSample>& b) {
  if (!same(a, b)) return false;
  for (std::size_t k = 0; k < a.size(); ++k)
    if (a[k].accel_base_mps2 != b[k].accel_base_mps2 || a[k].temperature_valid != b[k].temperature_valid)
      return false;
  return true;
}

TEST(SimTemperature, NoRiseLeavesTheStreamUnchangedWhateverTheCoefficients) {
  MotorConfig motor;
  const SimConfig plain = realistic_offline();
  SimConfig coeffs = plain;
  auto& t = coeffs.temperature;
  t.magnet_remanence_per_k = -0.003;
  t.hall_gain_tc_per_k = 0.002;
  t.hall_gain_tc_std_per_k = 0.001;
  t.hall_offset_tc_std_v_per_k = 0.005;
  t.reference_c = 40.0;
  t.profile = TProfile::ramp;  // delta_k = 0: the ramp goes nowhere
  t.duration_s = 1.0;
  const auto a = run(motor, plain, 3000);
  EXPECT_TRUE(same_with_base(a, run(motor, coeffs, 3000)));
  // The coefficients do not disturb the other track draws either.
  SimSource sa(motor, plain), sb(motor, coeffs);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(sa.sensor_position_m(i), sb.sensor_position_m(i));
  for (double x = 0.1; x < 0.2; x += 0.00731)
    for (int i = 0; i < 4; ++i) {
      EXPECT_EQ(sa.hall_voltage_noiseless(i, x), sb.hall_voltage_noiseless(i, x));
      EXPECT_EQ(sb.hall_voltage_noiseless(i, x, 0.0), sb.hall_voltage_noiseless(i, x));
    }
  // A rise does change it.
  coeffs.temperature.offset_k = 1.0;
  EXPECT_FALSE(same(a, run(motor, coeffs, 3000)));
}

TEST(SimTemperature, PerSensorCoefficientsComeFromTheTrackSeed) {
  MotorConfig motor;
  SimConfig cfg = offline(Kind::standstill);
  SimSource a(motor, cfg);
  const auto& t = cfg.temperature;
  double mean = 0.0;
  bool offsets_differ = false;
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(a.hall_gain_tc_per_k(i), t.hall_gain_tc_per_k, 5 * t.hall_gain_tc_std_per_k);
    EXPECT_NEAR(a.hall_offset_tc_v_per_k(i), 0.0, 5 * t.hall_offset_tc_std_v_per_k);
    mean += a.hall_gain_tc_per_k(i) / 4;
    offsets_differ = offsets_differ || a.hall_offset_tc_v_per_k(i) != a.hall_offset_tc_v_per_k(0);
  }
  EXPECT_NE(a.hall_gain_tc_per_k(0), a.hall_gain_tc_per_k(1));
  EXPECT_TRUE(offsets_differ);
  cfg.noise_seed += 1;  // the noise seed does not change the sensors
  SimSource b(motor, cfg);
  cfg.imperfections.track_seed += 1;
  SimSource c(motor, cfg);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(a.hall_gain_tc_per_k(i), b.hall_gain_tc_per_k(i));
    EXPECT_EQ(a.hall_offset_tc_v_per_k(i), b.hall_offset_tc_v_per_k(i));
    EXPECT_NE(a.hall_gain_tc_per_k(i), c.hall_gain_tc_per_k(i));
  }
}

TEST(SimTemperature, TenKelvinWarmerScalesEachHallByItsCoefficients) {
  MotorConfig motor;
  SimConfig cold = realistic_offline();
  cold.profile.kind = Kind::standstill;
  cold.imperfections.sensor_offset_std_v = 0.0;  // so the zero-field output is motor.hall.offset_v
  SimConfig warm = cold;
  warm.temperature.offset_k = 10.0;
  SimSource c(motor, cold), w(motor, warm);
  ASSERT_TRUE(w.ok()) << w.last_error();
  RawSample s;
  ASSERT_EQ(w.read(s), ReadStatus::ok);
  EXPECT_EQ(w.temperature_rise_k(), 10.0);
  EXPECT_EQ(w.temperature_at(0.0), 10.0);
  EXPECT_EQ(w.temperature_at(123.0), 10.0);
  EXPECT_FALSE(s.temperature_valid);  // not reported by default
  const double p = motor.magnet_pitch_m;
  for (int i = 0; i < 4; ++i) {
    // Peak amplitude over one magnet period (the track under the sensor is the same for
    // both; only the temperature differs).
    auto peak = [&](const SimSource& src, double dT) {
      double lo = 1e9, hi = -1e9;
      for (double x = 0.3; x < 0.3 + p; x += p / 2000) {
        const double v = src.hall_voltage_noiseless(i, x, dT);
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
      return 0.5 * (hi - lo);
    };
    const double scale = (1.0 + 10.0 * w.hall_gain_tc_per_k(i)) * (1.0 - 0.012);
    EXPECT_NEAR(peak(w, 10.0) / peak(c, 0.0), scale, 1e-9) << i;
    EXPECT_NEAR(scale, 0.978, 0.02) << i;  // about -1 % (sensor) -1.2 % (magnets)
    // Everywhere: warm - offset = scale (cold - offset) + the sensor's offset drift.
    for (double x = 0.3; x < 0.3 + p; x += p / 37)
      EXPECT_NEAR(w.hall_voltage_noiseless(i, x, 10.0) - motor.hall.offset_v,
                  scale * (c.hall_voltage_noiseless(i, x) - motor.hall.offset_v) + 10.0 * w.hall_offset_tc_v_per_k(i),
                  1e-12)
          << i << " " << x;
    // The source itself reads the warm signal: noiseless at 10 K plus the coil field.
    const double x = w.truth()->position_m;
    const double lsb = motor.adc.lsb_v();
    EXPECT_NEAR(s.hall_v[static_cast<std::size_t>(i)],
                std::clamp(w.hall_voltage_noiseless(i, x, 10.0), motor.adc.min_v, motor.adc.max_v),
                6 * motor.hall.noise_v + lsb);
  }
}

TEST(SimTemperature, ProfilesStepRampWarmup) {
  MotorConfig motor;
  SimConfig cfg = offline(Kind::standstill);
  auto& t = cfg.temperature;
  t.offset_k = 2.0;
  t.delta_k = -8.0;
  t.start_s = 1.0;
  t.duration_s = 4.0;

  t.profile = TProfile::constant;
  EXPECT_EQ(SimSource(motor, cfg).temperature_at(0.0), -6.0);

  t.profile = TProfile::step;
  {
    SimSource src(motor, cfg);
    EXPECT_EQ(src.temperature_at(0.999), 2.0);
    EXPECT_EQ(src.temperature_at(1.0), -6.0);
    EXPECT_EQ(src.temperature_at(100.0), -6.0);
  }
  t.profile = TProfile::ramp;
  {
    SimSource src(motor, cfg);
    ASSERT_TRUE(src.ok()) << src.last_error();
    EXPECT_EQ(src.temperature_at(0.5), 2.0);
    EXPECT_DOUBLE_EQ(src.temperature_at(3.0), 2.0 - 4.0);
    EXPECT_DOUBLE_EQ(src.temperature_at(5.0), -6.0);  // reaches delta_k at start + duration ...
    EXPECT_EQ(src.temperature_at(5.5), -6.0);         // ... and holds
    EXPECT_EQ(src.temperature_at(1e4), -6.0);
  }
  t.profile = TProfile::warmup;
  {
    SimSource src(motor, cfg);
    EXPECT_EQ(src.temperature_at(0.9), 2.0);
    for (double tt : {1.0, 2.0, 5.0, 9.0, 30.0})
      EXPECT_NEAR(src.temperature_at(tt), 2.0 - 8.0 * (1.0 - std::exp(-(tt - 1.0) / 4.0)), 1e-12) << tt;
  }
  // The source follows the profile sample by sample.
  t.start_s = 0.01;
  t.duration_s = 0.02;
  t.profile = TProfile::ramp;
  SimSource src(motor, cfg);
  RawSample s;
  for (int n = 0; n < 400; ++n) {
    ASSERT_EQ(src.read(s), ReadStatus::ok);
    EXPECT_EQ(src.temperature_rise_k(), src.temperature_at(static_cast<double>(n) / motor.sample_rate_hz));
  }
  EXPECT_EQ(src.temperature_rise_k(), -6.0);
  // Ramps and warm-ups need a duration.
  t.duration_s = 0.0;
  EXPECT_NE(SimSource::check(motor, cfg).find("duration_s"), std::string::npos);
  t.profile = TProfile::step;
  EXPECT_EQ(SimSource::check(motor, cfg), "");
}

TEST(SimTemperature, ReportedTemperatureIsNoisyAndQuantised) {
  MotorConfig motor;
  SimConfig cfg = offline(Kind::standstill);
  auto& t = cfg.temperature;
  t.report = true;
  t.offset_k = 10.0;
  t.reference_c = 30.0;
  const auto quiet = run(motor, offline(Kind::standstill), 4000);
  const auto samples = run(motor, cfg, 4000);
  double sum = 0.0, sum2 = 0.0;
  for (const RawSample& s : samples) {
    ASSERT_TRUE(s.temperature_valid);
    EXPECT_EQ(s.temperature_c, std::round(s.temperature_c / 0.0625) * 0.0625);
    sum += s.temperature_c;
    sum2 += (s.temperature_c - 40.0) * (s.temperature_c - 40.0);
  }
  EXPECT_NEAR(sum / 4000, 40.0, 0.01);
  EXPECT_NEAR(std::sqrt(sum2 / 4000), std::sqrt(0.1 * 0.1 + 0.0625 * 0.0625 / 12), 0.01);
  // Reporting draws its own noise: the accelerometer noise is untouched.
  for (std::size_t k = 0; k < samples.size(); ++k) EXPECT_EQ(samples[k].accel_mps2, quiet[k].accel_mps2);
  // Without noise or rounding it is exactly reference + rise.
  t.report_noise_k = 0.0;
  t.report_resolution_k = 0.0;
  EXPECT_EQ(run(motor, cfg, 1)[0].temperature_c, 40.0);
}

TEST(SimTemperature, InvalidTemperatureConfigIsReported) {
  auto bad = [](auto set) { return check_with(&SimConfig::temperature, set); };
  using TC = ve::sim::TemperatureConfig;
  EXPECT_NE(bad([](TC& t) { t.delta_k = 150.0; }).find("delta_k"), std::string::npos);
  EXPECT_NE(bad([](TC& t) { t.offset_k = std::nan(""); }).find("offset_k"), std::string::npos);
  EXPECT_NE(bad([](TC& t) { t.start_s = -1.0; }).find("start_s"), std::string::npos);
  EXPECT_NE(bad([](TC& t) { t.magnet_remanence_per_k = -0.01; }).find("remanence"), std::string::npos);
  EXPECT_NE(bad([](TC& t) { t.hall_gain_tc_std_per_k = -0.001; }).find("hall_gain_tc_std_per_k"), std::string::npos);
  EXPECT_NE(bad([](TC& t) { t.hall_offset_tc_std_v_per_k = 1.0; }).find("hall_offset_tc_std_v_per_k"),
            std::string::npos);
  EXPECT_NE(bad([](TC& t) { t.report_resolution_k = -0.1; }).find("report_resolution_k"), std::string::npos);
  EXPECT_EQ(bad([](TC& t) {
              t.profile = TC::Profile::warmup;
              t.delta_k = -20.0;
              t.offset_k = 30.0;
              t.duration_s = 600.0;
              t.report = true;
            }),
            "");
}

}  // namespace
