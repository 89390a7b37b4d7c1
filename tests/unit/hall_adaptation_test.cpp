// Hall adaptation on the realistic simulated motor: a motor warmer than at
// calibration has its sensors' gains and offsets learnt while it moves; one at
// its calibration temperature keeps them near zero; a dead sensor is not
// "adapted" into agreement.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "core/pipeline.hpp"
#include "core/status.hpp"
#include "realistic_fixture.hpp"
#include "sim/sim_source.hpp"

namespace {

/// The realistic machine's simulator, `rise_k` off its calibration temperature.
ve::sim::SimConfig sim_config(const ve::test::Realistic& r, double rise_k) {
  ve::sim::SimConfig cfg = r.axis.driver.sim;  // the multisine of the machine file
  cfg.realtime = false;
  cfg.noise_seed = 31;
  cfg.temperature.offset_k = rise_k;
  return cfg;
}

/// Runs the pipeline over the whole simulation: RMS position error from `from_s` on.
double late_position_rms_m(ve::sim::SimSource& sim, ve::core::AxisPipeline& pipeline, double from_s) {
  ve::core::RawSample s;
  double sum = 0.0;
  long n = 0;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const auto& e = pipeline.step(s);
    if (static_cast<double>(s.t_ns) * 1e-9 < from_s) continue;
    const double err = e.position_m - sim.truth()->position_m;
    sum += err * err;
    ++n;
  }
  return std::sqrt(sum / std::max(1L, n));
}

/// The simulated gain change of a sensor with coefficient `hall_tc_per_k`: the
/// magnets' remanence and the sensor's own.
double simulated_gain(const ve::sim::SimConfig& cfg, double rise_k, double hall_tc_per_k) {
  return (1.0 + hall_tc_per_k * rise_k) * (1.0 + cfg.temperature.magnet_remanence_per_k * rise_k) - 1.0;
}

struct AdaptationRun {
  double gain[ve::core::kMaxHalls] = {}, offset_v[ve::core::kMaxHalls] = {};
  double truth_gain[ve::core::kMaxHalls] = {}, truth_offset_v[ve::core::kMaxHalls] = {};
  double late_position_rms_m = 0.0;  ///< over the last 2 s
  std::uint32_t faulty = 0;
  int halls = 0;
};

AdaptationRun run(double rise_k, bool dead_sensor = false) {
  const auto& r = ve::test::realistic("sim-realistic.yaml");
  ve::sim::SimConfig cfg = sim_config(r, rise_k);
  cfg.duration_s = 6.0;
  if (dead_sensor) {
    cfg.fault_count = 1;
    cfg.faults[0].kind = ve::sim::FaultConfig::Kind::hall_stuck_mid;
    cfg.faults[0].sensor = 2;
    cfg.faults[0].start_s = 1.0;
  }
  ve::sim::SimSource sim(r.axis.motor, cfg);
  EXPECT_TRUE(sim.ok()) << sim.last_error();
  ve::core::AxisPipeline pipeline = ve::test::calibrated_pipeline(r, cfg.profile.start_m);
  const double late_rms_m = late_position_rms_m(sim, pipeline, 4.0);
  AdaptationRun out;
  out.halls = r.axis.motor.hall.count;
  out.late_position_rms_m = late_rms_m;
  out.faulty = pipeline.last().hall_faulty_mask;
  for (int i = 0; i < out.halls; ++i) {
    out.gain[i] = pipeline.adaptation().total_gain(i);  // the common gain and its own
    out.offset_v[i] = pipeline.adaptation().offset_v(i);
    out.truth_gain[i] = simulated_gain(cfg, rise_k, sim.hall_gain_tc_per_k(i));
    out.truth_offset_v[i] = sim.hall_offset_tc_v_per_k(i) * rise_k;
    std::printf("[ figures  ] %+.0f K sensor %d: gain %+.4f (simulated %+.4f), offset %+.2f mV (simulated %+.2f, plus "
                "the gain change times its static offset)\n",
                rise_k, i, out.gain[i], out.truth_gain[i], out.offset_v[i] * 1e3, out.truth_offset_v[i] * 1e3);
  }
  std::printf("[ figures  ] %+.0f K%s: position rms over the last 2 s %.3f um, faulty mask %02x\n", rise_k,
              dead_sensor ? ", sensor 2 dead" : "", out.late_position_rms_m * 1e6, out.faulty);
  return out;
}

