#include "hall_adaptation.hpp"

#include <algorithm>
#include <cmath>

namespace ve::core {

HallAdaptation::HallAdaptation(const MotorConfig& motor, double ts_s, const SensorModel* model)
    : enabled_(motor.filter.hall_adaptation),
      sensors_(std::min(motor.hall.count, kMaxHalls)),
      mid_v_(motor.hall.offset_v),
      lo_v_(motor.adc.min_v + motor.hall.saturation_margin_v),
      hi_v_(motor.adc.max_v - motor.hall.saturation_margin_v) {
  const auto& f = motor.filter;
  const double lsb = motor.adc.lsb_v();
  noise_var_v2_ = motor.hall.noise_v * motor.hall.noise_v + lsb * lsb / 12.0;
  q_gain_ = f.hall_gain_random_walk_per_sqrt_s * f.hall_gain_random_walk_per_sqrt_s * ts_s;
  q_offset_ = f.hall_offset_random_walk_v_per_sqrt_s * f.hall_offset_random_walk_v_per_sqrt_s * ts_s;
  gain_limit_ = f.hall_gain_limit;
  offset_limit_v_ = f.hall_offset_limit_v;
  reopen_threshold_ = f.hall_drift_cusum;
  max_shift_m_ = 1e-2 * motor.magnet_pitch_m;
  // Farther from the rails than the largest gain change followed moves a reading.
  rail_guard_v_ = f.hall_gain_limit * motor.hall.amplitude_v;
  reopen_gain_var_ = f.hall_gain_reopen_std * f.hall_gain_reopen_std;
  reopen_offset_var_ = f.hall_offset_reopen_std_v * f.hall_offset_reopen_std_v;
  p0_gg_ = f.hall_gain_initial_std * f.hall_gain_initial_std;
  p0_dd_ = f.hall_offset_initial_std_v * f.hall_offset_initial_std_v;
  for (int i = 0; i < sensors_; ++i) {
    pgg(i) = look_gg_[static_cast<std::size_t>(i)] = p0_gg_;
    pdd(i) = look_dd_[static_cast<std::size_t>(i)] = p0_dd_;
  }
  q_common_ = f.hall_common_gain_random_walk_per_sqrt_s * f.hall_common_gain_random_walk_per_sqrt_s * ts_s;
  p0_common_ = f.hall_common_gain_initial_std * f.hall_common_gain_initial_std;
  p_common_ = p0_common_;
  model_var_common_ = f.hall_common_gain_model_std * f.hall_common_gain_model_std;
  model_var_v2_ = f.hall_adaptation_model_std_v * f.hall_adaptation_model_std_v;
  common_tc_per_k_ = f.magnet_remanence_tc_per_k + f.hall_gain_tc_per_k;
  tc_rel_std_ = f.temperature_coefficient_rel_std;
  gain_tc_std_.fill(f.hall_gain_tc_std_per_k);
  offset_tc_std_v_.fill(f.hall_offset_tc_std_v_per_k);
  thermal_ = model != nullptr && model->thermal_known;
  if (thermal_) {
    if (std::isfinite(model->common_tc_per_k) && std::abs(model->common_tc_per_k) > 0.0) {
      common_tc_per_k_ = model->common_tc_per_k;
      if (std::isfinite(model->common_tc_rel_std)) tc_rel_std_ = model->common_tc_rel_std;
    }
    for (int i = 0; i < sensors_; ++i) {
      const auto k = static_cast<std::size_t>(i);
      gain_tc_[k] = model->hall_gain_tc_per_k[k];
      offset_tc_v_[k] = model->hall_offset_tc_v_per_k[k];
      gain_tc_std_[k] = model->hall_gain_tc_std_per_k[k];
      offset_tc_std_v_[k] = model->hall_offset_tc_std_v_per_k[k];
    }
  }
  for (int i = 0; i < sensors_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    gain_coefficient_[k] = Coefficient{p0_gg_, gain_tc_std_[k] * gain_tc_std_[k]};
    offset_coefficient_[k] = Coefficient{p0_dd_, offset_tc_std_v_[k] * offset_tc_std_v_[k]};
  }
  unread_rise_var_k2_ = f.hall_unread_temperature_rise_k * f.hall_unread_temperature_rise_k;
  for (int i = 0; i < sensors_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    unread_gain_var_ = std::max(unread_gain_var_, gain_tc_[k] * gain_tc_[k] + gain_tc_std_[k] * gain_tc_std_[k]);
    unread_offset_var_ =
        std::max(unread_offset_var_, offset_tc_v_[k] * offset_tc_v_[k] + offset_tc_std_v_[k] * offset_tc_std_v_[k]);
  }
  ts_s_ = ts_s;
  temperature_alpha_ = 1.0 - std::exp(-ts_s / kTemperatureAverageS);
  infer_decay_ = std::exp(-ts_s / kInferAverageS);
  infer_first_samples_ = static_cast<std::uint64_t>(std::ceil(kInferFirstS / ts_s));
}

double HallAdaptation::Coefficient::step(double x, double p, double r, double d_k, double cap, double s2, bool predict) {
  // The parameter at the rise r is a + c r: a what it held at the calibration, c the
  // sensor's coefficient, both with priors (the start-up one, the data sheet's spread).
  // The learning holds it as x known to p, from the unlearnt track (what the steps and
  // predictions alone would have made of it: mean u, variance pu) and what the fixes
  // said since the last step: that part is a measurement m known to v,
  // 1 / v = 1 / p - 1 / pu and m = v (x / p - u / pu), of a + c r, which updates (a, c).
  // Where the fixes explained less than kLearntCoefficientShare of the prior (the
  // carriage has stood since the last step, or too few sensors to tell a gain from an
  // offset), x moved mostly through its correlations with the other sensors, not by a
  // measurement of its own, and is not taken for one.
  const double rho = 1.0 - p / pu;
  if (rho >= kLearntCoefficientShare && p > 0.0) {
    const double v = p / rho;
    const double m = v * (x / p - u / pu);
    const double ha = paa + r * pac, hc = pac + r * pcc;
    const double sv = ha + r * hc + v;
    const double ka = ha / sv, kc = hc / sv;
    const double nu = m - (a + c * r);
    a += ka * nu;
    c += kc * nu;
    paa -= ka * ha;
    pac -= ka * hc;
    pcc -= kc * hc;
  }
  // The step to r + d_k moves the parameter by c d_k; what is left of c widens it.
  // Not predicted, it widens by the whole spread s2.
  if (!predict) {
    u = x;
    pu = std::min(p + s2 * d_k * d_k, cap);
    return 0.0;
  }
  u = x + c * d_k;
  pu = std::min(p + pcc * d_k * d_k, cap);
  return c;
}

void HallAdaptation::widen_for_rise(double from_k, double to_k) {
  const double limit2 = gain_limit_ * gain_limit_;
  // A sensor's coefficient is one number: what it moves the sensor by over a rise
  // taken in steps is its coefficient times the whole rise, not a sum of independent
  // steps. Steps of a quarter kelvin away from the calibration widened by the sum of
  // their squares (a ramp to 10 K: 2.5 K^2 where 100 K^2 is due), and the first
  // readings of the fixes' thermometer climb to the rise over tens of ms (motor 80 of
  // the population, 10 K cold: -2.5, -5.7, -7.9 ... -10.7 K; its sensors' offsets
  // were held to 1.1 mV where they had moved by 3.7-4.9 mV, and the axis was VALID
  // 12 um off under a sigma of 2.3 um). What the published sigma holds (look_gg_,
  // look_dd_) widens by the larger of a step's own square and what it adds to the
  // square of the farthest rise from the calibration widened for so far (the way out,
  // as if nothing had been learnt on it; steps back and forth within that, a
  // thermometer's noise at a standstill, by their own squares only). The learning's
  // own covariance widens by the step's square: widened by the whole rise, it let the
  // first fixes of a start from rest move 2-sensor motors' gains and offsets by their
  // noise (motor 8, 10 K cold: 5.0 um where it had been 3.5 um).
  const double d_k = to_k - from_k;
  const double d2 = d_k * d_k;
  const double d2_published = std::max(d2, to_k * to_k - farthest_k2_);
  farthest_k2_ = std::max(farthest_k2_, to_k * to_k);
  // Once the motor is a kelvin or more from its calibration, the sensors' drift
  // outgrows the prior and is learnt jointly (see joint_update).
  widened_k2_ += d2;
  if (!joint_ && widened_k2_ >= kJointFromK * kJointFromK) {
    joint_ = true;
    for (int i = 0; i < sensors_; ++i) {
      look_gg_[static_cast<std::size_t>(i)] = pgg(i);
      look_dd_[static_cast<std::size_t>(i)] = pdd(i);
    }
  }
  // Without a thermal calibration each sensor's coefficient is unknown but one number,
  // and what the sensor has been seen to drift by at the rise so far says what it is.
  // Widened by the data sheet's spread at every step instead, a sensor whose
  // coefficient is a 2.6-sigma draw stayed 0.3 mV behind on a 10 K per minute ramp,
  // three times what the learning allowed for (motor 72 of the population, +2sigma
  // position coverage 75 % in the multi-sine). See Coefficient::step().
  const double r = from_k;  // the rise the learning has seen since the last step
  // A motor's temperature does not move by a step within kLearntCoefficientStepS: steps
  // closer together are the fixes' thermometer settling (its first readings after a
  // start climb to the rise in tens of ms) or its noise, which the sensors do not
  // follow. Moved by them, a motor started 10 K warm (motor 80 of the population) was
  // VALID 5.8 um off.
  const bool predict = !thermal_ && static_cast<double>(clock_ - last_step_clock_) * ts_s_ >= kLearntCoefficientStepS;
  last_step_clock_ = clock_;
  for (int i = 0; i < sensors_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double sg2 = gain_tc_std_[k] * gain_tc_std_[k], sd2 = offset_tc_std_v_[k] * offset_tc_std_v_[k];
    // The learning widens by what is left of the coefficient; the published looks by
    // the spread (as if nothing had been learnt on the way out).
    double learn_g2 = sg2, learn_d2 = sd2;
    if (!thermal_) {
      auto& cg = gain_coefficient_[k];
      auto& cd = offset_coefficient_[k];
      const double c_g = cg.step(gamma_[k], pgg(i), r, d_k, limit2, sg2, predict);
      const double c_d = cd.step(delta_[k], pdd(i), r, d_k, HUGE_VAL, sd2, predict);
      if (predict) {
        move_sensor_by_rise(i, c_g * d_k, c_d * d_k);
        learn_g2 = cg.pcc;
        learn_d2 = cd.pcc;
      }
    }
    pgg(i) = std::min(pgg(i) + learn_g2 * d2, limit2);
    pdd(i) += learn_d2 * d2;
    look_gg_[k] = std::min(look_gg_[k] + sg2 * d2_published, limit2);
    look_dd_[k] += sd2 * d2_published;
  }
}

void HallAdaptation::widen_for_unread_share(double var_k2) {
  // A reading is the rise only as far as it is known. Where the carriage stands on
  // two sensors, the fixes read the common gain to a few percent: the thermometer
  // said 1.5 K for 9.4 K (motor 80 of the population, with a ruler, +10 K at
  // standstill), the published sigma held the sensors' drift for 1.5 K (offsets to
  // 0.5 mV where they had moved by 3.5-4.6 mV), and the position was 50 um off under a
  // sigma of 4.8 um. What is not read of the rise is still as wide as the unread band
  // (hall_unread_temperature_rise_k) allows, as before the first reading: the same
  // posterior variance follow_rise keeps with a thermal calibration, here for the
  // published looks only (the learning keeps widening by the reading: widened by the
  // band it moved two-sensor motors' gains and offsets by their noise at a start).
  if (thermal_ || !(var_k2 > 0.0)) return;
  const double post = unread_rise_var_k2_ * var_k2 / (unread_rise_var_k2_ + var_k2);
  if (!(post > unread_share_var_k2_)) return;
  const double add = post - unread_share_var_k2_;
  unread_share_var_k2_ = post;
  const double limit2 = gain_limit_ * gain_limit_;
  for (int i = 0; i < sensors_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    look_gg_[k] = std::min(look_gg_[k] + gain_tc_std_[k] * gain_tc_std_[k] * add, limit2);
    look_dd_[k] += offset_tc_std_v_[k] * offset_tc_std_v_[k] * add;
  }
}

void HallAdaptation::follow_rise(double to_k, double var_k2) {
  // A thermal calibration measured each sensor's own coefficients: the rise moves
  // its gain and offset by them (a prediction, what the learning then corrects),
  // and widen_for_rise widens by what the coefficients leave, not by their spread.
  if (!thermal_ || !std::isfinite(to_k)) return;
  // A rise read poorly is followed as far as it is known against the spread of an
  // unread one (the fixes' thermometer where the carriage stands on two sensors reads
  // the common gain to a percent or worse: motor 69 of the population, as calibrated,
  // read -2 to -3 K and its sensors, moved by that, put it 2.6 um off where it had
  // been 0.8), and the covariance holds what the coefficients make of the rest.
  if (var_k2 > 0.0) {
    const double post = unread_rise_var_k2_ * var_k2 / (unread_rise_var_k2_ + var_k2);
    to_k *= unread_rise_var_k2_ / (unread_rise_var_k2_ + var_k2);
    if (post > follow_var_k2_) {
      const double add = post - follow_var_k2_;
      follow_var_k2_ = post;
      const double limit2 = gain_limit_ * gain_limit_;
      for (int i = 0; i < sensors_; ++i) {
        const auto k = static_cast<std::size_t>(i);
        const double g2 = gain_tc_[k] * gain_tc_[k] * add, d2 = offset_tc_v_[k] * offset_tc_v_[k] * add;
        pgg(i) = std::min(pgg(i) + g2, limit2);
        pdd(i) += d2;
        look_gg_[k] = std::min(look_gg_[k] + g2, limit2);
        look_dd_[k] += d2;
      }
    }
  }
  const double d = to_k - followed_k_;
  followed_k_ = to_k;
  for (int i = 0; i < sensors_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    move_sensor_by_rise(i, gain_tc_[k] * d, offset_tc_v_[k] * d);
  }
}

void HallAdaptation::move_sensor_by_rise(int i, double d_gain, double d_offset_v) {
  move_sensor(i, d_gain, d_offset_v);
  // What the move does to a reading, at most: the filter widens by it (take_moved_v2).
  const double level = std::max(hi_v_ - mid_v_, mid_v_ - lo_v_);
  const double dv = std::abs(d_offset_v) + std::abs(d_gain) * level;
  moved_v2_ = std::max(moved_v2_, dv * dv);
}

void HallAdaptation::observe_fix_gain(double relative_change, double variance, double share,
                                      double offset_var_per_k2) {
  if (!enabled_ || temperature_known_ || !std::isfinite(relative_change) || !(variance > 0.0) ||
      !(std::abs(common_tc_per_k_) > 0.0))
    return;
  ++clock_;
  // A fix whose readings cannot tell the common gain from the position (one sensor
  // out of saturation, say) returns the gain it was given with the variance it was
  // given. Before anything is learnt that is the calibration's gain with the start-up
  // prior: taken as a reading, it said "no change of temperature", and a warm motor
  // standing there was VALID 10 um off (motor 52 of the population benchmark, 3
  // Halls, one out of saturation). A fix counts once the gain it returns is known to
  // at most kInferKnownShare of that prior's variance: from its own readings, or
  // from what the fixes before it taught.
  if (!reads_temperature(variance)) return;
  const double g = (1.0 + common_gain_) * (1.0 + relative_change) - 1.0;
  const double w = 1.0 / (variance + model_var_common_);
  infer_wg_ = infer_decay_ * infer_wg_ + w * g;
  infer_w_ = infer_decay_ * infer_w_ + w;
  // For how well the average knows the rise: its fixes' typical variance, divided by
  // the places they were taken at (a place is a quarter of a magnet period: 50 samples
  // of full share), not by their number.
  infer_n_ = infer_decay_ * infer_n_ + 1.0;
  infer_places_ = infer_decay_ * infer_places_ + std::clamp(share, 0.0, 1.0) / 50.0;
  // The sensors' offsets drift with the temperature too, each by its own coefficient,
  // and a drifted offset reads as a change of the common gain: by as much as the
  // unread band allows. Where two sensors are out of saturation that is most of what
  // a fix reads (motor 80 of the population, +10 K at standstill: the thermometer read
  // 1.5 K for 9.4 K and claimed to know it to 2.4 K). Not a weight of the reading (its
  // value is as before), but part of how well it is known (widen_for_unread_share).
  infer_wo_ = infer_decay_ * infer_wo_ + w * std::max(0.0, offset_var_per_k2) * unread_rise_var_k2_;
  if (++infer_samples_ < infer_first_samples_) return;
  const double read_var_k2 =
      infer_n_ / infer_w_ / (1.0 + infer_places_) / (common_tc_per_k_ * common_tc_per_k_);
  // The coefficients are known to tc_rel_std: the rise they imply, as far as it may be.
  const double read_k = infer_wg_ / infer_w_ / common_tc_per_k_;
  const double unsure_var_k2 =
      read_var_k2 + infer_wo_ / infer_w_ / (1.0 + infer_places_) / (common_tc_per_k_ * common_tc_per_k_);
  const double rise_k = read_k * std::sqrt(1.0 + tc_rel_std_ * tc_rel_std_);
  if (!inferred_started_) {
    inferred_started_ = true;
    inferred_k_ = rise_k;
    follow_rise(read_k, read_var_k2);
    widen_for_rise(0.0, rise_k);
    widen_for_unread_share(unsure_var_k2);
    return;
  }
  widen_for_unread_share(unsure_var_k2);
  // Then as temperature() follows a reported one: in steps of a quarter kelvin, each
  // step widening by what it allows (what was learnt in between stays learnt).
  const double d = rise_k - inferred_k_;
  if (std::abs(d) < 0.25) return;
  follow_rise(read_k, read_var_k2);
  widen_for_rise(inferred_k_, rise_k);
  inferred_k_ = rise_k;
}

void HallAdaptation::update_common(double relative_change, double variance, double share) {
  if (!enabled_ || !std::isfinite(relative_change) || !(variance > 0.0)) return;
  share = std::clamp(share, 0.0, 1.0);
  if (joint_) {
    common_jointly(relative_change, variance, share);
    return;
  }
  // The fix combined its sensors (information I) with the prior p_common_. Their
  // model is not exact (the table's own residual repeats along the travel), so
  // one fix says no more than model_var_common_: the update with the sensors'
  // estimate known to 1 / I + m instead of 1 / I. In closed form (stable for any I):
  // the change is relative_change (1 + p I) / (1 + p I + m I), the variance
  // p (1 + m I) / (1 + p I + m I).
  const double p = p_common_, m = model_var_common_;
  const double info = share * std::max(0.0, 1.0 / variance - 1.0 / p);
  const double den = 1.0 + p * info + m * info;
  const double change = relative_change * (1.0 + p * info) / den;
  const double g = 1.0 + common_gain_;
  common_gain_ = std::clamp(g * (1.0 + change) - 1.0, -gain_limit_, gain_limit_);
  p_common_ = std::max(p * (1.0 + m * info) / den, 1e-14);
}

void HallAdaptation::temperature(double delta_k) {
  if (!enabled_ || !std::isfinite(delta_k)) return;
  ++clock_;
  const double limit2 = gain_limit_ * gain_limit_;
  if (!temperature_known_) {
    // Known from the start: instead of the wide start-up prior of an unknown
    // temperature, what the data sheet predicts for this rise, as sure as the
    // coefficients and one reading of the node (its noise and resolution) are.
    temperature_known_ = true;
    temperature_k_ = smoothed_k_ = delta_k;
    const double g = common_tc_per_k_ * delta_k;
    common_gain_ = std::clamp(g, -gain_limit_, gain_limit_);
    const double sd = tc_rel_std_ * std::abs(g);
    const double sd_reading = common_tc_per_k_ * kReadingStdK;
    p_common_ = std::min(p0_gg_ + sd * sd + sd_reading * sd_reading, limit2);
    // Each sensor's spread for this rise; a reading's own error (kReadingStdK) moves
    // a sensor by far less than the start-up prior already allows for.
    follow_rise(delta_k);
    widen_for_rise(0.0, delta_k);
    return;
  }
  // The motor's temperature moves over minutes; the node's reading is noisy and
  // coarse: follow its average over a few seconds, in steps of a quarter kelvin.
  smoothed_k_ += temperature_alpha_ * (delta_k - smoothed_k_);
  const double d = smoothed_k_ - temperature_k_;
  if (std::abs(d) < 0.25) return;
  const double from_k = temperature_k_;
  temperature_k_ = smoothed_k_;
  const double dg = common_tc_per_k_ * d;
  common_gain_ = std::clamp((1.0 + common_gain_) * (1.0 + dg) - 1.0, -gain_limit_, gain_limit_);
  p_common_ = std::min(p_common_ + tc_rel_std_ * tc_rel_std_ * dg * dg, limit2);
  follow_rise(temperature_k_);
  widen_for_rise(from_k, temperature_k_);
}

double HallAdaptation::combined_variance(const std::array<double, kMaxHalls>& c,
                                         const std::array<double, kMaxHalls>& table_v, std::uint32_t mask,
                                         double& beyond_prior) const {
  beyond_prior = 0.0;
  if (!enabled_) return 0.0;
  // The sensors in `mask`, in order: every sum below runs over them in that order,
  // as sensor by sensor over the mask (the same terms added in the same order; the
  // list spares the inner loop a test per pair).
  int used[kMaxHalls];
  int m = 0;
  for (int i = 0; i < sensors_; ++i)
    if (mask >> i & 1u) used[m++] = i;
  double total = 0.0;
  if (!joint_) {
    // Sensor by sensor (no correlations): what each holds beyond its prior.
    double own_beyond = 0.0;
    for (int t = 0; t < m; ++t) {
      const int i = used[t];
      const auto k = static_cast<std::size_t>(i);
      own_beyond += c[k] * c[k] * drift_variance(i, table_v[k]);
      total += c[k] * c[k] * reading_variance(i, table_v[k]);
    }
    beyond_prior = own_beyond;
    return std::max(0.0, total);
  }
  // Jointly: the sensors' covariance with its correlations, and what the combination
  // holds beyond the prior's share.
  double cu[kMaxHalls], uu[kMaxHalls];
  for (int t = 0; t < m; ++t) {
    const auto k = static_cast<std::size_t>(used[t]);
    cu[t] = c[k];
    uu[t] = table_v[k] - mid_v_;
  }
  double prior = 0.0, looks = 0.0;
  for (int t = 0; t < m; ++t) {
    const auto k = static_cast<std::size_t>(used[t]);
    const double ci = cu[t], ui = uu[t];
    prior += ci * ci * (ui * ui * p0_gg_ + p0_dd_);
    looks += ci * ci * (ui * ui * look_gg_[k] + look_dd_[k]);
    const double* pg = p_[2 * used[t]];      // gamma_i's row
    const double* pd = p_[2 * used[t] + 1];  // delta_i's row
    for (int q = 0; q < m; ++q) {
      const int b = 2 * used[q];
      const double uj = uu[q];
      total += ci * cu[q] * (ui * uj * pg[b] + ui * pg[b + 1] + uj * pd[b] + pd[b + 1]);
    }
  }
  beyond_prior = std::max(0.0, std::max(total, looks) - prior);
  return std::max(0.0, total);
}

void HallAdaptation::correct(const RawSample& in, double common_mode_v, RawSample& out) const {
  out = in;
  if (!enabled_) return;
  for (int i = 0; i < sensors_; ++i) {
    const double y = in.hall_v[static_cast<std::size_t>(i)];
    if (!(y > lo_v_ && y < hi_v_)) continue;  // a rail reading stays a rail reading
    const auto k = static_cast<std::size_t>(i);
    // y = c + m + delta + (1 + G) (1 + gamma) (T - m)  =>  T = m + (y - c - m - delta) / ((1 + G) (1 + gamma))
    out.hall_v[k] =
        common_mode_v + mid_v_ + (y - common_mode_v - mid_v_ - delta_[k]) / ((1.0 + common_gain_) * (1.0 + gamma_[k]));
  }
}

double HallAdaptation::residual(const RawSample& raw, const HallTable& table, int i, double x_m, double common_mode_v,
                                double& std_v) const {
  const auto k = static_cast<std::size_t>(i);
  double t, slope;
  table.evaluate(i, x_m, t, slope);
  const double u = (1.0 + common_gain_) * (t - mid_v_);
  const double predicted = common_mode_v + mid_v_ + delta_[k] + (1.0 + gamma_[k]) * u;
  std_v = std::sqrt(noise_var_v2_ + reading_variance(i, t));
  return raw.hall_v[k] - predicted;
}


void HallAdaptation::update(const RawSample& raw, const HallTable& table, double x_m, double common_mode_v,
                            std::uint32_t mask, std::uint32_t learn_only_mask, double share) {
  if (!enabled_) return;
  // With thermal coefficients the first reading of the rise moves every sensor by what
  // the temperature did to it; what the sensors learnt before it would be counted
  // twice (motor 8 of the population, 10 K cold at 1 m/s: sensor 1 learnt 1.0 of its
  // 5.7 mV in the 10 ms before the first reading, and unlearning it was a magnet-period
  // pattern of 0.7 um in the position, 0.2 mm/s in the velocity).
  if (thermal_ && !temperature_checked()) return;
  share = std::clamp(share, 1e-9, 1.0);
  p_common_ = std::min(p_common_ + q_common_, p0_common_);
  for (int i = 0; i < sensors_; ++i) {
    // Random walk: the parameters may have moved since the last sample; unseen for
    // long (at standstill), no more unsure than at start-up.
    if (pgg(i) < p0_gg_) pgg(i) = std::min(pgg(i) + q_gain_, p0_gg_);
    if (pdd(i) < p0_dd_) pdd(i) = std::min(pdd(i) + q_offset_, p0_dd_);
    const auto k = static_cast<std::size_t>(i);
    if (look_gg_[k] < p0_gg_) look_gg_[k] = std::min(look_gg_[k] + q_gain_, p0_gg_);
    if (look_dd_[k] < p0_dd_) look_dd_[k] = std::min(look_dd_[k] + q_offset_, p0_dd_);
  }
  // Residuals of every usable sensor at the predicted position; when the sensors
  // together place the carriage away from it (the drift not learnt yet, or the
  // prediction off), once more where they place it, so that what is left is
  // linear in a small shift.
  std::array<double, kMaxHalls> r{}, u{}, sl{};
  std::uint32_t usable = 0;
  double s_sr = 0.0, s_ss = 0.0;
  residuals(raw, table, x_m, common_mode_v, mask, learn_only_mask, r, u, sl, usable, s_sr, s_ss);
  if (s_ss > 0.0 && std::abs(s_sr / s_ss) > 0.1 * max_shift_m_) {
    const double x1 = x_m + s_sr / s_ss;
    residuals(raw, table, x1, common_mode_v, mask, learn_only_mask, r, u, sl, usable, s_sr, s_ss);
  }
  learn(r, u, sl, usable, s_sr, s_ss, learn_only_mask, share);
}

void HallAdaptation::residuals(const RawSample& raw, const HallTable& table, double x_m, double common_mode_v,
                               std::uint32_t mask, std::uint32_t learn_only_mask, std::array<double, kMaxHalls>& r,
                               std::array<double, kMaxHalls>& u, std::array<double, kMaxHalls>& sl,
                               std::uint32_t& usable, double& s_sr, double& s_ss) const {
  usable = 0;
  s_sr = s_ss = 0.0;
  std::array<double, kMaxHalls> tv{}, sv{};
  table.evaluate_sensors(std::min(sensors_, table.sensors), x_m, tv.data(), sv.data());
  for (int i = 0; i < sensors_; ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (!(((mask | learn_only_mask) & raw.hall_valid_mask) >> i & 1u)) continue;
    const double y = raw.hall_v[k];
    if (!(y > lo_v_ && y < hi_v_)) continue;
    const double t = tv[k], slope = sv[k];
    // Where the table itself is at (or near) a rail it holds the clamp, not the
    // sensor's curve: a changed gain moves the reading off the rail there, which
    // the model cannot express. Such places teach nothing.
    if (!(t > lo_v_ + rail_guard_v_ && t < hi_v_ - rail_guard_v_)) continue;
    u[k] = (1.0 + common_gain_) * (t - mid_v_);
    sl[k] = (1.0 + common_gain_) * slope;
    r[k] = y - (common_mode_v + mid_v_ + delta_[k] + (1.0 + gamma_[k]) * u[k]);
    usable |= 1u << i;
    if (learn_only_mask >> i & 1u) continue;  // learns, but says nothing about the others
    s_sr += slope * r[k];
    s_ss += slope * slope;
  }
}

void HallAdaptation::learn(const std::array<double, kMaxHalls>& r, const std::array<double, kMaxHalls>& u,
                           const std::array<double, kMaxHalls>& sl, std::uint32_t usable, double s_sr, double s_ss,
                           std::uint32_t learn_only_mask, double share) {
  // First each sensor on its own: what a position error explains is the
  // position's business, not the sensor's, so the shift the other sensors see is
  // taken out (leave-one-out, so the sensor's own noise and drift are not in it),
  // and a residual that keeps one sign (a change faster than the random walk)
  // re-opens the sensor's covariance. One sensor alone teaches nothing.
  std::uint32_t learn_mask = 0;
  for (int i = 0; i < sensors_; ++i) {
    if (!(usable >> i & 1u)) continue;
    const auto k = static_cast<std::size_t>(i);
    const bool own = !(learn_only_mask >> i & 1u);
    const double others_ss = own ? s_ss - sl[k] * sl[k] : s_ss;
    if (!(others_ss > 1e-12 * (s_ss + 1e-300))) continue;
    const double shift_m = (own ? s_sr - sl[k] * r[k] : s_sr) / others_ss;
    // Far from the prediction the residual is no longer linear in the shift.
    if (std::abs(shift_m) > max_shift_m_) continue;
    const double res = r[k] - sl[k] * shift_m;
    const double rv = noise_var_v2_ * (1.0 + sl[k] * sl[k] / others_ss) + model_var_v2_;
    const double s_cusum = u[k] * u[k] * pgg(i) + 2.0 * u[k] * pgd(i) + pdd(i) + rv;
    Cusum& c = cusum_[k];
    const double z = res / std::sqrt(s_cusum);
    c.up = std::max(0.0, c.up + z - 1.0);
    c.down = std::max(0.0, c.down - z - 1.0);
    if (reopen_threshold_ > 0.0 && (c.up > reopen_threshold_ || c.down > reopen_threshold_)) {
      pgg(i) += reopen_gain_var_;
      pdd(i) += reopen_offset_var_;
      look_gg_[k] += reopen_gain_var_;
      look_dd_[k] += reopen_offset_var_;
      c = Cusum{};
      ++reopenings_;
      continue;  // the next sample learns with the wider covariance
    }
    learn_mask |= 1u << i;
    if (joint_) continue;
    // Close to the calibration, sensor by sensor: the drift is within the prior,
    // and what one sensor learns against the others' is not worth the joint cost.
    const double ph_g = pgg(i) * u[k] + pgd(i);
    const double ph_d = pgd(i) * u[k] + pdd(i);
    // The update itself takes the sample as worth `share` of a new one.
    const double s = s_cusum + rv * (1.0 / share - 1.0);
    const double kg = ph_g / s, kd = ph_d / s;
    pgg(i) -= kg * ph_g;
    pdd(i) -= kd * ph_d;
    pgd(i) -= kg * ph_d;
    keep_block(i);
    move_sensor(i, kg * res, kd * res);
  }
  if (!joint_) return;
  // Then all of them together, on every kJointEvery-th such sample.
  joint_share_ += share;
  if (++joint_count_ < kJointEvery) return;
  const double joint_share = joint_share_;  // the samples in between, each worth its share
  joint_count_ = 0;
  joint_share_ = 0.0;
  // Samples taken where the last ones were repeat one another's errors: however
  // small each one's share, thousands of them at standstill would push the
  // parameters along what the array cannot see. Left out; the random walk goes on.
  if (joint_share < kJointLeastShare) return;
  joint_update(r, u, sl, learn_mask, learn_only_mask, joint_share);
}

void HallAdaptation::common_jointly(double relative_change, double variance, double share) {
  // As update_common takes the fix's estimate (its mean; its information worth
  // `share` of a new fix's, and no better than model_var_common_), with the
  // covariance the common gain shares with the sensors' gains and offsets
  // (joint_update): they move with it by their regression on it, and their
  // covariance loses what that regression explained.
  const double p = p_common_, m = model_var_common_;
  const double info = share * std::max(0.0, 1.0 / variance - 1.0 / p);
  if (!(info > 0.0)) return;
  const double den = 1.0 + p * info + m * info;
  const double change = relative_change * (1.0 + p * info) / den;
  const double p_new = p * (1.0 + m * info) / den;
  // The sensors' share of it is along pgc_, which only shrinks (by p_new / p) until a
  // joint update turns it: summed against pgc_ as it was at the first fix since then
  // (common_scale_: how much it has shrunk since), and applied once every kJointEvery
  // fixes (flush_common), the cost of a joint update's. Until then the sensors lag by
  // the regression's few fixes and their covariance holds a little more than it
  // should, never less.
  common_loss_ += (1.0 - p_new / p) / p * common_scale_ * common_scale_;  // P -= that pgc pgc^T
  common_move_ += change / p * common_scale_;                            // x += that pgc
  common_scale_ *= p_new / p;
  common_gain_ = std::clamp((1.0 + common_gain_) * (1.0 + change) - 1.0, -gain_limit_, gain_limit_);
  p_common_ = std::max(p_new, 1e-14);
  if (++common_count_ >= kJointEvery) flush_common();
}

void HallAdaptation::flush_common() {
  if (common_count_ == 0) return;  // no fix since the last
  const int n = 2 * sensors_;
  for (int j = 0; j < n; ++j) {
    const double c = common_loss_ * pgc_[j];
    for (int l = 0; l < n; ++l) p_[j][l] -= c * pgc_[l];
  }
  for (int i = 0; i < sensors_; ++i) {
    move_sensor(i, common_move_ * pgc_[2 * i], common_move_ * pgc_[2 * i + 1]);
    keep_block(i);
  }
  for (int j = 0; j < n; ++j) pgc_[j] *= common_scale_;
  common_count_ = 0;
  common_loss_ = common_move_ = 0.0;
  common_scale_ = 1.0;
}

void HallAdaptation::move_sensor(int i, double d_gain, double d_offset_v) {
  const auto k = static_cast<std::size_t>(i);
  const double g = gamma_[k] + d_gain;
  const double d = delta_[k] + d_offset_v;
  at_limit_[k] = std::abs(g) >= gain_limit_ || std::abs(d) >= offset_limit_v_;
  gamma_[k] = std::clamp(g, -gain_limit_, gain_limit_);
  delta_[k] = std::clamp(d, -offset_limit_v_, offset_limit_v_);
}

void HallAdaptation::keep_block(int i) {
  pgg(i) = std::max(pgg(i), 1e-14);
  pdd(i) = std::max(pdd(i), 1e-14);
  const double bound = std::sqrt(pgg(i) * pdd(i));
  pgd(i) = std::clamp(pgd(i), -bound, bound);
  p_[2 * i + 1][2 * i] = pgd(i);
}

void HallAdaptation::joint_update(const std::array<double, kMaxHalls>& r, const std::array<double, kMaxHalls>& u,
                                  const std::array<double, kMaxHalls>& sl, std::uint32_t learn_mask,
                                  std::uint32_t learn_only_mask, double share) {
  // The readings' model: r_i = u_i gamma_i + delta_i + slope_i e + noise, e the
  // position error of the prediction, unknown (a wide prior, uncorrelated with the
  // parameters) and left out afterwards. Sequential scalar updates of the joint
  // state (deviations from the current parameters, in x). The sample counts as
  // `share` of a new one: its noise is taken 1 / share as large.
  flush_common();  // the common gain's updates since the last, before the direction turns
  const int n = 2 * sensors_;
  // The parameters' deviations, and the shift's (e).
  double x[kParams] = {}, xe = 0.0;
  // The shift's row and column of the covariance (pe[j]: with parameter j; pee: its
  // own variance), kept here: it is re-opened for every sample and left out after.
  // Uncorrelated with the parameters at first.
  double pe[kParams] = {}, pee = max_shift_m_ * max_shift_m_;
  // The gain every sensor shares is the fixes' (update_common), and the residuals
  // were taken with it as it stands: its error is in every residual (u_i times it), and
  // the common gain and the mean of the sensors' own gains are one thing seen two
  // ways. Taken as exact here, a pattern of offsets that a shift and a common gain
  // explain at every place was learnt twice over (the fixes moved the common gain to
  // absorb it, so the sensors' residuals no longer showed it, and their covariance
  // shrank as if they had): after a warm start the sensors' offsets stayed 3-5 sigma
  // off for tenths of a second, and sigma was too small for the 7-11 um of error it
  // left. So the common gain is a considered state here (Schmidt): its variance
  // p_common_ and its covariance with the parameters (pgc_, kept between samples)
  // enter every gain and are kept up to date, but this update does not move it.
  double* pg = pgc_;
  const double pgn = p_common_;
  double peg = 0.0;
  // P h for the sensor being taken in: ph[j] for parameter j, phe for the shift,
  // phg for the common gain.
  double ph[kParams], phe, phg;
  // The updates below keep only the upper triangle of p_ (row <= column) and mirror
  // it once at the end: each entry as before, without a scattered store for every one
  // of them. The lower triangle is stale until then and is never read.
  auto scalar_update = [&](int i, double rv, bool whole) {
    const auto k = static_cast<std::size_t>(i);
    const int a = 2 * i, b = 2 * i + 1;
    const double uk = u[k], sk = sl[k];
    // ph = P h with h = (u at a, 1 at b, slope at the shift, u at the common gain):
    // column a and b of the symmetric P, read from the upper triangle (above row a
    // down the columns, past row b along the rows), the same sum in the same order
    // for every state.
    for (int j = 0; j < a; ++j) ph[j] = p_[j][a] * uk + p_[j][b] + pe[j] * sk + pg[j] * uk;
    ph[a] = p_[a][a] * uk + p_[a][b] + pe[a] * sk + pg[a] * uk;
    ph[b] = p_[a][b] * uk + p_[b][b] + pe[b] * sk + pg[b] * uk;
    for (int j = b + 1; j < n; ++j) ph[j] = p_[a][j] * uk + p_[b][j] + pe[j] * sk + pg[j] * uk;
    phe = pe[a] * uk + pe[b] + pee * sk + peg * uk;
    phg = pg[a] * uk + pg[b] + peg * sk + pgn * uk;
    const double s = uk * ph[a] + ph[b] + sk * phe + uk * phg + rv / share;
    if (!(s > 0.0)) return;
    const double nu = r[k] - (uk * x[a] + x[b] + sk * xe);
    if (whole) {
      // The gain, each state's ph / s.
      double kg[kParams];
      for (int j = 0; j < n; ++j) kg[j] = ph[j] / s;
      const double kge = phe / s;
      for (int j = 0; j < n; ++j) x[j] += kg[j] * nu;
      xe += kge * nu;
      // P -= kg ph^T, the upper triangle row by row (each row's tail is contiguous).
      for (int j = 0; j < n; ++j) {
        const double kj = kg[j];
        double* row = p_[j];
        for (int l = j; l < n; ++l) row[l] -= kj * ph[l];
        pe[j] -= kj * phe;
        pg[j] -= kj * phg;
      }
      pee -= kge * phe;
      peg -= kge * phg;
    } else {
      // A sensor judged faulty learns from the others but tells them nothing: only
      // its own parameters move, against the position error the others found.
      const double ka = ph[a] / s, kb = ph[b] / s;
      x[a] += ka * nu;
      x[b] += kb * nu;
      const double paa = p_[a][a] - ka * ph[a], pab = p_[a][b] - ka * ph[b], pbb = p_[b][b] - kb * ph[b];
      p_[a][a] = paa;
      p_[a][b] = p_[b][a] = pab;
      p_[b][b] = pbb;
    }
  };
  for (int pass = 0; pass < 2; ++pass) {
    for (int i = 0; i < sensors_; ++i) {
      if (!(learn_mask >> i & 1u)) continue;
      const bool healthy = !(learn_only_mask >> i & 1u);
      if (healthy != (pass == 0)) continue;
      scalar_update(i, noise_var_v2_ + model_var_v2_, healthy);
    }
  }
  // The mirror (the shift's row and column are dropped with this function's locals).
  for (int j = 1; j < n; ++j)
    for (int l = 0; l < j; ++l) p_[j][l] = p_[l][j];
  // The looks: the table's error once per kModelShareOfPitch of travel, the noise of
  // every sample in between.
  const double model_share = std::min(1.0, share * kNewPlaceShareOfPitch / kModelShareOfPitch);
  const double look_info = 1.0 / (model_var_v2_ / model_share + noise_var_v2_ / share);
  for (int i = 0; i < sensors_; ++i) {
    if (!(learn_mask >> i & 1u)) continue;
    const auto k = static_cast<std::size_t>(i);
    look_gg_[k] = 1.0 / (1.0 / look_gg_[k] + u[k] * u[k] * look_info);
    look_dd_[k] = 1.0 / (1.0 / look_dd_[k] + look_info);
  }
  for (int i = 0; i < sensors_; ++i) {
    keep_block(i);
    // Every sensor's parameters move with what was learnt, through their correlations
    // with the sensors that took part.
    move_sensor(i, x[2 * i], x[2 * i + 1]);
  }
}

}  // namespace ve::core
