// Block K as this product runs it: the paper's kinematic Kalman filter on
// [position, velocity, acceleration], extended with what real sensors need:
//  - a jerk state, so the acceleration is extrapolated over the accelerometer's
//    delay and over the Halls' delay instead of being held;
//  - the Halls' delay in the measurement model: x(t - d) = x - d v + d^2/2 a - d^3/6 j;
//  - the accelerometer's delay likewise: a(t - d) = a - d j;
//  - accelerometer bias and scale as states (random walks), so a biased or
//    mis-scaled accelerometer (or the frame's reaction to the motor force, which
//    looks like a scale error) does not pull position and velocity;
//  - a resonator at the frame's vibration frequency: the moving accelerometer
//    feels the frame vibrate, the Halls (on the frame's track) do not, and the
//    filter learns the vibration's amplitude and phase instead of taking it for
//    motion;
//  - two models of how the acceleration changes: an agile one (jerk state plus
//    white snap) while it changes, and a calm one (white jerk of a fraction of a
//    m/s^3, jerk state at rest) while it holds still, as it does in constant-speed
//    and constant-acceleration phases. The calm model averages the
//    accelerometer's noise instead of integrating it into the velocity. It is
//    entered when the accelerometer's own jerk estimate stays small for a while
//    and left as soon as a CUSUM of its accelerometer innovations shows the
//    acceleration changing; what it missed since the change began (the sum of
//    those innovations) is then added back to acceleration, velocity and position.
//    On entry, the velocity (with position and acceleration) is taken from a
//    least-squares fit to the Hall fixes of the window the test found calm, where
//    the agile model had integrated the accelerometer's noise. The published
//    sigmas leave out what the calm model's own white jerk (and position walk)
//    added to the covariance, tracked as a consider covariance with the filter's
//    gains: the acceleration did hold still, and otherwise the model is left;
//  - the published position sigma adds the Hall table's systematic error
//    (hall_systematic_std_m), which no averaging removes;
//  - the accelerometer's delay is known to the calibration's accel_delay_std_s:
//    read at the wrong instant, every change of acceleration leaves an error in
//    the velocity and position. The filter carries the sensitivity of its state
//    to that delay (what each update and prediction makes of it, with its own
//    gains: a consider parameter), and the published sigmas add it times the
//    delay's sigma;
//  - detection of a step in the accelerometer's bias: a CUSUM of the Hall
//    innovations that widens the bias covariance, so the bias state follows.
// Fixed-size Eigen and arrays; nothing allocates per sample.
#pragma once

#include <array>

#include <Eigen/Core>

#include <cstdint>

#include "motor.hpp"

namespace ve::core {

class FusionFilter {
 public:
  enum Index : int { kPos = 0, kVel, kAcc, kJerk, kBias, kScale, kVibIn, kVibQuad, kStates };
  using Vec = Eigen::Matrix<double, kStates, 1>;
  using Mat = Eigen::Matrix<double, kStates, kStates>;
  using Row = Eigen::Matrix<double, 1, kStates>;

  FusionFilter(double ts_s, const FilterConfig& tuning, const SensorModel& model);

  /// Starts from a Hall position (and its variance) at rest; the acceleration from
  /// the accelerometer when it is available.
  void reset(double position_m, double position_var_m2, double accel_reading_mps2, bool accel_valid);
  void predict();
  /// Hall position fix z measured at t - hall_delay_s, variance r. Returns the
  /// normalised innovation; `applied` is false when it fell outside the gate.
  double update_hall(double z_m, double r_m2, double gate_sigma, bool& applied);
  /// The frame vibration's resonator starts over (states 0, their start-up
  /// variance, no correlation with the others) when its amplitude is beyond the
  /// calibration's by more than kVibrationDoubtSigma of its own uncertainty: what
  /// it took up came from somewhere else. Returns whether it did.
  bool doubt_vibration();
  static constexpr double kVibrationDoubtSigma = 3.0;
  /// Accelerometer reading (frame motion already removed when a frame
  /// accelerometer is used), variance r.
  double update_accel(double z_mps2, double r, double gate_sigma, bool& applied);
  /// Widens the covariance of the kinematic states (after persistent rejections).
  void inflate(double position_var_m2, double velocity_var, double acceleration_var);
  /// Moves the position by `dx_m` (homing: from a relative frame into the absolute one).
  void shift_position(double dx_m) {
    x_(kPos) += dx_m;
    fix_count_ = 0;  // the stored fixes are in the old frame
  }
  /// Switches between the tuning with the accelerometer and the Hall-only one.
  void set_accelerometer_available(bool available);
  bool accelerometer_available() const { return accel_available_; }

