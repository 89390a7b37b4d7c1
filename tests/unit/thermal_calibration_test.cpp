// Thermal calibration (core/thermal_calibration.hpp) on motors of the population:
// each motor calibrated from one simulated calibration run, then given a second run
// recorded 15 K warmer, from which each Hall sensor's own temperature coefficients
// are fitted. Without them, a motor standing 10 K off its calibration temperature
// has its sensors' offset drift in the position (several um), which no redundancy
// can see: honest, sigma covers it and VALID is not claimed. With them, the drift is
// followed from the rise the fixes' common gain reads.
#include <gtest/gtest.h>

#include <cstdio>
#include <tuple>

#include "../bench/population_eval.hpp"
#include "config/loader.hpp"
#include "shipped_tuning.hpp"
#include "core/thermal_calibration.hpp"

namespace {

using namespace ve;

using test::shipped_tuning;

constexpr double kThermalRunRiseK = 15.0;

struct Calibrated {
  bench::CalibrationOutcome plain, thermal;
  core::ThermalCalibrationReport report;
  std::string error;
};

Calibrated calibrate(const sim::PopulationMotor& p, bool with_ruler) {
  Calibrated c;
  std::vector<core::ReferenceSegment> segments, warm;
  if (!bench::record_population_calibration(p, segments, c.error) ||
      !bench::record_population_thermal_run(p, kThermalRunRiseK, warm, c.error))
    return c;
  c.plain = bench::calibrate_population_motor(p, segments, with_ruler);
  if (!c.plain.ok) {
    c.error = c.plain.error;
    return c;
  }
  c.thermal = c.plain;
  if (!bench::thermal_calibrate_population_motor(p, warm, c.thermal, c.report, c.error)) c.thermal.ok = false;
  return c;
}

class ThermalCalibrationPopulation : public ::testing::TestWithParam<std::uint64_t> {};

// Motors 1, 8 and 11 stand 10 K warm or cold: without the coefficients they are
// NOT VALID for the whole window (their drift is in sigma) and 2-10 um off. With
// them what the temperature adds to the error is a fraction of that, the motor is
// VALID for the whole window, and sigma still covers the error.
TEST_P(ThermalCalibrationPopulation, AWarmOrColdMotorAtStandstillFollowsItsSensorsCoefficients) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  ASSERT_FALSE(p.sim.temperature.report);
  const Calibrated c = calibrate(p, true);
  ASSERT_TRUE(c.thermal.ok) << c.error;
  EXPECT_TRUE(c.thermal.cal.model.thermal_known);
  EXPECT_FALSE(c.report.rise_reported);
  EXPECT_NEAR(c.report.rise_k, kThermalRunRiseK, 0.15 * kThermalRunRiseK) << "the common gain read as the rise";
  const auto standstill = bench::population_scenarios(p.datasheet.travel_m).at(0);
  ASSERT_EQ(standstill.name, "standstill");
  // What the temperature adds to the error as calibrated (motor 8's 10-bit converter
  // alone leaves 0.85 um where it stands), in quadrature.
  const auto cold = bench::run_population_scenario(p, c.thermal, standstill, bench::Condition::as_calibrated,
                                                   bench::run_noise_seed(GetParam()));
  ASSERT_TRUE(cold.ok) << cold.error;
  const double base = cold.err.position_m.rms();
  const auto added = [base](double rms) { return std::sqrt(std::max(0.0, rms * rms - base * base)); };
  for (const auto cond : {bench::Condition::ramp_plus_10k, bench::Condition::step_minus_10k}) {
    const auto before = bench::run_population_scenario(p, c.plain, standstill, cond, bench::run_noise_seed(GetParam()));
    const auto after =
        bench::run_population_scenario(p, c.thermal, standstill, cond, bench::run_noise_seed(GetParam()));
    ASSERT_TRUE(before.ok && after.ok) << before.error << after.error;
    std::printf("[ figures  ] %-11s as calibrated %.3f um | without coefficients %.3f um VALID %.1f %% | with them "
                "%.3f um VALID %.2f %% 2-sigma %.1f %% largest error while VALID %.3f um\n",
                bench::condition_name(cond), base * 1e6, before.err.position_m.rms() * 1e6,
                100 * before.valid_fraction(), after.err.position_m.rms() * 1e6, 100 * after.valid_fraction(),
                100 * after.err.position_coverage(), after.max_valid_error_m * 1e6);
    EXPECT_LE(added(after.err.position_m.rms()), 0.35 * added(before.err.position_m.rms()))
        << bench::condition_name(cond);
    EXPECT_GE(after.valid_fraction(), 0.999) << bench::condition_name(cond);
    EXPECT_GE(after.err.position_coverage(), 0.9) << bench::condition_name(cond);
    EXPECT_LE(after.max_valid_error_m, bench::kValidPositionAccuracyM) << bench::condition_name(cond);
    EXPECT_EQ(after.flagged, 0u) << bench::condition_name(cond) << ": no healthy sensor flagged";
  }
}

