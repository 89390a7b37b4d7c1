// Calibration without a reference on motors nobody tuned it on: the population of
// simulated motors (drivers/sim/population.hpp), each given to the calibration by
// its data sheet only, with the Hall delay from the hardware's design. For each:
// the simulated calibration run with its reference column blanked, and the result
// against the simulator's truth: the accelerometer's figures, the sensors'
// placement, and the position the self-made table gives on noiseless readings
// over the whole travel, from home (tests/unit/home_truth.hpp).
//
// Three motors run by default; VE_POPULATION_MOTORS=20 runs seeds 1..20, and
// VE_POPULATION_SEEDS=2,13 runs those.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "config/loader.hpp"
#include "core/hall_array.hpp"
#include "core/self_calibration.hpp"
#include "home_truth.hpp"
#include "sim/calibration_run.hpp"
#include "sim/population.hpp"
#include "sim/sim_source.hpp"

namespace {

/// The sweep speed of the population's calibration runs: 2.5x the default, so a
/// 2 m motor records 80 s rather than 200 s; the calibration must still meet its
/// accuracy at it.
constexpr double kSweepSpeedMps = 0.05;

struct Outcome {
  std::uint64_t seed = 0;
  std::string summary;
  bool ok = false, good = false;
  std::string error;
  std::vector<std::string> problems, iterations;
  double seconds = 0.0;
  double hall_delay_reproduced_err_s = 0.0;
  double accel_scale_rel_err = 0.0, accel_bias_err = 0.0, accel_delay_err_s = 0.0;
  double sensor_offset_max_err_m = 0.0;
  double position_rms_m = 0.0, position_max_m = 0.0, position_bias_m = 0.0;
  double position_worst_at_m = 0.0;  ///< where (simulator's frame)
  double track_scale_std = 0.0;      ///< what the calibration says its scale is good to
  double track_scale_true = 0.0;     ///< the simulated track's scale error over the travel
  int position_failed = 0;  ///< noiseless checks with no usable fix
};

ve::core::FilterConfig tuning() {
  const auto loaded = ve::config::load_machine_file(std::string(VE_SOURCE_DIR) + "/config/machines/sim.yaml");
  EXPECT_TRUE(loaded.ok()) << ve::config::to_string(loaded.errors);
  return loaded.config.axes.at(0).motor.filter;
}

/// The Hall position the calibration's table gives on noiseless readings, against
/// the truth measured from home, at positions spread over the whole travel.
/// The motor's simulator standing still inside its travel (the population leaves
/// the profile at its default, which a short motor does not accept): for its
/// noiseless Hall model and its sensors' placement.
ve::sim::SimConfig truth_config(const ve::sim::PopulationMotor& p) {
  ve::sim::SimConfig cfg = p.sim;
  cfg.profile = ve::sim::MotionProfileConfig{};
  cfg.profile.kind = ve::sim::MotionProfileConfig::Kind::standstill;
  cfg.profile.start_m = 0.5 * p.hardware.travel_m;
  cfg.profile.min_m = 0.05 * p.hardware.travel_m;
  cfg.profile.max_m = 0.95 * p.hardware.travel_m;
  return cfg;
}

/// The places a calibration is checked at, spread over the travel: kCheckPlaces of
/// them (not a multiple of anything the pitch is), place k at check_place(motor, k).
constexpr int kCheckPlaces = 997;
double check_place(const ve::core::MotorConfig& m, int k) { return m.travel_m * (k + 0.5) / kCheckPlaces; }

/// Every sensor's noiseless reading at simulator position x, as the converter clips it.
ve::core::RawSample noiseless_sample(const ve::sim::SimSource& sim, const ve::core::MotorConfig& m, double x) {
  ve::core::RawSample s;
  s.hall_count = m.hall.count;
  s.hall_valid_mask = (1u << m.hall.count) - 1u;
  for (int i = 0; i < m.hall.count; ++i)
    s.hall_v[static_cast<std::size_t>(i)] = std::clamp(sim.hall_voltage_noiseless(i, x), m.adc.min_v, m.adc.max_v);
  return s;
}

void check_positions(const ve::sim::PopulationMotor& p, const ve::core::Calibration& cal, double home, Outcome& o) {
  ve::sim::SimSource sim(p.hardware, truth_config(p));
  const ve::core::HallArray array(p.datasheet, cal.table);
  const auto& m = p.datasheet;
  double sum = 0.0, sum2 = 0.0, worst = 0.0;
  int used = 0;
  for (int k = 0; k < kCheckPlaces; ++k) {
    const double x = check_place(m, k);
    const ve::core::RawSample s = noiseless_sample(sim, m, x);
    const double truth = x - home;
    const auto fix = array.solve(s, truth);
    if (!fix.ok) {
      ++o.position_failed;
      continue;
    }
    const double e = fix.position_m - truth;
    sum += e, sum2 += e * e, ++used;
    if (std::abs(e) > worst) worst = std::abs(e), o.position_worst_at_m = x;
  }
  if (used > 0) {
    o.position_rms_m = std::sqrt(sum2 / used);
    o.position_bias_m = sum / used;
  }
  o.position_max_m = worst;
}

/// Motor `seed`'s calibration run, recorded with the simulator's truth as the reference.
bool record(std::uint64_t seed, const ve::sim::PopulationMotor& p, Outcome& o,
            std::vector<ve::core::ReferenceSegment>& segments) {
  o.seed = seed;
  o.summary = p.summary();
  ve::sim::CalibrationRunConfig run;
  run.sweep_speed_mps = kSweepSpeedMps;
  return ve::sim::record_calibration_run(p.hardware, p.sim, run, segments, o.error);
}

Outcome calibrate(std::uint64_t seed, const ve::core::FilterConfig& filter) {
  Outcome o;
  const auto p = ve::sim::draw_population_motor(seed, filter);
  std::vector<ve::core::ReferenceSegment> segments;
  if (!record(seed, p, o, segments)) return o;
  for (auto& s : segments) s.reference_m.assign(s.reference_m.size(), std::nan(""));
  ve::core::SelfCalibrationConfig cfg;
  cfg.hall_delay_s = p.sim.imperfections.hall_delay_s;
  ve::core::Calibration cal;
  ve::core::SelfCalibrationReport rep;
  const auto t0 = std::chrono::steady_clock::now();
  o.ok = ve::core::identify_without_reference(p.datasheet, segments, cfg, cal, rep, o.error);
  o.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!o.ok) return o;
  o.good = rep.identification.good;
  o.problems = rep.identification.problems;
  o.iterations = rep.iterations;
  const auto& im = p.sim.imperfections;
  const double scale = (1.0 + im.accel_scale_error) * (1.0 + im.frame_reaction_ratio);
  o.hall_delay_reproduced_err_s = rep.hall_delay_reproduced_s - im.hall_delay_s;
  o.accel_scale_rel_err = cal.model.accel_scale / scale - 1.0;
  o.accel_bias_err = cal.model.accel_bias_mps2 - im.accel_bias_mps2;
  o.accel_delay_err_s = cal.model.accel_delay_s - im.accel_delay_s;
  ve::sim::SimSource sim(p.hardware, truth_config(p));
  EXPECT_TRUE(sim.ok()) << sim.last_error();
  o.track_scale_std = cal.model.track_scale_std;
  o.track_scale_true = sim.track_scale_error(0.0, p.hardware.travel_m);
  for (int s = 1; s < p.datasheet.hall.count && s < static_cast<int>(rep.sensor_offset_m.size()); ++s) {
    const double truth = sim.sensor_position_m(s) - sim.sensor_position_m(0);
    o.sensor_offset_max_err_m =
        std::max(o.sensor_offset_max_err_m, std::abs(rep.sensor_offset_m[static_cast<std::size_t>(s)] - truth));
  }
  const double home = ve::test::home_truth_m(p.hardware, truth_config(p), rep);
  if (std::isfinite(home)) {
    check_positions(p, cal, home, o);
  } else {
    o.position_rms_m = o.position_max_m = std::nan("");
  }
  return o;
}

