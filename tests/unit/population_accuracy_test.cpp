// Accuracy on motors nobody tuned the estimator on: three motors of the population
// (drivers/sim/population.hpp), each calibrated with the simulator as the ruler
// from a simulated calibration run, given only its data-sheet values. The five
// motion scenarios of the population benchmark, as calibrated, and a sensor that
// dies in the middle of a run. The benchmark (tests/bench/population_bench.cpp)
// does the same on twenty motors, without a ruler and under temperature too.
#include <gtest/gtest.h>

#include <cstdio>

#include "../bench/population_eval.hpp"
#include "config/loader.hpp"
#include "shipped_tuning.hpp"

namespace {

using namespace ve;

using test::shipped_tuning;

/// The motor calibrated from one simulated calibration run, with a ruler or without.
bench::CalibrationOutcome calibrated(const sim::PopulationMotor& p, bool with_ruler) {
  std::vector<core::ReferenceSegment> segments;
  std::string error;
  if (!bench::record_population_calibration(p, segments, error)) {
    bench::CalibrationOutcome failed;
    failed.error = "recording the calibration run: " + error;
    return failed;
  }
  return bench::calibrate_population_motor(p, segments, with_ruler);
}

bench::CalibrationOutcome calibrated_with_a_ruler(const sim::PopulationMotor& p) { return calibrated(p, true); }
bench::CalibrationOutcome calibrated_without_a_ruler(const sim::PopulationMotor& p) { return calibrated(p, false); }

class PopulationMotor : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationMotor, WithARulerMeetsTheTargetsInEveryScenarioAndFlagsADeadSensor) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  std::printf("[ motor    ] %s\n", p.summary().c_str());
  const auto cal = calibrated_with_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  const auto scenarios = bench::population_scenarios(p.datasheet.travel_m);
  for (const auto& sc : scenarios) {
    const auto r =
        bench::run_population_scenario(p, cal, sc, bench::Condition::as_calibrated, bench::run_noise_seed(GetParam()));
    ASSERT_TRUE(r.ok) << sc.name << ": " << r.error;
    std::printf("[ figures  ] %-15s position rms %.3f um (bias %+.3f, max %.3f) | velocity rms %.4f mm/s | "
                "2-sigma %.1f %% / %.1f %% | VALID %.2f %% | largest error while VALID %.3f um\n",
                sc.name.c_str(), r.err.position_m.rms() * 1e6, r.err.position_m.bias() * 1e6,
                r.err.position_m.max_abs() * 1e6, r.err.velocity_mps.rms() * 1e3, 100 * r.err.position_coverage(),
                100 * r.err.velocity_coverage(), 100 * r.valid_fraction(), r.max_valid_error_m * 1e6);
    ASSERT_GT(r.samples, 100u) << sc.name;
    // The target with a ruler for position (RMS, bias included); the
    // paper's spec for velocity (the 0.1 mm/s target is not met everywhere yet:
    // see the population table in docs/accuracy.md).
    EXPECT_LE(r.err.position_m.rms(), 0.5e-6) << sc.name;
    EXPECT_LE(r.err.velocity_mps.rms(), 1.7e-3) << sc.name;
    EXPECT_EQ(r.valid, r.samples) << sc.name << ": VALID for the whole window";
    EXPECT_EQ(r.flagged, 0u) << sc.name << ": no healthy sensor flagged";
    EXPECT_LT(r.max_valid_error_m, 5e-6) << sc.name;
  }
  // A Hall sensor dies (stuck at its zero-field output) in the middle of a multisine.
  bench::FaultProbe probe;
  probe.inject = true;
  probe.sensor = static_cast<int>(GetParam() % static_cast<std::uint64_t>(p.datasheet.hall.count));
  probe.at_s = 5.0;
  const auto r = bench::run_population_scenario(p, cal, scenarios[3], bench::Condition::as_calibrated,
                                                bench::probe_noise_seed(GetParam()), probe);
  ASSERT_TRUE(r.ok) << r.error;
  std::printf("[ figures  ] dead sensor %d flagged after %.1f ms\n", probe.sensor, r.detect_s * 1e3);
  EXPECT_FALSE(r.probe_flagged_before);
  EXPECT_GE(r.detect_s, 0.0) << "the dead sensor was never flagged";
  EXPECT_LT(r.detect_s, 0.05);
}

// A motor whose fixes scatter by a micrometre or two from sample to sample (10-bit
// converters: 2.0-2.5 um per fix on these three) is calibrated GOOD with a ruler: the
// fast-motion residual is judged beyond the fixes' own noise, which the filter
// averages. Judged on the residual itself, all three were POOR and `calibrate`
// refused to write them. A reference read 20 us after the Halls in fast motion (what
// the check is for) is still POOR.
class PopulationCoarseConverter : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationCoarseConverter, CalibratesGoodWithARulerAndALateReferenceIsStillPoor) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  std::printf("[ motor    ] %s\n", p.summary().c_str());
  std::vector<core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(bench::record_population_calibration(p, segments, error)) << error;
  ASSERT_EQ(segments.size(), 2u);
  const auto cal = bench::calibrate_population_motor(p, segments, true);
  ASSERT_TRUE(cal.ok) << cal.error;
  std::printf("[ figures  ] fast motion %.2f um RMS, fixes' noise %.2f um, beyond %.2f um\n", cal.fast_residual_um,
              cal.fast_noise_um, cal.fast_beyond_noise_um);
  EXPECT_GT(cal.fast_noise_um, 1.0) << "not a coarse motor: the test would not show anything";
  EXPECT_TRUE(cal.good) << (cal.problems.empty() ? std::string() : cal.problems.front());

  // The fast-motion segment's reference read late by 20 us (interpolated).
  auto late = segments;
  const double shift = 20e-6 * p.datasheet.sample_rate_hz;
  ASSERT_LT(shift, 1.0);
  auto& ref = late[1].reference_m;
  for (std::size_t i = ref.size() - 1; i > 0; --i) ref[i] += (ref[i - 1] - ref[i]) * shift;
  const auto bad = bench::calibrate_population_motor(p, late, true);
  ASSERT_TRUE(bad.ok) << bad.error;
  std::printf("[ figures  ] late reference: fast motion %.2f um RMS, beyond the noise %.2f um\n",
              bad.fast_residual_um, bad.fast_beyond_noise_um);
  EXPECT_FALSE(bad.good);
  bool named = false;
  for (const auto& why : bad.problems) named = named || why.find("in fast motion the Hall position") != std::string::npos;
  EXPECT_TRUE(named) << "the late reference was not named as the fast-motion residual";
  // ... nor absorbed into the Hall delay, which the fast motion would otherwise give.
  bool timing = false;
  for (const auto& why : bad.problems) timing = timing || why.find("in fast motion the Halls lag") != std::string::npos;
  EXPECT_TRUE(timing) << "the fast motion's Hall delay, 20 us off the sweep's, was not reported";
}

// Without a ruler the calibration fits the accelerometer itself, against the fast
// motion's Hall positions; the identification's own fit against the self-made
// reference (bridged with the accelerometer at the turnarounds) is not used. Motor 33
// was refused on that unused fit ("the accelerometer scale is 0.624") while its own was
// 0.975. A sensor 30 % less sensitive than configured is still refused.
class PopulationNoRulerAccelerometer : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationNoRulerAccelerometer, TheFitUsedIsTheFitJudged) {
  auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  std::printf("[ motor    ] %s\n", p.summary().c_str());
  for (const double error : {0.0, -0.3, -0.5}) {
    p.sim.imperfections.accel_scale_error = error;
    std::vector<core::ReferenceSegment> segments;
    std::string why;
    ASSERT_TRUE(bench::record_population_calibration(p, segments, why)) << why;
    const auto cal = bench::calibrate_population_motor(p, segments, false);
    if (error == -0.5) {
      // Half the sensitivity: the turnarounds cannot be bridged, and the refusal says why.
      std::printf("[ figures  ] accelerometer sensitivity -50 %%: %s\n", cal.ok ? "calibrated" : cal.error.c_str());
      if (!cal.ok) {
        EXPECT_NE(cal.error.find("accelerometer's sensitivity"), std::string::npos) << cal.error;
      } else {
        EXPECT_FALSE(cal.good);
      }
      continue;
    }
    ASSERT_TRUE(cal.ok) << cal.error;
    std::printf("[ figures  ] accelerometer sensitivity %+.0f %%: scale %.4f, %s\n", error * 100,
                cal.cal.model.accel_scale, cal.good ? "good" : cal.problems.front().c_str());
    bool named = false;
    for (const auto& w : cal.problems) named = named || w.find("accelerometer scale") != std::string::npos;
    if (error == 0.0) {
      EXPECT_TRUE(cal.good) << (cal.problems.empty() ? std::string() : cal.problems.front());
      EXPECT_NEAR(cal.cal.model.accel_scale, 1.0, 0.05);
    } else {
      EXPECT_FALSE(cal.good);
      EXPECT_TRUE(named) << "the sensitivity 30 % low was not named";
    }
  }
}