TEST(HallAdaptation, LearnsTheGainsAndOffsetsOfAWarmerMotor) {
  const AdaptationRun w = run(10.0);
  for (int i = 0; i < w.halls; ++i) {
    // The gain is the magnets' remanence and the sensor's own coefficient, about -2.2 %.
    EXPECT_NEAR(w.gain[i], w.truth_gain[i], 0.003) << "sensor " << i;
    // The offset also takes up the gain change times the sensor's static offset
    // (20 mV one sigma on this motor: about 0.4 mV).
    EXPECT_NEAR(w.offset_v[i], w.truth_offset_v[i], 1.5e-3) << "sensor " << i;
  }
  EXPECT_EQ(w.faulty, 0u) << "a warmer motor is not a failing sensor";
  EXPECT_LT(w.late_position_rms_m, 1e-6);
}

TEST(HallAdaptation, AtTheCalibrationTemperatureLearnsNothing) {
  const AdaptationRun c = run(0.0);
  for (int i = 0; i < c.halls; ++i) {
    EXPECT_LT(std::abs(c.gain[i]), 0.001) << "sensor " << i;
    EXPECT_LT(std::abs(c.offset_v[i]), 0.5e-3) << "sensor " << i;
  }
  EXPECT_EQ(c.faulty, 0u);
  EXPECT_LT(c.late_position_rms_m, 0.2e-6);
}

TEST(HallAdaptation, ADeadSensorIsFlaggedNotAdaptedIntoAgreement) {
  const AdaptationRun d = run(10.0, true);
  EXPECT_EQ(d.faulty, 1u << 2) << "only the dead sensor is out";
  EXPECT_LT(d.late_position_rms_m, 1e-6);
}

/// Standing where one sensor alone is out of saturation on the realistic motor
/// (0.4321 m), `rise_k` away from the calibration temperature: the common gain
/// cannot be told from a position there; the node's temperature tells it.
struct StandstillRun {
  double rms_m = 0.0, common_gain = 0.0, simulated_common_gain = 0.0;
};

StandstillRun standstill(double rise_k, bool report) {
  const auto& r = ve::test::realistic("sim-realistic.yaml");
  ve::sim::SimConfig cfg = sim_config(r, rise_k);
  cfg.profile = ve::sim::MotionProfileConfig{};
  cfg.profile.kind = ve::sim::MotionProfileConfig::Kind::standstill;
  cfg.profile.start_m = 0.4321;
  cfg.profile.min_m = 0.02;
  cfg.profile.max_m = 0.98;
  cfg.duration_s = 2.0;
  cfg.temperature.report = report;
  ve::sim::SimSource sim(r.axis.motor, cfg);
  EXPECT_TRUE(sim.ok()) << sim.last_error();
  ve::core::AxisPipeline pipeline = ve::test::calibrated_pipeline(r, cfg.profile.start_m);
  StandstillRun out;
  out.rms_m = late_position_rms_m(sim, pipeline, 1.0);
  out.common_gain = pipeline.adaptation().common_gain();
  out.simulated_common_gain = simulated_gain(cfg, rise_k, cfg.temperature.hall_gain_tc_per_k);
  std::printf("[ figures  ] standstill on one sensor, %+.0f K, temperature %s: position rms %.3f um, common gain %+.4f "
              "(simulated mean %+.4f)\n",
              rise_k, report ? "reported" : "not reported", out.rms_m * 1e6, out.common_gain, out.simulated_common_gain);
  return out;
}

TEST(HallAdaptation, TheNodesTemperatureGivesTheCommonGainWhereOneSensorCannot) {
  ASSERT_TRUE(std::isfinite(ve::test::realistic("sim-realistic.yaml").cal.model.temperature_c))
      << "the calibration run's sensor node reports its temperature";
  for (double rise : {10.0, -10.0}) {
    const StandstillRun with = standstill(rise, true);
    EXPECT_NEAR(with.common_gain, with.simulated_common_gain, 0.003) << rise << " K";
    EXPECT_LT(with.rms_m, 0.3e-6) << rise << " K";
    // Without the temperature the one sensor's gain is unknown: the fix is off by
    // the gain change times that sensor's distance from its zero-field output.
    const StandstillRun without = standstill(rise, false);
    EXPECT_GT(without.rms_m, 5.0 * with.rms_m) << rise << " K";
  }
}

}  // namespace
