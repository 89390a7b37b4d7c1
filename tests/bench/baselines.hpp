// Baseline estimators that accuracy_bench compares the product (core::AxisPipeline)
// against. Each is what a competent engineer would build from the paper or from an
// open-source motor controller, given the SAME calibrated Hall table the product
// gets, so the comparison is about the estimation and not about the table.
//
// What the baselines deliberately do NOT have (that is what the product adds):
//  - no Hall-delay compensation: the Halls read the carriage hall_delay_s late, so
//    every baseline's position lags by v * hall_delay_s;
//  - no coil-field compensation: the common-mode Hall offset from the motor force
//    goes straight into the Hall fix;
//  - (paper KF) no accelerometer bias, scale, delay or frame-vibration handling.
//
// All are causal: one call per sample, using only that sample and the past.
// Header-only; used by tests/bench/accuracy_bench.cpp only.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

#include "core/hall_array.hpp"
#include "core/hall_table.hpp"
#include "core/kalman.hpp"
#include "core/motor.hpp"
#include "core/sample.hpp"

namespace ve::bench {

/// One estimator output. position_std_m < 0: the estimator has no uncertainty.
struct BaselineEstimate {
  double position_m = 0.0;
  double velocity_mps = 0.0;
  double position_std_m = -1.0;
  double velocity_std_mps = -1.0;
};

/// Consecutive samples without a Hall fix before a tracker re-acquires (as the product).
inline constexpr int kMaxSamplesWithoutFix = 40;

// ---------------------------------------------------------------------------
/// The paper's block SF + block K, plainly: the Hall array solved near the
/// filter's prediction (no delay, no coil-field compensation) and the 3-state
/// kinematic Kalman filter [x, v, a] updated with that position (variance from the
/// fix, the hall_position_floor already inside it) and with the raw accelerometer
/// reading (variance noise_mps2^2; no bias, scale, delay or vibration handling).
/// No innovation gate: the paper has none (and without the product's
/// re-acquisition logic a gate could lock the filter out for good).
class PaperKalman {
 public:
  PaperKalman(const core::MotorConfig& motor, core::HallTable table, double start_position_m)
      : motor_(motor),
        hall_(motor, std::move(table)),
        kf_(motor.sample_period_s(), motor.filter.jerk_std_mps3),
        start_m_(start_position_m),
        accel_var_(motor.accelerometer.noise_mps2 * motor.accelerometer.noise_mps2) {}

  BaselineEstimate step(const core::RawSample& s) {
    if (!initialised_) {
      // Start-up as the product does: search within half a pitch of the known start
      // (or, after a loss, of the last estimate).
      const double centre = started_ ? kf_.state()(core::KinematicKalman::kPos) : start_m_;
      const double p = motor_.magnet_pitch_m;
      const core::HallFix fix = hall_.acquire(s, centre - 0.5 * p, centre + 0.5 * p);
      if (fix.ok) {
        core::KinematicKalman::Vec x;
        x << fix.position_m, 0.0, accel_ok(s) ? s.accel_mps2 : 0.0;
        core::KinematicKalman::Mat pm = core::KinematicKalman::Mat::Zero();
        const double sv = motor_.filter.initial_velocity_std_mps;
        const double sa = motor_.filter.initial_acceleration_std_mps2;
        pm(0, 0) = fix.variance_m2;
        pm(1, 1) = sv * sv;
        pm(2, 2) = sa * sa;
        kf_.reset(x, pm);
        initialised_ = started_ = true;
        without_fix_ = 0;
      }
      return output();
    }
    kf_.predict();
    bool applied = false;
    const core::HallFix fix = hall_.solve(s, kf_.state()(core::KinematicKalman::kPos));
    if (fix.ok) {
      without_fix_ = 0;
      kf_.update(core::KinematicKalman::kPos, fix.position_m, fix.variance_m2, 0.0, applied);
    } else {
      ++fixes_missed_;
      if (++without_fix_ >= kMaxSamplesWithoutFix) initialised_ = false;
    }
    if (accel_ok(s)) kf_.update(core::KinematicKalman::kAcc, s.accel_mps2, accel_var_, 0.0, applied);
    return output();
  }

  std::uint64_t fixes_missed() const { return fixes_missed_; }

 private:
  bool accel_ok(const core::RawSample& s) const {
    return s.accel_valid && std::abs(s.accel_mps2) < motor_.accelerometer.range_mps2;
  }
  BaselineEstimate output() const {
    BaselineEstimate e;
    e.position_m = kf_.state()(core::KinematicKalman::kPos);
    e.velocity_mps = kf_.state()(core::KinematicKalman::kVel);
    e.position_std_m = std::sqrt(kf_.covariance()(core::KinematicKalman::kPos, core::KinematicKalman::kPos));
    e.velocity_std_mps = std::sqrt(kf_.covariance()(core::KinematicKalman::kVel, core::KinematicKalman::kVel));
    return e;
  }

