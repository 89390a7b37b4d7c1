#include "fusion_filter.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>

namespace ve::core {

namespace {
/// An accelerometer innovation beyond this many sigmas is a step of acceleration.
constexpr double kAccelStepSigma = 8.0;
/// The bias step test starts this long after the filter (re)starts with the
/// accelerometer: before, its own start-up transient leans the Hall innovations
/// one way [s].
constexpr double kBiasStepSettleS = 0.1;
}  // namespace

FusionFilter::FusionFilter(double ts_s, const FilterConfig& tuning, const SensorModel& model)
    : ts_(ts_s), tuning_(tuning), model_(model) {
  const double t = ts_s;
  const bool jerk = tuning.snap_std_mps4 > 0.0;
  a_.setIdentity();
  a_(kPos, kVel) = t;
  a_(kPos, kAcc) = t * t / 2.0;
  a_(kVel, kAcc) = t;
  if (jerk) {
    a_(kPos, kJerk) = t * t * t / 6.0;
    a_(kVel, kJerk) = t * t / 2.0;
    a_(kAcc, kJerk) = t;
  }
  vibration_ = model.frame_vibration_hz > 0.0;
  if (vibration_) {
    // The in-phase and quadrature parts of a sinusoid rotate by w Ts per sample.
    const double w = 2.0 * M_PI * model.frame_vibration_hz * t;
    a_(kVibIn, kVibIn) = std::cos(w);
    a_(kVibIn, kVibQuad) = -std::sin(w);
    a_(kVibQuad, kVibIn) = std::sin(w);
    a_(kVibQuad, kVibQuad) = std::cos(w);
  }

  q_.setZero();
  const double da = tuning.jerk_std_mps3 * t;
  q_(kAcc, kAcc) = da * da;
  if (jerk) {
    const double dj = tuning.snap_std_mps4 * t;
    q_(kJerk, kJerk) = dj * dj;
  }
  q_(kBias, kBias) = tuning.accel_bias_random_walk_mps2_per_sqrt_s * tuning.accel_bias_random_walk_mps2_per_sqrt_s * t;
  q_(kScale, kScale) = tuning.accel_scale_random_walk_per_sqrt_s * tuning.accel_scale_random_walk_per_sqrt_s * t;
  if (vibration_) {
    const double dv = tuning.vibration_random_walk_mps2_per_sqrt_s * tuning.vibration_random_walk_mps2_per_sqrt_s * t;
    q_(kVibIn, kVibIn) = dv;
    q_(kVibQuad, kVibQuad) = dv;
  }

  q_accel_ = q_;
  // Hall only: the acceleration is a random walk of its own, the jerk state rests.
  q_hall_only_ = q_;
  const double dh = tuning.hall_only_jerk_std_mps3 * t;
  q_hall_only_(kAcc, kAcc) = dh * dh;
  q_hall_only_(kJerk, kJerk) = 0.0;

  // Calm model: the jerk state rests (as without the accelerometer) and a small
  // white jerk drives the acceleration.
  q_steady_ = q_;
  const double ds = tuning.steady_jerk_std_mps3 * t;
  q_steady_(kAcc, kAcc) = ds * ds;
  q_steady_(kJerk, kJerk) = 0.0;
  // ... and the position a small random walk of its own, so that it keeps
  // following the Halls at about the agile model's pace while the velocity
  // averages over the calm phase.
  const double dx = tuning.steady_position_walk_m_per_sqrt_s * std::sqrt(t);
  q_steady_(kPos, kPos) = dx * dx;
  excess_q_ = Eigen::Vector3d(dx * dx, 0.0, ds * ds);
  steady_floor_delta_m2_ = tuning.hall_position_floor_m * tuning.hall_position_floor_m -
                          tuning.steady_hall_position_floor_m * tuning.steady_hall_position_floor_m;
  hold_samples_ = std::max(1, static_cast<int>(std::lround(tuning.steady_hold_s / t)));
  bias_step_settle_ = std::max(0, static_cast<int>(std::lround(kBiasStepSettleS / t)));

  const double d = model.hall_delay_s;
  h_hall_(kPos) = 1.0;
  h_hall_(kVel) = -d;
  h_hall_(kAcc) = d * d / 2.0;
  h_hall_(kJerk) = jerk ? -d * d * d / 6.0 : 0.0;
}

void FusionFilter::reset(double position_m, double position_var_m2, double accel_reading_mps2, bool accel_valid) {
  x_.setZero();
  p_.setZero();
  delay_sens_.setZero();
  clear_detectors();
  hall_updates_ = 0;
  steady_ = false;
  fix_count_ = 0;
  q_ = accel_available_ ? q_accel_ : q_hall_only_;
  const double a0 = accel_valid ? (accel_reading_mps2 - model_.accel_bias_mps2) / model_.accel_scale : 0.0;
  x_(kPos) = position_m;
  x_(kAcc) = a0;
  x_(kBias) = model_.accel_bias_mps2;
  x_(kScale) = model_.accel_scale;
  p_(kPos, kPos) = position_var_m2;
  p_(kVel, kVel) = tuning_.initial_velocity_std_mps * tuning_.initial_velocity_std_mps;
  const double sa = accel_valid ? tuning_.accel_bias_std_mps2 + 0.05 : tuning_.initial_acceleration_std_mps2;
  p_(kAcc, kAcc) = sa * sa;
  if (tuning_.snap_std_mps4 > 0.0) p_(kJerk, kJerk) = 100.0 * 100.0;  // [m/s^3]^2: unknown at start
  p_(kBias, kBias) = tuning_.accel_bias_std_mps2 * tuning_.accel_bias_std_mps2;
  p_(kScale, kScale) = tuning_.accel_scale_std * tuning_.accel_scale_std;
  // The fix is where the carriage was hall_delay ago: x(t) = z + d v with v still
  // unknown, so position and velocity start correlated (otherwise a start in
  // motion would take the first fix for the present and misjudge the speed).
  const double d = model_.hall_delay_s;
  p_(kPos, kPos) += d * d * p_(kVel, kVel);
  p_(kPos, kVel) = p_(kVel, kPos) = d * p_(kVel, kVel);
  if (vibration_) {
    const double sv = std::max(model_.frame_vibration_mps2, 0.01);
    p_(kVibIn, kVibIn) = sv * sv;
    p_(kVibQuad, kVibQuad) = sv * sv;
  }
}

bool FusionFilter::doubt_vibration() {
  if (!vibration_) return false;
  const double amplitude = std::hypot(x_(kVibIn), x_(kVibQuad));
  const double sd = std::sqrt(0.5 * (p_(kVibIn, kVibIn) + p_(kVibQuad, kVibQuad)));
  if (amplitude <= model_.frame_vibration_mps2 + kVibrationDoubtSigma * sd) return false;
  const double sv = std::max(model_.frame_vibration_mps2, 0.01);
  for (int s : {static_cast<int>(kVibIn), static_cast<int>(kVibQuad)}) {
    x_(s) = 0.0;
    delay_sens_(s) = 0.0;
    p_.row(s).setZero();
    p_.col(s).setZero();
    p_(s, s) = sv * sv;
  }
  return true;
}

void FusionFilter::predict() {
  ++k_;
  // A is block diagonal: kinematics (x, v, a, j), identity (bias, scale) and the
  // resonator's rotation. Multiplying by the blocks costs a fifth of 8x8 products.
  constexpr int K = kPos, B = kBias, V = kVibIn;
  const auto ak = a_.block<4, 4>(K, K);
  const auto av = a_.block<2, 2>(V, V);
  x_.segment<4>(K) = (ak * x_.segment<4>(K)).eval();
  x_.segment<2>(V) = (av * x_.segment<2>(V)).eval();
  delay_sens_.segment<4>(K) = (ak * delay_sens_.segment<4>(K)).eval();
  delay_sens_.segment<2>(V) = (av * delay_sens_.segment<2>(V)).eval();

  p_.block<4, 4>(K, K) = (ak * p_.block<4, 4>(K, K) * ak.transpose()).eval();
  p_.block<4, 2>(K, B) = (ak * p_.block<4, 2>(K, B)).eval();
  p_.block<4, 2>(K, V) = (ak * p_.block<4, 2>(K, V) * av.transpose()).eval();
  p_.block<2, 2>(B, V) = (p_.block<2, 2>(B, V) * av.transpose()).eval();
  p_.block<2, 2>(V, V) = (av * p_.block<2, 2>(V, V) * av.transpose()).eval();
  // Lower blocks mirror the upper ones.
  p_.block<2, 4>(B, K) = p_.block<4, 2>(K, B).transpose();
  p_.block<2, 4>(V, K) = p_.block<4, 2>(K, V).transpose();
  p_.block<2, 2>(V, B) = p_.block<2, 2>(B, V).transpose();
  p_.block<4, 4>(K, K) = (0.5 * (p_.block<4, 4>(K, K) + p_.block<4, 4>(K, K).transpose())).eval();
  p_.block<2, 2>(B, B) = (0.5 * (p_.block<2, 2>(B, B) + p_.block<2, 2>(B, B).transpose())).eval();
  p_.block<2, 2>(V, V) = (0.5 * (p_.block<2, 2>(V, V) + p_.block<2, 2>(V, V).transpose())).eval();
  p_ += q_;
  if (steady_) {
    const Eigen::Matrix3d a3 = a_.block<3, 3>(K, K);
    excess_ = (a3 * excess_ * a3.transpose()).eval();
    excess_.diagonal() += excess_q_;
  }
}

void FusionFilter::set_accelerometer_available(bool available) {
  if (available == accel_available_) return;
  accel_available_ = available;
  steady_ = false;
  clear_detectors();
  hall_updates_ = 0;
  fix_count_ = 0;
  q_ = available ? q_accel_ : q_hall_only_;
  if (!available) {
    // Freeze the jerk at zero: without the accelerometer nothing observes it well.
    x_(kJerk) = 0.0;
    p_.row(kJerk).setZero();
    p_.col(kJerk).setZero();
  } else if (tuning_.snap_std_mps4 > 0.0) {
    p_(kJerk, kJerk) = 100.0 * 100.0;
  }
}

void FusionFilter::inflate(double position_var_m2, double velocity_var, double acceleration_var) {
  p_(kPos, kPos) += position_var_m2;
  p_(kVel, kVel) += velocity_var;
  p_(kAcc, kAcc) += acceleration_var;
  // The prediction was wrong: whatever the acceleration did, it did not hold still.
  if (steady_) leave_steady(nullptr, 0.0, 0.0);
}

void FusionFilter::clear_detectors() {
  win_.fill(0.0);
  win_head_ = 0;
  win_filled_ = 0;
  win_old_ = win_new_ = 0.0;
  calm_count_ = 0;
  acc_up_ = acc_down_ = Cusum{};
  hall_up_ = hall_down_ = Cusum{};
}

bool FusionFilter::cusum_step(Cusum& c, double z, double nu, double drift, double threshold) {
  const double g = c.g + z - drift;
  if (g <= 0.0) {
    c = Cusum{};
    return false;
  }
  c.g = g;
  c.s0 += nu;
  c.s1 += c.n * nu;
  c.n += 1.0;
  return g > threshold;
}

void FusionFilter::enter_steady() {
  steady_ = true;
  q_ = q_steady_;
  x_(kJerk) = 0.0;
  delay_sens_(kJerk) = 0.0;  // the jerk is held at 0 in the calm model
  p_.row(kJerk).setZero();
  p_.col(kJerk).setZero();
  acc_up_ = acc_down_ = Cusum{};
  excess_.setZero();
  seed_from_fixes();
}

void FusionFilter::seed_from_fixes() {
  // The agile model integrated the accelerometer's noise into the velocity while
  // the acceleration was in fact holding still; the Hall fixes of that window say
  // more. Fit x(t) = x + v t + a t^2 / 2 (t <= 0 now) to them, each fix taken at
  // t - hall_delay, and start the calm model from the fit where it knows better.
  const int n = std::min(fix_count_, std::min(kFixes, 2 * kWin + hold_samples_));
  if (n < 16) return;
  const double d = model_.hall_delay_s;
  // Normal equations in scaled time u = t / T (conditioning).
  const double span = static_cast<double>(k_ - fix_k_[static_cast<std::size_t>((fix_head_ - n + kFixes) % kFixes)]) * ts_ + d;
  if (!(span > 0.0)) return;
  const double inv_span = 1.0 / span;
  Eigen::Matrix3d nm = Eigen::Matrix3d::Zero();
  Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
  for (int i = 0; i < n; ++i) {
    const auto j = static_cast<std::size_t>((fix_head_ - 1 - i + kFixes) % kFixes);
    const double u = (-static_cast<double>(k_ - fix_k_[j]) * ts_ - d) * inv_span;
    const Eigen::Vector3d g(1.0, u, 0.5 * u * u);
    const double w = 1.0 / std::max(1.0 / fix_w_[j] - steady_floor_delta_m2_, 0.25 / fix_w_[j]);
    nm.noalias() += w * g * g.transpose();
    rhs.noalias() += w * fix_z_[j] * g;
  }
  Eigen::LDLT<Eigen::Matrix3d> ldlt(nm);
  if (ldlt.info() != Eigen::Success) return;
  const Eigen::Vector3d c = ldlt.solve(rhs);
  Eigen::Matrix3d cov = ldlt.solve(Eigen::Matrix3d::Identity());
  // Back to seconds: c = (x, v T, a T^2).
  const Eigen::Vector3d scale(1.0, inv_span, inv_span * inv_span);
  const Eigen::Vector3d fit = c.cwiseProduct(scale);
  cov = scale.asDiagonal() * cov * scale.asDiagonal();
  // Only where the fit knows the velocity better, and agrees with the filter.
  const double pv = p_(kVel, kVel);
  if (!(cov(1, 1) < pv)) return;
  const double dv = fit(1) - x_(kVel);
  if (dv * dv > 9.0 * (pv + cov(1, 1))) return;
  x_(kPos) = fit(0);
  x_(kVel) = fit(1);
  x_(kAcc) = fit(2);
  delay_sens_.head<3>().setZero();  // the fixes do not depend on the accelerometer
  for (int r = kPos; r <= kAcc; ++r) {
    p_.row(r).setZero();
    p_.col(r).setZero();
  }
  p_.block<3, 3>(kPos, kPos) = cov;
}

void FusionFilter::leave_steady(const Cusum* c, double last_nu, double r) {
  steady_ = false;
  excess_.setZero();
  calm_count_ = 0;
  q_ = q_accel_;
  if (c != nullptr && c->n > 0.0) {
    // The calm model barely followed the accelerometer since the change began, so
    // its innovations are what it missed: add them back as the agile model would
    // have integrated them, with their noise in the covariance.
    const double inv = 1.0 / x_(kScale);
    const double n = c->n, t = ts_;
    x_(kAcc) += last_nu * inv;
    x_(kVel) += t * c->s0 * inv;
    x_(kPos) += t * t * (n * c->s0 - c->s1) * inv;
    p_(kAcc, kAcc) += r * inv * inv;
    p_(kVel, kVel) += n * r * t * t * inv * inv;
    p_(kPos, kPos) += n * n * n / 3.0 * r * t * t * t * t * inv * inv;
  }
  if (tuning_.snap_std_mps4 > 0.0) p_(kJerk, kJerk) = 100.0 * 100.0;
  acc_up_ = acc_down_ = Cusum{};
}

void FusionFilter::steady_test(double reading) {
  // Two consecutive windows of kWin readings; the difference of their means over
  // their spacing estimates the jerk. Sums kept incrementally, recomputed once per
  // turn of the ring so rounding cannot accumulate.
  const int mid_i = (win_head_ + kWin) % (2 * kWin);
  const double oldest = win_[static_cast<std::size_t>(win_head_)];
  const double mid = win_[static_cast<std::size_t>(mid_i)];
  win_old_ += mid - oldest;
  win_new_ += reading - mid;
  win_[static_cast<std::size_t>(win_head_)] = reading;
  win_head_ = (win_head_ + 1) % (2 * kWin);
  if (win_head_ == 0) {
    double a = 0.0, b = 0.0;
    for (int i = 0; i < kWin; ++i) a += win_[static_cast<std::size_t>(i)];
    for (int i = kWin; i < 2 * kWin; ++i) b += win_[static_cast<std::size_t>(i)];
    win_old_ = a;
    win_new_ = b;
  }
  if (win_filled_ < 2 * kWin) {
    ++win_filled_;
    return;
  }
  if (!(tuning_.steady_jerk_std_mps3 > 0.0)) return;
  const double jerk = std::abs(win_new_ - win_old_) / (static_cast<double>(kWin) * kWin * ts_);
  const double limit = tuning_.steady_jerk_limit_mps3;
  if (steady_) {
    // A slow change of acceleration that the innovations do not reveal yet.
    if (jerk > 2.0 * limit) leave_steady(nullptr, 0.0, 0.0);
    return;
  }
  // The windows' estimate lags by a window; the agile model's jerk state does not.
  calm_count_ = jerk < limit ? calm_count_ + 1 : 0;
  if (calm_count_ >= hold_samples_) enter_steady();
}

double FusionFilter::scalar_update(const Row& h, double innovation, double r, double gate_sigma, bool& applied) {
  const Vec ph = p_ * h.transpose();
  const double s = h.dot(ph) + r;
  const double nu_norm = innovation / std::sqrt(s);
  applied = !(gate_sigma > 0.0 && std::abs(nu_norm) > gate_sigma);
  if (!applied) return nu_norm;
  const Vec k = ph / s;
  x_ += k * innovation;
  // The estimate's sensitivity to the accelerometer's delay goes through the update
  // as the estimate does: x += k (z - h x).
  delay_sens_ -= k * h.dot(delay_sens_);
  last_gain_ = k;
  if (steady_) {
    // Joseph form of the update on the excess (no measurement noise in it).
    const Eigen::Vector3d k3 = k.head<3>();
    const Eigen::Vector3d u = excess_ * h.head<3>().transpose();
    const double hu = h.head<3>().dot(u);
    excess_ += hu * k3 * k3.transpose() - k3 * u.transpose() - u * k3.transpose();
  }
  // k ph' = ph ph' / s is symmetric; rounding asymmetry is removed once per predict().
  p_.noalias() -= k * ph.transpose();
  return nu_norm;
}

double FusionFilter::update_hall(double z_m, double r_m2, double gate_sigma, bool& applied) {
  // The calm model averages many fixes: it takes their variance with its own floor.
  if (steady_) r_m2 = std::max(r_m2 - steady_floor_delta_m2_, 0.25 * r_m2);
  const double nu_norm = scalar_update(h_hall_, z_m - h_hall_.dot(x_), r_m2, gate_sigma, applied);
  if (applied) {
    const auto j = static_cast<std::size_t>(fix_head_);
    fix_z_[j] = z_m;
    fix_w_[j] = 1.0 / r_m2;
    fix_k_[j] = k_;
    fix_head_ = (fix_head_ + 1) % kFixes;
    fix_count_ = std::min(fix_count_ + 1, kFixes);
  }
  const double h = tuning_.accel_bias_step_cusum;
  // While the filter settles after a (re)start its Hall innovations lean one way
  // for a while (initial velocity, jerk and bias uncertain); that is not a bias step.
  if (hall_updates_ < bias_step_settle_) {
    ++hall_updates_;
    return nu_norm;
  }
  if (accel_available_ && h > 0.0) {
    // Hall innovations persistently of one sign: the accelerometer's reading moved
    // without the carriage (a bias step). Free the bias state to follow it.
    // A bias step shows as innovations that grow sample after sample; one far
    // beyond the gate is a step of acceleration (or a spike) seen by the Halls
    // first, and counts no more than the gate.
    const double z = gate_sigma > 0.0 ? std::clamp(nu_norm, -gate_sigma, gate_sigma) : nu_norm;
    const bool up = cusum_step(hall_up_, z, 0.0, 1.0, h);
    const bool down = cusum_step(hall_down_, -z, 0.0, 1.0, h);
    if (up || down) {
      const double sb = tuning_.accel_bias_step_std_mps2;
      p_(kBias, kBias) += sb * sb;
      ++bias_steps_;
      hall_up_ = hall_down_ = Cusum{};
      if (steady_) leave_steady(nullptr, 0.0, 0.0);
    }
  }
  return nu_norm;
}

double FusionFilter::update_accel(double z_mps2, double r, double gate_sigma, bool& applied) {
  // Reading = scale * a(t - delay) + bias + vibration, a(t - delay) = a - delay j.
  // Linearised about the current scale (an EKF step).
  const double d = model_.accel_delay_s;
  const double a_delayed = x_(kAcc) - d * x_(kJerk);
  const double scale = x_(kScale);
  Row h = Row::Zero();
  h(kAcc) = scale;
  h(kJerk) = -scale * d;
  h(kBias) = 1.0;
  h(kScale) = a_delayed;
  if (vibration_) h(kVibIn) = 1.0;
  const double vib = vibration_ ? x_(kVibIn) : 0.0;
  const double predicted = scale * a_delayed + x_(kBias) + vib;
  const double nu = z_mps2 - predicted;
  // A step of acceleration (a drive without a jerk limit commands them): far beyond
  // what the model lets the acceleration do in one sample, so the update would give
  // most of it to the bias (in the calm model, all of it). The acceleration is
  // opened by the size of the step first, and the calm model left.
  bool step = false;
  if (std::abs(nu) > kAccelStepSigma * std::sqrt(r)) {
    const double s_pred = h.dot(p_ * h.transpose()) + r;
    if (std::abs(nu) > kAccelStepSigma * std::sqrt(s_pred) && !(gate_sigma > 0.0 && std::abs(nu) > gate_sigma * std::sqrt(s_pred))) {
      step = true;
      if (steady_) leave_steady(nullptr, 0.0, 0.0);
      const double da = nu / scale;
      p_(kAcc, kAcc) += da * da;
    }
  }
  const double a_before = x_(kAcc);
  const double jerk_before = x_(kJerk);
  const double nu_norm = scalar_update(h, nu, r, gate_sigma, applied);
  if (!applied) return nu_norm;  // a spike tells nothing about the motion
  // Had the delay been longer by e, the reading would have been scale * j * e
  // lower than predicted, and the update would have taken that in (the sensitivity
  // is the estimate's error per second of delay error).
  delay_sens_ -= last_gain_ * (scale * jerk_before);
  // The reading shows a step after it happened, and the jerk state, made for
  // smooth changes, cannot say so: what the carriage did in the meantime at the new
  // acceleration is added, as it happened.
  if (step) {
    // It happened between d and d + ts ago (the reading before this one did not
    // show it yet): half a period more than the delay, on average.
    const double since = d + 0.5 * ts_;
    const double da = x_(kAcc) - a_before;
    x_(kVel) += da * since;
    x_(kPos) += 0.5 * da * since * since;
    // A delay longer by e: the step happened e earlier than added for here.
    delay_sens_(kVel) -= da;
    delay_sens_(kPos) -= da * since;
    // When within the period it happened is uniform over ts: that much velocity
    // and position are unknown, which the Hall fixes settle in a few samples.
    const double var_t = ts_ * ts_ / 12.0;
    const double gv = da, gp = da * since;  // d(velocity), d(position) per second of "since"
    p_(kVel, kVel) += gv * gv * var_t;
    p_(kPos, kPos) += gp * gp * var_t;
    p_(kPos, kVel) += gp * gv * var_t;
    p_(kVel, kPos) += gp * gv * var_t;
    // The Hall innovations lean one way until then: that is the step, not the bias.
    hall_up_ = hall_down_ = Cusum{};
  }
  steady_test(z_mps2 - vib);
  if (steady_) {
    const double th = tuning_.steady_exit_cusum;
    if (cusum_step(acc_up_, nu_norm, nu, 1.0, th)) {
      const Cusum c = acc_up_;
      leave_steady(&c, nu, r);
    } else if (cusum_step(acc_down_, -nu_norm, nu, 1.0, th)) {
      const Cusum c = acc_down_;
      leave_steady(&c, nu, r);
    }
  }
  return nu_norm;
}

double FusionFilter::position_variance() const {
  const double p = p_(kPos, kPos);
  const double sys = tuning_.hall_systematic_std_m;
  const double dly = delay_sens_(kPos) * model_.accel_delay_std_s;
  return std::max(p - excess_(0, 0), 0.1 * p) + sys * sys + dly * dly;
}

double FusionFilter::velocity_variance() const {
  const double p = p_(kVel, kVel);
  const double dly = delay_sens_(kVel) * model_.accel_delay_std_s;
  return std::max(p - excess_(1, 1), 0.1 * p) + dly * dly;
}

double FusionFilter::vibration_amplitude_mps2() const {
  return vibration_ ? std::hypot(x_(kVibIn), x_(kVibQuad)) : 0.0;
}

}  // namespace ve::core