// Without a ruler the coil's field (a Hall offset in step with the acceleration) is
// found in the fast motion, as what leaves no residual in step with the acceleration.
// A multisine's acceleration follows where the carriage is, and so do the self-made
// table's errors: taken over the whole motion, they made the coil field 1.645 instead
// of 0.846 mV/(m/s^2) on motor 33 and -2.160 instead of -1.682 on motor 34. Motor 33's
// healthy sensors were then flagged in a point-to-point move at 10 m/s^2, the last two
// slipped magnet periods, and the position ran 1.7 m away (NOT VALID, but lost). Only how
// the residual changes with the acceleration at the same place counts now.
class PopulationNoRulerCoilField : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationNoRulerCoilField, TheTablesErrorsAreNotTakenForTheCoil) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  std::printf("[ motor    ] %s\n", p.summary().c_str());
  const auto cal = calibrated_without_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  const double truth = p.sim.imperfections.coil_field_v_per_mps2;
  std::printf("[ figures  ] coil field: true %.3f, calibrated without a ruler %.3f mV/(m/s^2)\n", truth * 1e3,
              cal.cal.model.coil_field_v_per_mps2 * 1e3);
  EXPECT_TRUE(cal.good) << (cal.problems.empty() ? std::string() : cal.problems.front());
  EXPECT_NEAR(cal.cal.model.coil_field_v_per_mps2, truth, 0.1e-3);
  const auto sc = bench::population_scenarios(p.datasheet.travel_m)[4];  // point-to-point, 10 m/s^2
  ASSERT_EQ(sc.name, "point-to-point");
  double worst = 0.0;
  const auto r = bench::run_population_scenario(
      p, cal, sc, bench::Condition::as_calibrated, bench::run_noise_seed(GetParam()), {},
      [&](double t, const core::EncoderEstimate& e, const core::AxisPipeline&, const sim::SimSource& src) {
        if (t >= sc.t0_s) worst = std::max(worst, std::abs(e.position_m - (src.truth()->position_m - cal.zero_m)));
      });
  ASSERT_TRUE(r.ok) << r.error;
  std::printf("[ figures  ] point-to-point without a ruler: position rms %.2f um, largest %.2f um, sensors flagged "
              "0x%x\n",
              r.err.position_m.rms() * 1e6, worst * 1e6, r.flagged);
  // The ruler-less floor is the track's own scale (up to 13 um on this population):
  // a magnet period (12-30 mm) lost is far beyond it.
  EXPECT_LT(worst, 50e-6);
}

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationNoRulerCoilField, ::testing::Values(33u, 34u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

// Motor 73 (of the motors 41-80 nothing was tuned on): its Halls' amplitude (3.56 V
// about 2.5 V) clips them for half of every magnet period. Its slow sweep's Hall
// positions once jumped by 7 periods within a slow pass, and the refusal blamed the
// accelerometer ("its bridge over a turnaround needed its scale corrected by
// 58600 %"), though the two passes it tried to bridge went the same way at the same
// speed: no turnaround at all. It now says what happened, where, and what to check.
// The motor calibrates without a ruler since its sweep is tracked through the clipped
// stretches (SelfCalibrationPopulation.MotorsWhoseHallsMostlySaturate...), so the
// jump is made here: 0.3 s of its first slow pass are cut out of the recording and
// the time stamps after the cut moved back to close it, as a logger that lost data
// without saying so would leave it.
TEST(PopulationNoRulerRefusal, AJumpWithinASlowPassIsNotBlamedOnTheAccelerometer) {
  const auto p = sim::draw_population_motor(73, shipped_tuning());
  std::printf("[ motor    ] %s\n", p.summary().c_str());
  std::vector<core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(bench::record_population_calibration(p, segments, error)) << error;
  ASSERT_FALSE(segments.empty());
  auto& sweep = segments.front();
  const auto rate = p.datasheet.sample_rate_hz;
  const auto from = static_cast<std::size_t>(10.0 * rate), to = static_cast<std::size_t>(10.3 * rate);
  ASSERT_GT(sweep.samples.size(), to);
  // Within the first slow pass: moving forward at the sweep's speed on either side.
  const double speed = (sweep.reference_m[to + 1000] - sweep.reference_m[from - 1000]) /
                       ((static_cast<double>(to - from) + 2000.0) / rate);
  ASSERT_GT(speed, 0.0);
  const std::int64_t closed_ns = sweep.samples[to].t_ns - sweep.samples[from].t_ns;
  for (std::size_t i = to; i < sweep.samples.size(); ++i) sweep.samples[i].t_ns -= closed_ns;
  sweep.samples.erase(sweep.samples.begin() + static_cast<std::ptrdiff_t>(from),
                      sweep.samples.begin() + static_cast<std::ptrdiff_t>(to));
  sweep.reference_m.erase(sweep.reference_m.begin() + static_cast<std::ptrdiff_t>(from),
                          sweep.reference_m.begin() + static_cast<std::ptrdiff_t>(to));
  const auto cal = bench::calibrate_population_motor(p, segments, false);
  std::printf("[ figures  ] %s\n", cal.ok ? "calibrated" : cal.error.c_str());
  ASSERT_FALSE(cal.ok);
  EXPECT_NE(cal.error.find("jumped"), std::string::npos) << cal.error;
  EXPECT_NE(cal.error.find("within a slow pass"), std::string::npos) << cal.error;
  EXPECT_EQ(cal.error.find("accelerometer's sensitivity"), std::string::npos) << cal.error;
  EXPECT_TRUE(calibrated_with_a_ruler(p).good);
}

// The Hall delay from the slow sweep's two directions is good to a few tenths of a
// microsecond (motor 16: 0.14 us off, 0.14 um at 1 m/s, where sigma said 0.07 um);
// the fast motion against the reference gives it tenfold better, and the calibration
// takes it when the two agree.
class PopulationHallDelay : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationHallDelay, FastMotionGivesTheHallDelayTheSweepOnlyApproaches) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  std::vector<core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(bench::record_population_calibration(p, segments, error)) << error;
  core::Calibration cal;
  core::IdentificationReport rep;
  ASSERT_TRUE(core::identify_with_reference(p.datasheet, segments, {}, cal, rep, error)) << error;
  const double truth = p.sim.imperfections.hall_delay_s;
  std::printf("[ figures  ] Hall delay: true %.3f us, sweep %.3f us, fast motion %.3f +- %.3f us, calibration %.3f us\n",
              truth * 1e6, rep.hall_delay_s * 1e6, rep.fast_hall_delay_s * 1e6, rep.fast_hall_delay_std_s * 1e6,
              cal.model.hall_delay_s * 1e6);
  EXPECT_TRUE(rep.good);
  EXPECT_TRUE(rep.hall_delay_from_fast_motion);
  EXPECT_GT(rep.fast_hall_delay_std_s, 0.0);
  EXPECT_LT(rep.fast_hall_delay_std_s, 0.05e-6);
  EXPECT_NEAR(cal.model.hall_delay_s, truth, 4.0 * rep.fast_hall_delay_std_s);
  EXPECT_LT(std::abs(cal.model.hall_delay_s - truth), 0.5 * std::abs(rep.hall_delay_s - truth));
}

