// Nominal description of a motor and its sensors, plus the estimator tuning.
// Plain structs with defaults in class; units in the names. Only the config
// loader (component/config) knows YAML.
#pragma once

#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "sample.hpp"

namespace ve::core {

struct HallConfig {
  int count = 4;
  /// Position of each sensor along the moving part relative to sensor 0 [m].
  /// Empty: sensors spaced by spacing_m (the paper: pitch / 8).
  std::vector<double> offsets_m;
  double spacing_m = 0.012 / 8.0;
  double offset_v = 2.5;                      ///< output at zero field [V]
  double amplitude_v = 2.5 * std::sqrt(2.0);  ///< unclamped peak about offset_v [V]
  double noise_v = 0.0006;                    ///< output noise, one sigma [V]
  /// Readings closer than this to an ADC rail count as saturated and carry no position [V].
  double saturation_margin_v = 0.05;

  double offset_of(int i) const {
    return offsets_m.empty() ? i * spacing_m : offsets_m[static_cast<std::size_t>(i)];
  }
};

struct AdcConfig {
  int bits = 12;
  double min_v = 0.0;
  double max_v = 5.0;
  double lsb_v() const { return (max_v - min_v) / static_cast<double>((1 << bits) - 1); }
};

struct AccelerometerConfig {
  double noise_mps2 = 0.02;   ///< white noise per sample, one sigma [m/s^2]
  double range_mps2 = 160.0;  ///< full scale; readings at or beyond it are saturated [m/s^2]
};

/// How the real sensors deviate from ideal ones in ways the estimator compensates.
/// Identified by calibration (stored in the calibration file); the defaults are
/// ideal sensors.
struct SensorModel {
  /// The Halls are sampled this long before the sample instant (filters, ADC) [s].
  double hall_delay_s = 0.0;
  /// Common-mode Hall offset from the motor coils' field, proportional to the
  /// force and so to the acceleration [V per m/s^2].
  double coil_field_v_per_mps2 = 0.0;
  /// How well the calibration knows it, one sigma (0: not known, taken as exact). A
  /// coil field error moves every reading alike in proportion to the acceleration,
  /// and the fix by its sensitivity to such a common offset, which the published
  /// sigmas hold (AxisPipeline) [V per m/s^2].
  double coil_field_std_v_per_mps2 = 0.0;
  /// The accelerometer reads the acceleration this long before the sample instant [s].
  double accel_delay_s = 0.0;
  /// How well the calibration knows that delay, one sigma (0: not known, taken as
  /// exact). A delay error makes the filter read the acceleration at the wrong
  /// instant: at every change of acceleration a velocity error of about the error
  /// times the change, which the published sigmas hold (FusionFilter) [s].
  double accel_delay_std_s = 0.0;
  /// Without a ruler: how far the fixes in the calibration's fast motion stayed from
  /// the motion the accelerometer and the slow passes made of it, beyond their own
  /// noise: what the self-made table leaves in a fix from one place to the next
  /// (magnets the slow sweep placed slightly wrong). The filter takes it as part of
  /// every fix's noise; 0 with a ruler, whose calibration refuses more than 1 um [m].
  double hall_fix_excess_std_m = 0.0;
  /// Accelerometer reading = accel_scale * a + accel_bias_mps2 (initial values;
  /// the filter keeps estimating both).
  double accel_bias_mps2 = 0.0;
  double accel_scale = 1.0;
  /// A vibration of the frame that the moving accelerometer feels and the Halls
  /// do not (the track is on the frame): its frequency and amplitude as
  /// identified. 0 Hz: none, or removed by a frame accelerometer.
  double frame_vibration_hz = 0.0;
  double frame_vibration_mps2 = 0.0;
  /// The sensor node's mean temperature during the calibration run [deg C]; NaN:
  /// not reported. With it and a reported temperature while running, the Hall
  /// adaptation knows how far the motor is from its calibration (hall_adaptation.hpp).
  double temperature_c = std::numeric_limits<double>::quiet_NaN();
  /// How far the table's length scale may be from the true metre, one sigma
  /// (dimensionless). 0 with a ruler: the ruler set the scale. Without one the
  /// magnet track is the only length, and its magnets' placement errors make its
  /// scale uncertain (self_calibration.hpp); the position's sigma grows by this
  /// times the distance from position 0 (home).
  double track_scale_std = 0.0;
  /// Calibration without a ruler: the stretch of the table made from the slow passes,
  /// in the table's frame [m] (NaN: the whole table, as with a ruler). Beyond it, within
  /// about a magnet period of either end of the sweep, the carriage was turning: the
  /// table there rests on the accelerometer's bridge between the passes, good only to
  /// table_outside_std_m (one sigma, the largest the bridges' disagreement shows). The
  /// position's sigma says so there, and it is never VALID.
  double table_trusted_from_m = std::numeric_limits<double>::quiet_NaN();
  double table_trusted_to_m = std::numeric_limits<double>::quiet_NaN();
  double table_outside_std_m = 0.0;
  /// The table's own error at any one place, one sigma, as a sensor reading [V]: each
  /// node is a fit to the few sweep readings near it, whose noise it keeps. Measured by
  /// the calibration from its forward and backward passes (independent readings of the
  /// same track). It repeats wherever the carriage stands, so no averaging of fixes
  /// there removes it; in motion the filter averages it over the nodes it crosses. 0:
  /// not measured (older files), taken as nothing.
  double table_noise_v = 0.0;
  /// Each Hall sensor's own temperature coefficients, measured by a thermal
  /// calibration (thermal_calibration.hpp): a second recording of the motor some
  /// kelvin away from this calibration, fitted against its table. Without them the
  /// estimator knows only the data sheet's spread of the coefficients, and at
  /// standstill a sensor's offset drift cannot be told from a position (at 10 K, a
  /// few um); with them each sensor's gain and offset follow the rise the node
  /// reports or the fixes' common gain reads (HallAdaptation). The rise is counted in
  /// the kelvin of common_tc_per_k: the node's when the thermal recording reported a
  /// temperature, else the data sheet's coefficient read through the common gain.
  bool thermal_known = false;
  /// The rise of the thermal recording over this calibration [K].
  double thermal_rise_k = 0.0;
  /// The gain all sensors share, per kelvin, as measured (NaN: the data sheet's
  /// remanence + Hall sensitivity coefficients), and its relative uncertainty.
  double common_tc_per_k = std::numeric_limits<double>::quiet_NaN();
  double common_tc_rel_std = std::numeric_limits<double>::quiet_NaN();
  /// Per sensor: its own gain change on top of the common one [1/K], its offset
  /// change [V/K], and how well each is known, one sigma (the fit's own
  /// uncertainty and how far a sensor may be from linear over the rise).
  std::array<double, kMaxHalls> hall_gain_tc_per_k{}, hall_offset_tc_v_per_k{};
  std::array<double, kMaxHalls> hall_gain_tc_std_per_k{}, hall_offset_tc_std_v_per_k{};
  bool trusted_span_known() const { return std::isfinite(table_trusted_from_m) && std::isfinite(table_trusted_to_m); }
};

/// Block K tuning (the paper's Kalman filter on [x, v, a], extended).
struct FilterConfig {
  /// Process noise: white jerk driving the acceleration state, one sigma per
  /// sample expressed as a jerk [m/s^3]: Q(a,a) = (jerk_std_mps3 * Ts)^2. With the
  /// jerk state on (snap_std_mps4 > 0) this covers only what the jerk state does
  /// not (steps of acceleration), so it can be small.
  double jerk_std_mps3 = 20.0;
  /// ... and white snap driving the jerk state: Q(j,j) = (snap_std_mps4 * Ts)^2.
  /// The jerk state lets the filter extrapolate the acceleration over the
  /// accelerometer's delay; 0 turns it off (the paper's model).
  double snap_std_mps4 = 2.0e4;
  /// How much the frame vibration's amplitude may change per second [m/s^2/sqrt(s)].
  double vibration_random_walk_mps2_per_sqrt_s = 0.01;
  /// Floor added to the Hall position variance computed from sensor slopes [m].
  double hall_position_floor_m = 0.2e-6;
  /// Systematic error of the Hall position (what calibration leaves in the table):
  /// no averaging removes it, so the published position sigma includes it [m].
  double hall_systematic_std_m = 0.0;
  /// Innovation gate on the Hall position, in standard deviations.
  double gate_sigma = 6.0;
  /// Initial standard deviations of the state.
  double initial_position_std_m = 1e-3;
  double initial_velocity_std_mps = 1.0;
  double initial_acceleration_std_mps2 = 10.0;
  /// Accelerometer bias: initial uncertainty and random walk the filter allows.
  double accel_bias_std_mps2 = 0.1;
  double accel_bias_random_walk_mps2_per_sqrt_s = 1e-3;
  /// Accelerometer scale (relative): initial uncertainty and random walk. Off by
  /// default: the scale comes from calibration. Online, scale and bias cannot be
  /// told apart while the acceleration is constant, and the pair drifts.
  double accel_scale_std = 0.0;
  double accel_scale_random_walk_per_sqrt_s = 0.0;
  /// An accelerometer innovation beyond this is a spike, not motion [m/s^2].
  /// (A sigma gate would also reject real steps of acceleration.)
  double accel_spike_mps2 = 60.0;
  /// Consecutive Hall fixes rejected by the gate before the filter concludes that
  /// it is the prediction that is wrong (an acceleration step) and widens its
  /// covariance to follow the Halls again.
  int hall_rejections_before_reset = 3;
  /// Use the frame accelerometer, when the source has one, to remove the frame's
  /// own motion from the moving accelerometer.
  bool use_frame_accelerometer = true;

