// One axis: Hall array (block SF) + Kalman filter (block K) -> an encoder
// estimate with its uncertainty and a status word. Samples are pushed in with
// their timestamps; nothing here sleeps, allocates per sample or does I/O.
#pragma once

#include <cstdint>

#include "hall_adaptation.hpp"
#include "hall_array.hpp"
#include "fusion_filter.hpp"
#include "motor.hpp"
#include "sample.hpp"
#include "signature_homing.hpp"

namespace ve::core {

struct PipelineConfig {
  MotorConfig motor;
  SensorModel sensors;          ///< delays, coil field, accelerometer bias/scale (from calibration)
  bool calibrated = false;      ///< the table comes from a calibration, not the nominal model
  /// Start-up: true -> the carriage is within half a pitch of start_position_m and the
  /// position is absolute (HOMED); false -> the best match anywhere in the first
  /// periods is taken and the position is relative.
  bool start_position_known = true;
  double start_position_m = 0.5;
  /// Homing by the magnets' signature (a calibrated table only): without a known
  /// start the axis runs relative and homes itself within the first periods of
  /// motion; with one (e.g. the position kept at the last clean shutdown) the first
  /// motion checks it, and a start position off by whole periods is corrected.
  bool signature_homing = false;
  SignatureHomingTuning signature;
  /// Consecutive samples without a Hall fix (no sensor out of saturation, or one
  /// inconsistent with the saturated ones) before the axis re-acquires.
  int max_samples_without_fix = 40;
  /// Gap in the sample stream beyond which the filter restarts instead of
  /// predicting through it; the period is then unknown and HOMED is lost [s].
  double max_gap_s = 0.05;
};

struct EncoderEstimate {
  std::int64_t t_ns = 0;
  std::uint64_t seq = 0;
  double position_m = 0.0;
  double velocity_mps = 0.0;
  double acceleration_mps2 = 0.0;
  double position_std_m = 0.0;
  double velocity_std_mps = 0.0;
  double acceleration_std_mps2 = 0.0;
  std::uint32_t status = 0;
  // Diagnostics of this sample.
  double hall_position_m = 0.0;
  double hall_std_m = 0.0;
  int hall_sensors_used = 0;
  double hall_innovation_sigma = 0.0;  ///< normalised innovation of the Hall position
  double accel_bias_mps2 = 0.0;        ///< current accelerometer bias estimate
  double accel_scale = 1.0;            ///< current accelerometer scale estimate
  std::uint32_t samples_skipped = 0;   ///< samples missing before this one (from the timestamps)
  std::uint32_t hall_faulty_mask = 0;  ///< Hall sensors judged faulty (left out until healthy again)
  std::uint32_t hall_outlier_mask = 0; ///< Hall sensor left out of this sample's fix
  bool accel_stuck = false;            ///< the accelerometer repeats one reading: dead
};

class AxisPipeline {
 public:
  AxisPipeline(const PipelineConfig& config, HallTable table);

  /// Processes one sample; the returned reference stays valid until the next call.
  const EncoderEstimate& step(const RawSample& sample);

  const EncoderEstimate& last() const { return out_; }
  const HallArray& hall_array() const { return hall_; }
  const FusionFilter& filter() const { return kf_; }
  const HallAdaptation& adaptation() const { return adapt_; }
  /// Sensors judged faulty and later found consistent again, re-admitted.
  std::uint64_t sensors_readmitted() const { return readmitted_; }
  bool initialised() const { return initialised_; }
  /// Signature homing: searching, and the motion it has seen so far [m].
  bool homing_in_progress() const { return homing_.state() == SignatureHoming::State::collecting; }
  const SignatureHoming& signature_homing() const { return homing_; }
  /// Times the signature showed a start position (kept or configured) off by whole
  /// periods, and the position was corrected.
  std::uint64_t homing_corrections() const { return homing_corrections_; }
  /// Forget the state; the next sample re-acquires near the last position.
  void restart() { initialised_ = false; }

 private:
  bool acquire(const RawSample& sample);
  void signature_step(const RawSample& sample, double x_hall_m, double common_mode_v, std::uint32_t use);
  bool use_frame(const RawSample& sample) const;
  bool accel_usable(const RawSample& sample) const;
  double accel_reading(const RawSample& sample) const;
  /// The accelerometer's measurement update (its spike test included).
  void update_accelerometer(const RawSample& sample);

