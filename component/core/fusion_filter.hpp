// Block K as this product runs it: the paper's kinematic Kalman filter on
// [position, velocity, acceleration], extended with what real sensors need:
//  - accelerometer bias and scale as states (random walks), so a biased or
//    mis-scaled accelerometer (or the frame's reaction to the motor force, which
//    looks like a scale error) does not pull position and velocity;
//  - the accelerometer's delay, through the acceleration of the last samples
//    kept as states: the reading is compared with the acceleration at its own
//    instant, not the current one;
//  - the Halls' delay, through the measurement model x(t - d) = x - d v + d^2/2 a.
// Fixed-size Eigen; nothing allocates per sample.
#pragma once

#include <Eigen/Core>

#include "motor.hpp"

namespace ve::core {

class FusionFilter {
 public:
  enum Index : int { kPos = 0, kVel, kAcc, kBias, kScale, kAcc1, kAcc2, kAcc3, kStates };
  /// Longest accelerometer delay the filter represents, in samples.
  static constexpr int kMaxAccelDelaySamples = 3;
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
  /// Widens the covariance of the kinematic states (after persistent rejections).
  void inflate(double position_var_m2, double velocity_var, double acceleration_var);
  /// Accelerometer reading (frame motion already removed), variance r.
  double update_accel(double z_mps2, double r, double gate_sigma, bool& applied);

  const Vec& state() const { return x_; }
  const Mat& covariance() const { return p_; }
  double period_s() const { return ts_; }
  /// True when the configured accelerometer delay exceeds what the filter represents.
  bool accel_delay_clipped() const { return accel_delay_clipped_; }

 private:
  double scalar_update(const Row& h, double innovation, double r, double gate_sigma, bool& applied);

  double ts_;
  Mat a_;
  Mat q_;
  Vec x_ = Vec::Zero();
  Mat p_ = Mat::Identity();
  FilterConfig tuning_;
  SensorModel model_;
  Row h_hall_ = Row::Zero();
  int accel_tap_ = 0;        ///< the reading lies between taps accel_tap_ and accel_tap_ + 1
  double accel_frac_ = 0.0;  ///< ... this far towards the older one
  bool accel_delay_clipped_ = false;
};

}  // namespace ve::core
