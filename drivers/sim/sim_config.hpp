// Configuration of the simulated motor: motion profile, imperfections, timing.
// The nominal motor (pitch, sensors, ADC) comes from core::MotorConfig; this adds
// what only a simulator has.
#pragma once

#include <cstdint>

namespace ve::sim {

struct MotionProfileConfig {
  enum class Kind { standstill, constant_velocity, constant_acceleration, multisine, shuttle, point_to_point };
  Kind kind = Kind::multisine;
  double start_m = 0.5;               ///< position at t = 0 [m]
  double velocity_mps = 1.0;          ///< constant_velocity: speed; constant_acceleration: initial speed
  double acceleration_mps2 = 5.0;     ///< constant_acceleration
  double max_velocity_mps = 2.0;      ///< multisine, shuttle, point_to_point: peak speed
  double max_acceleration_mps2 = 10.0;///< multisine, shuttle, point_to_point: peak acceleration
  double min_m = 0.05;                ///< shuttle, point_to_point: lower end; all profiles stay above it
  double max_m = 0.95;                ///< shuttle, point_to_point: upper end; all profiles stay below it
  double max_jerk_mps3 = 250.0;       ///< point_to_point: peak jerk
  double dwell_s = 0.1;               ///< point_to_point: rest at each end before moving back
};

/// Largest |ImperfectionConfig::field_third_harmonic|: beyond 1/3 the field would
/// cross zero inside a magnet.
inline constexpr double kMaxThirdHarmonic = 0.3;

/// Deviations of the simulated hardware from the nominal motor. All zero (and
/// frame_accelerometer false): the ideal motor of the paper, bit for bit what the
/// simulator produced before the imperfections existed. (The accuracy work turns them on.)
struct ImperfectionConfig {
  std::uint64_t track_seed = 7;             ///< fixes magnet tolerances so calibration and run see one track

  // ---- magnet track and Hall sensors
  double magnet_strength_std = 0.0;         ///< relative, per magnet period
  double magnet_placement_std_m = 0.0;      ///< per magnet boundary
  /// Relative third harmonic of the track field: the normalised field is
  /// sin(theta) + h3 sin(3 theta), theta the local magnet phase. |h3| <= 0.3
  /// (so the field crosses zero only at the magnet boundaries); +0.03 flattens the tops.
  double field_third_harmonic = 0.0;
  double sensor_placement_std_m = 0.0;
  double sensor_gain_std = 0.0;             ///< relative
  double sensor_offset_std_v = 0.0;
  double hall_delay_s = 0.0;                ///< the Halls see the carriage at t - hall_delay_s
  /// Field of the motor coils on the Halls: a common-mode offset k * a added to every
  /// Hall output, a the carriage acceleration (standing in for the motor force) at the
  /// Halls' own (delayed) sample instant [V per m/s^2].
  double coil_field_v_per_mps2 = 0.0;

  // ---- accelerometer on the carriage: reads (1 + scale) * a_inertial(t - d) + bias(t) + noise
  double accel_bias_mps2 = 0.0;             ///< bias at the first sample read
  double accel_scale_error = 0.0;           ///< relative, +0.005 reads 0.5 % high
  /// The bias random-walks from accel_bias_mps2: each later sample adds
  /// N(0, (rw sqrt(Ts))^2), so after T seconds its std is rw sqrt(T) [m/s^2 / sqrt(s)].
  double accel_bias_random_walk_mps2_per_sqrt_s = 0.0;
  double accel_delay_s = 0.0;               ///< both accelerometers read the motion at t - accel_delay_s [s]

  // ---- stationary frame: a_frame(t) = frame_reaction_ratio * a(t) + frame_vibration_mps2 sin(2 pi f t)
  /// Frame acceleration per carriage acceleration (the motor force pushes the frame
  /// back: negative, about -carriage mass / frame mass).
  double frame_reaction_ratio = 0.0;
  double frame_vibration_mps2 = 0.0;        ///< amplitude of the frame's own vibration [m/s^2]
  double frame_vibration_hz = 35.0;         ///< its frequency f [Hz]
  /// A second accelerometer on the frame (as in the paper): RawSample::accel_base_mps2 =
  /// a_frame(t - accel_delay_s) + white noise (motor.accelerometer.noise_mps2, its own
  /// stream); no bias, scale error or bias walk (a reference-grade sensor).
  bool frame_accelerometer = false;
};

/// Temperature of the motor relative to its calibration, and what it does to the Hall
/// signals. The temperature rise at simulated time t (the profile's clock) is
///   dT(t) = offset_k + profile part, the profile part being
///   constant: delta_k throughout;
///   step:     0 before start_s, delta_k from start_s on;
///   ramp:     0 before start_s, then linear to delta_k at start_s + duration_s, then held;
///   warmup:   0 before start_s, then delta_k (1 - exp(-(t - start_s) / duration_s)).
/// Hall i then reads offset_v + offset_i + offset_tc_i dT + amplitude_v gain_i (1 +
/// gain_tc_i dT) (1 + magnet_remanence_per_k dT) field: the magnets' remanence scales
/// every magnet's field alike; each sensor has its own sensitivity and zero-field offset
/// coefficients, drawn once from the track seed (a property of the sensors):
/// gain_tc_i = hall_gain_tc_per_k + hall_gain_tc_std_per_k N(0,1), offset_tc_i =
/// hall_offset_tc_std_v_per_k N(0,1). dT = 0 (the defaults): bit for bit the simulator
/// without a temperature model, whatever the coefficients.
struct TemperatureConfig {
  enum class Profile { constant, step, ramp, warmup };
  Profile profile = Profile::constant;
  double delta_k = 0.0;                     ///< change of the profile part [K], may be negative
  double start_s = 0.0;                     ///< step / ramp / warmup: when the change begins [s]
  double duration_s = 0.0;                  ///< ramp: time to reach delta_k; warmup: time constant [s] (> 0)
  double offset_k = 0.0;                    ///< constant rise present from t = 0 [K]