  PipelineConfig cfg_;
  HallArray hall_;
  FusionFilter kf_;
  SignatureHoming homing_;
  std::uint64_t homing_corrections_ = 0;
  EncoderEstimate out_;
  bool started_ = false;      ///< the filter has run at least once
  bool initialised_ = false;  ///< the filter is running
  bool homed_ = false;
  std::int64_t last_t_ns_ = 0;
  std::int64_t period_ns_;
  int rejected_in_row_ = 0;
  int without_fix_in_row_ = 0;
  /// ... of which not merely unreadable (every sensor on a rail where the table has
  /// it): after max_samples_without_fix of these the axis re-acquires.
  int lost_in_row_ = 0;
  int acquire_failures_ = 0;   ///< acquisitions failed in a row
  double accel_var_;
  // Sensor health.
  /// `ambiguous`: the fix disagreed, but more than one sensor's removal would make
  /// it consistent (two sensors out of saturation always are), so no sensor can be
  /// blamed for it (a common drift looks like that).
  HallFix solve_robust(const RawSample& sample, double guess_m, double common_mode_v, std::uint32_t use_mask,
                       std::uint32_t& outlier_mask, bool& ambiguous);
  void update_hall_health(std::uint32_t used_mask, std::uint32_t outlier_mask);
  /// Faulty sensors consistent with the estimate again over enough motion come back.
  void readmission_step(const RawSample& raw, double x_m, double common_mode_v);
  HallAdaptation adapt_;
  RawSample corrected_;  ///< this sample's readings mapped back to the calibration's conditions
  int readmit_streak_[kMaxHalls] = {};
  double readmit_lo_m_[kMaxHalls] = {};
  double readmit_hi_m_[kMaxHalls] = {};
  int readmit_samples_ = 1;
  /// Samples after a start before a sensor may be blamed (the adaptation's first
  /// moment); as long as readmission takes, by the same reasoning.
  int blame_wait_samples_ = 1;
  int settled_samples_ = 0;  ///< samples since the filter last (re)acquired
  int settle_samples_ = 1;   ///< ... before the Hall adaptation learns
  int settle_moving_samples_ = 1;  ///< ... or this many, once each sample is at a new place
  bool drift_unlearnt_ = false;  ///< the last fix carried drift the adaptation had not learnt
  double disagreement_seen_m2_ = 0.0;  ///< this sample's unexplained disagreement (solve_robust)
  bool table_explains_ = false;  ///< solve_robust: the sensors agree within the table's own error
  double disagreement_var_m2_ = 0.0;   ///< its recent average, added to the published sigma
  /// The last fix's quantisation error that the filter cannot average away at
  /// this speed (HallFix::quantisation_m2), added to the published sigma [m^2].
  double quantisation_var_m2_ = 0.0;
  /// Likewise the table's own noise (SensorModel::table_noise_v) [m^2], and that
  /// noise's variance as a reading [V^2].
  double table_var_m2_ = 0.0;
  double table_noise_v2_ = 0.0;
  /// What the coil field's uncertainty leaves in the last fix at the current
  /// acceleration [m^2], and its change with the jerk [(m/s)^2].
  double coil_var_m2_ = 0.0;
  double coil_jerk_var_ = 0.0;
  /// Likewise the sensors' gain and offset uncertainty (HallFix::drift_m2) [m^2].
  double drift_var_m2_ = 0.0;
  /// The velocity error that drift's pattern makes at the current speed [(m/s)^2].
  double drift_velocity_var_ = 0.0;
  /// The last fix's pattern rate (2 pi v / pitch) [rad/s] and the time over which the
  /// filter averages fixes [s]: what makes the disagreement a velocity error.
  double pattern_rate_ = 0.0;
  double averaged_s_ = 0.0;
  /// Until a fix has read the temperature (HallAdaptation::temperature_checked):
  /// what the sensors' own gains and offsets may have moved the last fix by over
  /// FilterConfig::hall_unread_temperature_rise_k [m^2], added to the published sigma;
  /// and whether the carriage stands where no fix can read it (one sensor out of
  /// saturation), where VALID follows that sigma instead of waiting for a reading.
  double unread_var_m2_ = 0.0;
  bool unread_place_ = false;
  /// The sensors' covariance was widened (a temperature change): the next fix widens
  /// the filter's covariance by the drift it allows for.
  bool widen_filter_ = false;
  /// The thermal coefficients moved the sensors' readings (HallAdaptation::
  /// take_moved_v2), not yet taken by a fix [V^2].
  double moved_v2_ = 0.0;
  /// Travel over which a sensor's reading crosses one ADC step, on average [m].
  double quantisation_travel_m_ = 0.0;
  double disagreement_hold_m2_ = 0.0;  ///< its recent largest, widening the blame test
  double disagreement_decay_ = 1.0;
  double hold_decay_ = 1.0;
  std::uint64_t readmitted_ = 0;
  double fault_score_[kMaxHalls] = {};
  std::uint32_t faulty_mask_ = 0;
  std::uint32_t all_halls_mask_ = 0;
  int min_healthy_ = 1;
  double last_accel_ = 0.0;
  int accel_repeats_ = 0;
  bool accel_stuck_ = false;
};

}  // namespace ve::core
