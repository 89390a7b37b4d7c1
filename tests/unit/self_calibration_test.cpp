// Calibration without a reference on the realistic simulated motor: the same
// calibration run as with a reference, its reference column never read; then the
// accuracy scenarios of accuracy_realistic_test with the result, next to the
// calibration with a reference.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "core/error_stats.hpp"
#include "core/pipeline.hpp"
#include "core/self_calibration.hpp"
#include "core/status.hpp"
#include "home_truth.hpp"
#include "realistic_fixture.hpp"
#include "sim/sim_source.hpp"

namespace {

using ve::sim::MotionProfileConfig;

struct NoRef {
  ve::core::Calibration cal;
  ve::core::SelfCalibrationReport report;
  bool ok = false;
};

/// The realistic machine's calibration run with its reference column made
/// useless (NaN), calibrated without a reference. The timing anchor is the Hall
/// front end's delay, as its design gives it (the recording cannot tell it).
const NoRef& no_ref() {
  static NoRef r = [] {
    NoRef n;
    const auto& axis = ve::test::realistic("sim-realistic.yaml").axis;
    std::vector<ve::core::ReferenceSegment> segments;
    std::string error;
    EXPECT_TRUE(ve::sim::record_calibration_run(axis.motor, axis.driver.sim, {}, segments, error)) << error;
    for (auto& s : segments) s.reference_m.assign(s.reference_m.size(), std::nan(""));
    ve::core::SelfCalibrationConfig cfg;
    cfg.hall_delay_s = axis.driver.sim.imperfections.hall_delay_s;
    n.ok = ve::core::identify_without_reference(axis.motor, segments, cfg, n.cal, n.report, error);
    EXPECT_TRUE(n.ok) << error;
    return n;
  }();
  return r;
}

struct Scenario {
  const char* name;
  MotionProfileConfig::Kind kind;
  double start_m, velocity_mps, acceleration_mps2;
  double t0_s, t1_s;
};

const Scenario kScenarios[] = {
    {"standstill", MotionProfileConfig::Kind::standstill, 0.4321, 0, 0, 0.5, 4.0},
    {"constant_1mps", MotionProfileConfig::Kind::constant_velocity, 0.05, 1.0, 0, 0.1, 0},
    {"constant_5mps2", MotionProfileConfig::Kind::constant_acceleration, 0.05, 0.0, 5.0, 0.1, 0},
};

ve::core::EstimateErrors evaluate(const ve::config::AxisConfig& axis, const ve::core::Calibration& cal,
                                  const Scenario& sc, std::uint64_t seed, double zero_m = 0.0) {
  // zero_m: where the calibration's position 0 is in the simulator's frame.
  ve::sim::SimConfig cfg = axis.driver.sim;
  cfg.realtime = false;
  cfg.noise_seed = seed;
  cfg.profile = MotionProfileConfig{};
  cfg.profile.kind = sc.kind;
  cfg.profile.start_m = sc.start_m;
  cfg.profile.velocity_mps = sc.velocity_mps;
  cfg.profile.acceleration_mps2 = sc.acceleration_mps2;
  cfg.profile.min_m = 0.02;
  cfg.profile.max_m = 0.98;
  ve::sim::SimSource sim(axis.motor, cfg);
  EXPECT_TRUE(sim.ok()) << sim.last_error();
  const double t1 = sc.t1_s > 0 ? sc.t1_s : sim.profile().steady_duration_s();
  ve::core::PipelineConfig pc;
  pc.motor = axis.motor;
  pc.sensors = cal.model;
  pc.calibrated = true;
  pc.start_position_m = sc.start_m - zero_m;
  ve::core::AxisPipeline pipeline(pc, cal.table);
  ve::core::EstimateErrors e;
  ve::core::RawSample s;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const double t = static_cast<double>(s.t_ns) * 1e-9;
    if (t > t1) break;
    const auto& est = pipeline.step(s);
    if (t < sc.t0_s) continue;
    const auto& truth = *sim.truth();
    e.add(est.position_m - (truth.position_m - zero_m), est.position_std_m, est.velocity_mps - truth.velocity_mps,
          est.velocity_std_mps, (est.status & ve::core::status::kValid) != 0);
  }
  return e;
}

