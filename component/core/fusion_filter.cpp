#include "fusion_filter.hpp"

#include <algorithm>
#include <cmath>

namespace ve::core {

namespace {
constexpr int tap_index(int k) { return k == 0 ? FusionFilter::kAcc : FusionFilter::kAcc1 + (k - 1); }
}  // namespace

FusionFilter::FusionFilter(double ts_s, const FilterConfig& tuning, const SensorModel& model)
    : ts_(ts_s), tuning_(tuning), model_(model) {
  a_.setIdentity();
  a_(kPos, kVel) = ts_s;
  a_(kPos, kAcc) = 0.5 * ts_s * ts_s;
  a_(kVel, kAcc) = ts_s;
  // Delay line: each tap takes the value of the newer one.
  a_(kAcc1, kAcc1) = 0.0;
  a_(kAcc2, kAcc2) = 0.0;
  a_(kAcc3, kAcc3) = 0.0;
  a_(kAcc1, kAcc) = 1.0;
  a_(kAcc2, kAcc1) = 1.0;
  a_(kAcc3, kAcc2) = 1.0;

  q_.setZero();
  const double da = tuning.jerk_std_mps3 * ts_s;
  q_(kAcc, kAcc) = da * da;
  q_(kBias, kBias) = tuning.accel_bias_random_walk_mps2_per_sqrt_s * tuning.accel_bias_random_walk_mps2_per_sqrt_s * ts_s;
  q_(kScale, kScale) = tuning.accel_scale_random_walk_per_sqrt_s * tuning.accel_scale_random_walk_per_sqrt_s * ts_s;

  // x(t - d) = x - d v + d^2/2 a (the jerk term is below a nanometre for d < 100 us).
  const double d = model.hall_delay_s;
  h_hall_(kPos) = 1.0;
  h_hall_(kVel) = -d;
  h_hall_(kAcc) = 0.5 * d * d;

  double delay_samples = std::max(0.0, model.accel_delay_s / ts_s);
  if (delay_samples > kMaxAccelDelaySamples) {
    delay_samples = kMaxAccelDelaySamples;
    accel_delay_clipped_ = true;
  }
  accel_tap_ = std::min(static_cast<int>(delay_samples), kMaxAccelDelaySamples - 1);
  accel_frac_ = delay_samples - accel_tap_;
}

void FusionFilter::reset(double position_m, double position_var_m2, double accel_reading_mps2, bool accel_valid) {
  x_.setZero();
  p_.setZero();
  const double a0 = accel_valid ? (accel_reading_mps2 - model_.accel_bias_mps2) / model_.accel_scale : 0.0;
  x_(kPos) = position_m;
  x_(kAcc) = a0;
  x_(kAcc1) = a0;
  x_(kAcc2) = a0;
  x_(kAcc3) = a0;
  x_(kBias) = model_.accel_bias_mps2;
  x_(kScale) = model_.accel_scale;
  p_(kPos, kPos) = position_var_m2;
  p_(kVel, kVel) = tuning_.initial_velocity_std_mps * tuning_.initial_velocity_std_mps;
  const double sa = accel_valid ? tuning_.accel_bias_std_mps2 + 0.05 : tuning_.initial_acceleration_std_mps2;
  for (int i : {kAcc, kAcc1, kAcc2, kAcc3}) p_(i, i) = sa * sa;
  // The taps start as one value: fully correlated.
  for (int i : {kAcc, kAcc1, kAcc2, kAcc3})
    for (int j : {kAcc, kAcc1, kAcc2, kAcc3}) p_(i, j) = sa * sa;
  p_(kBias, kBias) = tuning_.accel_bias_std_mps2 * tuning_.accel_bias_std_mps2;
  p_(kScale, kScale) = tuning_.accel_scale_std * tuning_.accel_scale_std;
}

void FusionFilter::predict() {
  x_ = a_ * x_;
  p_ = (a_ * p_ * a_.transpose()).eval() + q_;
}

void FusionFilter::inflate(double position_var_m2, double velocity_var, double acceleration_var) {
  p_(kPos, kPos) += position_var_m2;
  p_(kVel, kVel) += velocity_var;
  for (int i : {kAcc, kAcc1, kAcc2, kAcc3}) p_(i, i) += acceleration_var;
}

double FusionFilter::scalar_update(const Row& h, double innovation, double r, double gate_sigma, bool& applied) {
  const Vec ph = p_ * h.transpose();
  const double s = h.dot(ph) + r;
  const double nu_norm = innovation / std::sqrt(s);
  applied = !(gate_sigma > 0.0 && std::abs(nu_norm) > gate_sigma);
  if (!applied) return nu_norm;
  const Vec k = ph / s;
  x_ += k * innovation;
  p_ -= k * ph.transpose();
  p_ = 0.5 * (p_ + p_.transpose()).eval();
  return nu_norm;
}

double FusionFilter::update_hall(double z_m, double r_m2, double gate_sigma, bool& applied) {
  return scalar_update(h_hall_, z_m - h_hall_.dot(x_), r_m2, gate_sigma, applied);
}

double FusionFilter::update_accel(double z_mps2, double r, double gate_sigma, bool& applied) {
  // Reading = scale * a(t - delay) + bias, with a(t - delay) interpolated between
  // two taps of the delay line. Linearised about the current scale (EKF).
  const int i0 = tap_index(accel_tap_);
  const int i1 = tap_index(accel_tap_ + 1);
  const double a_delayed = (1.0 - accel_frac_) * x_(i0) + accel_frac_ * x_(i1);
  const double scale = x_(kScale);
  Row h = Row::Zero();
  h(i0) = scale * (1.0 - accel_frac_);
  h(i1) += scale * accel_frac_;
  h(kBias) = 1.0;
  h(kScale) = a_delayed;
  return scalar_update(h, z_mps2 - (scale * a_delayed + x_(kBias)), r, gate_sigma, applied);
}

}  // namespace ve::core
