// Homing without a reference mark, on the realistic simulated track (magnet
// strength and placement tolerances, sensor errors, delays, coil field), with the
// table from a simulated calibration run: from random start positions anywhere on
// the travel, the axis finds the right magnet period within 2 periods of motion.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

#include "core/pipeline.hpp"
#include "core/status.hpp"
#include "realistic_fixture.hpp"
#include "sim/sim_source.hpp"

namespace {

using ve::sim::MotionProfileConfig;
using ve::test::Realistic;
using ve::test::realistic;

struct Move {
  double start_m;
  double distance_m;  ///< signed: the move's direction
  double speed_mps;
  double accel_mps2;
};

struct Outcome {
  bool homed = false;
  double motion_at_homing_m = 0.0;    ///< path length from the start when HOMED first appeared
  double max_error_after_m = 0.0;     ///< largest |error| from then to the end
  double final_error_m = 0.0;         ///< |error| at the end, at rest
  bool homed_before_decision = false; ///< HOMED set while the matcher still searched
  std::uint64_t corrections = 0;
  double first_relative_error_m = 0.0;  ///< |error| of the first estimate (relative frame)
};

/// The pipeline of the calibrated realistic axis with signature homing.
ve::core::PipelineConfig homing_pipeline(const Realistic& r, bool start_known, double start_hint_m) {
  ve::core::PipelineConfig pc;
  pc.motor = r.axis.motor;
  pc.sensors = r.cal.model;
  pc.calibrated = true;
  pc.signature_homing = true;
  pc.start_position_known = start_known;
  pc.start_position_m = start_hint_m;
  return pc;
}

Outcome run(const Realistic& r, const Move& m, std::uint64_t seed, bool start_known = false, double start_hint_m = 0.0) {
  ve::sim::SimConfig cfg = r.axis.driver.sim;
  cfg.realtime = false;
  cfg.noise_seed = seed;
  cfg.profile = MotionProfileConfig{};
  cfg.profile.kind = MotionProfileConfig::Kind::point_to_point;
  cfg.profile.start_m = m.start_m;
  // The farther end comes first: a short stub on the other side.
  cfg.profile.min_m = m.distance_m > 0 ? m.start_m - 0.001 : m.start_m + m.distance_m;
  cfg.profile.max_m = m.distance_m > 0 ? m.start_m + m.distance_m : m.start_m + 0.001;
  cfg.profile.max_velocity_mps = m.speed_mps;
  cfg.profile.max_acceleration_mps2 = m.accel_mps2;
  cfg.profile.dwell_s = 1.0;
  ve::sim::SimSource sim(r.axis.motor, cfg);
  EXPECT_TRUE(sim.ok()) << sim.last_error();

  ve::core::AxisPipeline pipeline(homing_pipeline(r, start_known, start_hint_m), r.cal.table);

  Outcome o;
  ve::core::RawSample s;
  double path = 0.0, last_x = m.start_m;
  bool first = true;
  // The whole first stroke and some rest (well before the way back).
  const double t_end = std::abs(m.distance_m) / m.speed_mps + 2.0 * m.speed_mps / m.accel_mps2 + 0.25;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const auto& truth = *sim.truth();
    if (static_cast<double>(s.t_ns) * 1e-9 > t_end) break;
    path += std::abs(truth.position_m - last_x);
    last_x = truth.position_m;
    const auto& est = pipeline.step(s);
    const double err = std::abs(est.position_m - truth.position_m);
    if (first && pipeline.initialised()) {
      o.first_relative_error_m = err;
      first = false;
    }
    const bool homed = (est.status & ve::core::status::kHomed) != 0;
    if (homed && !o.homed) {
      o.homed = true;
      o.motion_at_homing_m = path;
      if (pipeline.homing_in_progress()) o.homed_before_decision = true;
    }
    if (o.homed) o.max_error_after_m = std::max(o.max_error_after_m, err);
    o.final_error_m = err;
  }
  o.corrections = pipeline.homing_corrections();
  const auto& h = pipeline.signature_homing();
  std::printf("[ homing   ] records %d, candidates left %d, best chi2 %.1f, runner-up %.1f, matcher motion %.2f mm, in progress %d\n",
              h.records(), h.candidates_alive(), h.best_chi2(), h.runner_up_chi2(), h.motion_m() * 1e3,
              pipeline.homing_in_progress() ? 1 : 0);
  return o;
}

