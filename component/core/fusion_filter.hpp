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
//    motion.
// Fixed-size Eigen; nothing allocates per sample.
#pragma once

#include <Eigen/Core>

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
  /// Accelerometer reading (frame motion already removed when a frame
  /// accelerometer is used), variance r.
  double update_accel(double z_mps2, double r, double gate_sigma, bool& applied);
  /// Widens the covariance of the kinematic states (after persistent rejections).
  void inflate(double position_var_m2, double velocity_var, double acceleration_var);
  /// Switches between the tuning with the accelerometer and the Hall-only one.
  void set_accelerometer_available(bool available);
  bool accelerometer_available() const { return accel_available_; }

  const Vec& state() const { return x_; }
  const Mat& covariance() const { return p_; }
  double period_s() const { return ts_; }
  /// The frame vibration's current amplitude estimate [m/s^2].
  double vibration_amplitude_mps2() const;

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
  bool vibration_ = false;
  bool accel_available_ = true;
  Mat q_accel_;      ///< process noise with the accelerometer
  Mat q_hall_only_;  ///< ... without it
};

}  // namespace ve::core
