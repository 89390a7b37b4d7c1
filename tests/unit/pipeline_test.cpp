// The whole estimation chain (Hall array + Kalman filter) on the ideal simulated
// motor, against the simulator's exact truth, sample by sample and causally.
#include <gtest/gtest.h>

#include <cmath>

#include "core/pipeline.hpp"
#include "core/status.hpp"
#include "sim/sim_source.hpp"

namespace {

using ve::core::AxisPipeline;
using ve::core::MotorConfig;
using ve::sim::MotionProfileConfig;
using ve::sim::SimConfig;
using ve::sim::SimSource;

struct Stats {
  double pos_rms_m = 0, pos_max_m = 0, vel_rms_mps = 0, vel_max_mps = 0, coverage_2sigma = 0;
  int n = 0, invalid = 0;
};

Stats evaluate(const MotorConfig& motor, const SimConfig& cfg, double start_position_m, double t0_s, double t1_s) {
  SimSource sim(motor, cfg);
  EXPECT_TRUE(sim.ok()) << sim.last_error();
  ve::core::PipelineConfig pc;
  pc.motor = motor;
  pc.start_position_m = start_position_m;
  AxisPipeline pipeline(pc, ve::core::nominal_hall_table(motor));
  ve::core::RawSample s;
  Stats st;
  double sp = 0, sv = 0;
  int inside = 0;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const double t = static_cast<double>(s.t_ns) * 1e-9;
    if (t > t1_s) break;
    const auto& est = pipeline.step(s);
    if (t < t0_s) continue;
    const auto& truth = *sim.truth();
    if (!(est.status & ve::core::status::kValid)) ++st.invalid;
    const double ep = est.position_m - truth.position_m;
    const double ev = est.velocity_mps - truth.velocity_mps;
    sp += ep * ep;
    sv += ev * ev;
    st.pos_max_m = std::max(st.pos_max_m, std::abs(ep));
    st.vel_max_mps = std::max(st.vel_max_mps, std::abs(ev));
    if (std::abs(ep) <= 2.0 * est.position_std_m) ++inside;
    ++st.n;
  }
  st.pos_rms_m = std::sqrt(sp / st.n);
  st.vel_rms_mps = std::sqrt(sv / st.n);
  st.coverage_2sigma = static_cast<double>(inside) / st.n;
  return st;
}

SimConfig profile(MotionProfileConfig::Kind kind, double start_m, double v = 0.0, double a = 0.0) {
  SimConfig cfg;
  cfg.realtime = false;
  cfg.noise_seed = 11;
  cfg.profile.kind = kind;
  cfg.profile.start_m = start_m;
  cfg.profile.velocity_mps = v;
  cfg.profile.acceleration_mps2 = a;
  cfg.profile.min_m = 0.02;
  cfg.profile.max_m = 0.98;
  return cfg;
}

void print(const char* name, const Stats& s) {
  std::printf("[ figures  ] %-22s n=%6d position rms %.3f um max %.3f um | velocity rms %.3f mm/s max %.3f mm/s | "
              "2-sigma coverage %.1f %%\n",
              name, s.n, s.pos_rms_m * 1e6, s.pos_max_m * 1e6, s.vel_rms_mps * 1e3, s.vel_max_mps * 1e3,
              100.0 * s.coverage_2sigma);
}

// The paper's spec: 5 um position and 1.7 mm/s velocity (RMS, bias included).
constexpr double kSpecPositionM = 5e-6;
constexpr double kSpecVelocityMps = 1.7e-3;

TEST(PipelineIdealMotor, StandstillMeetsTheSpec) {
  MotorConfig motor;
  const Stats s = evaluate(motor, profile(MotionProfileConfig::Kind::standstill, 0.4321), 0.4321, 0.25, 5.0);
  print("standstill", s);
  EXPECT_EQ(s.invalid, 0);
  EXPECT_LT(s.pos_rms_m, kSpecPositionM);
  EXPECT_LT(s.vel_rms_mps, kSpecVelocityMps);
}

TEST(PipelineIdealMotor, ConstantOneMetrePerSecondMeetsTheSpec) {
  MotorConfig motor;
  const Stats s = evaluate(motor, profile(MotionProfileConfig::Kind::constant_velocity, 0.05, 1.0), 0.05, 0.25, 0.85);
  print("constant 1 m/s", s);
  EXPECT_EQ(s.invalid, 0);
  EXPECT_LT(s.pos_rms_m, kSpecPositionM);
  EXPECT_LT(s.vel_rms_mps, kSpecVelocityMps);
}