  core::MotorConfig motor_;
  core::HallArray hall_;
  core::KinematicKalman kf_;
  double start_m_;
  double accel_var_;
  bool initialised_ = false;
  bool started_ = false;
  int without_fix_ = 0;
  std::uint64_t fixes_missed_ = 0;
};

// ---------------------------------------------------------------------------
/// The raw Hall position every non-filtering baseline starts from: acquired
/// within half a pitch of the start, then each sample solved starting from the
/// previous fix (no prediction, no delay or coil-field compensation). A sample
/// without a fix repeats the previous position.
class HallTracker {
 public:
  HallTracker(const core::MotorConfig& motor, core::HallTable table, double start_position_m)
      : hall_(motor, std::move(table)), pitch_m_(motor.magnet_pitch_m), last_m_(start_position_m) {}

  /// Hall position for this sample; `ok` false when the array gave no fix (then the
  /// previous position is returned) or has not acquired yet.
  double step(const core::RawSample& s, bool& ok) {
    core::HallFix fix;
    if (!acquired_) {
      fix = hall_.acquire(s, last_m_ - 0.5 * pitch_m_, last_m_ + 0.5 * pitch_m_);
    } else {
      fix = hall_.solve(s, last_m_);
    }
    ok = fix.ok;
    if (fix.ok) {
      last_m_ = fix.position_m;
      acquired_ = true;
      without_fix_ = 0;
    } else {
      ++fixes_missed_;
      if (acquired_ && ++without_fix_ >= kMaxSamplesWithoutFix) acquired_ = false;
    }
    return last_m_;
  }

  std::uint64_t fixes_missed() const { return fixes_missed_; }

 private:
  core::HallArray hall_;
  double pitch_m_;
  double last_m_;
  bool acquired_ = false;
  int without_fix_ = 0;
  std::uint64_t fixes_missed_ = 0;
};

// ---------------------------------------------------------------------------
/// Position = the Hall fix; velocity = (x_k - x_{k-1}) / Ts. The first sample has
/// no predecessor and reports 0 velocity.
class FiniteDifference {
 public:
  explicit FiniteDifference(double ts_s) : ts_(ts_s) {}

  BaselineEstimate step(double hall_position_m) {
    BaselineEstimate e;
    e.position_m = hall_position_m;
    e.velocity_mps = has_last_ ? (hall_position_m - last_m_) / ts_ : 0.0;
    last_m_ = hall_position_m;
    has_last_ = true;
    return e;
  }

 private:
  double ts_;
  double last_m_ = 0.0;
  bool has_last_ = false;
};

// ---------------------------------------------------------------------------
/// ODrive's encoder PLL (Encoder::update) on the Hall position, in metres:
///   pos_est += Ts * vel_est;            // predict
///   err      = x_hall - pos_est;
///   pos_est += Ts * kp * err;
///   vel_est += Ts * ki * err;
/// with kp = 2 bw and ki = 0.25 kp^2 = bw^2 (critically damped). ODrive refuses
/// gains with Ts * kp >= 1 (ERROR_UNSTABLE_GAIN); so does gains_ok(). ODrive's
/// "snap velocity to zero below 0.5 Ts ki counts/s" is left out: it exists to
/// hide integer-count quantisation, and in metres the threshold (0.5 Ts bw^2
/// m/s) would zero real motion.
class OdrivePll {
 public:
  static bool gains_ok(double bandwidth_rps, double ts_s) { return ts_s * 2.0 * bandwidth_rps < 1.0; }

  OdrivePll(double bandwidth_rps, double ts_s)
      : ts_(ts_s), kp_(2.0 * bandwidth_rps), ki_(0.25 * kp_ * kp_) {}

  BaselineEstimate step(double hall_position_m) {
    if (!started_) {
      pos_ = hall_position_m;  // start on the first measurement, at rest
      vel_ = 0.0;
      started_ = true;
    } else {
      pos_ += ts_ * vel_;
      const double err = hall_position_m - pos_;
      pos_ += ts_ * kp_ * err;
      vel_ += ts_ * ki_ * err;
    }
    BaselineEstimate e;
    e.position_m = pos_;
    e.velocity_mps = vel_;
    return e;
  }

 private:
  double ts_;
  double kp_;
  double ki_;
  double pos_ = 0.0;
  double vel_ = 0.0;
  bool started_ = false;
};

}  // namespace ve::bench
