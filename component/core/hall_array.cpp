#include "hall_array.hpp"

#include "hall_adaptation.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace ve::core {

HallArray::HallArray(const MotorConfig& motor, HallTable table)
    : table_(std::move(table)),
      pitch_m_(motor.magnet_pitch_m),
      sensors_(std::min(motor.hall.count, table_.sensors)),
      lo_v_(motor.adc.min_v + motor.hall.saturation_margin_v),
      hi_v_(motor.adc.max_v - motor.hall.saturation_margin_v) {
  // Noise as read: analogue noise plus uniform quantisation of the ADC.
  const double lsb = motor.adc.lsb_v();
  const double var_v2 = motor.hall.noise_v * motor.hall.noise_v + lsb * lsb / 12.0;
  weight_ = 1.0 / var_v2;
  // Gaussian noise of sigma s before a quantiser of step q leaves the mean reading
  // off the input by a periodic error whose k-th harmonic has the amplitude
  // (q / (pi k)) exp(-2 pi^2 k^2 s^2 / q^2); its mean square over the input is the
  // sum below (q^2 / 12 without noise, nothing once s is half a step).
  double qv = 0.0;
  const double s2 = motor.hall.noise_v * motor.hall.noise_v;
  for (int k = 1; k <= 64; ++k) {
    const double kk = static_cast<double>(k) * k;
    qv += std::exp(-4.0 * M_PI * M_PI * kk * s2 / (lsb * lsb)) / (2.0 * M_PI * M_PI * kk);
  }
  quantisation_v2_ = lsb * lsb * qv;
  floor_m2_ = motor.filter.hall_position_floor_m * motor.filter.hall_position_floor_m;
  sensors_ = std::min(sensors_, kMaxHalls);
  if (table_.valid()) {
    const auto points = static_cast<std::size_t>(table_.points);
    knots_.assign(points * kMaxHalls, 0.0);
    for (int s = 0; s < sensors_; ++s)
      for (std::size_t k = 0; k < points; ++k)
        knots_[k * kMaxHalls + static_cast<std::size_t>(s)] = table_.v[static_cast<std::size_t>(s) * points + k];
  }
}

void HallArray::add_table_error(double std_m) {
  if (!(std_m > 0.0) || !table_.valid() || table_.points < 3) return;
  // Mean over the nodes of sum_i slope_i^2, the sensors between the rails only.
  const auto points = static_cast<std::size_t>(table_.points);
  double info = 0.0;
  for (std::size_t k = 1; k + 1 < points; ++k)
    for (int s = 0; s < sensors_; ++s) {
      const double* v = table_.v.data() + static_cast<std::size_t>(s) * points;
      if (!(v[k] > lo_v_ && v[k] < hi_v_)) continue;
      const double slope = (v[k + 1] - v[k - 1]) / (2.0 * table_.step_m);
      info += slope * slope;
    }
  info /= static_cast<double>(points - 2);
  table_error_v2_ = std_m * std_m * info;
}

void HallArray::evaluate_all(double x_m, Cell& cell, std::array<double, kMaxHalls>& value_v,
                             std::array<double, kMaxHalls>& slope_v_per_m) const {
  const int points = table_.points;
  double u = (x_m - table_.start_m) / table_.step_m;
  u = std::clamp(u, 0.0, static_cast<double>(points - 1));
  int k = static_cast<int>(u);
  if (k > points - 2) k = points - 2;
  const double t = u - k;
  if (!knots_.empty() && k > 0 && k + 2 < points) {
    // As HallTable::evaluate, every sensor at once (the same operations in the same
    // order, element by element): Catmull-Rom through p0..p3 around [k, k+1].
    using Knots = Eigen::Array<double, kMaxHalls, 1>;
    using Coefficients = Eigen::Map<Knots>;
    if (cell.k != k) {
      const double* r1 = knots_.data() + static_cast<std::size_t>(k) * kMaxHalls;
      const double* r2 = r1 + kMaxHalls;
      const Eigen::Map<const Knots> p0(r1 - kMaxHalls), p1(r1), p2(r2), p3(r2 + kMaxHalls);
      Coefficients a(cell.a.data()), b(cell.b.data());
      a = -0.5 * p0 + 1.5 * p1 - 1.5 * p2 + 0.5 * p3;
      b = p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3;
      Coefficients(cell.c.data()) = -0.5 * p0 + 0.5 * p2;
      Coefficients(cell.p1.data()) = p1;
      Coefficients(cell.a3.data()) = 3.0 * a;
      Coefficients(cell.b2.data()) = 2.0 * b;
      cell.k = k;
    }
    const Eigen::Map<const Knots> a(cell.a.data()), b(cell.b.data()), c(cell.c.data()), p1(cell.p1.data()),
        a3(cell.a3.data()), b2(cell.b2.data());
    Eigen::Map<Knots>(value_v.data()) = ((a * t + b) * t + c) * t + p1;
    Eigen::Map<Knots>(slope_v_per_m.data()) = ((a3 * t + b2) * t + c) / table_.step_m;
    return;
  }
  for (int s = 0; s < sensors_; ++s)  // an end of the table: its own mirroring
    table_.evaluate(s, x_m, value_v[static_cast<std::size_t>(s)], slope_v_per_m[static_cast<std::size_t>(s)]);
}