// Moving off right after a start 10 K off the calibration temperature, the sensors'
// learning settles over the first tenths of a second, and until it has the array's
// disagreement (in the position's sigma) is a pattern the filter's velocity follows
// at the speed it crosses the magnets. The velocity's sigma holds it: before it did,
// 29-35 % of motor 8's velocity samples at 1 m/s (a 0.15 s window on its 0.26 m
// travel) and 62 % of motor 14's from rest at 5 m/s^2 were within 2 sigma; now
// 84-86 % and 100 %. (The population's target, 90 % over the motors, is in
// docs/accuracy.md.)
TEST(ThermalCalibrationPopulationMoving, TheVelocitySigmaHoldsTheSensorsLearningAfterAStart) {
  for (const auto& [seed, scenario, cond] : {std::tuple{8ull, 1, bench::Condition::ramp_plus_10k},
                                             std::tuple{8ull, 1, bench::Condition::step_minus_10k},
                                             std::tuple{14ull, 2, bench::Condition::step_minus_10k}}) {
    const auto p = sim::draw_population_motor(seed, shipped_tuning());
    ASSERT_FALSE(p.sim.temperature.report);
    const Calibrated c = calibrate(p, true);
    ASSERT_TRUE(c.thermal.ok) << c.error;
    const auto sc = bench::population_scenarios(p.datasheet.travel_m).at(static_cast<std::size_t>(scenario));
    const auto r = bench::run_population_scenario(p, c.thermal, sc, cond, bench::run_noise_seed(seed));
    ASSERT_TRUE(r.ok) << r.error;
    std::printf("[ figures  ] motor %llu %-8s %-11s velocity %.4f mm/s RMS, 2-sigma %.1f %%; position %.3f um, "
                "2-sigma %.1f %%; VALID %.1f %%\n",
                static_cast<unsigned long long>(seed), sc.name.c_str(), bench::condition_name(cond),
                r.err.velocity_mps.rms() * 1e3, 100 * r.err.velocity_coverage(), r.err.position_m.rms() * 1e6,
                100 * r.err.position_coverage(), 100 * r.valid_fraction());
    EXPECT_GE(r.err.velocity_coverage(), 0.8) << "motor " << seed << " " << sc.name << " " << bench::condition_name(cond);
    EXPECT_GE(r.err.position_coverage(), 0.9) << "motor " << seed << " " << sc.name << " " << bench::condition_name(cond);
    EXPECT_EQ(r.flagged, 0u) << "motor " << seed << ": no healthy sensor flagged";
  }
}

// Without a temperature from the node the rise is the fixes' common gain read as a
// thermometer; where the carriage stands on two sensors that gain is known to a
// percent or worse, and the sensors must not be moved by a rise the thermometer does
// not know. Motor 69 as calibrated read -2 to -3 K there: moved by it, it was 2.6 um
// off (0.8 um without the coefficients) and VALID at 5.1 um; motor 81, 10 K warm, was
// VALID at 7.9 um. The sensors now follow the rise as far as it is known, and the
// covariance holds what the coefficients make of the rest. (Both motors are of the
// held-out sets, 61-100, where these two cases were found.)
TEST(ThermalCalibrationPopulationNoRuler, APoorReadingOfTheRiseMovesTheSensorsOnlyAsFarAsItIsKnown) {
  for (const auto& [seed, cond] : {std::pair{69ull, bench::Condition::as_calibrated},
                                   std::pair{81ull, bench::Condition::ramp_plus_10k}}) {
    const auto p = sim::draw_population_motor(seed, shipped_tuning());
    ASSERT_FALSE(p.sim.temperature.report);
    const Calibrated c = calibrate(p, true);
    ASSERT_TRUE(c.thermal.ok) << c.error;
    const auto standstill = bench::population_scenarios(p.datasheet.travel_m).at(0);
    int used = 0;
    const auto plain = bench::run_population_scenario(p, c.plain, standstill, cond, bench::run_noise_seed(seed));
    const auto after =
        bench::run_population_scenario(p, c.thermal, standstill, cond, bench::run_noise_seed(seed), {},
                                       [&](double, const core::EncoderEstimate& e, const core::AxisPipeline&,
                                           const sim::SimSource&) { used = e.hall_sensors_used; });
    ASSERT_TRUE(plain.ok && after.ok) << plain.error << after.error;
    std::printf("[ figures  ] motor %llu %-13s sensors used %d | without coefficients %.3f um VALID %.1f %% | with "
                "them %.3f um VALID %.1f %% 2-sigma %.1f %% largest error while VALID %.3f um\n",
                static_cast<unsigned long long>(seed), bench::condition_name(cond), used,
                plain.err.position_m.rms() * 1e6, 100 * plain.valid_fraction(), after.err.position_m.rms() * 1e6,
                100 * after.valid_fraction(), 100 * after.err.position_coverage(), after.max_valid_error_m * 1e6);
    ASSERT_EQ(used, 2) << "the premise: two sensors out of saturation where it stands";
    EXPECT_LE(after.max_valid_error_m, bench::kValidPositionAccuracyM) << "motor " << seed;
    // Not asserted: motor 81's 2-sigma coverage, 80.8 % (100 % without the coefficients,
    // whose sigma was 15 um wide); docs/accuracy.md, thermal calibration.
    if (cond == bench::Condition::as_calibrated) {
      EXPECT_LE(after.err.position_m.rms(), 2.0 * plain.err.position_m.rms()) << "motor " << seed;
    }
  }
}