  // --- sensor health ---
  /// A Hall fix whose sensors disagree beyond this chi-square is re-solved without
  /// the sensor that explains the disagreement (a spike or a failing sensor).
  double sensor_chi2_limit = 25.0;
  /// Per-sensor fault score: an exponential average (this time constant, in
  /// samples) of "was the outlier" (only where the outlier is unambiguous); above
  /// sensor_fault_on the sensor is faulty and left out until it is consistent again.
  double sensor_fault_time_constant_samples = 20.0;
  double sensor_fault_on = 0.3;
  /// A faulty sensor comes back when its readings agree with the estimate (within
  /// this many sigmas) for this long, over at least half a magnet period of motion.
  double sensor_readmit_s = 0.25;
  double sensor_readmit_sigma = 4.0;
  /// VALID means: the position and the velocity are within these of the truth at
  /// this confidence (valid_confidence_sigma times the published sigma), besides
  /// enough healthy sensors and a filter that follows its fixes. The defaults
  /// (100 um, 20 mm/s at 2 sigma) only say the estimate has converged; a machine
  /// sets what its position loop needs.
  double valid_position_accuracy_m = 100e-6;
  double valid_velocity_accuracy_mps = 20e-3;
  double valid_confidence_sigma = 2.0;
  /// Fewest healthy Hall sensors for a VALID position; 0: all but one.
  int min_healthy_halls = 0;
  /// The accelerometer is dead when it repeats exactly the same reading this many
  /// samples in a row (its noise alone never does).
  int accel_stuck_samples = 8;
  /// The accelerometer's bias has left its calibration when the estimate is this far from it [m/s^2].
  double accel_bias_limit_mps2 = 0.5;
  /// Without the accelerometer (failed or absent) the filter runs on the Halls
  /// alone: white jerk of this size drives the acceleration, and the jerk state rests.
  double hall_only_jerk_std_mps3 = 500.0;

