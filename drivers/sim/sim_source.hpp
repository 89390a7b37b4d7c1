// Simulated motor: Hall array over a (possibly imperfect) magnet track plus an
// accelerometer on the carriage, driven by an analytic motion profile, sampled on
// the ADC grid. Deterministic: the same seeds give the same stream bit for bit.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "core/motor.hpp"
#include "core/sample.hpp"
#include "sim/motion_profile.hpp"
#include "sim/sim_config.hpp"
#include "source.hpp"

namespace ve::sim {

/// Imperfections (all in ImperfectionConfig; zero = none, bit for bit):
/// - Halls: track (magnet strength/placement, third harmonic), sensor placement, gain
///   and offset, delay hall_delay_s, and the coil field: + coil_field_v_per_mps2 * a(t -
///   hall_delay_s) on every output (a = the profile's acceleration, standing in for the
///   motor force). Then noise, ADC clamping and quantization.
/// - Frame: a_frame(t) = frame_reaction_ratio a(t) + frame_vibration_mps2 sin(2 pi f t).
///   The Halls measure relative to the frame, so truth() stays the profile.
/// - Moving accelerometer, d = accel_delay_s: (1 + accel_scale_error) (a(t - d) +
///   a_frame(t - d)) + bias + N(0, noise_mps2), bias = accel_bias_mps2 + a random walk
///   that starts at the first sample read; clamped to +-range_mps2.
/// - Frame accelerometer (frame_accelerometer): a_frame(t - d) + its own N(0,
///   noise_mps2); no bias, scale error or walk; clamped to +-range_mps2.
/// - Temperature (SimConfig::temperature, see TemperatureConfig): the rise dT(t) at the
///   sample instant scales the magnets' field and each Hall's sensitivity and shifts
///   each Hall's offset; with report, RawSample::temperature_c carries it. dT = 0: no effect.
class SimSource final : public drivers::SensorSource {
 public:
  /// Never throws on bad parameters: ok() is then false, last_error() says why and
  /// read() returns ReadStatus::error. `start_time_s` starts the profile (and t_ns,
  /// seq) at sample round(start_time_s * rate) instead of 0; duration_s counts from there.
  SimSource(const core::MotorConfig& motor, const SimConfig& cfg, double start_time_s = 0.0);

  /// What the constructor would complain about; empty if the pair is usable.
  static std::string check(const core::MotorConfig& motor, const SimConfig& cfg);

  bool ok() const { return error_.empty(); }

  /// Realtime: the first call returns at once and starts the clock; sample n is
  /// returned no earlier than n periods later on CLOCK_MONOTONIC (no drift; a late
  /// caller catches up without sleeping). Non-realtime: returns at once.
  /// A no_samples fault: the samples of its window are never returned (seq and t_ns
  /// jump over them); in real time read() returns ReadStatus::timeout every
  /// kSilentReadTimeoutNs until the next sample is due, as a silent CAN node's driver does.
  drivers::ReadStatus read(core::RawSample& out) override;
  /// Carriage state at the instant of the last sample read (not delayed).
  const core::Truth* truth() const override { return samples_read_ > 0 ? &truth_ : nullptr; }
  /// The simulator's exact position stands in for a reference ruler.
  bool reference_position(double& position_m) const override {
    if (samples_read_ == 0) return false;
    position_m = truth_.position_m;
    return true;
  }
  /// Real time only: the clock starts at `start_ns` (not at the first read) and read()
  /// never sleeps; a silent node's timeouts come every kSilentReadTimeoutNs as
  /// next_due_ns() says. False when not real time or already started.
  bool share_clock(std::int64_t start_ns) override;
  std::int64_t next_due_ns() const override;
  /// Wakes a sleeping read() within a few ms; every later read() returns stopped.
  void stop() override { stop_.store(true, std::memory_order_relaxed); }
  std::string describe() const override;
  std::string last_error() const override { return error_; }