// The accelerometer's delay, from the calibration's fast motion. The frame's own
// vibration (0.035 and 0.047 m/s^2 at 59 and 46 Hz on motors 1 and 12) is not the
// carriage's motion; left in the readings it was noise to the fit and pulled the delay
// 31 and 35 us off (15.8 and 3.9 us with the vibration switched off in the simulator).
// Fitted alongside, it moves the delay by no more than a microsecond, and the delay
// lands within three of its standard errors.
core::Calibration identified(const sim::PopulationMotor& p, core::IdentificationReport& rep) {
  std::vector<core::ReferenceSegment> segments;
  std::string error;
  core::Calibration cal;
  EXPECT_TRUE(bench::record_population_calibration(p, segments, error)) << error;
  EXPECT_TRUE(core::identify_with_reference(p.datasheet, segments, {}, cal, rep, error)) << error;
  return cal;
}

class PopulationAccelDelay : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationAccelDelay, TheFramesVibrationDoesNotMoveTheDelay) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  ASSERT_GT(p.sim.imperfections.frame_vibration_mps2, 0.03);
  core::IdentificationReport rep, rep_still;
  const auto cal = identified(p, rep);
  auto still = p;
  still.sim.imperfections.frame_vibration_mps2 = 0.0;
  const auto cal_still = identified(still, rep_still);
  const double truth = p.sim.imperfections.accel_delay_s;
  std::printf("[ figures  ] accelerometer delay: true %.1f us, identified %.1f +- %.1f us (vibration %.3f m/s^2 at "
              "%.1f Hz found), %.1f us with the frame still\n",
              truth * 1e6, cal.model.accel_delay_s * 1e6, cal.model.accel_delay_std_s * 1e6, rep.vibration_mps2,
              rep.vibration_hz, cal_still.model.accel_delay_s * 1e6);
  EXPECT_TRUE(rep.good);
  EXPECT_GT(rep.vibration_hz, 0.0) << "the vibration was not found";
  EXPECT_NEAR(cal.model.accel_delay_s, cal_still.model.accel_delay_s, 1e-6);
  EXPECT_GT(cal.model.accel_delay_std_s, 0.0);
  EXPECT_LT(cal.model.accel_delay_std_s, 20e-6);
  EXPECT_NEAR(cal.model.accel_delay_s, truth, 3.0 * cal.model.accel_delay_std_s);
}

// The slow sweep turns with steps of acceleration, which an accelerometer sampled
// without a filter places only to within a sample period; they carry no timing the
// fit can trust. With an ideal accelerometer (no noise, no frame motion) they pulled
// the delay 9.8 and 12.2 us off on motors 5 and 7 (2.8 and 3.1 kHz); the fast motion
// alone times it to a few microseconds.
class PopulationAccelDelayIdeal : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationAccelDelayIdeal, TheSweepsTurnsDoNotTimeTheAccelerometer) {
  auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  auto& im = p.sim.imperfections;
  im.frame_vibration_mps2 = 0.0;
  im.frame_reaction_ratio = 0.0;
  im.accel_bias_random_walk_mps2_per_sqrt_s = 0.0;
  p.hardware.accelerometer.noise_mps2 = 1e-6;
  core::IdentificationReport rep;
  const auto cal = identified(p, rep);
  std::printf("[ figures  ] ideal accelerometer at %.0f Hz: delay true %.1f us, identified %.1f us\n",
              p.hardware.sample_rate_hz, im.accel_delay_s * 1e6, cal.model.accel_delay_s * 1e6);
  EXPECT_NEAR(cal.model.accel_delay_s, im.accel_delay_s, 4e-6);
}

/// The motor's point-to-point run, as calibrated, with the calibration `c` after
/// `set` changed it: its error statistics.
template <class Set>
core::EstimateErrors point_to_point_errors(const sim::PopulationMotor& p, const bench::CalibrationOutcome& c,
                                       std::uint64_t noise_seed, Set set) {
  const auto sc = bench::population_scenarios(p.datasheet.travel_m)[4];
  EXPECT_EQ(sc.name, std::string("point-to-point"));
  auto cc = c;
  set(cc.cal.model);
  return bench::run_population_scenario(p, cc, sc, bench::Condition::as_calibrated, noise_seed).err;
}

// The filter holds what a delay error does: every change of acceleration read at the
// wrong instant leaves an error in the velocity and the position (a consider
// parameter, FusionFilter). Motor 11 in point-to-point moves, its calibrated delay
// moved 20 us and its standard error set to say so: the velocity's 2-sigma coverage
// holds with the sensitivity, and falls without it.
TEST(PopulationAccelDelaySigma, TheSigmaHoldsADelayErrorTheCalibrationAdmits) {
  const auto p = sim::draw_population_motor(11u, shipped_tuning());
  auto c = calibrated_with_a_ruler(p);
  ASSERT_TRUE(c.ok && c.good) << c.error;
  c.cal.model.accel_delay_s += 20e-6;
  auto coverage = [&](double std_s) {
    return point_to_point_errors(p, c, 1011, [&](core::SensorModel& m) { m.accel_delay_std_s = std_s; })
        .velocity_coverage();
  };
  const double with = coverage(20e-6), without = coverage(0.0);
  std::printf("[ figures  ] delay 20 us off: velocity within 2 sigma %.1f %% with its sigma held, %.1f %% without\n",
              100.0 * with, 100.0 * without);
  EXPECT_GE(with, 0.90);
  EXPECT_LT(without, with - 0.05);
}

// The coil field, known to the calibration's standard error: its error is an offset on
// every reading in proportion to the force, which moves each fix by the fix's
// sensitivity to a common offset (AxisPipeline). Motor 51 in point-to-point moves (a
// coil field of 2.4 mV per m/s^2), its calibrated coil field moved 1.5 % and its
// standard error set to say so: the position's 2-sigma coverage holds with it, and
// falls without it.
TEST(PopulationCoilFieldSigma, TheSigmaHoldsACoilFieldErrorTheCalibrationAdmits) {
  const auto p = sim::draw_population_motor(51u, shipped_tuning());
  auto c = calibrated_with_a_ruler(p);
  ASSERT_TRUE(c.ok && c.good) << c.error;
  EXPECT_GT(c.cal.model.coil_field_std_v_per_mps2, 0.0) << "the calibration gave the coil field no standard error";
  const double off = 0.015 * std::abs(c.cal.model.coil_field_v_per_mps2);
  c.cal.model.coil_field_v_per_mps2 += off;
  auto coverage = [&](double std_v) {
    return point_to_point_errors(p, c, 1051, [&](core::SensorModel& m) { m.coil_field_std_v_per_mps2 = std_v; })
        .position_coverage();
  };
  const double with = coverage(off), without = coverage(0.0);
  std::printf("[ figures  ] coil field %.1f uV/(m/s^2) off: position within 2 sigma %.1f %% with its sigma held, "
              "%.1f %% without\n",
              off * 1e6, 100.0 * with, 100.0 * without);
  EXPECT_GE(with, 0.90);
  EXPECT_LT(without, with - 0.05);
}