/// The same motor calibrated with the simulator as its ruler, checked the same way:
/// what its Halls allow at all (a few of the check's noiseless places can have no
/// sensor out of saturation on a steep enough slope, whatever the table).
Outcome calibrate_with_ruler(std::uint64_t seed, const ve::core::FilterConfig& filter) {
  Outcome o;
  const auto p = ve::sim::draw_population_motor(seed, filter);
  std::vector<ve::core::ReferenceSegment> segments;
  if (!record(seed, p, o, segments)) return o;
  ve::core::Calibration cal;
  ve::core::IdentificationReport rep;
  o.ok = ve::core::identify_with_reference(p.datasheet, segments, {}, cal, rep, o.error);
  if (!o.ok) return o;
  o.good = rep.good;
  check_positions(p, cal, 0.0, o);
  return o;
}

/// Seeds 1..VE_POPULATION_MOTORS (3 unless set), or the list VE_POPULATION_SEEDS
/// ("2,13") when that is set.
std::vector<std::uint64_t> seeds_to_run() {
  std::vector<std::uint64_t> seeds;
  if (const char* list = std::getenv("VE_POPULATION_SEEDS")) {
    for (const char* c = list; *c != '\0';) {
      char* end = nullptr;
      const unsigned long long v = std::strtoull(c, &end, 10);
      if (end == c) {
        ++c;
        continue;
      }
      seeds.push_back(v);
      c = end;
    }
    if (!seeds.empty()) return seeds;
  }
  const char* env = std::getenv("VE_POPULATION_MOTORS");
  const int n = std::clamp(env != nullptr ? std::atoi(env) : 3, 1, 200);
  for (int seed = 1; seed <= n; ++seed) seeds.push_back(static_cast<std::uint64_t>(seed));
  return seeds;
}

