// Accuracy on the realistic simulated motor (every imperfection on, as shipped in
// config/machines/sim-realistic.yaml), after calibration from a simulated
// calibration run: the paper's spec (5 um / 1.7 mm/s RMS, bias included), this
// product's stretch target (0.5 um / 0.1 mm/s), and honest sigmas.
#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "core/error_stats.hpp"
#include "core/identification.hpp"
#include "core/pipeline.hpp"
#include "core/status.hpp"
#include "sim/calibration_run.hpp"
#include "realistic_fixture.hpp"
#include "sim/sim_source.hpp"

namespace {

using ve::sim::MotionProfileConfig;

using ve::test::Realistic;
using ve::test::realistic;

struct Scenario {
  const char* name;
  MotionProfileConfig::Kind kind;
  double start_m, velocity_mps, acceleration_mps2;
  double t0_s, t1_s;  ///< evaluation window; t1 <= 0: to the end of the profile's steady phase
};

void PrintTo(const Scenario& s, std::ostream* os) { *os << s.name; }

ve::core::EstimateErrors run(const Realistic& r, const Scenario& sc, std::uint64_t seed) {
  ve::sim::SimConfig cfg = r.axis.driver.sim;
  cfg.realtime = false;
  cfg.noise_seed = seed;
  cfg.profile = MotionProfileConfig{};
  cfg.profile.kind = sc.kind;
  cfg.profile.start_m = sc.start_m;
  cfg.profile.velocity_mps = sc.velocity_mps;
  cfg.profile.acceleration_mps2 = sc.acceleration_mps2;
  cfg.profile.min_m = 0.02;
  cfg.profile.max_m = 0.98;
  ve::sim::SimSource sim(r.axis.motor, cfg);
  EXPECT_TRUE(sim.ok()) << sim.last_error();
  const double t1 = sc.t1_s > 0 ? sc.t1_s : sim.profile().steady_duration_s();
  ve::core::PipelineConfig pc;
  pc.motor = r.axis.motor;
  pc.sensors = r.cal.model;
  pc.calibrated = true;
  pc.start_position_m = sc.start_m;
  ve::core::AxisPipeline pipeline(pc, r.cal.table);
  ve::core::EstimateErrors e;
  ve::core::RawSample s;
  while (sim.read(s) == ve::drivers::ReadStatus::ok) {
    const double t = static_cast<double>(s.t_ns) * 1e-9;
    if (t > t1) break;
    const auto& est = pipeline.step(s);
    if (t < sc.t0_s) continue;
    const auto& truth = *sim.truth();
    e.add(est.position_m - truth.position_m, est.position_std_m, est.velocity_mps - truth.velocity_mps,
          est.velocity_std_mps, (est.status & ve::core::status::kValid) != 0);
  }
  return e;
}

class RealisticAccuracy : public ::testing::TestWithParam<std::tuple<std::string, Scenario>> {};

TEST_P(RealisticAccuracy, MeetsSpecAndTargetWithHonestSigma) {
  const auto& [machine, sc] = GetParam();
  const Realistic& r = realistic(machine);
  ASSERT_TRUE(r.report.good);
  std::uint64_t samples = 0, pos_inside = 0, vel_inside = 0;
  for (std::uint64_t seed : {101u, 202u}) {
    const auto e = run(r, sc, seed);
    samples += e.position_m.count();
    pos_inside += e.position_within_2sigma;
    vel_inside += e.velocity_within_2sigma;
    std::printf("[ figures  ] %-34s %-16s seed %3llu: position rms %.3f um (bias %+.3f, max %.3f) | velocity rms "
                "%.4f mm/s (bias %+.4f, max %.3f) | 2-sigma coverage %.1f %% / %.1f %%\n",
                machine.c_str(), sc.name, static_cast<unsigned long long>(seed), e.position_m.rms() * 1e6,
                e.position_m.bias() * 1e6, e.position_m.max_abs() * 1e6, e.velocity_mps.rms() * 1e3,
                e.velocity_mps.bias() * 1e3, e.velocity_mps.max_abs() * 1e3, 100 * e.position_coverage(),
                100 * e.velocity_coverage());
    ASSERT_GT(e.position_m.count(), 1000u);
    EXPECT_EQ(e.not_valid, 0u);
    // The paper's spec, RMS with the bias in it.
    EXPECT_LE(e.position_m.rms(), 5e-6);
    EXPECT_LE(e.velocity_mps.rms(), 1.7e-3);
    // This product's target beyond the spec.
    EXPECT_LE(e.position_m.rms(), 0.5e-6);
    EXPECT_LE(e.velocity_mps.rms(), 0.1e-3);
    // The published sigmas are honest: about 95 % of errors inside +-2 sigma; no run
    // may have too many outside (sigma too small).
    EXPECT_GE(e.position_coverage(), 0.85);
    EXPECT_GE(e.velocity_coverage(), 0.85);
  }
  // ... nor too few, over both runs: within one short run the errors are correlated
  // over tenths of a second (on the realistic machine at 5 m/s^2 one run has 91 % and
  // the other 99.6 % inside). At standstill the position's error is mostly what the
  // table makes of that one place (its noise, which sigma holds,
  // SensorModel::table_noise_v): one draw, inside 2 sigma or not, so whether sigma is
  // too large there is judged over many places (StandstillSigmaHoldsOverPlaces).
  const double pos_coverage = static_cast<double>(pos_inside) / static_cast<double>(samples);
  const double vel_coverage = static_cast<double>(vel_inside) / static_cast<double>(samples);
  if (sc.kind != MotionProfileConfig::Kind::standstill) {
    EXPECT_LE(pos_coverage, 0.995);
  }
  EXPECT_LE(vel_coverage, 0.995);
}

INSTANTIATE_TEST_SUITE_P(
    Scenarios, RealisticAccuracy,
    ::testing::Combine(::testing::Values(std::string("sim-realistic.yaml"), std::string("sim-realistic-frame-accel.yaml")),
                       ::testing::Values(Scenario{"standstill", MotionProfileConfig::Kind::standstill, 0.4321, 0, 0, 0.5, 4.0},
                                         Scenario{"constant_1mps", MotionProfileConfig::Kind::constant_velocity, 0.05, 1.0, 0, 0.1, 0},
                                         Scenario{"constant_5mps2", MotionProfileConfig::Kind::constant_acceleration, 0.05, 0.0, 5.0, 0.1, 0})),
    [](const auto& info) {
      std::string m = std::get<0>(info.param);
      m = m.substr(0, m.find('.'));
      for (char& c : m)
        if (c == '-') c = '_';
      return m + "_" + std::get<1>(info.param).name;
    });

// At standstill the position's error is what the table, the ADC's steps and the
// sensors make of that one place: sigma is honest if, over many places, the errors
// are about sigma in size (too many outside 2 sigma: sigma too small; errors far
// inside it everywhere: sigma too large, VALID withheld for nothing).
TEST(RealisticAccuracyStandstill, StandstillSigmaHoldsOverPlaces) {
  const Realistic& r = realistic("sim-realistic.yaml");
  constexpr int kPlaces = 24;
  const double pitch = r.axis.motor.magnet_pitch_m;
  double z2 = 0.0;
  int outside = 0;
  for (int k = 0; k < kPlaces; ++k) {
    // Two magnet periods' worth of places, not on the table's grid.
    const double x = 0.3 + 2.0 * pitch * (k + 0.37) / kPlaces;
    const Scenario sc{"standstill", MotionProfileConfig::Kind::standstill, x, 0, 0, 0.15, 0.3};
    const auto e = run(r, sc, 300u + static_cast<std::uint64_t>(k));
    ASSERT_GT(e.position_m.count(), 100u);
    // The mean error over the window against the mean sigma: the noise averages, what
    // belongs to the place stays.
    const double z = e.position_m.bias() / std::sqrt(e.position_std_m2_mean());
    z2 += z * z;
    if (std::abs(z) > 2.0) ++outside;
  }
  const double rms_z = std::sqrt(z2 / kPlaces);
  std::printf("[ figures  ] standstill at %d places: error / sigma %.2f RMS, %d outside 2 sigma\n", kPlaces, rms_z,
              outside);
  EXPECT_LE(outside, kPlaces / 6);  // about 1 in 20 for an honest sigma
  EXPECT_GE(rms_z, 0.4);
  EXPECT_LE(rms_z, 1.5);
}

TEST(RealisticCalibration, IdentifiesTheSimulatedSensorModel) {
  const Realistic& r = realistic("sim-realistic.yaml");
  const auto& im = r.axis.driver.sim.imperfections;
  const auto& m = r.cal.model;
  const auto& rep = r.report;
  std::printf("[ figures  ] identified: hall delay %.2f us, coil field %.4f mV/(m/s^2), accel scale %.5f, bias %.4f, "
              "delay %.1f us, vibration %.2f Hz %.4f m/s^2; table residual %.3f mV; Hall position in fast motion "
              "%.3f um (uncompensated %.3f um)\n",
              m.hall_delay_s * 1e6, m.coil_field_v_per_mps2 * 1e3, m.accel_scale, m.accel_bias_mps2,
              m.accel_delay_s * 1e6, m.frame_vibration_hz, m.frame_vibration_mps2, rep.table_residual_mv,
              rep.position_residual_um, rep.position_residual_uncompensated_um);
  EXPECT_TRUE(rep.good);
  EXPECT_NEAR(m.hall_delay_s, im.hall_delay_s, 1e-6);
  EXPECT_NEAR(m.coil_field_v_per_mps2, im.coil_field_v_per_mps2, 0.05 * im.coil_field_v_per_mps2);
  // Without a frame accelerometer the frame's recoil looks like a scale error.
  EXPECT_NEAR(m.accel_scale, (1.0 + im.accel_scale_error) * (1.0 + im.frame_reaction_ratio), 1e-3);
  EXPECT_NEAR(m.accel_bias_mps2, im.accel_bias_mps2, 3e-3);
  EXPECT_NEAR(m.accel_delay_s, im.accel_delay_s, 20e-6);
  EXPECT_NEAR(m.frame_vibration_hz, im.frame_vibration_hz, 0.2);
  EXPECT_NEAR(m.frame_vibration_mps2, im.frame_vibration_mps2, 0.005);
  EXPECT_LT(rep.position_residual_um, 1.0);
  EXPECT_GT(rep.position_residual_uncompensated_um, 5.0 * rep.position_residual_um);

  const Realistic& f = realistic("sim-realistic-frame-accel.yaml");
  EXPECT_TRUE(f.report.frame_accelerometer_used);
  EXPECT_NEAR(f.cal.model.accel_scale, 1.0 + im.accel_scale_error, 1e-3);
  EXPECT_EQ(f.cal.model.frame_vibration_hz, 0.0) << "the frame accelerometer removes the vibration";
}

TEST(RealisticCalibration, ShippedCalibrationsAreWhatCalibrateProduces) {
  // The calibration files in config/calibration come from `virtual-encoder
  // calibrate` on these machines; the run is deterministic, so they must match.
  for (const char* machine : {"sim-realistic.yaml", "sim-realistic-frame-accel.yaml"}) {
    const Realistic& r = realistic(machine);
    ASSERT_FALSE(r.axis.calibration_file.empty()) << machine;
    const auto shipped = ve::config::load_calibration_file(r.axis.calibration_file, r.axis.motor);
    ASSERT_TRUE(shipped.ok()) << ve::config::to_string(shipped.errors);
    EXPECT_EQ(shipped.calibration.info.id, ve::core::calibration_checksum(r.cal))
        << machine << ": regenerate " << r.axis.calibration_file << " with `virtual-encoder calibrate`";
  }
}

TEST(RealisticCalibration, WithoutFastMotionSaysWhatIsMissing) {
  const Realistic& r = realistic("sim-realistic.yaml");
  std::vector<ve::core::ReferenceSegment> segments;
  std::string error;
  ve::sim::CalibrationRunConfig run;
  run.dynamic_duration_s = 0.0;
  ASSERT_TRUE(ve::sim::record_calibration_run(r.axis.motor, r.axis.driver.sim, run, segments, error)) << error;
  ve::core::Calibration cal;
  ve::core::IdentificationReport rep;
  ASSERT_TRUE(ve::core::identify_with_reference(r.axis.motor, segments, {}, cal, rep, error)) << error;
  EXPECT_FALSE(rep.good);
  ASSERT_FALSE(rep.problems.empty());
  EXPECT_NE(rep.problems.front().find("fast motion"), std::string::npos) << rep.problems.front();
  // The slow sweep alone still gives the Hall delay.
  EXPECT_NEAR(cal.model.hall_delay_s, r.axis.driver.sim.imperfections.hall_delay_s, 1e-6);
}

}  // namespace
