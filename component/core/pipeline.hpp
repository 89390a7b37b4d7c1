// One axis: Hall array (block SF) + Kalman filter (block K) -> an encoder
// estimate with its uncertainty and a status word. Samples are pushed in with
// their timestamps; nothing here sleeps, allocates per sample or does I/O.
#pragma once

#include <cstdint>

#include "hall_array.hpp"
#include "kalman.hpp"
#include "motor.hpp"
#include "sample.hpp"

namespace ve::core {

struct PipelineConfig {
  MotorConfig motor;
  bool calibrated = false;      ///< the table comes from a calibration, not the nominal model
  /// Start-up: true -> the carriage is within half a pitch of start_position_m and the
  /// position is absolute (HOMED); false -> the best match anywhere in the first
  /// periods is taken and the position is relative.
  bool start_position_known = true;
  double start_position_m = 0.5;
  /// Consecutive rejected Hall fixes before the axis re-acquires and reports not valid.
  int max_rejected_in_row = 40;
  /// Gap in the sample stream beyond which the filter restarts instead of predicting through [s].
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
  std::uint32_t samples_skipped = 0;   ///< samples missing before this one (from the timestamps)
};

class AxisPipeline {
 public:
  AxisPipeline(const PipelineConfig& config, HallTable table);

  /// Processes one sample; the returned reference stays valid until the next call.
  const EncoderEstimate& step(const RawSample& sample);

  const EncoderEstimate& last() const { return out_; }
  const HallArray& hall_array() const { return hall_; }
  const KinematicKalman& filter() const { return kf_; }
  bool initialised() const { return initialised_; }
  /// Forget the state; the next sample re-acquires as at start-up.
  void restart() { initialised_ = false; }

 private:
  bool initialise(const RawSample& sample);

  PipelineConfig cfg_;
  HallArray hall_;
  KinematicKalman kf_;
  EncoderEstimate out_;
  bool initialised_ = false;
  bool homed_ = false;
  std::int64_t last_t_ns_ = 0;
  std::int64_t period_ns_;
  int rejected_in_row_ = 0;
  double accel_var_;
};

}  // namespace ve::core