  const Vec& state() const { return x_; }
  /// Variances to publish. In the calm model the filter's covariance carries the
  /// white jerk it allows the acceleration (so that it can follow a slow change)
  /// although the acceleration holds still; what that jerk added is taken out
  /// (see excess_). The position adds the Hall table's systematic error, which no
  /// averaging removes.
  double position_variance() const;
  double velocity_variance() const;
  const Mat& covariance() const { return p_; }
  double period_s() const { return ts_; }
  /// The frame vibration's current amplitude estimate [m/s^2].
  double vibration_amplitude_mps2() const;
  /// True while the calm (steady acceleration) model runs.
  bool steady() const { return steady_; }
  /// Times the Hall innovations pointed to a step in the accelerometer bias.
  std::uint64_t bias_steps_detected() const { return bias_steps_; }

 private:
  double scalar_update(const Row& h, double innovation, double r, double gate_sigma, bool& applied);

  /// One side of a CUSUM, with what it summed since it last left zero.
  struct Cusum {
    double g = 0.0;   ///< statistic
    double n = 0.0;   ///< samples since it left zero
    double s0 = 0.0;  ///< sum of raw innovations
    double s1 = 0.0;  ///< sum of (sample index since start) * innovation
  };
  static bool cusum_step(Cusum& c, double z, double nu, double drift, double threshold);
  void enter_steady();
  /// On entry into the calm model: a least-squares fit of a constant acceleration
  /// to the Hall fixes of the window over which the acceleration held still.
  void seed_from_fixes();
  void leave_steady(const Cusum* c, double last_nu, double r);
  void steady_test(double reading);
  void clear_detectors();

  // Steady-motion detection: two consecutive windows of accelerometer readings.
  static constexpr int kWin = 80;
  std::array<double, 2 * kWin> win_{};
  int win_head_ = 0;
  int win_filled_ = 0;
  double win_old_ = 0.0, win_new_ = 0.0;
  int calm_count_ = 0;
  int hold_samples_ = 0;
  bool steady_ = false;
  Cusum acc_up_, acc_down_;
  Cusum hall_up_, hall_down_;
  std::uint64_t bias_steps_ = 0;
  /// Hall updates since the filter (re)started with the accelerometer; the bias
  /// step test waits until the start-up transient has settled.
  int hall_updates_ = 0;
  int bias_step_settle_ = 0;
  Mat q_steady_;  ///< process noise of the calm model
  /// In the calm model: the part of the (position, velocity, acceleration)
  /// covariance that its white jerk contributed, propagated with the filter's own
  /// gains (a consider covariance). Zero in the agile model.
  Eigen::Matrix3d excess_ = Eigen::Matrix3d::Zero();
  Eigen::Vector3d excess_q_ = Eigen::Vector3d::Zero();  ///< its process noise (diagonal)
  /// hall_position_floor^2 - steady_hall_position_floor^2 (see update_hall).
  double steady_floor_delta_m2_ = 0.0;
  // The last Hall fixes (position, weight, sample index), for seed_from_fixes().
  static constexpr int kFixes = 256;
  std::array<double, kFixes> fix_z_{};
  std::array<double, kFixes> fix_w_{};
  std::array<std::int64_t, kFixes> fix_k_{};
  int fix_head_ = 0;
  int fix_count_ = 0;
  std::int64_t k_ = 0;  ///< predictions since construction

  double ts_;
  Mat a_;
  Mat q_;
  Vec x_ = Vec::Zero();
  /// d(estimate's error)/d(accelerometer delay): what the calibrated delay being
  /// short of the true one has moved the estimate by, per second of the shortfall
  /// (see position_variance()).
  Vec delay_sens_ = Vec::Zero();
  Vec last_gain_ = Vec::Zero();  ///< the last scalar update's gain
  Mat p_ = Mat::Identity();
  FilterConfig tuning_;
  SensorModel model_;
  Row h_hall_ = Row::Zero();
  bool vibration_ = false;
  bool accel_available_ = true;
  Mat q_accel_;      ///< process noise with the accelerometer
  Mat q_hall_only_;  ///< ... without it
};

}  // namespace ve::core