// Without a ruler the positions of the thermal run come from the array itself. Motor
// 2's run starts at the end of its table (where the table rests on the
// accelerometer's bridge), motor 7's track has almost no signature (magnets 1 um,
// 0.3 %), motor 8's travel is 0.26 m: each was placed whole periods off before the
// anchor was scored over several magnets. Their coefficients must come out as with
// a ruler.
TEST(ThermalCalibrationPopulationNoRuler, CoefficientsMatchARulersOnHardTracks) {
  for (const std::uint64_t seed : {2u, 7u, 8u}) {
    const auto p = sim::draw_population_motor(seed, shipped_tuning());
    const Calibrated ruler = calibrate(p, true), none = calibrate(p, false);
    ASSERT_TRUE(ruler.thermal.ok) << "motor " << seed << ": " << ruler.error;
    ASSERT_TRUE(none.thermal.ok) << "motor " << seed << ": " << none.error;
    double worst_offset = 0.0, worst_gain = 0.0;
    for (int i = 0; i < p.datasheet.hall.count; ++i) {
      const auto k = static_cast<std::size_t>(i);
      worst_offset = std::max(worst_offset, std::abs(ruler.thermal.cal.model.hall_offset_tc_v_per_k[k] -
                                                     none.thermal.cal.model.hall_offset_tc_v_per_k[k]));
      worst_gain = std::max(worst_gain, std::abs(ruler.thermal.cal.model.hall_gain_tc_per_k[k] -
                                                 none.thermal.cal.model.hall_gain_tc_per_k[k]));
      // The fit's residual is the sensors' noise, as with a ruler: no period misplaced.
      EXPECT_LE(none.report.residual_v[k], 1.1 * ruler.report.residual_v[k]) << "motor " << seed << " sensor " << i;
    }
    std::printf("[ figures  ] motor %llu: rise %.2f / %.2f K, coefficients differ by at most %.4f mV/K and "
                "%.5f %%/K\n",
                static_cast<unsigned long long>(seed), ruler.report.rise_k, none.report.rise_k, worst_offset * 1e3,
                worst_gain * 100);
    EXPECT_LE(worst_offset, 1e-5) << "motor " << seed << ": 0.01 mV/K";
    EXPECT_LE(worst_gain, 2e-6) << "motor " << seed << ": 0.0002 %/K";
  }
}

// A recording too close in temperature says nothing about the coefficients: refused,
// with what to record instead; the calibration given is not changed.
TEST(ThermalCalibrationPopulationNoRuler, ARecordingTooCloseInTemperatureIsRefused) {
  const auto p = sim::draw_population_motor(1, shipped_tuning());
  std::vector<core::ReferenceSegment> segments, warm;
  std::string error;
  ASSERT_TRUE(bench::record_population_calibration(p, segments, error)) << error;
  ASSERT_TRUE(bench::record_population_thermal_run(p, 2.0, warm, error)) << error;
  auto c = bench::calibrate_population_motor(p, segments, true);
  ASSERT_TRUE(c.ok) << c.error;
  const auto before = core::calibration_checksum(c.cal);
  core::ThermalCalibrationReport report;
  EXPECT_FALSE(bench::thermal_calibrate_population_motor(p, warm, c, report, error));
  EXPECT_NE(error.find("record it at least 5 K warmer or colder"), std::string::npos) << error;
  EXPECT_EQ(core::calibration_checksum(c.cal), before);
  EXPECT_FALSE(c.cal.model.thermal_known);
}

INSTANTIATE_TEST_SUITE_P(Seeds, ThermalCalibrationPopulation, ::testing::Values(1u, 8u, 11u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

}  // namespace