// At standstill the error is what the table, the ADC's steps and the sensors make of
// that one place. Each table node is a fit to the few sweep readings near it and keeps
// their noise; where the carriage stands, that noise repeats and no averaging of fixes
// removes it. Motors 9 (12-bit) and 19 (16-bit) had 10 of 40 places outside 2 sigma
// before sigma held it (SensorModel::table_noise_v, measured by the calibration).
class PopulationStandstillPlaces : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationStandstillPlaces, SigmaHoldsTheTablesOwnNoiseWhereverTheCarriageStands) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  std::printf("[ motor    ] %s\n", p.summary().c_str());
  const auto cal = calibrated_with_a_ruler(p);
  ASSERT_TRUE(cal.ok && cal.good) << cal.error;
  EXPECT_GT(cal.cal.model.table_noise_v, 0.0) << "the calibration measured no table noise";
  constexpr int kPlaces = 40;
  double z2 = 0.0;
  int outside = 0;
  for (int k = 0; k < kPlaces; ++k) {
    auto sc = bench::population_scenarios(p.datasheet.travel_m)[0];
    // One magnet period's worth of places, not on the table's grid.
    sc.profile.start_m = 0.3 * p.datasheet.travel_m + p.datasheet.magnet_pitch_m * (k + 0.37) / kPlaces;
    sc.t0_s = 0.2;
    sc.t1_s = 0.3;
    double err = 0.0, var = 0.0;
    int n = 0;
    // This motor's noise seed, moved by the place: each place its own draw of the noise.
    const auto r = bench::run_population_scenario(
        p, cal, sc, bench::Condition::as_calibrated, bench::run_noise_seed(GetParam()) + static_cast<std::uint64_t>(k),
        {}, [&](double t, const core::EncoderEstimate& e, const core::AxisPipeline&, const sim::SimSource& src) {
          if (t < sc.t0_s || t > sc.t1_s) return;
          err += e.position_m - (src.truth()->position_m - cal.zero_m);
          var += e.position_std_m * e.position_std_m;
          ++n;
        });
    ASSERT_TRUE(r.ok) << r.error;
    ASSERT_GT(n, 100);
    // The mean error over the window against the mean sigma: the noise averages, what
    // belongs to the place stays.
    const double z = (err / n) / std::sqrt(var / n);
    z2 += z * z;
    if (std::abs(z) > 2.0) ++outside;
  }
  const double rms_z = std::sqrt(z2 / kPlaces);
  std::printf("[ figures  ] table noise %.3f mV; standstill at %d places: error / sigma %.2f RMS, %d outside 2 sigma\n",
              cal.cal.model.table_noise_v * 1e3, kPlaces, rms_z, outside);
  EXPECT_LE(outside, kPlaces / 8);  // about 1 in 20 for an honest sigma
  EXPECT_GE(rms_z, 0.4);
  EXPECT_LE(rms_z, 1.5);
}

// Without a ruler, within about a magnet period of the sweep's ends the carriage
// was turning, and the table there rests on the accelerometer's bridges between the
// slow passes: good to tens of um. Motor 3 at standstill a quarter and half a
// period from the near end was 13-14 um off and VALID at sigma 1 um; the
// calibration now says where its passes made the table, sigma beyond includes what
// the bridges disagree by, and VALID is withheld there. Two periods in it is VALID.
class PopulationNoRulerEnds : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationNoRulerEnds, BeyondTheSlowPassesSigmaSaysSoAndValidIsWithheld) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  std::printf("[ motor    ] %s\n", p.summary().c_str());
  const auto cal = calibrated_without_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  EXPECT_TRUE(cal.good) << (cal.problems.empty() ? std::string() : cal.problems.front());
  const auto& m = cal.cal.model;
  ASSERT_TRUE(m.trusted_span_known());
  std::printf("[ figures  ] slow passes made the table from %.2f to %.2f mm (from home); beyond it %.1f um\n",
              m.table_trusted_from_m * 1e3, m.table_trusted_to_m * 1e3, m.table_outside_std_m * 1e6);
  EXPECT_GT(m.table_outside_std_m, 2e-6);
  const double pitch = p.datasheet.magnet_pitch_m;
  for (const double at : {0.25 * pitch, 0.5 * pitch, 2.0 * pitch}) {
    bench::PopScenario sc;
    sc.name = "standstill";
    sc.profile.kind = sim::MotionProfileConfig::Kind::standstill;
    sc.profile.min_m = 0.0;
    sc.profile.max_m = p.datasheet.travel_m;
    sc.profile.start_m = at;
    sc.t0_s = 0.5;
    sc.t1_s = 1.5;
    const auto r = bench::run_population_scenario(p, cal, sc, bench::Condition::as_calibrated, 77);
    ASSERT_TRUE(r.ok) << r.error;
    const bool beyond = at - cal.zero_m < m.table_trusted_from_m;
    std::printf("[ figures  ] standstill %.2f mm from the end (%s the passes): error %.2f um RMS, 2-sigma %.1f %%, "
                "VALID %.1f %%\n", at * 1e3, beyond ? "beyond" : "within", r.err.position_m.rms() * 1e6,
                100 * r.err.position_coverage(), 100 * r.valid_fraction());
    if (at < pitch) {
      EXPECT_TRUE(beyond) << at * 1e3 << " mm";
      EXPECT_EQ(r.valid, 0u) << at * 1e3 << " mm";
      EXPECT_GE(r.err.position_coverage(), 0.9) << at * 1e3 << " mm";
    } else {
      EXPECT_FALSE(beyond);
      EXPECT_GE(r.valid_fraction(), 0.99);
      EXPECT_LT(r.max_valid_error_m, 5e-6);
    }
  }
}

// The frame's vibration, felt by the moving accelerometer and not by the Halls, is
// found by calibration wherever its frequency falls: these four motors' lines fell
// between the points of a scan in steps of twice the spectrum's resolution, were
// missed, and the filter took the vibration for motion (velocity errors of
// 0.08-0.16 mm/s RMS at standstill, velocity 2-sigma coverage 30-60 %).
class PopulationVibration : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationVibration, CalibrationFindsTheFramesVibrationWhereverItsLineFalls) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  const auto cal = calibrated_with_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  const auto& im = p.sim.imperfections;
  std::printf("[ figures  ] vibration %.4f m/s^2 at %.3f Hz, found %.4f m/s^2 at %.3f Hz\n", im.frame_vibration_mps2,
              im.frame_vibration_hz, cal.cal.model.frame_vibration_mps2, cal.cal.model.frame_vibration_hz);
  EXPECT_NEAR(cal.cal.model.frame_vibration_hz, im.frame_vibration_hz, 0.02);
  EXPECT_NEAR(cal.cal.model.frame_vibration_mps2, im.frame_vibration_mps2, 0.1 * im.frame_vibration_mps2);
}

// A motor 10 K warmer or colder than at calibration, standing still from the first
// sample, with no temperature from the sensor node: each sensor's offset and gain
// have moved by a few mV and tenths of a percent, which at standstill no redundancy
// can tell from a position (1-10 um on these motors). The common gain every fix sees
// (mostly the magnets' remanence) shows the change of temperature; sigma must then
// cover the error, and VALID must not be claimed beyond its accuracy. Before the
// common gain was read as a thermometer, these motors were VALID with 8.5-10 um
// errors under a 2-sigma of 2-4 um.
/// A motor of the population without a temperature from its node, calibrated with a
/// ruler, and its standstill scenario.
class StandstillWithARuler : public ::testing::TestWithParam<std::uint64_t> {
 protected:
  void SetUp() override {
    p = sim::draw_population_motor(GetParam(), shipped_tuning());
    ASSERT_FALSE(p.sim.temperature.report);
    cal = calibrated_with_a_ruler(p);
    ASSERT_TRUE(cal.ok) << cal.error;
    standstill = bench::population_scenarios(p.datasheet.travel_m).at(0);
    ASSERT_EQ(standstill.name, "standstill");
  }
  sim::PopulationMotor p;
  bench::CalibrationOutcome cal;
  bench::PopScenario standstill;
};

class PopulationWarmStandstill : public StandstillWithARuler {};

TEST_P(PopulationWarmStandstill, SigmaCoversTheDriftNoRedundancyCanSeeAndValidKeepsItsPromise) {
  for (const auto cond : {bench::Condition::ramp_plus_10k, bench::Condition::step_minus_10k}) {
    const auto r = bench::run_population_scenario(p, cal, standstill, cond, bench::run_noise_seed(GetParam()));
    ASSERT_TRUE(r.ok) << r.error;
    std::printf("[ figures  ] %-11s position rms %.3f um | 2-sigma %.1f %% | VALID %.2f %% | largest error while "
                "VALID %.3f um\n",
                bench::condition_name(cond), r.err.position_m.rms() * 1e6, 100 * r.err.position_coverage(),
                100 * r.valid_fraction(), r.max_valid_error_m * 1e6);
    EXPECT_GE(r.err.position_coverage(), 0.9) << bench::condition_name(cond);
    EXPECT_LE(r.max_valid_error_m, bench::kValidPositionAccuracyM) << bench::condition_name(cond);
    EXPECT_EQ(r.flagged, 0u) << bench::condition_name(cond) << ": no healthy sensor flagged";
  }
}