bool HallArray::usable(const RawSample& s, int i, std::uint32_t use_mask) const {
  return (s.hall_valid_mask & use_mask) >> i & 1u && s.hall_v[i] > lo_v_ && s.hall_v[i] < hi_v_;
}

HallFix HallArray::solve(const RawSample& sample, double guess_m, double common_mode_v,
                         std::uint32_t use_mask, const HallAdaptation* adaptation) const {
  // Weight of sensor i with its reading's table value t: the noise, plus what its
  // adapted gain and offset are still unsure of.
  const double noise_var = 1.0 / weight_;
  // The weights of the sensors taking part (`on`, listed below) where the table reads
  // `t`; no other sensor's weight is read. One at a time: gathered into a vector for
  // paired divisions, the values just stored one by one would be loaded back in
  // pairs, which the processor cannot forward from its store buffer (a stall longer
  // than the divisions saved, in every iteration).
  int on[kMaxHalls];
  int n_on = 0;
  auto weights = [&](const std::array<double, kMaxHalls>& t, std::array<double, kMaxHalls>& w) {
    if (!adaptation) {
      w.fill(weight_);
      return;
    }
    for (int q = 0; q < n_on; ++q) {
      const auto k = static_cast<std::size_t>(on[q]);
      w[k] = 1.0 / (noise_var + adaptation->reading_variance(on[q], t[k]));
    }
  };
  HallFix fix;
  for (int i = 0; i < sensors_; ++i)
    if (!(sample.hall_valid_mask >> i & 1u)) fix.missing_mask |= 1u << i;

  // Gauss-Newton on sum_i w (y_i - (1 + e) T_i(x) + e m)^2 + e^2 / pc over the
  // sensors out of saturation, where e is the common gain not yet learnt (prior
  // variance pc; without one, e stays 0 and this is a search on x alone). The
  // step is limited so that a poor guess cannot jump into another period.
  const double pc = adaptation ? adaptation->common_gain_variance() : 0.0;
  const bool with_gain = pc > 0.0;
  const double info_c = with_gain ? 1.0 / pc : 0.0;
  const double mid = adaptation ? adaptation->mid_v() : 0.0;
  const double max_step = pitch_m_ / 8.0;
  // The sensors that take part (valid, in use_mask, out of saturation), and those
  // whose residual is checked at the solution (saturated ones too).
  // Also listed in order: the sums below run over the lists, the same terms in the
  // same order as over the masks, without a test per sensor in every iteration.
  std::uint32_t in_use = 0, checked = 0;
  int checked_list[kMaxHalls];
  int n_checked = 0;
  for (int i = 0; i < sensors_; ++i) {
    if (usable(sample, i, use_mask)) {
      in_use |= 1u << i;
      on[n_on++] = i;
    }
    if ((sample.hall_valid_mask & use_mask) >> i & 1u) {
      checked |= 1u << i;
      checked_list[n_checked++] = i;
    }
  }
  std::array<double, kMaxHalls> tab{}, slp{}, wgt{};
  Cell cell;  // the interval the iterations are on
  double x = guess_m, e = 0.0;
  // Nothing out of saturation: no search, but the saturated sensors are still
  // checked against the guess below (a conflict says the guess is wrong).
  for (int iter = 0, iters = n_on > 0 ? (with_gain ? 8 : 6) : 0; iter < iters; ++iter) {
    double hxx = 0.0, hxe = 0.0, hee = info_c, gx = 0.0, ge = -e * info_c;
    if (in_use) {
      evaluate_all(x, cell, tab, slp);
      weights(tab, wgt);
    }
    for (int q = 0; q < n_on; ++q) {
      const int i = on[q];
      const double t = tab[static_cast<std::size_t>(i)], slope = slp[static_cast<std::size_t>(i)];
      const double w = wgt[static_cast<std::size_t>(i)];
      const double u = t - mid;
      const double r = sample.hall_v[i] - common_mode_v - t - e * u;
      const double jx = (1.0 + e) * slope;
      hxx += w * jx * jx;
      gx += w * jx * r;
      if (with_gain) {
        hxe += w * jx * u;
        hee += w * u * u;
        ge += w * u * r;
      }
    }
    if (hxx <= 0.0) return fix;
    double dx, de = 0.0;
    if (with_gain) {
      const double det = hxx * hee - hxe * hxe;
      if (!(det > 0.0)) return fix;
      dx = (hee * gx - hxe * ge) / det;
      de = (hxx * ge - hxe * gx) / det;
    } else {
      dx = gx / hxx;
    }
    dx = std::clamp(dx, -max_step, max_step);
    x += dx;
    e = std::clamp(e + de, -0.5, 0.5);
    if (std::abs(dx) < 1e-10 && std::abs(de) < 1e-9) break;
  }
  if (x < table_.start_m || x > table_.end_m()) {
    fix.out_of_table = true;
    x = std::clamp(x, table_.start_m, table_.end_m());
  }

  // Residuals at the solution. Saturated sensors must agree too: a sensor reading
  // a rail whose table value is far from that rail means we are in the wrong place.
  double chi2 = with_gain ? e * e * info_c : 0.0;
  double chi2_table = chi2;
  int used = 0;
  double hxx = 0.0, hxe = 0.0, hee = info_c;
  double qxx = 0.0, qxe = 0.0, qee = 0.0;  // the same sums with w^2: the quantisation's share
  // Each used sensor's weighted slope and regressor, and its table reading: the
  // position's sensitivity to its reading, for the adaptation's joint uncertainty.
  std::array<double, kMaxHalls> wjx{}, wu{}, tv{};
  std::uint32_t used_mask = 0;
  if (checked) {
    evaluate_all(x, cell, tab, slp);
    weights(tab, wgt);
  }
  for (int q = 0; q < n_checked; ++q) {
    const int i = checked_list[q];
    const double t = tab[static_cast<std::size_t>(i)], slope = slp[static_cast<std::size_t>(i)];
    const double u = t - mid;
    const double r = sample.hall_v[i] - common_mode_v - t - e * u;
    if (in_use >> i & 1u) {
      const double w = wgt[static_cast<std::size_t>(i)];
      const double jx = (1.0 + e) * slope;
      chi2 += r * r * w;
      chi2_table += r * r * w / (1.0 + w * table_error_v2_);
      hxx += w * jx * jx;
      hxe += w * jx * u;
      hee += w * u * u;
      qxx += w * w * jx * jx;
      qxe += w * w * jx * u;
      qee += w * w * u * u;
      const auto k = static_cast<std::size_t>(i);
      wjx[k] = w * jx;
      wu[k] = w * u;
      tv[k] = t;
      used_mask |= 1u << i;
      ++used;
    } else if (std::abs(r) > 0.25) {
      fix.conflict_mask |= 1u << i;  // inconsistent with a saturated sensor
    }
  }
  fix.position_m = x;
  fix.chi2 = chi2;
  fix.chi2_table = chi2_table;
  fix.sensors_used = used;
  if (used == 0 || hxx <= 0.0 || fix.conflict_mask != 0) return fix;
  // The position moves by sum_i g_i dy_i for reading errors dy_i, g the position
  // row of the normal equations' inverse times w_i (jx_i, u_i).
  double var_x = 1.0 / hxx;
  double gain_sq = qxx / (hxx * hxx);  // sum of the squared sensitivities c_i below
  double gain_prior_share = 0.0;       // what the common gain's prior adds to the position's variance
  // The position's sensitivity to each reading, of the sensors used (the only ones
  // read; one at a time, as the weights).
  std::array<double, kMaxHalls> c{};
  if (!with_gain)
    for (int q = 0; q < n_on; ++q) {
      const auto k = static_cast<std::size_t>(on[q]);
      c[k] = wjx[k] / hxx;
    }
  if (with_gain) {
    const double det = hxx * hee - hxe * hxe;
    if (!(det > 0.0)) return fix;
    var_x = hee / det;
    gain_sq = (hee * hee * qxx - 2.0 * hee * hxe * qxe + hxe * hxe * qee) / (det * det);
    for (int q = 0; q < n_on; ++q) {
      const auto k = static_cast<std::size_t>(on[q]);
      c[k] = (hee * wjx[k] - hxe * wu[k]) / det;
    }
    fix.common_gain = e;
    fix.common_gain_variance = hxx / det;
    if (adaptation) {
      // The gain's sensitivity to each reading: the gain row of the inverse times w_i (jx_i, u_i).
      double offset_var = 0.0;
      for (int q = 0; q < n_on; ++q) {
        const auto k = static_cast<std::size_t>(on[q]);
        const double ge_k = (hxx * wu[k] - hxe * wjx[k]) / det;
        offset_var += ge_k * ge_k * adaptation->offset_tc_variance(on[q]);
      }
      fix.common_gain_offset_var_per_k2 = offset_var;
    }
    const double ce = hxe / det;  // the position's sensitivity to the common gain's prior
    gain_prior_share = ce * ce * info_c;
  }
  double drift = 0.0;
  if (adaptation) {
    // Weighted by each sensor's own uncertainty, but the fix's error is what the
    // sensors' joint uncertainty leaves in this combination of them: the drift learnt
    // so far is correlated between the sensors (the part the array cannot tell from a
    // shift is held in common).
    const double joint = adaptation->combined_variance(c, tv, used_mask, drift);
    var_x = noise_var * gain_sq + gain_prior_share + joint;
  }
  fix.quantisation_m2 = quantisation_v2_ * gain_sq;
  fix.sensitivity_m2_per_v2 = gain_sq;
  for (int q = 0; q < n_on; ++q) fix.offset_sensitivity_m_per_v += c[static_cast<std::size_t>(on[q])];
  // A sensor's own gain error moves its reading by its level about mid times the
  // error: the position's variance per unit of such errors, independent per sensor.
  // A gain error all sensors share moves the fix by its sum of those, signed. Only
  // wanted until a fix has read the temperature (AxisPipeline's unread variance).
  if (adaptation && !adaptation->temperature_checked()) {
    double level_sq = 0.0, level = 0.0;
    for (int q = 0; q < n_on; ++q) {
      const auto k = static_cast<std::size_t>(on[q]);
      const double u = tv[k] - mid;
      level_sq += c[k] * c[k] * u * u;
      level += c[k] * u;
    }
    fix.level_sensitivity_m2 = level_sq;
    fix.common_level_m = level;
  }
  fix.drift_m2 = std::max(0.0, drift);
  fix.ok = true;
  fix.variance_m2 = var_x + floor_m2_;
  return fix;
}