TEST(SelfCalibration, IdentifiesTheSensorModelWithoutAReference) {
  const NoRef& n = no_ref();
  ASSERT_TRUE(n.ok);
  const auto& axis = ve::test::realistic("sim-realistic.yaml").axis;
  const auto& with_ref = ve::test::realistic("sim-realistic.yaml").cal.model;
  const auto& im = axis.driver.sim.imperfections;
  const auto& m = n.cal.model;
  const auto& rep = n.report;
  std::printf("[ figures  ] without reference: hall delay %.2f us (reproduced %.2f), coil field %.4f mV/(m/s^2), "
              "accel scale %.5f, bias %.4f, delay %.1f us, vibration %.2f Hz %.4f m/s^2; table residual "
              "%.3f mV; passes %d+%d at %.4f/%.4f mm/s, swept %.4f mm (%d periods), pass line residual %.3f um, "
              "joins %.3f um\n",
              m.hall_delay_s * 1e6, rep.hall_delay_reproduced_s * 1e6, m.coil_field_v_per_mps2 * 1e3, m.accel_scale,
              m.accel_bias_mps2, m.accel_delay_s * 1e6, m.frame_vibration_hz, m.frame_vibration_mps2,
              rep.identification.table_residual_mv, rep.passes_forward, rep.passes_backward,
              rep.forward_speed_mps * 1e3, rep.backward_speed_mps * 1e3, rep.swept_m * 1e3, rep.periods,
              rep.pass_line_residual_m * 1e6, rep.join_mismatch_m * 1e6);
  std::printf("[ figures  ] with reference:    hall delay %.2f us, coil field %.4f mV/(m/s^2), accel scale %.5f, "
              "bias %.4f, delay %.1f us\n",
              with_ref.hall_delay_s * 1e6, with_ref.coil_field_v_per_mps2 * 1e3, with_ref.accel_scale,
              with_ref.accel_bias_mps2, with_ref.accel_delay_s * 1e6);
  for (const auto& p : rep.identification.problems) std::printf("[ problem  ] %s\n", p.c_str());
  for (const auto& l : rep.iterations) std::printf("[ iteration] %s\n", l.c_str());
  EXPECT_TRUE(rep.identification.good);
  EXPECT_EQ(n.cal.info.method, "no-reference");
  EXPECT_NEAR(m.hall_delay_s, im.hall_delay_s, 2e-6);
  EXPECT_NEAR(m.accel_bias_mps2, im.accel_bias_mps2, 0.005);
  const double scale = (1.0 + im.accel_scale_error) * (1.0 + im.frame_reaction_ratio);
  EXPECT_NEAR(m.accel_scale, scale, 0.002 * scale);
  EXPECT_NEAR(m.coil_field_v_per_mps2, im.coil_field_v_per_mps2, 0.1 * im.coil_field_v_per_mps2);
  EXPECT_NEAR(m.accel_delay_s, im.accel_delay_s, 20e-6);
  EXPECT_EQ(rep.passes_forward, 1);
  EXPECT_EQ(rep.passes_backward, 1);
  EXPECT_EQ(rep.periods, static_cast<int>(axis.motor.travel_m / axis.motor.magnet_pitch_m));
  EXPECT_NEAR(rep.swept_m, axis.motor.travel_m, 1e-3);

  // Sensor geometry against the simulator's placement (relative to sensor 0).
  ve::sim::SimSource sim(axis.motor, axis.driver.sim);
  ASSERT_EQ(rep.sensor_offset_m.size(), 4u);
  for (int s = 1; s < 4; ++s) {
    const double truth = sim.sensor_position_m(s) - sim.sensor_position_m(0);
    std::printf("[ figures  ] sensor %d at %.4f mm from sensor 0 (simulated %.4f, nominal %.4f)\n", s,
                rep.sensor_offset_m[static_cast<std::size_t>(s)] * 1e3, truth * 1e3, axis.motor.hall.offset_of(s) * 1e3);
    EXPECT_NEAR(rep.sensor_offset_m[static_cast<std::size_t>(s)], truth, 5e-6);
  }
  // Every magnet period with its own pitch, summing to the swept length.
  ASSERT_GE(rep.period_pitch_m.size(), 80u);
  for (double p : rep.period_pitch_m) EXPECT_NEAR(p, axis.motor.magnet_pitch_m, 200e-6);
}