// Where only one sensor is out of saturation (3-Hall motors 52 and 92 at their
// standstill place), a fix has no second reading to tell the common gain from the
// position: it returns the gain it was given. Before anything is learnt that is the
// calibration's, and read as the thermometer it said "no change of temperature":
// 10 K warm or cold, motor 52 was VALID 9-10 um off under a 2-sigma of 3 um (12.6 um
// at most), motor 92 7-8 um off. Such fixes are no reading; standing there, sigma
// holds what a change of filter.hall_unread_temperature_rise_k (10 K) does to the fix,
// and VALID follows sigma: here, with the single sensor's reading far from its mid
// level, that is beyond the accuracy, as calibrated too.
class PopulationStandstillOneSensor : public StandstillWithARuler {};

TEST_P(PopulationStandstillOneSensor, NoFixReadsTheTemperatureAndValidIsNotClaimed) {
  for (const auto cond :
       {bench::Condition::as_calibrated, bench::Condition::ramp_plus_10k, bench::Condition::step_minus_10k}) {
    int used = -1;
    bool checked = false;
    const auto r = bench::run_population_scenario(
        p, cal, standstill, cond, bench::run_noise_seed(GetParam()), {},
        [&](double, const core::EncoderEstimate& e, const core::AxisPipeline& pipeline, const sim::SimSource&) {
          used = e.hall_sensors_used;
          checked = checked || pipeline.adaptation().temperature_checked();
        });
    ASSERT_TRUE(r.ok) << r.error;
    std::printf("[ figures  ] %-13s position rms %.3f um | 2-sigma %.1f %% | sensors used %d | VALID %.2f %%\n",
                bench::condition_name(cond), r.err.position_m.rms() * 1e6, 100 * r.err.position_coverage(), used,
                100 * r.valid_fraction());
    ASSERT_EQ(used, 1) << "the premise: one sensor out of saturation at this place";
    EXPECT_FALSE(checked) << bench::condition_name(cond) << ": a fix with one sensor read the temperature";
    EXPECT_EQ(r.valid, 0u) << bench::condition_name(cond) << ": VALID claimed, largest error "
                           << r.max_valid_error_m * 1e6 << " um";
    EXPECT_GE(r.err.position_coverage(), 0.9) << bench::condition_name(cond) << ": sigma holds the drift";
  }
}

// The same warm or cold motor in motion, with a ruler and no temperature from the
// node. Each sensor's gain and offset moved by a few tenths of a percent and a few
// mV; learnt sensor by sensor, each against the others' drift not learnt yet, these
// motors stayed at 3.5-5.3 um and 0.8-1.4 mm/s at 1 m/s for seconds. Learnt jointly
// (the motor found a kelvin or more from its calibration), the same runs settle
// within tenths of a second: the RMS over the window stays within 3.5 um and
// 0.7 mm/s, and the moves that sweep the magnet period (multisine, point-to-point)
// within the 1 um and 0.2 mm/s for a motor 10 K off.
class PopulationWarmMotion : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationWarmMotion, SensorsDriftedByTemperatureAreLearntTogetherInTenthsOfASecond) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  ASSERT_FALSE(p.sim.temperature.report);
  const auto cal = calibrated_with_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  const auto scenarios = bench::population_scenarios(p.datasheet.travel_m);
  for (const auto cond : {bench::Condition::ramp_plus_10k, bench::Condition::step_minus_10k}) {
    for (std::size_t k = 1; k < scenarios.size(); ++k) {
      const auto& sc = scenarios[k];
      const auto r = bench::run_population_scenario(p, cal, sc, cond, bench::run_noise_seed(GetParam()));
      ASSERT_TRUE(r.ok) << r.error;
      std::printf("[ figures  ] %-11s %-15s position rms %.3f um | velocity rms %.4f mm/s | 2-sigma %.1f %% / %.1f %% | "
                  "VALID %.2f %%\n",
                  bench::condition_name(cond), sc.name.c_str(), r.err.position_m.rms() * 1e6,
                  r.err.velocity_mps.rms() * 1e3, 100 * r.err.position_coverage(), 100 * r.err.velocity_coverage(),
                  100 * r.valid_fraction());
      const bool sweeps = sc.name == "multisine" || sc.name == "point-to-point";
      // Started warm at 1 m/s, learning begins once the filter has followed the fixes
      // for 10 ms: on motor 8 2.0-2.1 um and 0.47-0.53 mm/s while it waited 50 ms. Then
      // 0.97-1.04 um and 0.31-0.32 mm/s while the frame vibration's resonator (38.3 Hz)
      // kept ringing with the drift it had taken up at 41.8 Hz, the magnet period's
      // rate: now 0.53-0.59 um and 0.15-0.20 mm/s. The 1 um holds; its 0.2 mm/s
      // holds with no margin on motor 8 (0.199), so 0.25 is asserted.
      const bool at_speed = sc.name == "1 m/s";
      EXPECT_LE(r.err.position_m.rms(), sweeps || at_speed ? 1e-6 : 3.5e-6)
          << bench::condition_name(cond) << " " << sc.name;
      EXPECT_LE(r.err.velocity_mps.rms(), sweeps ? 0.2e-3 : at_speed ? 0.25e-3 : 0.7e-3)
          << bench::condition_name(cond) << " " << sc.name;
      EXPECT_EQ(r.flagged, 0u) << bench::condition_name(cond) << " " << sc.name << ": no healthy sensor flagged";
    }
  }
}

// Warming at 10 K per minute while it moves: every sensor's gain and offset keep
// moving by its own coefficient, one number per sensor that the data sheet gives only
// as a spread. Learnt as a random walk widened by that spread at every quarter kelvin,
// a sensor whose coefficient is a 2.6-sigma draw (motor 72, 0.79 mV/K) stayed 0.3 mV
// behind all along, three times what the learning allowed for: the multi-sine's
// position within 2 sigma 74.5 % (motor 76: 80 %). Estimated from what each sensor has
// drifted by at the rise so far (HallAdaptation::Coefficient), the coefficient moves the
// sensor at every step: 93.5 and 97.5 %. Both motors are of the held-out set 61-80.
class PopulationWarmingRamp : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationWarmingRamp, EachSensorsOwnCoefficientIsFollowedAsTheMotorWarms) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  ASSERT_FALSE(p.sim.temperature.report);
  const auto cal = calibrated_with_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  const auto sc = bench::population_scenarios(p.datasheet.travel_m)[3];  // multisine
  ASSERT_EQ(sc.name, "multisine");
  const auto r =
      bench::run_population_scenario(p, cal, sc, bench::Condition::ramp_plus_10k, bench::run_noise_seed(GetParam()));
  ASSERT_TRUE(r.ok) << r.error;
  std::printf("[ figures  ] +10 K ramp, multisine: position rms %.3f um | 2-sigma %.1f %% / %.1f %% | VALID %.2f %%\n",
              r.err.position_m.rms() * 1e6, 100 * r.err.position_coverage(), 100 * r.err.velocity_coverage(),
              100 * r.valid_fraction());
  EXPECT_GE(r.err.position_coverage(), 0.90);
  EXPECT_GE(r.err.velocity_coverage(), 0.90);
  EXPECT_EQ(r.flagged, 0u) << "no healthy sensor flagged";
}

/// One run of a held-out motor without a ruler: its errors, VALID and the largest error while VALID.
void print_no_ruler_figures(bench::Condition cond, const bench::RunResult& r) {
  std::printf("[ figures  ] %-13s position rms %.3f um | velocity rms %.4f mm/s | VALID %.2f %% | largest error "
              "while VALID %.2f um\n",
              bench::condition_name(cond), r.err.position_m.rms() * 1e6, r.err.velocity_mps.rms() * 1e3,
              100 * r.valid_fraction(), r.max_valid_error_m * 1e6);
}

