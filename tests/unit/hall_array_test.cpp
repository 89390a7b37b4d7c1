// Block SF against the simulator's truth: over a full magnet period and across
// period boundaries, in both directions, with the nominal table and with one
// built from a reference sweep.
#include <gtest/gtest.h>

#include <cmath>

#include "core/hall_array.hpp"
#include "core/table_builder.hpp"
#include "sim/sim_source.hpp"

namespace {

using ve::core::HallArray;
using ve::core::MotorConfig;
using ve::core::RawSample;
using ve::sim::MotionProfileConfig;
using ve::sim::SimConfig;
using ve::sim::SimSource;

SimConfig moving(double start_m, double velocity_mps) {
  SimConfig cfg;
  cfg.realtime = false;
  cfg.profile.kind = MotionProfileConfig::Kind::constant_velocity;
  cfg.profile.start_m = start_m;
  cfg.profile.velocity_mps = velocity_mps;
  cfg.profile.min_m = 0.0;
  cfg.profile.max_m = 1.0;
  return cfg;
}

struct Errors {
  double rms_m = 0, max_m = 0, normalised_rms = 0;
  int n = 0, periods_crossed = 0, failures = 0;
};

/// Tracks the carriage with HallArray::solve, seeded by its own previous answer
/// (no help from the truth after the first sample).
Errors track(const HallArray& array, SimSource& sim, double duration_s, double pitch_m) {
  Errors e;
  RawSample s;
  double guess = std::numeric_limits<double>::quiet_NaN();
  double sum_sq = 0, sum_norm = 0;
  long first_period = 0, last_period = 0;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const auto& truth = *sim.truth();
    if (static_cast<double>(s.t_ns) * 1e-9 > duration_s) break;
    if (std::isnan(guess)) {
      guess = truth.position_m + 1e-3;  // a start-up guess a millimetre off
      first_period = static_cast<long>(std::floor(truth.position_m / pitch_m));
    }
    const auto fix = array.solve(s, guess);
    if (!fix.ok) {
      ++e.failures;
      continue;
    }
    const double err = fix.position_m - truth.position_m;
    sum_sq += err * err;
    sum_norm += err * err / fix.variance_m2;
    e.max_m = std::max(e.max_m, std::abs(err));
    guess = fix.position_m;
    last_period = static_cast<long>(std::floor(truth.position_m / pitch_m));
    ++e.n;
  }
  e.rms_m = std::sqrt(sum_sq / e.n);
  e.normalised_rms = std::sqrt(sum_norm / e.n);
  e.periods_crossed = static_cast<int>(std::abs(last_period - first_period));
  return e;
}

struct Case {
  const char* name;
  double start_m;
  double velocity_mps;
  double duration_s;
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.name; }

class HallArrayVsTruth : public ::testing::TestWithParam<Case> {};

TEST_P(HallArrayVsTruth, NominalTableTracksWithinAMicrometre) {
  const Case c = GetParam();
  MotorConfig motor;
  SimSource sim(motor, moving(c.start_m, c.velocity_mps));
  ASSERT_TRUE(sim.ok()) << sim.last_error();
  HallArray array(motor, ve::core::nominal_hall_table(motor));
  const Errors e = track(array, sim, c.duration_s, motor.magnet_pitch_m);
  std::printf("[ figures  ] %-28s n=%6d periods=%3d rms=%.3f um max=%.3f um err/sigma rms=%.2f\n", c.name, e.n,
              e.periods_crossed, e.rms_m * 1e6, e.max_m * 1e6, e.normalised_rms);
  EXPECT_EQ(e.failures, 0);
  EXPECT_GE(e.periods_crossed, 1) << "the case must cross at least one period boundary";
  // Sensor noise 0.6 mV + 12-bit quantisation over slopes of 1.3..1.9 mV/um: about 0.3..0.5 um per sample.
  EXPECT_LT(e.rms_m, 1.0e-6);
  EXPECT_LT(e.max_m, 3.0e-6);
  // The variance the array reports is honest: errors over sigma have an RMS near one
  // (the variance floor of 0.2 um makes it a little conservative).
  EXPECT_GT(e.normalised_rms, 0.5);
  EXPECT_LT(e.normalised_rms, 1.5);
}