TEST(SignatureHoming, FindsTheRightPeriodFrom20RandomStartsWithin2PeriodsOfMotion) {
  const Realistic& r = realistic("sim-realistic.yaml");
  ASSERT_TRUE(r.report.good);
  const double pitch = r.axis.motor.magnet_pitch_m;
  std::mt19937_64 rng(20261122);
  std::uniform_real_distribution<double> where(0.06, 0.94);
  std::uniform_real_distribution<double> speed(0.02, 0.5);
  std::uniform_int_distribution<int> dir(0, 1);
  double worst_motion = 0.0;
  for (int i = 0; i < 20; ++i) {
    const Move m{where(rng), (dir(rng) ? 1.0 : -1.0) * 3.0 * pitch, speed(rng), 2.0};
    const Outcome o = run(r, m, 1000 + static_cast<std::uint64_t>(i));
    std::printf("[ figures  ] start %.6f m, move %+.0f mm at %.3f m/s: homed after %.2f mm (%.2f periods), "
                "max error after %.1f um, at rest %.3f um, relative start off by %.3f mm\n",
                m.start_m, m.distance_m * 1e3, m.speed_mps, o.motion_at_homing_m * 1e3, o.motion_at_homing_m / pitch,
                o.max_error_after_m * 1e6, o.final_error_m * 1e6, o.first_relative_error_m * 1e3);
    EXPECT_TRUE(o.homed) << "start " << m.start_m;
    EXPECT_LE(o.motion_at_homing_m, 2.0 * pitch) << "start " << m.start_m;
    EXPECT_FALSE(o.homed_before_decision);
    // The right period: a wrong one would be off by a whole pitch (12 mm).
    EXPECT_LT(o.max_error_after_m, 0.1e-3) << "start " << m.start_m;
    EXPECT_LT(o.final_error_m, 5e-6) << "start " << m.start_m;
    worst_motion = std::max(worst_motion, o.motion_at_homing_m);
  }
  std::printf("[ figures  ] worst motion before homing: %.2f mm = %.2f periods\n", worst_motion * 1e3,
              worst_motion / pitch);
}

TEST(SignatureHoming, StartsRelativeAndStaysNotHomedWithoutMotion) {
  const Realistic& r = realistic("sim-realistic.yaml");
  ve::sim::SimConfig cfg = r.axis.driver.sim;
  cfg.realtime = false;
  cfg.profile = MotionProfileConfig{};
  cfg.profile.kind = MotionProfileConfig::Kind::standstill;
  cfg.profile.start_m = 0.4321;
  ve::sim::SimSource sim(r.axis.motor, cfg);
  ASSERT_TRUE(sim.ok()) << sim.last_error();
  ve::core::AxisPipeline pipeline(homing_pipeline(r, false, 0.0), r.cal.table);
  ve::core::RawSample s;
  int n = 0, valid = 0;
  double first_err = 0.0;
  while (n < 4000 && sim.read(s) == ve::drivers::ReadStatus::ok) {
    const auto& est = pipeline.step(s);
    EXPECT_EQ(est.status & ve::core::status::kHomed, 0u);
    if (est.status & ve::core::status::kValid) ++valid;
    if (n == 0) first_err = std::abs(est.position_m - sim.truth()->position_m);
    ++n;
  }
  EXPECT_TRUE(pipeline.homing_in_progress());
  // Relative: valid for a control loop, but in another period than the truth.
  EXPECT_GT(valid, 3000);
  EXPECT_GT(first_err, 0.5 * r.axis.motor.magnet_pitch_m);
}

TEST(SignatureHoming, AStartPositionOffByWholePeriodsIsCorrectedOnTheFirstMove) {
  // The position kept at the last shutdown says 0.3; someone moved the carriage
  // three periods by hand while the machine was off.
  const Realistic& r = realistic("sim-realistic.yaml");
  const double pitch = r.axis.motor.magnet_pitch_m;
  const double truth_start = 0.3 + 3 * pitch + 0.0002;
  const Outcome o = run(r, {truth_start, 3 * pitch, 0.1, 2.0}, 77, true, 0.3);
  std::printf("[ figures  ] kept 0.3 m, truly at %.4f m: %llu correction(s), error at rest %.3f um\n", truth_start,
              static_cast<unsigned long long>(o.corrections), o.final_error_m * 1e6);
  EXPECT_EQ(o.corrections, 1u);
  EXPECT_LT(o.final_error_m, 5e-6);
}

TEST(SignatureHoming, ARightStartPositionIsConfirmedNotMoved) {
  const Realistic& r = realistic("sim-realistic.yaml");
  const double pitch = r.axis.motor.magnet_pitch_m;
  const Outcome o = run(r, {0.6123, -3 * pitch, 0.2, 2.0}, 78, true, 0.6123);
  EXPECT_TRUE(o.homed);
  EXPECT_EQ(o.motion_at_homing_m, 0.0);  // homed from the first sample
  EXPECT_EQ(o.corrections, 0u);
  EXPECT_LT(o.max_error_after_m, 5e-6);
}

}  // namespace