TEST(SelfCalibrationPopulation, EveryMotorCalibratesWithoutAReference) {
  const auto filter = tuning();
  std::vector<Outcome> all;
  for (const std::uint64_t seed : seeds_to_run()) {
    all.push_back(calibrate(seed, filter));
    const Outcome& o = all.back();
    std::printf("[ motor    ] %s\n", o.summary.c_str());
    if (!o.ok) std::printf("[ refused  ] %s\n", o.error.c_str());
    for (const auto& l : o.iterations) std::printf("[ iteration] %s\n", l.c_str());
    for (const auto& pr : o.problems) std::printf("[ problem  ] %s\n", pr.c_str());
    std::fflush(stdout);
  }
  std::printf("[ table    ] seed ok good  time_s  pos_rms_um pos_bias_um pos_max_um at_mm fails  scale_err_%% bias_err "
              "delay_err_us hall_delay_repr_err_us sensor_max_err_um scale_std_ppm scale_true_ppm\n");
  for (const auto& o : all)
    std::printf("[ table    ] %4llu %2d %4d %7.2f %11.3f %11.3f %10.3f %6.1f %5d %12.4f %8.4f %12.1f %22.2f %17.2f %13.2f %14.2f\n",
                static_cast<unsigned long long>(o.seed), o.ok ? 1 : 0, o.good ? 1 : 0, o.seconds,
                o.position_rms_m * 1e6, o.position_bias_m * 1e6, o.position_max_m * 1e6, o.position_worst_at_m * 1e3, o.position_failed,
                o.accel_scale_rel_err * 100.0, o.accel_bias_err, o.accel_delay_err_s * 1e6,
                o.hall_delay_reproduced_err_s * 1e6, o.sensor_offset_max_err_m * 1e6, o.track_scale_std * 1e6,
                o.track_scale_true * 1e6);
  // Met on motors 1-32 (VE_POPULATION_MOTORS=32): no refusal, a verdict of good (the
  // calibration is written), a table that solves everywhere, the accelerometer's scale.
  // Motor 33 misses the scale: 0.120 % off (6 Halls 1.1 mm apart on an 11.9 mm pitch,
  // all near one phase, where a common-mode offset looks like a shift of the position:
  // its coil field comes out 0.71 against 0.85 mV per m/s^2 and the accelerometer's
  // delay 5.8 us early; docs/accuracy.md, what is left). The target
  // not met on every motor yet (Hall position within 2 um RMS over the whole travel:
  // the track's own scale, see docs/accuracy.md) is counted here and asserted with
  // VE_POPULATION_TARGETS=1.
  const bool targets = std::getenv("VE_POPULATION_TARGETS") != nullptr;
  int good = 0, accurate = 0;
  for (const auto& o : all) {
    SCOPED_TRACE(o.summary);
    ASSERT_TRUE(o.ok) << o.error;
    EXPECT_EQ(o.position_failed, 0);
    EXPECT_LE(std::abs(o.accel_scale_rel_err), 0.001);
    // The scale the calibration cannot know, it says it does not know: the track's
    // true scale error within 4 of its sigma (over the 20 motors the ratio is 1.0 RMS).
    EXPECT_GT(o.track_scale_std, 0.0);
    EXPECT_LE(std::abs(o.track_scale_true), 4.0 * o.track_scale_std);
    EXPECT_TRUE(o.good) << (o.problems.empty() ? std::string() : o.problems.front());
    good += o.good ? 1 : 0;
    accurate += o.position_rms_m <= 2e-6 ? 1 : 0;
    if (targets) {
      EXPECT_LE(o.position_rms_m, 2e-6);
    }
  }
  std::printf("[ summary  ] %zu motors: %zu calibrated, %d good, %d within 2 um RMS\n", all.size(),
              static_cast<std::size_t>(std::count_if(all.begin(), all.end(), [](const Outcome& o) { return o.ok; })),
              good, accurate);
}