  // --- Hall adaptation to slow change (temperature, ageing; hall_adaptation.hpp) ---
  /// Track each Hall's gain and offset while running.
  bool hall_adaptation = true;
  /// How fast they may drift: random walks [1/sqrt(s)], [V/sqrt(s)].
  double hall_gain_random_walk_per_sqrt_s = 2e-4;
  double hall_offset_random_walk_v_per_sqrt_s = 0.05e-3;
  /// Their uncertainty at start-up (the motor need not be at its calibration temperature).
  double hall_gain_initial_std = 0.001;
  double hall_offset_initial_std_v = 0.0003;
  /// A CUSUM of a sensor's normalised residual beyond this re-opens its covariance
  /// by these (a change faster than the random walk: a step of temperature). 0: off.
  double hall_drift_cusum = 40.0;
  double hall_gain_reopen_std = 0.02;
  double hall_offset_reopen_std_v = 0.005;
  /// Largest gain and offset change followed; beyond it the sensor has changed more
  /// than temperature explains and is judged by the health check instead.
  double hall_gain_limit = 0.1;
  double hall_offset_limit_v = 0.1;
  /// The gain all sensors share (the magnets' field, which falls by about 0.12 %/K,
  /// and the sensors' common sensitivity): its uncertainty at start-up when the
  /// temperature is not known (a motor 20 K away from its calibration temperature
  /// is about 4 % off), and how fast it may drift [1/sqrt(s)]. It is estimated with
  /// the position in every Hall fix; where one sensor alone carries the fix it
  /// cannot be, and the fix's sigma says so until the carriage moves.
  double hall_common_gain_initial_std = 0.05;
  double hall_common_gain_random_walk_per_sqrt_s = 3e-4;
  /// Data-sheet temperature coefficients, used when the sensor node reports its
  /// temperature and the calibration recorded it: the magnets' remanence and the
  /// Halls' mean sensitivity [1/K] (their sum moves the common gain), the spread
  /// of the sensitivity between sensors [1/K] and of the zero-field offset's drift
  /// [V/K] (what each sensor's own gain and offset may have moved by), and how
  /// sure the mean coefficients are, relative [-].
  double magnet_remanence_tc_per_k = -0.0012;
  double hall_gain_tc_per_k = -0.001;
  double hall_gain_tc_std_per_k = 0.0003;
  double hall_offset_tc_std_v_per_k = 0.0003;
  double temperature_coefficient_rel_std = 0.2;
  /// Where no fix can read the temperature (one sensor out of saturation: the gain
  /// it shares with the others and the position are one equation short) and the
  /// carriage stands, how far from its calibration temperature the motor is taken to
  /// be at most, one sigma [K]: the published sigma holds what each sensor's own gain
  /// and offset may have moved by over it until a fix reads the temperature, and
  /// VALID follows that sigma. 0: the temperature is taken as the calibration's there.
  double hall_unread_temperature_rise_k = 10.0;
  /// What one sample can tell of a sensor's own gain and offset at best: the
  /// table's own error and the prediction's error repeat from sample to sample,
  /// so a sample's residual is trusted no more than this [V] (keeps the sensors'
  /// parameters, learnt from each other, from chasing each other).
  double hall_adaptation_model_std_v = 3e-3;
  /// What one fix can tell of it at best: the table's own error repeats along the travel.
  double hall_common_gain_model_std = 1e-4;

