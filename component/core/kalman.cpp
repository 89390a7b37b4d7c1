#include "kalman.hpp"

#include <cmath>

namespace ve::core {

KinematicKalman::KinematicKalman(double ts_s, double jerk_std_mps3) : ts_(ts_s) {
  a_ << 1.0, ts_s, 0.5 * ts_s * ts_s,  //
      0.0, 1.0, ts_s,                  //
      0.0, 0.0, 1.0;
  q_.setZero();
  const double da = jerk_std_mps3 * ts_s;  // acceleration change per sample, one sigma
  q_(kAcc, kAcc) = da * da;
}

void KinematicKalman::reset(const Vec& x, const Mat& p) {
  x_ = x;
  p_ = p;
}

void KinematicKalman::predict() {
  x_ = a_ * x_;
  p_ = a_ * p_ * a_.transpose() + q_;
}

double KinematicKalman::update(Index index, double z, double r, double gate, bool& applied) {
  const double s = p_(index, index) + r;
  const double nu = z - x_(index);
  const double nu_norm = nu / std::sqrt(s);
  applied = !(gate > 0.0 && std::abs(nu_norm) > gate);
  if (!applied) return nu_norm;
  const Vec k = p_.col(index) / s;
  x_ += k * nu;
  // Joseph form would cost more; the symmetric update below stays positive
  // definite in double precision for these magnitudes and is re-symmetrised.
  p_ -= k * p_.row(index);
  p_ = 0.5 * (p_ + p_.transpose()).eval();
  return nu_norm;
}

}  // namespace ve::core