/// Motor 11 (40 mm pitch, 10-bit ADC, 2.4 mV/(m/s^2) of coil field): in fast
/// motion its Hall solve errs by tens of um wherever the coil field is misjudged
/// and a single sensor is out of saturation. The coil field regressed on the
/// self-made position's own acceleration was pulled low by those errors, which
/// grew with it: the accelerometer's scale went 0.63, 0.20, ... 0.08 and every
/// moving scenario lost the track. The coil field is now regressed on the
/// accelerometer, and the scale fitted through a filter that the Hall solve's
/// errors at the magnet frequency do not pass (they biased it 1.7 % low).
TEST(SelfCalibrationPopulation, TheCoilFieldAndTheAccelerometerScaleDoNotFeedEachOther) {
  const Outcome o = calibrate(11, tuning());
  SCOPED_TRACE(o.summary);
  for (const auto& l : o.iterations) std::printf("[ iteration] %s\n", l.c_str());
  ASSERT_TRUE(o.ok) << o.error;
  EXPECT_LE(std::abs(o.accel_scale_rel_err), 0.001);
  EXPECT_LE(std::abs(o.accel_delay_err_s), 100e-6);
  EXPECT_EQ(o.position_failed, 0);
  // Converged: no problem says the iterations did not settle.
  for (const auto& pr : o.problems) EXPECT_EQ(pr.find("did not settle"), std::string::npos) << pr;
}

/// Motor 89 (3 Halls 7.4 mm apart on a 27.7 mm pitch, two out of saturation at a
/// time; held out of the population the calibration was developed on) does not
/// settle without a ruler: its coil field comes out -0.08 mV/(m/s^2) against the
/// motor's -0.56 and the fast motion stays 3.8 um beyond the fixes' noise, while its
/// slow passes were steady (they meet the Hall positions to 0.04 um). The refusal had
/// asked for the sweep again at a steady speed: it now says the sweep was steady,
/// that the fit to the fast motion is what did not settle, and what to do instead.
TEST(SelfCalibrationPopulation, AnUnsettledFitToTheFastMotionIsNotBlamedOnTheSweep) {
  const Outcome o = calibrate(89, tuning());
  SCOPED_TRACE(o.summary);
  ASSERT_TRUE(o.ok) << o.error;
  EXPECT_FALSE(o.good);
  const auto unsettled = std::find_if(o.problems.begin(), o.problems.end(),
                                      [](const std::string& pr) { return pr.find("did not settle") != std::string::npos; });
  ASSERT_NE(unsettled, o.problems.end()) << "no problem says the iterations did not settle";
  std::printf("[ refusal  ] %s\n", unsettled->c_str());
  EXPECT_NE(unsettled->find("the slow passes were steady"), std::string::npos) << *unsettled;
  EXPECT_NE(unsettled->find("fit to the fast motion"), std::string::npos) << *unsettled;
  EXPECT_NE(unsettled->find("Calibrate with a ruler"), std::string::npos) << *unsettled;
  EXPECT_EQ(unsettled->find("record the sweep again"), std::string::npos) << *unsettled;
}