// Without a ruler the table is made from the slow passes, and what it leaves in a fix
// from place to place (magnets placed slightly wrong) is only known from the fast
// motion: on motor 67 of the held-out set (magnets placed to 46 um) the fixes stayed
// 4.0 um beyond their sensors' 0.6 um of noise there. Trusted to 0.6 um they made the
// point-to-point velocity 0.40 mm/s RMS, and 10 K cold the filter took them for steps of
// acceleration until it lost the track, 0.86 m off. The calibration writes that excess
// and the filter takes it as part of every fix's noise.
TEST(PopulationNoRulerFixNoiseHeldOut, TheTablesErrorFromPlaceToPlaceIsFixNoiseOnMotor67) {
  const auto p = sim::draw_population_motor(67, shipped_tuning());
  const auto cal = calibrated_without_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  std::printf("[ figures  ] fix excess written %.2f um\n", cal.cal.model.hall_fix_excess_std_m * 1e6);
  EXPECT_GT(cal.cal.model.hall_fix_excess_std_m, 2e-6);
  const auto sc = bench::population_scenarios(p.datasheet.travel_m)[4];  // point-to-point
  ASSERT_EQ(sc.name, "point-to-point");
  for (const auto cond : {bench::Condition::as_calibrated, bench::Condition::step_minus_10k}) {
    const auto r = bench::run_population_scenario(p, cal, sc, cond, 1067);
    ASSERT_TRUE(r.ok) << r.error;
    print_no_ruler_figures(cond, r);
    // The track's own scale (up to 25 um on this motor far from home) is in the position.
    EXPECT_LE(r.err.position_m.rms(), 50e-6) << bench::condition_name(cond) << ": the track is kept";
    // Where a sensor comes out of saturation at 1.4 m/s its reading is 5-9 mV off this
    // table: learnt as drift (a gain of -1.35 %, offsets of 8-14 mV) it made sensor 6 the
    // odd one out everywhere else, until the adaptation learnt against the table's
    // measured error too (HallAdaptation::add_model_variance).
    EXPECT_EQ(r.flagged, 0u) << bench::condition_name(cond) << ": no healthy sensor flagged";
    if (cond == bench::Condition::as_calibrated) {
      EXPECT_LE(r.err.velocity_mps.rms(), 0.3e-3) << "the issue's 0.3 mm/s without a ruler";
    }
    EXPECT_LE(r.max_valid_error_m, bench::kValidPositionAccuracyM) << bench::condition_name(cond);
  }
}

/// A held-out motor calibrated without a ruler and run through the multi-sine as
/// calibrated, on the +10 K ramp and 10 K cold (noise seed: bench::run_noise_seed of its seed).
struct NoRulerMultisine {
  sim::PopulationMotor motor;
  bench::CalibrationOutcome cal;
  bench::PopScenario scenario;
  std::vector<std::pair<bench::Condition, bench::RunResult>> runs;
};

NoRulerMultisine no_ruler_multisine(std::uint64_t seed) {
  NoRulerMultisine m{sim::draw_population_motor(seed, shipped_tuning()), {}, {}, {}};
  m.cal = calibrated_without_a_ruler(m.motor);
  m.scenario = bench::population_scenarios(m.motor.datasheet.travel_m)[3];  // multi-sine
  EXPECT_EQ(m.scenario.name, "multisine");
  if (!m.cal.ok) return m;
  for (const auto cond :
       {bench::Condition::as_calibrated, bench::Condition::ramp_plus_10k, bench::Condition::step_minus_10k})
    m.runs.emplace_back(cond,
                        bench::run_population_scenario(m.motor, m.cal, m.scenario, cond, bench::run_noise_seed(seed)));
  return m;
}

// The same motor in the multi-sine. Its table made without a ruler has places where its
// sensors' curves are 2-4 mV apart (at 0.112-0.116 m: sensor 0 +4 mV, sensors 2-4 -2 to
// -4 mV against the ruler's table), which the fixes' 0.6 mV of noise called an outlier:
// healthy sensors were flagged one after the other (up to five of the eight), and the
// velocity at -10 K point-to-point was 2.1 mm/s RMS. The calibration's excess is the
// table's error as each reading carries it, and judging the sensors allows for it (the
// odd sensor is still left out of the fix there). A dead sensor is as far off as ever:
// flagged as fast.
TEST(PopulationNoRulerFixNoiseHeldOut, HealthySensorsAreNotBlamedForTheTablesErrorOnMotor67) {
  const auto m = no_ruler_multisine(67);
  ASSERT_TRUE(m.cal.ok) << m.cal.error;
  for (const auto& [cond, r] : m.runs) {
    ASSERT_TRUE(r.ok) << r.error;
    print_no_ruler_figures(cond, r);
    EXPECT_EQ(r.flagged, 0u) << bench::condition_name(cond) << ": no healthy sensor flagged";
    EXPECT_LE(r.err.velocity_mps.rms(), 0.3e-3) << bench::condition_name(cond);
    EXPECT_LE(r.max_valid_error_m, bench::kValidPositionAccuracyM) << bench::condition_name(cond);
  }
  const auto& p = m.motor;
  const auto& cal = m.cal;
  const auto& sc = m.scenario;
  for (int sensor : {0, 5}) {
    bench::FaultProbe probe;
    probe.inject = true;
    probe.sensor = sensor;
    probe.at_s = 5.0;
    const auto r = bench::run_population_scenario(p, cal, sc, bench::Condition::ramp_plus_10k, 2067, probe);
    ASSERT_TRUE(r.ok) << r.error;
    std::printf("[ figures  ] dead sensor %d flagged after %.1f ms\n", sensor, r.detect_s * 1e3);
    EXPECT_FALSE(r.probe_flagged_before) << "sensor " << sensor;
    EXPECT_GE(r.detect_s, 0.0) << "dead sensor " << sensor << " was never flagged";
    EXPECT_LT(r.detect_s, 0.05) << "sensor " << sensor;
  }
  // What the allowance costs: a sensor that is only noisy must be noisier than it
  // (4.5 mV here) to be flagged. 5 and 10 mV of extra noise are printed (flagged in
  // 3-4 ms before the allowance, not at all with it); from 20 mV on it is flagged
  // within the 50 ms a fault must be.
  for (const double noise_mv : {5.0, 10.0, 20.0, 50.0}) {
    bench::FaultProbe probe;
    probe.inject = true;
    probe.sensor = 3;
    probe.at_s = 5.0;
    probe.kind = sim::FaultConfig::Kind::hall_noisy;
    probe.magnitude = noise_mv * 1e-3;
    const auto r = bench::run_population_scenario(p, cal, sc, bench::Condition::as_calibrated, 3000, probe);
    ASSERT_TRUE(r.ok) << r.error;
    if (r.detect_s >= 0.0)
      std::printf("[ figures  ] sensor 3 with %.0f mV of extra noise: flagged after %.1f ms\n", noise_mv,
                  r.detect_s * 1e3);
    else
      std::printf("[ figures  ] sensor 3 with %.0f mV of extra noise: never flagged\n", noise_mv);
    EXPECT_FALSE(r.probe_flagged_before) << noise_mv << " mV";
    if (noise_mv >= 20.0) {
      EXPECT_GE(r.detect_s, 0.0) << noise_mv << " mV of noise was never flagged";
      EXPECT_LT(r.detect_s, 0.05) << noise_mv << " mV";
    }
  }
}

// Motor 54 of the held-out set has three Halls 7 mm apart on a 28.5 mm period: the
// outer two are half a period apart and see one phase of the pattern, the middle one
// the other, and most of the time only one of them is out of saturation. Its table made
// without a ruler is 10-20 mV off over 2 mm where all three cross into saturation, and
// in the multi-sine the middle sensor is blamed there and flagged. The outer two then
// make no fix wherever they read a rail; the axis re-acquired after 40 such samples,
// and the search, seeing one phase only, took the mirror image of the place within the
// period: 41 um RMS as calibrated (4.3 mm/s), 9.3 mm at +10 K, 2.8 mm at -10 K. Rails
// where the table has them say nothing against the prediction: the filter bridges them
// on the accelerometer instead (VALID goes, a search does not start).
TEST(PopulationNoRulerThreeHallsHeldOut, RailsWithoutAConflictAreBridgedNotSearchedOnMotor54) {
  const auto m = no_ruler_multisine(54);
  ASSERT_EQ(m.motor.datasheet.hall.count, 3);
  ASSERT_TRUE(m.cal.ok) << m.cal.error;
  for (const auto& [cond, r] : m.runs) {
    ASSERT_TRUE(r.ok) << r.error;
    print_no_ruler_figures(cond, r);
    EXPECT_LE(r.err.position_m.rms(), 10e-6) << bench::condition_name(cond) << ": the track is kept";
    EXPECT_LE(r.err.velocity_mps.rms(), 0.3e-3) << bench::condition_name(cond);
    EXPECT_LE(r.max_valid_error_m, bench::kValidPositionAccuracyM) << bench::condition_name(cond);
    // Nor is its middle sensor blamed for the table's error there (HealthySensors* above).
    EXPECT_EQ(r.flagged, 0u) << bench::condition_name(cond) << ": no healthy sensor flagged";
  }
}

