// Accuracy on a population of motors: calibrate a drawn motor (with or without a
// ruler) from a simulated calibration run, then run the five motion scenarios
// under a temperature condition and score the product's estimate against the
// simulator's truth. Shared by the population benchmark (tests/bench) and the
// three-motor guard in the unit tests; header-only so that both can build it.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/error_stats.hpp"
#include "core/identification.hpp"
#include "core/pipeline.hpp"
#include "core/self_calibration.hpp"
#include "core/status.hpp"
#include "core/thermal_calibration.hpp"
#include "sim/calibration_run.hpp"
#include "sim/population.hpp"
#include "sim/sim_source.hpp"
#include "../unit/home_truth.hpp"

namespace ve::bench {

using Kind = sim::MotionProfileConfig::Kind;

struct PopScenario {
  std::string name;
  sim::MotionProfileConfig profile;
  double t0_s = 0.0, t1_s = 0.0;  ///< evaluation window; t1 from the profile when until_steady_end
  bool until_steady_end = false;
};

/// The five scenarios of the accuracy benchmark, placed on this motor's travel.
/// A short motor cannot hold the full multisine or reach 1.5 m/s: the speed is
/// lowered until the profile fits (said in the name).
inline std::vector<PopScenario> population_scenarios(double travel_m) {
  std::vector<PopScenario> v;
  auto base = [&](const char* name, Kind kind) {
    PopScenario s;
    s.name = name;
    s.profile.kind = kind;
    s.profile.min_m = 0.02 * travel_m;
    s.profile.max_m = 0.98 * travel_m;
    s.profile.start_m = 0.5 * travel_m;
    return s;
  };
  {
    PopScenario s = base("standstill", Kind::standstill);
    s.profile.start_m = 0.4321 * travel_m;
    s.t0_s = 0.5;
    s.t1_s = 4.0;
    v.push_back(s);
  }
  {
    PopScenario s = base("1 m/s", Kind::constant_velocity);
    s.profile.start_m = 0.03 * travel_m;
    s.profile.velocity_mps = 1.0;
    s.t0_s = 0.05;
    s.until_steady_end = true;
    v.push_back(s);
  }
  {
    PopScenario s = base("5 m/s^2", Kind::constant_acceleration);
    s.profile.start_m = 0.03 * travel_m;
    s.profile.velocity_mps = 0.0;
    s.profile.acceleration_mps2 = 5.0;
    s.t0_s = 0.05;
    s.until_steady_end = true;
    v.push_back(s);
  }
  {
    PopScenario s = base("multisine", Kind::multisine);
    s.profile.max_velocity_mps = 2.0;
    s.profile.max_acceleration_mps2 = 10.0;
    s.profile.min_m = 0.05 * travel_m;
    s.profile.max_m = 0.95 * travel_m;
    s.t0_s = 0.5;
    s.t1_s = 10.0;
    v.push_back(s);
  }
  {
    PopScenario s = base("point-to-point", Kind::point_to_point);
    s.profile.max_velocity_mps = 1.5;
    s.profile.max_acceleration_mps2 = 10.0;
    s.profile.max_jerk_mps3 = 250.0;
    s.profile.dwell_s = 0.1;
    s.profile.min_m = 0.05 * travel_m;
    s.profile.max_m = 0.95 * travel_m;
    s.t0_s = 0.5;
    s.t1_s = 10.0;
    v.push_back(s);
  }
  return v;
}

/// The accuracy VALID stands for in the benchmark: the paper's spec, at 2 sigma.
constexpr double kValidPositionAccuracyM = 5e-6;
constexpr double kValidVelocityAccuracyMps = 1.7e-3;

/// The population runs' sensor-noise seeds. Draw 0 is the committed tables': 1000 + the
/// motor's seed for the scenario runs and 2000 + it for the fault probe; each further
/// draw adds kNoiseDrawStride, beyond any motor seed.
constexpr std::uint64_t kNoiseDrawStride = 1000000;
constexpr std::uint64_t run_noise_seed(std::uint64_t motor_seed, std::uint64_t draw = 0) {
  return 1000 + motor_seed + kNoiseDrawStride * draw;
}
constexpr std::uint64_t probe_noise_seed(std::uint64_t motor_seed, std::uint64_t draw = 0) {
  return 2000 + motor_seed + kNoiseDrawStride * draw;
}

enum class Condition { as_calibrated, ramp_plus_10k, step_minus_10k };
inline const char* condition_name(Condition c) {
  switch (c) {
    case Condition::as_calibrated: return "as calibrated";
    case Condition::ramp_plus_10k: return "+10 K ramp";
    case Condition::step_minus_10k: return "-10 K step";
  }
  return "?";
}

struct CalibrationOutcome {
  bool ok = false;     ///< a calibration came out at all
  bool good = false;   ///< its own verdict
  core::Calibration cal;
  std::vector<std::string> problems;
  std::string error;
  double seconds = 0.0;  ///< identification's compute time (the recording excluded)
  /// The report's fast-motion Hall position residual, the fixes' own noise and the
  /// residual beyond it [um].
  double fast_residual_um = 0.0, fast_noise_um = 0.0, fast_beyond_noise_um = 0.0;
  /// The readings' scatter about the table [mV]; without a ruler also the Hall
  /// positions' straight-line residual along the slow passes [um].
  double table_residual_mv = 0.0, pass_line_residual_um = 0.0;
  /// Where the calibration's position 0 lies in the simulator's frame: 0 with a
  /// ruler (the simulator is the ruler); without one, home (a track feature).
  double zero_m = 0.0;
  bool with_ruler = true;
};

/// Home of a calibration without a ruler (sensor 0's first whole positive
/// half-wave) located on the simulator's own noiseless sensor 0, as the ADC reads
/// it, near where the calibration says it is (tests/unit/home_truth.hpp).
inline double home_in_sim_frame(const core::MotorConfig& hardware, const sim::SimConfig& simcfg,
                                const core::SelfCalibrationReport& rep) {
  sim::SimConfig cfg = simcfg;
  cfg.profile = sim::MotionProfileConfig{};
  cfg.profile.kind = Kind::standstill;
  cfg.profile.min_m = 0.0;
  cfg.profile.max_m = hardware.travel_m;
  cfg.profile.start_m = 0.5 * hardware.travel_m;
  if (!sim::SimSource(hardware, cfg).ok()) return std::nan("");
  return test::home_truth_m(hardware, cfg, rep);
}

/// The calibration run a commissioning engineer would record on this motor.
inline sim::CalibrationRunConfig population_calibration_run() {
  sim::CalibrationRunConfig run;
  run.sweep_speed_mps = 0.05;
  return run;
}

inline bool record_population_calibration(const sim::PopulationMotor& p, std::vector<core::ReferenceSegment>& segments,
                                          std::string& error) {
  return sim::record_calibration_run(p.hardware, p.sim, population_calibration_run(), segments, error);
}

/// Calibrates from a recorded calibration run (the reference column is blanked
/// for the ruler-less calibration, which is given the Hall delay as the hardware's
/// design would give it).
inline CalibrationOutcome calibrate_population_motor(const sim::PopulationMotor& p,
                                                     std::vector<core::ReferenceSegment> segments, bool with_ruler) {
  CalibrationOutcome o;
  o.with_ruler = with_ruler;
  const auto t0 = std::chrono::steady_clock::now();
  if (with_ruler) {
    core::IdentificationReport rep;
    o.ok = core::identify_with_reference(p.datasheet, segments, {}, o.cal, rep, o.error);
    o.good = o.ok && rep.good;
    o.problems = rep.problems;
    o.fast_residual_um = rep.position_residual_um;
    o.fast_noise_um = rep.position_noise_um;
    o.fast_beyond_noise_um = rep.position_residual_beyond_noise_um;
    o.table_residual_mv = rep.table_residual_mv;
  } else {
    for (auto& s : segments) s.reference_m.assign(s.reference_m.size(), std::nan(""));
    core::SelfCalibrationConfig cfg;
    cfg.hall_delay_s = p.sim.imperfections.hall_delay_s;
    core::SelfCalibrationReport rep;
    o.ok = core::identify_without_reference(p.datasheet, segments, cfg, o.cal, rep, o.error);
    o.good = o.ok && rep.identification.good;
    o.problems = rep.identification.problems;
    o.fast_residual_um = rep.identification.position_residual_um;
    o.fast_noise_um = rep.identification.position_noise_um;
    o.fast_beyond_noise_um = rep.identification.position_residual_beyond_noise_um;
    o.table_residual_mv = rep.identification.table_residual_mv;
    o.pass_line_residual_um = rep.pass_line_residual_m * 1e6;
    if (o.ok) o.zero_m = home_in_sim_frame(p.hardware, p.sim, rep);
  }
  o.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return o;
}

/// A second calibration run recorded `rise_k` away from the first's temperature
/// (the motor warmed by running, or a cold shift), as a commissioning engineer
/// would record it for a thermal calibration.
inline bool record_population_thermal_run(const sim::PopulationMotor& p, double rise_k,
                                          std::vector<core::ReferenceSegment>& segments, std::string& error) {
  sim::SimConfig cfg = p.sim;
  cfg.temperature.profile = sim::TemperatureConfig::Profile::constant;
  cfg.temperature.offset_k = rise_k;
  cfg.noise_seed = p.sim.noise_seed + 7919;
  return sim::record_calibration_run(p.hardware, cfg, population_calibration_run(), segments, error);
}

/// Thermal calibration of `c` from that run (its ruler column blanked when `c` was
/// made without a ruler): on success c.cal.model holds the sensors' coefficients.
inline bool thermal_calibrate_population_motor(const sim::PopulationMotor& p,
                                               std::vector<core::ReferenceSegment> segments, CalibrationOutcome& c,
                                               core::ThermalCalibrationReport& report, std::string& error) {
  if (!c.with_ruler)
    for (auto& s : segments) s.reference_m.assign(s.reference_m.size(), std::nan(""));
  core::SensorModel model;
  if (!core::fit_thermal_coefficients(p.datasheet, c.cal, segments, {}, model, report, error)) return false;
  c.cal.model = model;
  return true;
}

struct FaultProbe {
  bool inject = false;
  int sensor = 0;
  double at_s = 0.0;  ///< a dead sensor (stuck at its zero-field output) from then on
  /// Or another fault of the sensor from then on (with its magnitude, as in sim::FaultConfig).
  sim::FaultConfig::Kind kind = sim::FaultConfig::Kind::hall_stuck_mid;
  double magnitude = 0.0;
};

struct RunResult {
  bool ok = false;
  std::string error;
  core::EstimateErrors err;     ///< over the window, in the calibration's frame
  std::uint64_t samples = 0;
  std::uint64_t valid = 0;      ///< VALID samples in the window
  double max_valid_error_m = 0.0;  ///< largest |position error| while VALID in the window
  std::uint32_t flagged = 0;    ///< Hall sensors ever judged faulty (whole run)
  double detect_s = -1.0;       ///< fault probe: time from injection to the sensor's flag; < 0: never
  bool probe_flagged_before = false;  ///< fault probe: the sensor was flagged before it failed
  double window_s = 0.0;
  /// Without a ruler: the position error an exact calibration would still have,
  /// because the track is its only length (SimSource::track_scale_error over the
  /// stretch the calibration's slow passes crossed, times the distance from home),
  /// RMS over the window; and the product's
  /// error with that part taken out, RMS (what the calibration and the estimator
  /// add). Both 0 with a ruler.
  double track_floor_rms_m = 0.0, beyond_floor_rms_m = 0.0;
  double valid_fraction() const { return samples ? static_cast<double>(valid) / samples : 0.0; }
};

/// Runs one scenario under one temperature condition with noise seed `noise_seed`.
/// Every estimate, from the first sample on (not only the window's), as it is made.
using SampleObserver = std::function<void(double t_s, const core::EncoderEstimate& estimate,
                                          const core::AxisPipeline& pipeline, const sim::SimSource& source)>;

inline RunResult run_population_scenario(const sim::PopulationMotor& p, const CalibrationOutcome& c,
                                         const PopScenario& sc, Condition cond, std::uint64_t noise_seed,
                                         const FaultProbe& probe = {}, const SampleObserver& observe = {}) {
  RunResult r;
  sim::SimConfig cfg = p.sim;
  cfg.realtime = false;
  cfg.noise_seed = noise_seed;
  cfg.profile = sc.profile;
  // A short motor cannot hold the full motion: slow it down until it fits.
  for (int i = 0; i < 30 && !sim::MotionProfile::create(cfg.profile, p.hardware.travel_m); ++i) {
    cfg.profile.max_velocity_mps *= 0.85;
    cfg.profile.velocity_mps *= 0.85;
    cfg.profile.acceleration_mps2 *= 0.85;
  }
  {
    sim::SimSource probe_src(p.hardware, cfg);
    if (!probe_src.ok()) {
      r.error = probe_src.last_error();
      return r;
    }
    const double t1 = sc.until_steady_end ? std::min(20.0, probe_src.profile().steady_duration_s()) : sc.t1_s;
    r.window_s = t1 - sc.t0_s;
    cfg.duration_s = t1 + 0.5 / p.hardware.sample_rate_hz;
  }
  const double t0 = sc.t0_s, t1 = sc.t0_s + r.window_s;
  switch (cond) {
    case Condition::as_calibrated: break;
    case Condition::ramp_plus_10k:
      // Warming at 10 K per minute, the window ending 10 K above the calibration:
      // the estimator starts on a motor already warmer than at calibration.
      cfg.temperature.profile = sim::TemperatureConfig::Profile::ramp;
      cfg.temperature.delta_k = 10.0;
      cfg.temperature.start_s = 0.0;
      cfg.temperature.duration_s = 60.0;
      cfg.temperature.offset_k = 10.0 - 10.0 * t1 / 60.0;
      break;
    case Condition::step_minus_10k:
      // 10 K colder than at calibration from the first sample: the step happened
      // between calibration and the run (a motor's thermal mass makes a step
      // during motion take minutes, not a sample).
      cfg.temperature.profile = sim::TemperatureConfig::Profile::constant;
      cfg.temperature.offset_k = -10.0;
      break;
  }
  if (probe.inject) {
    cfg.fault_count = 1;
    cfg.faults[0].kind = probe.kind;
    cfg.faults[0].magnitude = probe.magnitude;
    cfg.faults[0].sensor = probe.sensor;
    cfg.faults[0].start_s = probe.at_s;
  }
  sim::SimSource src(p.hardware, cfg);
  if (!src.ok()) {
    r.error = src.last_error();
    return r;
  }
  core::PipelineConfig pc;
  pc.motor = p.datasheet;
  pc.motor.filter.valid_position_accuracy_m = kValidPositionAccuracyM;
  pc.motor.filter.valid_velocity_accuracy_mps = kValidVelocityAccuracyMps;
  pc.sensors = c.cal.model;
  pc.calibrated = true;
  pc.start_position_known = true;
  pc.start_position_m = cfg.profile.start_m - c.zero_m;
  core::AxisPipeline pipeline(pc, c.cal.table);
  // The scale of the stretch of track the calibration's slow passes crossed (the
  // table's trusted stretch), which is all a calibration without a ruler can take
  // its metre from: on a short track the magnets beyond it change a line through
  // the whole travel by tens of ppm (motor 17: -10 ppm over the travel, +63 ppm
  // over the stretch swept).
  const auto& model = c.cal.model;
  const double track_scale =
      c.with_ruler ? 0.0
      : model.trusted_span_known()
          ? src.track_scale_error(c.zero_m + model.table_trusted_from_m, c.zero_m + model.table_trusted_to_m)
          : src.track_scale_error(0.0, p.hardware.travel_m);
  double floor_sq = 0.0, beyond_sq = 0.0;
  core::RawSample s;
  const std::uint32_t probe_bit = probe.inject ? 1u << probe.sensor : 0u;
  while (src.read(s) == drivers::ReadStatus::ok) {
    const double t = static_cast<double>(s.t_ns) * 1e-9;
    const auto& e = pipeline.step(s);
    if (observe) observe(t, e, pipeline, src);
    r.flagged |= e.hall_faulty_mask & ~probe_bit;
    if (probe.inject && t < probe.at_s && (e.hall_faulty_mask & probe_bit)) r.probe_flagged_before = true;
    if (probe.inject && r.detect_s < 0.0 && t >= probe.at_s && (e.hall_faulty_mask & probe_bit))
      r.detect_s = t - probe.at_s;
    if (t < t0 || t > t1) continue;
    const auto& tr = *src.truth();
    const bool valid = (e.status & core::status::kValid) != 0;
    r.err.add(e.position_m - (tr.position_m - c.zero_m), e.position_std_m, e.velocity_mps - tr.velocity_mps,
              e.velocity_std_mps, valid);
    ++r.samples;
    {
      const double floor = -track_scale * (tr.position_m - c.zero_m);
      const double err = e.position_m - (tr.position_m - c.zero_m);
      floor_sq += floor * floor;
      beyond_sq += (err - floor) * (err - floor);
    }
    if (valid) {
      ++r.valid;
      r.max_valid_error_m = std::max(r.max_valid_error_m, std::abs(e.position_m - (tr.position_m - c.zero_m)));
    }
  }
  r.ok = r.samples > 0;
  if (!r.ok) r.error = "no sample in the window";
  if (r.ok) {
    r.track_floor_rms_m = std::sqrt(floor_sq / static_cast<double>(r.samples));
    r.beyond_floor_rms_m = std::sqrt(beyond_sq / static_cast<double>(r.samples));
  }
  return r;
}

}  // namespace ve::bench