  // --- steady motion ---
  /// While the acceleration holds still, the filter runs a calm model: the jerk
  /// state rests and white jerk of this size drives the acceleration, so the
  /// accelerometer's noise is averaged instead of integrated into the velocity.
  /// 0: always the agile model above.
  double steady_jerk_std_mps3 = 0.0;
  /// ... and a random walk of the position of this size [m/sqrt(s)], so that the
  /// position keeps following the Halls closely while the velocity averages.
  double steady_position_walk_m_per_sqrt_s = 0.0;
  /// The calm model averages many Hall fixes: it takes their variance with this
  /// floor instead of hall_position_floor_m (which the Hall array and its health
  /// checks keep using) [m].
  double steady_hall_position_floor_m = 0.2e-6;
  /// The acceleration holds still when the accelerometer's own jerk estimate (the
  /// difference of two consecutive 20 ms means) stays below this ...
  double steady_jerk_limit_mps3 = 0.5;
  /// ... for this long [s].
  double steady_hold_s = 0.02;
  /// The calm model ends when a CUSUM of its normalised accelerometer innovations
  /// (drift 1 sigma per sample) exceeds this: the acceleration has started to
  /// change. What the calm model missed since the change began is then added back.
  double steady_exit_cusum = 8.0;

  // --- accelerometer bias steps ---
  /// A CUSUM of the normalised Hall innovations (drift 1 sigma per sample) beyond
  /// this means the Halls and the accelerometer disagree persistently, which a
  /// sudden change of the accelerometer's bias explains: the bias covariance is
  /// widened by accel_bias_step_std_mps2 so the filter re-estimates it within a few
  /// tens of milliseconds (and the bias check flags it). 0: off.
  double accel_bias_step_cusum = 40.0;
  double accel_bias_step_std_mps2 = 1.0;
};

struct MotorConfig {
  std::string name = "sim-12mm";
  double magnet_pitch_m = 0.012;
  double travel_m = 1.0;
  double sample_rate_hz = 4000.0;
  HallConfig hall;
  AdcConfig adc;
  AccelerometerConfig accelerometer;
  FilterConfig filter;

  double sample_period_s() const { return 1.0 / sample_rate_hz; }
};

}  // namespace ve::core