  /// Output of Hall `sensor` with the carriage at `carriage_x_m`, with all track and
  /// sensor imperfections but before noise, ADC clamping and quantization [V].
  /// At the calibration temperature (temperature rise 0).
  double hall_voltage_noiseless(int sensor, double carriage_x_m) const;
  /// The same with the motor `temperature_rise_k` warmer than at calibration [V].
  double hall_voltage_noiseless(int sensor, double carriage_x_m, double temperature_rise_k) const;
  /// Normalised track field at track position `x_m` (ideal: sin(2 pi x / pitch); with
  /// field_third_harmonic h3: sin(theta) + h3 sin(3 theta) of the local magnet phase
  /// theta, times the local magnet strength). Excludes the coil field, which depends on
  /// the acceleration: read() adds coil_field_v_per_mps2 * a(t - hall_delay_s) to every Hall.
  double track_field(double x_m) const;
  /// Acceleration of the stationary frame at `t_s`, given the carriage's (relative)
  /// acceleration at that instant: frame_reaction_ratio * a + frame_vibration_mps2 *
  /// sin(2 pi frame_vibration_hz t_s) [m/s^2]; exactly 0 when both are 0.
  double frame_acceleration(double t_s, double carriage_acceleration_mps2) const;
  double frame_acceleration(double t_s) const { return frame_acceleration(t_s, profile_.at(t_s).acceleration_mps2); }
  /// Bias of the moving accelerometer at the last sample read (accel_bias_mps2 plus the
  /// random walk so far) [m/s^2].
  double accel_bias_now_mps2() const { return bias_now_mps2_; }
  /// Temperature rise over the calibration temperature at simulated time `t_s` (the
  /// profile's clock) [K]: offset_k plus the profile part.
  double temperature_at(double t_s) const;
  /// Temperature rise at the instant of the last sample read (0 before the first) [K].
  double temperature_rise_k() const { return temperature_rise_k_; }
  /// Sensor `sensor`'s relative sensitivity change per K, as drawn [1/K].
  double hall_gain_tc_per_k(int sensor) const { return sensors_[static_cast<std::size_t>(sensor)].gain_tc_per_k; }
  /// Sensor `sensor`'s zero-field offset drift, as drawn [V/K].
  double hall_offset_tc_v_per_k(int sensor) const { return sensors_[static_cast<std::size_t>(sensor)].offset_tc_v_per_k; }
  /// Where sensor `sensor` really sits relative to the carriage (offset + placement error) [m].
  double sensor_position_m(int sensor) const { return sensors_[static_cast<std::size_t>(sensor)].position_m; }
  /// The magnet track's scale over [lo_m, hi_m] of track coordinate: the slope of
  /// a least-squares line through the magnet boundaries there against their
  /// nominal places (j * pitch), minus 1. The track is the only length a
  /// calibration without a ruler has; this is how far its placement errors make
  /// it differ from the data sheet's pitch there.
  double track_scale_error(double lo_m, double hi_m) const;

  const MotionProfile& profile() const { return profile_; }
  const core::MotorConfig& motor() const { return motor_; }
  const SimConfig& config() const { return cfg_; }
  /// Samples returned so far (without those a no_samples fault withheld).
  std::uint64_t samples_read() const { return samples_read_; }
  /// Simulated instant of sample index k (as in RawSample::seq) [ns].
  std::int64_t sample_time_ns(std::uint64_t k) const;

 private:
  struct Sensor {
    double position_m = 0.0;  ///< relative to the carriage
    double gain = 1.0;
    double offset_v = 0.0;
    double gain_tc_per_k = 0.0;      ///< sensitivity temperature coefficient
    double offset_tc_v_per_k = 0.0;  ///< offset drift
  };

  void build_track();
  double field_shape(double theta) const;
  void start_clock();                    // real time: at the first read()
  bool wait_until_due(std::uint64_t n);  // false: stopped while waiting
  /// The first stream index >= n that no no_samples fault withholds; kNeverSent when
  /// one lasts for good.
  std::uint64_t next_sent(std::uint64_t n) const;
  static constexpr std::uint64_t kNeverSent = ~0ull;
  void inject_faults(double t_s, std::uint64_t k, core::RawSample& out) const;

  core::MotorConfig motor_;
  SimConfig cfg_;
  MotionProfile profile_;
  std::string error_;

  std::vector<Sensor> sensors_;
  double wavenumber_rad_per_m_ = 0.0;  // 2 pi / pitch
  double lsb_v_ = 0.0;
  int max_code_ = 0;

  // Imperfect track, magnets j_first_ .. j_first_ + strength_.size() - 1; outside it
  // (and always when both magnet tolerances are zero) the track is ideal.
  bool ideal_track_ = true;
  std::int64_t j_first_ = 0;
  std::vector<double> boundary_m_;  // size + 1 entries; the first and last are nominal
  std::vector<double> strength_;    // per period, at the period's centre

  double third_harmonic_ = 0.0;
  bool frame_moves_ = false;        // frame_reaction_ratio or frame_vibration_mps2 non-zero
  double frame_omega_rps_ = 0.0;
  double bias_step_mps2_ = 0.0;     // random-walk step per sample, one sigma
  double bias_walk_mps2_ = 0.0;     // walk so far (sequential state)
  double bias_now_mps2_ = 0.0;
  double temperature_rise_k_ = 0.0;  // at the last sample read

  std::uint64_t first_index_ = 0;
  std::uint64_t max_samples_ = 0;  // 0: unlimited
  std::uint64_t samples_read_ = 0;
  std::uint64_t next_index_ = 0;   // stream index (from first_index_) of the next sample
  bool has_silence_ = false;       // a no_samples fault is configured
  core::Truth truth_{};

  std::atomic<bool> stop_{false};
  bool clock_started_ = false;
  bool clock_shared_ = false;        // share_clock(): the caller waits, read() does not
  std::int64_t silent_due_ns_ = 0;   // shared clock, silent node: the next timeout
  std::int64_t clock_start_ns_ = 0;  // CLOCK_MONOTONIC at the first read
};

}  // namespace ve::sim
