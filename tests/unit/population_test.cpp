// The motor population: deterministic draws inside the catalogue's ranges, every
// motor one the simulator accepts and whose sensor array has no blind spot.
#include <gtest/gtest.h>

#include <set>

#include "sim/population.hpp"
#include "sim/sim_source.hpp"

namespace {

TEST(Population, DrawsAreDeterministicAndInsideTheRanges) {
  const ve::sim::PopulationRanges r;
  std::set<int> counts, bits;
  double pitch_lo = 1, pitch_hi = 0, rate_lo = 1e9, rate_hi = 0;
  for (std::uint64_t seed = 1; seed <= 200; ++seed) {
    const auto p = ve::sim::draw_population_motor(seed, {});
    const auto q = ve::sim::draw_population_motor(seed, {});
    EXPECT_EQ(p.summary(), q.summary());
    EXPECT_EQ(p.sim.imperfections.track_seed, q.sim.imperfections.track_seed);
    const auto& m = p.datasheet;
    EXPECT_GE(m.magnet_pitch_m, r.pitch_min_m);
    EXPECT_LE(m.magnet_pitch_m, r.pitch_max_m);
    EXPECT_GE(m.hall.count, r.halls_min);
    EXPECT_LE(m.hall.count, r.halls_max);
    EXPECT_GE(m.sample_rate_hz, r.rate_min_hz);
    EXPECT_LE(m.sample_rate_hz, r.rate_max_hz);
    EXPECT_GE(m.travel_m, r.travel_min_m);
    EXPECT_LE(m.travel_m, r.travel_max_m);
    const auto& im = p.sim.imperfections;
    EXPECT_LE(im.hall_delay_s, r.hall_delay_max_s);
    EXPECT_LE(im.accel_delay_s, r.accel_delay_max_s);
    EXPECT_LE(im.magnet_placement_std_m, r.magnet_placement_max_m);
    EXPECT_LE(std::abs(im.coil_field_v_per_mps2), r.coil_field_max_v_per_mps2);
    EXPECT_NE(p.datasheet.hall.amplitude_v, p.hardware.hall.amplitude_v) << "the data sheet is not the hardware";
    int min_n = 0;
    double two = 0;
    ve::sim::hall_coverage(m, min_n, two);
    EXPECT_GE(min_n, 1) << p.summary();
    ve::sim::SimConfig cfg = p.sim;
    cfg.profile.start_m = 0.5 * m.travel_m;
    cfg.profile.min_m = 0.05 * m.travel_m;
    cfg.profile.max_m = 0.95 * m.travel_m;
    cfg.profile.kind = ve::sim::MotionProfileConfig::Kind::standstill;
    EXPECT_EQ(ve::sim::SimSource::check(p.hardware, cfg), "") << p.summary();
    counts.insert(m.hall.count);
    bits.insert(m.adc.bits);
    pitch_lo = std::min(pitch_lo, m.magnet_pitch_m);
    pitch_hi = std::max(pitch_hi, m.magnet_pitch_m);
    rate_lo = std::min(rate_lo, m.sample_rate_hz);
    rate_hi = std::max(rate_hi, m.sample_rate_hz);
  }
  // The draws span the ranges, not a corner of them.
  EXPECT_EQ(counts.size(), 6u);
  EXPECT_EQ(bits.size(), 3u);
  EXPECT_LT(pitch_lo, 0.012);
  EXPECT_GT(pitch_hi, 0.035);
  EXPECT_LT(rate_lo, 3000.0);
  EXPECT_GT(rate_hi, 9000.0);
  EXPECT_NE(ve::sim::draw_population_motor(1, {}).summary(), ve::sim::draw_population_motor(2, {}).summary());
}

TEST(Population, CoverageFindsABlindSpot) {
  ve::core::MotorConfig m;
  m.hall.count = 2;
  m.hall.spacing_m = 0.0;  // two sensors on one spot see the same thing: half the period is blind
  int min_n = 0;
  double two = 0;
  ve::sim::hall_coverage(m, min_n, two);
  EXPECT_EQ(min_n, 0);
  m.hall.count = 4;
  m.hall.spacing_m = m.magnet_pitch_m / 8.0;  // the paper's array
  ve::sim::hall_coverage(m, min_n, two);
  EXPECT_GE(min_n, 1);
  EXPECT_GT(two, 0.5);
}

}  // namespace
