// Block K: the paper's kinematic Kalman filter on [position, velocity,
// acceleration]. No motor model, so it carries over between machines. White jerk
// drives the acceleration; the Hall position and the accelerometer are measured.
// Fixed-size Eigen throughout: nothing allocates per sample.
#pragma once

#include <Eigen/Core>

namespace ve::core {

class KinematicKalman {
 public:
  enum Index : int { kPos = 0, kVel = 1, kAcc = 2 };
  using Vec = Eigen::Matrix<double, 3, 1>;
  using Mat = Eigen::Matrix<double, 3, 3>;

  /// ts_s: sample period; jerk_std_mps3: process noise as in FilterConfig.
  KinematicKalman(double ts_s, double jerk_std_mps3);

  void reset(const Vec& x, const Mat& p);
  /// x(k|k-1) = A x, P(k|k-1) = A P A' + Q.
  void predict();
  /// Scalar measurement of state `index` with variance r. Returns the innovation
  /// normalised by its standard deviation, and applies it only if |nu| <= gate
  /// (gate <= 0: always). Sequential scalar updates with diagonal R equal the
  /// paper's joint update of [position, acceleration].
  double update(Index index, double z, double r, double gate, bool& applied);

  const Vec& state() const { return x_; }
  const Mat& covariance() const { return p_; }
  const Mat& transition() const { return a_; }
  const Mat& process_noise() const { return q_; }
  double period_s() const { return ts_; }

 private:
  double ts_;
  Mat a_;
  Mat q_;
  Vec x_ = Vec::Zero();
  Mat p_ = Mat::Identity();
};

}  // namespace ve::core