// Position 0 of a calibration without a reference is home, a feature of the
// track (sensor 0's first whole positive half-wave); its truth is the same
// feature located on the simulator's noiseless Hall model, and every scenario's
// truth is measured from it. Nothing is fitted to the estimates.
TEST(SelfCalibration, MeetsTheSpecOnTheRealisticScenarios) {
  const NoRef& n = no_ref();
  ASSERT_TRUE(n.ok);
  const auto& r = ve::test::realistic("sim-realistic.yaml");
  const double home = ve::test::home_truth_m(r.axis.motor, r.axis.driver.sim, n.report);
  ASSERT_TRUE(std::isfinite(home));
  std::printf("[ figures  ] home: %.4f mm in the simulator's frame (the calibration put it %.4f mm from the sweep's "
              "start: the accelerometer bridge is off by %.3f um); %s\n",
              home * 1e3, n.report.home_from_sweep_start_m * 1e3, (n.report.home_from_sweep_start_m - home) * 1e6,
              n.report.zero_definition.c_str());
  // The calibration's table has its home at 0.
  double h = 0, hr = 0, hf = 0;
  ASSERT_TRUE(ve::core::table_home(n.cal.table, n.report.home_rising_m - 0.1 * r.axis.motor.magnet_pitch_m, h, hr, hf));
  EXPECT_NEAR(h, 0.0, 1e-9);
  for (const auto& sc : kScenarios) {
    for (std::uint64_t seed : {101u, 202u}) {
      const auto e = evaluate(r.axis, n.cal, sc, seed, home);
      const auto w = evaluate(r.axis, r.cal, sc, seed);
      std::printf("[ figures  ] %-15s seed %3llu: without reference position rms %.3f um (bias %+.3f, max %.3f), "
                  "velocity rms %.4f mm/s | with reference %.3f um (bias %+.3f), %.4f mm/s | difference %.3f um\n",
                  sc.name, static_cast<unsigned long long>(seed), e.position_m.rms() * 1e6, e.position_m.bias() * 1e6,
                  e.position_m.max_abs() * 1e6, e.velocity_mps.rms() * 1e3, w.position_m.rms() * 1e6,
                  w.position_m.bias() * 1e6, w.velocity_mps.rms() * 1e3,
                  (e.position_m.rms() - w.position_m.rms()) * 1e6);
      ASSERT_GT(e.position_m.count(), 1000u);
      EXPECT_EQ(e.not_valid, 0u) << sc.name;
      EXPECT_LE(e.position_m.rms(), 5e-6) << sc.name;
      EXPECT_LE(e.velocity_mps.rms(), 1.7e-3) << sc.name;
    }
  }
}

TEST(SelfCalibration, WithoutATimingAnchorSaysWhatIsMissing) {
  const auto& axis = ve::test::realistic("sim-realistic.yaml").axis;
  ve::sim::CalibrationRunConfig run;
  run.dynamic_duration_s = 2.0;
  ve::core::MotorConfig motor = axis.motor;
  std::vector<ve::core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(ve::sim::record_calibration_run(motor, axis.driver.sim, run, segments, error)) << error;
  ve::core::Calibration cal;
  ve::core::SelfCalibrationReport rep;
  ve::core::SelfCalibrationConfig cfg;
  cfg.iterations = 2;
  ASSERT_TRUE(ve::core::identify_without_reference(motor, segments, cfg, cal, rep, error)) << error;
  EXPECT_FALSE(rep.identification.good);
  bool named = false;
  for (const auto& p : rep.identification.problems) named = named || p.find("--hall-delay-us") != std::string::npos;
  EXPECT_TRUE(named);
}

TEST(SelfCalibration, WithoutSlowPassesSaysWhatMotionIsMissing) {
  const auto& axis = ve::test::realistic("sim-realistic.yaml").axis;
  std::vector<ve::core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(ve::sim::record_calibration_run(axis.motor, axis.driver.sim, {}, segments, error)) << error;
  segments.erase(segments.begin());  // fast motion only
  ve::core::Calibration cal;
  ve::core::SelfCalibrationReport rep;
  EXPECT_FALSE(ve::core::identify_without_reference(axis.motor, segments, {}, cal, rep, error));
  EXPECT_NE(error.find("slow pass over the whole travel in each direction"), std::string::npos) << error;
}

}  // namespace