/// Motors 73 (4 Halls 5.1 mm apart on a 21 mm pitch) and 92 (3 Halls 2.6 mm apart on
/// 9.5 mm), held out of the population the calibration was developed on, have Hall
/// amplitudes of about 3.5 V about a 2.5 V mid on a 0..5 V converter: most of the
/// time every sensor but one or two is on a rail. Tracked sample to sample, a solve
/// from the extrapolated guess settled where a saturated sensor contradicted it, or
/// found no slope, and the tracker went on from there: motor 73's sweep jumped by 7
/// magnet periods within a slow pass and was refused; motor 92's second iteration
/// ran off from the sweep's first sample (its table's least-sampled end) at 5 mm a
/// sample, lost its forward pass and was refused. Such a sample is now searched for
/// over the period about the guess with every sensor, the rails included, and
/// bridged at the speed of the last fixes when it has no fix.
TEST(SelfCalibrationPopulation, MotorsWhoseHallsMostlySaturateCalibrateWithoutAReference) {
  const auto filter = tuning();
  for (const std::uint64_t seed : {73, 92}) {
    const Outcome o = calibrate(seed, filter);
    SCOPED_TRACE(o.summary);
    std::printf("[ motor    ] %s\n", o.summary.c_str());
    ASSERT_TRUE(o.ok) << o.error;
    EXPECT_TRUE(o.good) << (o.problems.empty() ? std::string() : o.problems.front());
    EXPECT_LE(std::abs(o.accel_scale_rel_err), 0.001);
    EXPECT_LE(std::abs(o.track_scale_true), 4.0 * o.track_scale_std);
    // The table solves wherever the one a ruler makes does.
    const Outcome r = calibrate_with_ruler(seed, filter);
    ASSERT_TRUE(r.ok) << r.error;
    EXPECT_LE(o.position_failed, r.position_failed);
    std::printf("[ result   ] motor %llu: %.3f um RMS, %.3f um at most, %d of %d places without a fix, "
                "accelerometer scale %+.4f %%; with a ruler %.3f um RMS, %.3f um at most, %d without a fix\n",
                static_cast<unsigned long long>(seed), o.position_rms_m * 1e6, o.position_max_m * 1e6,
                o.position_failed, kCheckPlaces, o.accel_scale_rel_err * 100.0, r.position_rms_m * 1e6,
                r.position_max_m * 1e6, r.position_failed);
  }
}

/// Motor 60 (magnets placed to 6 um, strengths alike to 0.0 %, held out) has a track
/// with almost no signature: the fast motion scores within 0.05 % in neighbouring
/// magnet periods of the table, and the choice went back and forth between two of
/// them from one iteration to the next. That changed nothing of the result (the
/// table repeats there), but the estimate moved by a whole period (6.7 mm RMS)
/// each time, so the iterations never settled and the verdict was POOR. A segment
/// now keeps its period unless another scores clearly (1 %) better.
TEST(SelfCalibrationPopulation, ATrackWithoutASignatureStillSettles) {
  const Outcome o = calibrate(60, tuning());
  SCOPED_TRACE(o.summary);
  for (const auto& l : o.iterations) std::printf("[ iteration] %s\n", l.c_str());
  ASSERT_TRUE(o.ok) << o.error;
  EXPECT_TRUE(o.good) << (o.problems.empty() ? std::string() : o.problems.front());
  for (const auto& pr : o.problems) EXPECT_EQ(pr.find("did not settle"), std::string::npos) << pr;
  EXPECT_EQ(o.position_failed, 0);
}