HallFix HallArray::acquire(const RawSample& sample, double lo_m, double hi_m, double common_mode_v,
                           std::uint32_t use_mask, const HallAdaptation* adaptation) const {
  lo_m = std::max(lo_m, table_.start_m);
  hi_m = std::min(hi_m, table_.end_m());
  const int k0 = static_cast<int>(std::ceil((lo_m - table_.start_m) / table_.step_m));
  const int k1 = static_cast<int>(std::floor((hi_m - table_.start_m) / table_.step_m));
  double best = std::numeric_limits<double>::infinity();
  int best_k = -1;
  // Coarse scan on the grid with every sensor, saturated ones included (the table
  // holds their clamped values), then refine around the best grid point.
  for (int k = k0; k <= k1; ++k) {
    double cost = 0.0;
    for (int i = 0; i < sensors_; ++i) {
      if (!((sample.hall_valid_mask & use_mask) >> i & 1u)) continue;
      const double r = sample.hall_v[i] - common_mode_v - table_.v[static_cast<std::size_t>(i) * table_.points + k];
      cost += r * r;
    }
    if (cost < best) {
      best = cost;
      best_k = k;
    }
  }
  if (best_k < 0) return HallFix{};
  return solve(sample, table_.start_m + best_k * table_.step_m, common_mode_v, use_mask, adaptation);
}

}  // namespace ve::core