TEST(PipelineIdealMotor, ConstantAccelerationAndMultisineAreTracked) {
  MotorConfig motor;
  const SimConfig ca = profile(MotionProfileConfig::Kind::constant_acceleration, 0.05, 0.0, 5.0);
  // Up to the end of the constant-acceleration phase (then it brakes with a step).
  const auto ca_profile = ve::sim::MotionProfile::create(ca.profile, motor.travel_m);
  ASSERT_TRUE(ca_profile);
  const Stats acc = evaluate(motor, ca, 0.05, 0.1, ca_profile->steady_duration_s());
  print("constant 5 m/s^2", acc);
  SimConfig ms = profile(MotionProfileConfig::Kind::multisine, 0.5);
  ms.profile.max_velocity_mps = 2.0;
  ms.profile.max_acceleration_mps2 = 10.0;
  const Stats sine = evaluate(motor, ms, 0.5, 0.25, 10.0);
  print("multisine 2 m/s 10 m/s^2", sine);
  for (const Stats* s : {&acc, &sine}) {
    EXPECT_EQ(s->invalid, 0);
    EXPECT_LT(s->pos_rms_m, kSpecPositionM);
    EXPECT_LT(s->vel_rms_mps, kSpecVelocityMps);
  }
}

TEST(PipelineStatus, StartsValidAndHomedNearTheHintAndFlagsAMissingSensor) {
  MotorConfig motor;
  SimSource sim(motor, profile(MotionProfileConfig::Kind::standstill, 0.2));
  ve::core::PipelineConfig pc;
  pc.motor = motor;
  pc.start_position_m = 0.2 + 0.004;  // the hint only has to be within half a pitch (6 mm)
  AxisPipeline pipeline(pc, ve::core::nominal_hall_table(motor));
  ve::core::RawSample s;
  for (int i = 0; i < 400; ++i) {
    ASSERT_EQ(sim.read(s), ve::drivers::ReadStatus::ok);
    pipeline.step(s);
  }
  EXPECT_TRUE(pipeline.last().status & ve::core::status::kValid);
  EXPECT_TRUE(pipeline.last().status & ve::core::status::kHomed);
  EXPECT_NEAR(pipeline.last().position_m, 0.2, 3e-6);
  ASSERT_EQ(sim.read(s), ve::drivers::ReadStatus::ok);
  s.hall_valid_mask &= ~(1u << 2);
  const auto& est = pipeline.step(s);
  EXPECT_TRUE(est.status & ve::core::status::hall_fault(2));
  EXPECT_TRUE(est.status & ve::core::status::kDegraded);
}

TEST(PipelineTiming, BridgesDroppedSamplesByPrediction) {
  MotorConfig motor;
  SimSource sim(motor, profile(MotionProfileConfig::Kind::constant_velocity, 0.1, 0.5));
  ve::core::PipelineConfig pc;
  pc.motor = motor;
  pc.start_position_m = 0.1;
  AxisPipeline pipeline(pc, ve::core::nominal_hall_table(motor));
  ve::core::RawSample s;
  for (int i = 0; i < 2000; ++i) {
    ASSERT_EQ(sim.read(s), ve::drivers::ReadStatus::ok);
    if (i >= 1000 && i < 1010) continue;  // ten samples lost
    const auto& est = pipeline.step(s);
    if (i == 1010) {
      EXPECT_EQ(est.samples_skipped, 10u);
    }
  }
  EXPECT_NEAR(pipeline.last().position_m, sim.truth()->position_m, 3e-6);
  EXPECT_TRUE(pipeline.last().status & ve::core::status::kValid);
}

// A start position the Halls cannot confirm (off the table: a wrong kept position,
// a mistyped machine file) must not leave the axis searching there for ever: after a
// few failed acquisitions it starts again as if no position were known (not homed).
TEST(Pipeline, AStartPositionOffTheTableIsGivenUpNotSearchedForEver) {
  MotorConfig motor;
  SimConfig cfg = profile(MotionProfileConfig::Kind::constant_velocity, 0.3, 0.2);
  cfg.duration_s = 0.2;
  SimSource sim(motor, cfg);
  ASSERT_TRUE(sim.ok()) << sim.last_error();
  ve::core::PipelineConfig pc;
  pc.motor = motor;
  pc.start_position_known = true;
  pc.start_position_m = motor.travel_m + 0.5;  // half a metre beyond the travel
  AxisPipeline pipeline(pc, ve::core::nominal_hall_table(motor));
  ve::core::RawSample s;
  int samples = 0, first_fix = -1;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const auto& e = pipeline.step(s);
    if (first_fix < 0 && !(e.status & ve::core::status::kHallRejected)) first_fix = samples;
    ++samples;
  }
  ASSERT_GE(first_fix, 0) << "never acquired";
  EXPECT_LT(first_fix, 100);
  EXPECT_FALSE(pipeline.last().status & ve::core::status::kHomed) << "the period is not known";
  EXPECT_TRUE(std::isfinite(pipeline.last().position_m));
}

}  // namespace