/// Motor 41 (held out) never settles to 0.05 um: from its 6th iteration on the
/// estimate goes back and forth by 0.05 to 0.09 um RMS, which the verdict tolerates
/// (unsettled_limit_m). Running on to the 12th only trades one of those neighbouring
/// solutions for another. The iterations stop once the change has stopped shrinking
/// twice in a row; the result is within that back-and-forth of the 12th iteration's,
/// and as good. (This was motor 8, at 0.08 um, until a segment kept its magnet period
/// on the table from one iteration to the next: motor 8 now converges in 5.)
TEST(SelfCalibrationPopulation, IterationsGoingBackAndForthStopBelowTheToleratedLimit) {
  const auto p = ve::sim::draw_population_motor(41, tuning());
  ve::sim::CalibrationRunConfig run;
  run.sweep_speed_mps = kSweepSpeedMps;
  std::vector<ve::core::ReferenceSegment> segments;
  std::string error;
  ASSERT_TRUE(ve::sim::record_calibration_run(p.hardware, p.sim, run, segments, error)) << error;
  for (auto& s : segments) s.reference_m.assign(s.reference_m.size(), std::nan(""));
  ve::core::Calibration cal[2];
  ve::core::SelfCalibrationReport rep[2];
  for (int k = 0; k < 2; ++k) {
    ve::core::SelfCalibrationConfig cfg;
    cfg.hall_delay_s = p.sim.imperfections.hall_delay_s;
    if (k == 0) cfg.stalled_iterations = 0;  // run on to cfg.iterations, as before the rule
    ASSERT_TRUE(ve::core::identify_without_reference(p.datasheet, segments, cfg, cal[k], rep[k], error)) << error;
    for (const auto& l : rep[k].iterations) std::printf("[ iteration %s] %s\n", k == 0 ? "on " : "cut", l.c_str());
    EXPECT_TRUE(rep[k].identification.good);
    for (const auto& pr : rep[k].identification.problems) ADD_FAILURE() << pr;
    EXPECT_FALSE(rep[k].converged);
  }
  EXPECT_FALSE(rep[0].stalled);
  EXPECT_EQ(rep[0].iterations.size(), 12u);
  EXPECT_TRUE(rep[1].stalled);
  EXPECT_LE(rep[1].iterations.size(), 9u);
  EXPECT_LE(rep[1].last_change_m, ve::core::SelfCalibrationConfig{}.unsettled_limit_m);
  // What the kept calibration reads against the one run on: the Hall position each
  // table gives on the same noiseless readings, at places spread over the travel,
  // differs by less than the back-and-forth the verdict tolerates.
  ASSERT_EQ(cal[0].table.v.size(), cal[1].table.v.size());
  ve::sim::SimSource sim(p.hardware, truth_config(p));
  const ve::core::HallArray array0(p.datasheet, cal[0].table), array1(p.datasheet, cal[1].table);
  const double home = ve::test::home_truth_m(p.hardware, truth_config(p), rep[0]);
  ASSERT_TRUE(std::isfinite(home));
  double sum = 0.0, sq = 0.0, worst = 0.0;
  int compared = 0;
  for (int k = 0; k < kCheckPlaces; ++k) {
    const double x = check_place(p.datasheet, k);
    const ve::core::RawSample s = noiseless_sample(sim, p.datasheet, x);
    const auto f0 = array0.solve(s, x - home), f1 = array1.solve(s, x - home);
    if (!f0.ok || !f1.ok) continue;
    const double d = f1.position_m - f0.position_m;
    sum += d, sq += d * d, worst = std::max(worst, std::abs(d)), ++compared;
  }
  ASSERT_GT(compared, 900);
  // About their mean: that is the two homes' difference, judged on its own below.
  const double mean_m = sum / compared;
  const double rms_m = std::sqrt(std::max(0.0, sq / compared - mean_m * mean_m));
  std::printf("[ stalled  ] %zu iterations instead of 12; positions differ by %.3f um RMS about their mean "
              "%.3f um, %.3f um at most, home by %.4f um\n",
              rep[1].iterations.size(), rms_m * 1e6, mean_m * 1e6, worst * 1e6, (cal[1].table.start_m - cal[0].table.start_m) * 1e6);
  EXPECT_LE(rms_m, ve::core::SelfCalibrationConfig{}.unsettled_limit_m);
  EXPECT_LE(std::abs(cal[1].table.start_m - cal[0].table.start_m), 0.5e-6);
}

}  // namespace