  double magnet_remanence_per_k = -0.0012;  ///< relative field change per K (NdFeB: -0.12 %/K)
  double hall_gain_tc_per_k = -0.001;       ///< mean relative Hall sensitivity change per K
  double hall_gain_tc_std_per_k = 0.0003;   ///< its spread between sensors [1/K]
  double hall_offset_tc_std_v_per_k = 0.0003;  ///< zero-field offset drift, one sigma per sensor [V/K]
  double reference_c = 25.0;                ///< temperature at calibration [deg C]

  /// The sensor node reports its temperature: RawSample::temperature_c = reference_c +
  /// dT + N(0, report_noise_k), rounded to a multiple of report_resolution_k (0: not rounded).
  bool report = false;
  double report_noise_k = 0.1;
  double report_resolution_k = 0.0625;
};

/// Limits of TemperatureConfig: |offset_k| + |delta_k| (the largest |dT|), |remanence| and
/// |mean gain coefficient|, the gain coefficients' spread, the offset drift's spread; so
/// every factor (1 + c dT) stays positive (>= 0.1 even for a 6-sigma sensor).
inline constexpr double kMaxTemperatureRiseK = 100.0;
inline constexpr double kMaxTemperatureCoefficientPerK = 0.003;
inline constexpr double kMaxTemperatureCoefficientStdPerK = 0.001;
inline constexpr double kMaxHallOffsetDriftStdVPerK = 0.01;

/// A sensor fault injected at a chosen time, so every failure case is a test.
struct FaultConfig {
  enum class Kind {
    hall_stuck_high,    ///< Hall `sensor` reads the top rail
    hall_stuck_low,     ///< ... the bottom rail
    hall_stuck_mid,     ///< ... its zero-field output (a dead sensor behind its amplifier)
    hall_noisy,         ///< ... extra white noise of `magnitude` volts
    hall_intermittent,  ///< ... its sample is missing with probability `magnitude`
    hall_spikes,        ///< ... a `magnitude`-volt spike with probability 1 % per sample
    accel_dead,         ///< the accelerometer reads 0
    accel_saturated,    ///< ... its full scale
    accel_bias,         ///< ... an extra bias of `magnitude` m/s^2
    accel_missing,      ///< no accelerometer sample at all
    no_samples,         ///< the sensor node sends nothing (a stalled node): the samples of the
                        ///< window are lost; in real time read() returns timeout meanwhile
  };
  Kind kind = Kind::hall_stuck_high;
  int sensor = 0;          ///< Hall index, for the hall_* kinds
  double start_s = 0.0;    ///< from this simulated time on ...
  double end_s = 1e300;    ///< ... until this one
  double magnitude = 0.0;
};

/// Most faults one simulation injects (fixed, so the source never allocates).
inline constexpr int kMaxFaults = 4;

/// A silent simulated node (FaultConfig::Kind::no_samples) in real time: read() returns
/// ReadStatus::timeout after this long without a sample, as the SocketCAN driver does
/// after its default timeout_ms [ns].
inline constexpr std::int64_t kSilentReadTimeoutNs = 20000000;

struct SimConfig {
  MotionProfileConfig profile;
  ImperfectionConfig imperfections;
  TemperatureConfig temperature;
  FaultConfig faults[kMaxFaults];
  int fault_count = 0;
  std::uint64_t noise_seed = 1;  ///< seeds the per-sample sensor noise
  bool realtime = true;          ///< true: one sample per period of wall time; false: as fast as possible
  double duration_s = 0.0;       ///< > 0: the source ends (end_of_stream) after this much simulated time [s]
};

}  // namespace ve::sim