INSTANTIATE_TEST_SUITE_P(
    Motions, HallArrayVsTruth,
    ::testing::Values(Case{"forward_slow_one_period", 0.3001, 0.02, 0.7},    // 14 mm: one full period and more
                      Case{"backward_slow_one_period", 0.7003, -0.02, 0.7},  // same, the other way
                      Case{"forward_1mps_many_periods", 0.05, 1.0, 0.5},
                      Case{"backward_1mps_many_periods", 0.95, -1.0, 0.5}),
    [](const auto& info) { return std::string(info.param.name); });

TEST(HallArrayAcquire, FindsThePositionWithinHalfAPitchOfTheHint) {
  MotorConfig motor;
  HallArray array(motor, ve::core::nominal_hall_table(motor));
  for (double x : {0.1, 0.2503, 0.4999, 0.7771}) {
    SimConfig cfg;
    cfg.realtime = false;
    cfg.profile.kind = MotionProfileConfig::Kind::standstill;
    cfg.profile.start_m = x;
    SimSource sim(motor, cfg);
    RawSample s;
    ASSERT_EQ(sim.read(s), ve::drivers::ReadStatus::ok);
    const double p = motor.magnet_pitch_m;
    const auto fix = array.acquire(s, x + 0.3 * p - 0.5 * p, x + 0.3 * p + 0.5 * p);
    ASSERT_TRUE(fix.ok) << x;
    EXPECT_NEAR(fix.position_m, x, 3e-6) << x;
  }
}

TEST(HallArrayTable, TableFromAReferenceSweepMatchesTheMotor) {
  MotorConfig motor;
  motor.travel_m = 0.1;  // a short motor keeps the sweep quick
  SimConfig cfg;
  cfg.realtime = false;
  cfg.profile.kind = MotionProfileConfig::Kind::shuttle;
  cfg.profile.start_m = 0.0;
  cfg.profile.min_m = 0.0;
  cfg.profile.max_m = motor.travel_m;
  cfg.profile.max_velocity_mps = 0.02;
  cfg.profile.max_acceleration_mps2 = 0.5;
  SimSource sim(motor, cfg);
  ASSERT_TRUE(sim.ok()) << sim.last_error();
  ve::core::TableBuilder builder(motor);
  RawSample s;
  const double sweep_s = 2.0 * (motor.travel_m / 0.02 + 0.02 / 0.5);
  while (sim.read(s) == ve::drivers::ReadStatus::ok && static_cast<double>(s.t_ns) * 1e-9 < sweep_s)
    builder.add(sim.truth()->position_m, s);
  EXPECT_DOUBLE_EQ(builder.coverage(), 1.0);
  ve::core::HallTable table;
  std::string error;
  ASSERT_TRUE(builder.finish(table, error)) << error;
  // Where a sensor is out of saturation the fitted table matches the noiseless
  // output to well below the noise of one sample (0.6 mV + quantisation, 0.7 mV):
  // each node fits some 40 samples, so its own error is about 0.15 mV.
  double worst = 0, sum_sq = 0;
  int nodes = 0;
  for (int sensor = 0; sensor < motor.hall.count; ++sensor) {
    for (int k = 2; k < table.points - 2; ++k) {
      const double x = table.start_m + k * table.step_m;
      const double truth = sim.hall_voltage_noiseless(sensor, x);
      if (truth < 0.1 || truth > 4.9) continue;
      const double err = table.v[static_cast<std::size_t>(sensor) * table.points + k] - truth;
      worst = std::max(worst, std::abs(err));
      sum_sq += err * err;
      ++nodes;
    }
  }
  const double rms = std::sqrt(sum_sq / nodes);
  std::printf("[ figures  ] reference-sweep table: %d nodes, error rms %.3f mV, worst %.3f mV\n", nodes, rms * 1e3,
              worst * 1e3);
  EXPECT_LT(rms, 0.25e-3);
  EXPECT_LT(worst, 1.2e-3);  // about 7 node sigmas

  // An incomplete sweep is refused with a reason.
  ve::core::TableBuilder partial(motor);
  partial.add(0.01, s);
  ve::core::HallTable t2;
  EXPECT_FALSE(partial.finish(t2, error));
  EXPECT_NE(error.find("cover the whole travel"), std::string::npos) << error;
}

}  // namespace