// The same warm motor started from rest at 5 m/s^2, where the sensors are learnt from
// the first magnet periods at low speed. The common gain is the fixes' to learn; taken
// as exact by the joint update of the sensors' own gains and offsets, a pattern of
// offsets that a shift and a common gain explain at every place was learnt twice over
// (the fixes moved the common gain to absorb it, the sensors' covariance shrank as if
// they had learnt it): on motor 8 the offsets stayed 3-5 sigma off for tenths of a
// second, the position 2.3-2.6 um RMS with 81-89 % of it within 2 sigma, and 7.5 um
// off while VALID. Considered in the joint update (its variance and its covariance
// with the sensors), 1.2 um with every sample within 2 sigma.
/// A motor calibrated with a ruler and the scenario it is started in, from rest at
/// 5 m/s^2, for the warm starts below (each run at +10 K and at -10 K).
struct WarmStartFromRest {
  sim::PopulationMotor motor;
  bench::CalibrationOutcome cal;
  bench::PopScenario scenario;
};

WarmStartFromRest warm_start_from_rest(std::uint64_t seed) {
  auto p = sim::draw_population_motor(seed, shipped_tuning());
  auto cal = calibrated_with_a_ruler(p);
  const auto sc = bench::population_scenarios(p.datasheet.travel_m)[2];  // 5 m/s^2, from rest
  return {std::move(p), std::move(cal), sc};
}

constexpr bench::Condition kWarmConditions[] = {bench::Condition::ramp_plus_10k, bench::Condition::step_minus_10k};

void print_warm_start_figures(bench::Condition cond, const bench::PopScenario& sc, const bench::RunResult& r) {
  std::printf("[ figures  ] %-11s %-15s position rms %.3f um | 2-sigma %.1f %% | VALID %.2f %% | largest error "
              "while VALID %.2f um\n",
              bench::condition_name(cond), sc.name.c_str(), r.err.position_m.rms() * 1e6,
              100 * r.err.position_coverage(), 100 * r.valid_fraction(), r.max_valid_error_m * 1e6);
}

