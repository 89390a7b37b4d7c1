// Steps of acceleration on the realistic simulated motor: trapezoidal moves (the
// acceleration jumps between +10, 0 and -10 m/s^2, as a drive without jerk limit
// commands them). The accelerometer shows each step its delay late (0.24 ms here);
// what the carriage did at the new acceleration meanwhile must not be taken for a
// step of the accelerometer's bias.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "core/error_stats.hpp"
#include "core/pipeline.hpp"
#include "core/status.hpp"
#include "realistic_fixture.hpp"
#include "sim/sim_source.hpp"

namespace {

TEST(AccelerationSteps, AreNotTakenForABiasStepNorAnAccelerometerFault) {
  const auto& r = ve::test::realistic("sim-realistic.yaml");
  ve::sim::SimConfig cfg = r.axis.driver.sim;
  cfg.realtime = false;
  cfg.noise_seed = 77;
  cfg.profile = ve::sim::MotionProfileConfig{};
  cfg.profile.kind = ve::sim::MotionProfileConfig::Kind::shuttle;
  cfg.profile.start_m = 0.3;
  cfg.profile.min_m = 0.1;
  cfg.profile.max_m = 0.9;
  cfg.profile.max_velocity_mps = 2.0;
  cfg.profile.max_acceleration_mps2 = 10.0;
  cfg.duration_s = 4.0;
  ve::sim::SimSource sim(r.axis.motor, cfg);
  ASSERT_TRUE(sim.ok()) << sim.last_error();
  ve::core::AxisPipeline pipeline = ve::test::calibrated_pipeline(r, cfg.profile.start_m);
  ve::core::RawSample s;
  ve::core::EstimateErrors e;
  std::uint64_t accel_fault = 0, samples = 0;
  double worst_bias_change = 0.0;
  const double calibrated_bias = r.cal.model.accel_bias_mps2;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const auto& est = pipeline.step(s);
    if (static_cast<double>(s.t_ns) * 1e-9 < 0.5) continue;  // after the start
    const auto& truth = *sim.truth();
    ++samples;
    if (est.status & ve::core::status::kAccelFault) ++accel_fault;
    worst_bias_change = std::max(worst_bias_change, std::abs(est.accel_bias_mps2 - calibrated_bias));
    e.add(est.position_m - truth.position_m, est.position_std_m, est.velocity_mps - truth.velocity_mps,
          est.velocity_std_mps, (est.status & ve::core::status::kValid) != 0);
  }
  std::printf("[ figures  ] shuttle 2 m/s, 10 m/s^2 steps: position rms %.3f um (max %.3f), velocity rms %.4f mm/s "
              "(max %.3f), 2-sigma %.1f %% / %.1f %%, bias steps detected %llu, bias moved up to %.4f m/s^2, "
              "ACCEL_FAULT in %llu of %llu samples\n",
              e.position_m.rms() * 1e6, e.position_m.max_abs() * 1e6, e.velocity_mps.rms() * 1e3,
              e.velocity_mps.max_abs() * 1e3, 100 * e.position_coverage(), 100 * e.velocity_coverage(),
              static_cast<unsigned long long>(pipeline.filter().bias_steps_detected()), worst_bias_change,
              static_cast<unsigned long long>(accel_fault), static_cast<unsigned long long>(samples));
  ASSERT_GT(samples, 10000u);
  EXPECT_EQ(pipeline.filter().bias_steps_detected(), 0u);
  EXPECT_EQ(accel_fault, 0u);
  // The realistic motor's bias random walk moves it by about a mm/s^2 in 4 s.
  EXPECT_LT(worst_bias_change, 0.05);
  EXPECT_EQ(e.not_valid, 0u);
  EXPECT_LT(e.position_m.max_abs(), 5e-6);
}

}  // namespace