class PopulationWarmStartFromRest : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationWarmStartFromRest, SigmaHoldsWhatTheSensorsHaveNotLearntYet) {
  const auto [p, cal, sc] = warm_start_from_rest(GetParam());
  ASSERT_FALSE(p.sim.temperature.report);
  ASSERT_TRUE(cal.ok) << cal.error;
  for (const auto cond : kWarmConditions) {
    const auto r = bench::run_population_scenario(p, cal, sc, cond, bench::run_noise_seed(GetParam()));
    ASSERT_TRUE(r.ok) << r.error;
    print_warm_start_figures(cond, sc, r);
    EXPECT_GE(r.err.position_coverage(), 0.9) << bench::condition_name(cond);
    EXPECT_LE(r.max_valid_error_m, bench::kValidPositionAccuracyM) << bench::condition_name(cond);
    EXPECT_LE(r.err.position_m.rms(), 1.5e-6) << bench::condition_name(cond);
    EXPECT_EQ(r.flagged, 0u) << bench::condition_name(cond) << ": no healthy sensor flagged";
  }
}

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationWarmStartFromRest, ::testing::Values(8u, 20u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

// A motor of the held-out population (seeds 61-80, nothing tuned on them): motor 80,
// a 40 mm pitch, 4 Halls 9.5 mm apart, three of whose offsets drift by 0.37-0.49 mV/K
// (1.2-1.6 times the data sheet's spread, all of one sign). Started from rest 10 K
// warm or cold, the fixes' thermometer reads the rise in steps over tens of ms (-2.5,
// -5.7, -7.9 ... -10.7 K); the published sigma had widened by the sum of the steps'
// squares, a third of the rise's, and held the offsets to 1.1 mV where they had moved
// by 3.7-4.9 mV: VALID 9.4 and 12.6 um off under a sigma of 2.3 um. Its position
// error is large here (4.9-6.3 um RMS, the drift is learnt over the first periods);
// what is asserted is that VALID is not set while it is.
TEST(PopulationWarmStartFromRestHeldOut, ValidOnlyWithinTheAccuracyOnMotor80) {
  const auto [p, cal, sc] = warm_start_from_rest(80);
  ASSERT_TRUE(cal.ok) << cal.error;
  for (const auto cond : kWarmConditions) {
    const auto r = bench::run_population_scenario(p, cal, sc, cond, 1080);
    ASSERT_TRUE(r.ok) << r.error;
    print_warm_start_figures(cond, sc, r);
    EXPECT_LE(r.max_valid_error_m, bench::kValidPositionAccuracyM) << bench::condition_name(cond);
    EXPECT_GT(r.valid_fraction(), 0.2) << bench::condition_name(cond) << ": VALID once the drift is learnt";
    EXPECT_EQ(r.flagged, 0u) << bench::condition_name(cond) << ": no healthy sensor flagged";
  }
}

// Motor 69 of the same held-out set (32.4 mm pitch, 4 Halls 5.4 mm apart) standing 10 K
// warmer than at calibration, no temperature from its node: where it stands two of its
// sensors are out of saturation, and a drifted offset reads there as a change of the
// gain all sensors share, the fixes' thermometer. It read a fraction of the rise and
// claimed to know it to a couple of kelvin; the published sigma held the sensors' drift
// for that fraction, and the position was 9 um off under it (2-sigma coverage 4 %). The
// reading is now known only as far as the offsets' spreads let it be, and what is not
// read of the rise stays as wide as the unread band allows.
TEST(PopulationWarmStandstillHeldOut, SigmaHoldsTheRiseItsThermometerCannotReadOnMotor69) {
  const auto p = sim::draw_population_motor(69, shipped_tuning());
  ASSERT_FALSE(p.sim.temperature.report);
  const auto cal = calibrated_with_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  const auto sc = bench::population_scenarios(p.datasheet.travel_m)[0];
  const auto cond = bench::Condition::ramp_plus_10k;
  const auto r = bench::run_population_scenario(p, cal, sc, cond, 1069);
  ASSERT_TRUE(r.ok) << r.error;
  print_warm_start_figures(cond, sc, r);
  EXPECT_GT(r.err.position_m.rms(), bench::kValidPositionAccuracyM) << "the case this guards: the drift is not learnt at rest";
  EXPECT_GE(r.err.position_coverage(), 0.9);
  EXPECT_LE(r.max_valid_error_m, bench::kValidPositionAccuracyM);
}

// Motor 52 of the same held-out set (3 Halls 21 mm apart on a 16.2 mm pitch) started
// from rest 10 K cold: where the carriage passes from two sensors out of saturation to
// one read near its mid level, that fix's drift is small, and the published sigma had
// dropped with it in one sample (4.2 -> 1.1 um) while the position still held the 7 um
// the earlier fixes had left: VALID 8.1 um off. Sigma now keeps what earlier fixes left
// until the filter has averaged it out. Asserted over the benchmark's window: sigma does
// not fall to less than half its value from one sample to the next while the position is
// more than 2 sigma off.
TEST(PopulationWarmStartFromRestHeldOut, SigmaKeepsWhatEarlierFixesLeftOnMotor52) {
  // Named references, not a structured binding: the observer below captures them.
  const WarmStartFromRest w = warm_start_from_rest(52);
  const auto& p = w.motor;
  const auto& cal = w.cal;
  const auto& sc = w.scenario;
  ASSERT_TRUE(cal.ok) << cal.error;
  for (const auto cond : kWarmConditions) {
    double previous_std = 0.0, worst_ratio = 1.0, error_there = 0.0;
    const auto r = bench::run_population_scenario(
        p, cal, sc, cond, 1052, {},
        [&](double t, const core::EncoderEstimate& e, const core::AxisPipeline&, const sim::SimSource& source) {
          const auto* truth = source.truth();
          if (!truth) return;
          const double error = std::abs(e.position_m - (truth->position_m - cal.zero_m));
          if (t >= sc.t0_s && previous_std > 0.0 && error > 2.0 * e.position_std_m &&
              e.position_std_m / previous_std < worst_ratio) {
            worst_ratio = e.position_std_m / previous_std;
            error_there = error;
          }
          previous_std = e.position_std_m;
        });
    ASSERT_TRUE(r.ok) << r.error;
    std::printf("[ figures  ] %-11s %-15s largest one-sample fall of sigma while more than 2 sigma off: to %.2f of it "
                "(%.2f um off) | largest error while VALID %.2f um\n",
                bench::condition_name(cond), sc.name.c_str(), worst_ratio, error_there * 1e6,
                r.max_valid_error_m * 1e6);
    EXPECT_GE(worst_ratio, 0.5) << bench::condition_name(cond);
  }
}

// A motor 10 K warmer than at calibration, started at speed without a temperature from
// its node: the fixes' common gain is its thermometer, read after the first 20 ms. That
// reading widens the sensors' covariance (the drift a rise of that size allows), but the
// fix of the sample that made it was solved with the covariance before: VALID waits for
// the next fix. (It used to be set on that sample: 13.3 um off with a sigma of 2.49 um on
// motor 5.) And the filter's own variance takes the drift its earlier fixes carried.
class PopulationWarmStart : public ::testing::TestWithParam<std::uint64_t> {};

TEST_P(PopulationWarmStart, ValidWaitsForTheFixThatHoldsTheThermometersWidening) {
  const auto p = sim::draw_population_motor(GetParam(), shipped_tuning());
  const auto cal = calibrated_with_a_ruler(p);
  ASSERT_TRUE(cal.ok) << cal.error;
  const auto scenarios = bench::population_scenarios(p.datasheet.travel_m);
  for (const auto& sc : {scenarios[1], scenarios[2]}) {  // 1 m/s (a flying start), 5 m/s^2 (from rest)
    bool checked = false;
    double checked_at = -1.0, sigma_before = 0.0, sigma_after = 0.0;
    bool valid_at_reading = false;
    int after = -1;
    const auto r = bench::run_population_scenario(
        p, cal, sc, bench::Condition::ramp_plus_10k, bench::run_noise_seed(GetParam()), {},
        [&](double t, const core::EncoderEstimate& e, const core::AxisPipeline& pipeline, const sim::SimSource&) {
          // The filter's own sigma: the published one also holds, until the reading, what
          // a temperature not read yet may have done (PopulationWarmStartHeldOut below).
          const double filter_sigma = std::sqrt(pipeline.filter().position_variance());
          if (after >= 0 && after < 2 && ++after == 2) sigma_after = filter_sigma;
          if (checked || !pipeline.adaptation().temperature_checked()) {
            if (!checked) sigma_before = filter_sigma;
            return;
          }
          checked = true;
          checked_at = t;
          valid_at_reading = (e.status & core::status::kValid) != 0;
          after = 0;
        });
    ASSERT_TRUE(r.ok) << r.error;
    ASSERT_TRUE(checked) << sc.name << ": the thermometer never read";
    std::printf("[ figures  ] %-15s thermometer read at %.4f s; the filter's position sigma %.2f um before, %.2f um "
                "two samples after\n",
                sc.name.c_str(), checked_at, sigma_before * 1e6, sigma_after * 1e6);
    EXPECT_FALSE(valid_at_reading) << sc.name << ": VALID on the sample whose fix predates the widening";
    EXPECT_GT(sigma_after, sigma_before) << sc.name << ": the widening reaches the filter's sigma";
  }
}

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationWarmStart, ::testing::Values(4u, 5u, 14u, 20u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

// Motor 60 of the held-out set (3 Halls, 10-bit) started from rest at 5 m/s^2, 10 K
// colder than at calibration, under the second draw of the benchmark's noise
// (population_bench --noise-draw 1): two of its sensors out of saturation, and the first
// fix that reads the temperature comes 55 ms into the run. Until then its fixes carry the
// drift of a temperature nobody has read; sigma held it only where the carriage stands,
// and the position went 15 um and the velocity 1.5 mm/s off under a sigma of 0.6 um and
// 0.08 mm/s (NOT VALID: VALID waits for the reading). Asserted over every sample before the
// reading: the position within 2 sigma, and not VALID. The velocity's sigma holds the
// drift's pattern at speed, but not all of the velocity error of these first tens of ms:
// printed, not asserted (149 of 387 samples outside 2 sigma, 4.3 sigma at worst).
TEST(PopulationWarmStartHeldOut, SigmaHoldsTheUnreadTemperatureWhileMovingOnMotor60) {
  const WarmStartFromRest w = warm_start_from_rest(60);
  ASSERT_TRUE(w.cal.ok) << w.cal.error;
  int before = 0, position_out = 0, velocity_out = 0;
  double worst_position = 0.0, worst_velocity = 0.0;  // |error| / sigma
  const auto r = bench::run_population_scenario(
      w.motor, w.cal, w.scenario, bench::Condition::step_minus_10k, bench::run_noise_seed(60, 1), {},
      [&](double, const core::EncoderEstimate& e, const core::AxisPipeline& pipeline, const sim::SimSource& source) {
        const auto* truth = source.truth();
        if (!truth || pipeline.adaptation().temperature_checked() || !pipeline.initialised()) return;
        if (!(e.position_std_m > 0.0 && e.velocity_std_mps > 0.0)) return;
        ++before;
        const double zp = std::abs(e.position_m - (truth->position_m - w.cal.zero_m)) / e.position_std_m;
        const double zv = std::abs(e.velocity_mps - truth->velocity_mps) / e.velocity_std_mps;
        worst_position = std::max(worst_position, zp);
        worst_velocity = std::max(worst_velocity, zv);
        position_out += zp > 2.0;
        velocity_out += zv > 2.0;
        EXPECT_FALSE(e.status & core::status::kValid) << "VALID before the temperature is read, moving";
      });
  ASSERT_TRUE(r.ok) << r.error;
  std::printf("[ figures  ] before the first reading: %d samples, %d / %d outside 2 sigma (position / velocity), "
              "worst %.2f / %.2f sigma\n",
              before, position_out, velocity_out, worst_position, worst_velocity);
  ASSERT_GT(before, 100) << "the case this guards: a reading some tens of ms into the run";
  EXPECT_EQ(position_out, 0);
}

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationWarmingRamp, ::testing::Values(72u, 76u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationWarmMotion, ::testing::Values(8u, 17u, 20u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationStandstillOneSensor, ::testing::Values(52u, 92u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationWarmStandstill, ::testing::Values(1u, 8u, 11u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationVibration, ::testing::Values(5u, 17u, 18u, 19u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

INSTANTIATE_TEST_SUITE_P(Seeds, PopulationCoarseConverter, ::testing::Values(7u, 11u, 18u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });
INSTANTIATE_TEST_SUITE_P(Seeds, PopulationNoRulerAccelerometer, ::testing::Values(33u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });
INSTANTIATE_TEST_SUITE_P(Seeds, PopulationHallDelay, ::testing::Values(5u, 16u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });
INSTANTIATE_TEST_SUITE_P(Seeds, PopulationAccelDelay, ::testing::Values(1u, 12u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });
INSTANTIATE_TEST_SUITE_P(Seeds, PopulationAccelDelayIdeal, ::testing::Values(5u, 7u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });
INSTANTIATE_TEST_SUITE_P(Seeds, PopulationStandstillPlaces, ::testing::Values(9u, 19u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });
INSTANTIATE_TEST_SUITE_P(Seeds, PopulationNoRulerEnds, ::testing::Values(3u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });
INSTANTIATE_TEST_SUITE_P(Seeds, PopulationMotor, ::testing::Values(1u, 2u, 3u),
                         [](const auto& info) { return "motor_" + std::to_string(info.param); });

}  // namespace
