#include "thermal_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <Eigen/Dense>

#include "hall_array.hpp"

namespace ve::core {

namespace {

struct Sums {
  double n = 0, su = 0, suu = 0, sy = 0, suy = 0, syy = 0;
  void add(double u, double y) {
    n += 1;
    su += u;
    suu += u * u;
    sy += y;
    suy += u * y;
    syy += y * y;
  }
};

struct SensorFit {
  bool ok = false;
  double offset_v = 0.0, gain = 1.0;  ///< delta_i and g_i
  double offset_se_v = 0.0, gain_se = 0.0, residual_v = 0.0;
  int samples = 0;
};

SensorFit solve_fit(const Sums& s, int min_samples) {
  SensorFit f;
  f.samples = static_cast<int>(s.n);
  const double det = s.n * s.suu - s.su * s.su;
  if (s.n < min_samples || !(det > 0.0)) return f;
  f.gain = (s.n * s.suy - s.su * s.sy) / det;
  f.offset_v = (s.sy - f.gain * s.su) / s.n;
  // Residual sum of squares of y - delta - g u.
  const double rss = std::max(0.0, s.syy - f.offset_v * s.sy - f.gain * s.suy);
  const double var = rss / std::max(1.0, s.n - 2.0);
  f.residual_v = std::sqrt(var);
  f.gain_se = std::sqrt(var * s.n / det);
  f.offset_se_v = std::sqrt(var * s.suu / det);
  f.ok = std::isfinite(f.gain) && std::isfinite(f.offset_v) && f.gain > 0.5 && f.gain < 1.5;
  return f;
}

}  // namespace

bool fit_thermal_coefficients(const MotorConfig& motor, const Calibration& base,
                              const std::vector<ReferenceSegment>& recording, const ThermalCalibrationConfig& config,
                              SensorModel& out, ThermalCalibrationReport& report, std::string& error) {
  report = ThermalCalibrationReport{};
  const int n = std::min({motor.hall.count, kMaxHalls, base.table.sensors});
  const HallTable& table = base.table;
  if (!table.valid() || n < 2) {
    error = "the calibration has no usable Hall table";
    return false;
  }
  const SensorModel& m0 = base.model;
  const double mid = motor.hall.offset_v;
  const double lo = motor.adc.min_v + motor.hall.saturation_margin_v;
  const double hi = motor.adc.max_v - motor.hall.saturation_margin_v;
  // Table values this close to a rail hold the clamp, not the sensor's curve.
  const double guard = motor.filter.hall_gain_limit * motor.hall.amplitude_v;
  const double ts = motor.sample_period_s();
  const double scale = std::abs(m0.accel_scale) > 0.0 ? m0.accel_scale : 1.0;
  // The acceleration the calibrated accelerometer reads (its delay aside): the coil
  // field's common mode, and which samples are calm enough to fit.
  const auto acceleration = [&](const RawSample& raw) { return (raw.accel_mps2 - m0.accel_bias_mps2) / scale; };

  bool ruler = false;
  std::size_t total = 0;
  double temp_sum = 0.0;
  std::size_t temp_n = 0;
  for (const auto& seg : recording) {
    total += seg.samples.size();
    for (std::size_t j = 0; j < seg.samples.size(); ++j) {
      if (j < seg.reference_m.size() && std::isfinite(seg.reference_m[j])) ruler = true;
      if (seg.samples[j].temperature_valid && std::isfinite(seg.samples[j].temperature_c)) {
        temp_sum += seg.samples[j].temperature_c;
        ++temp_n;
      }
    }
  }
  if (total == 0) {
    error = "the recording has no samples";
    return false;
  }

  // The positions at the Halls' instant, per segment and sample (NaN: none).
  std::vector<std::vector<double>> x(recording.size());
  std::array<SensorFit, kMaxHalls> fit{};
  for (int i = 0; i < n; ++i) fit[static_cast<std::size_t>(i)].ok = false;

  auto positions_from_ruler = [&]() {
    for (std::size_t s = 0; s < recording.size(); ++s) {
      const auto& seg = recording[s];
      const std::size_t len = seg.samples.size();
      x[s].assign(len, std::nan(""));
      for (std::size_t j = 0; j < len && j < seg.reference_m.size(); ++j) {
        if (!std::isfinite(seg.reference_m[j])) continue;
        const std::size_t a = j > 0 ? j - 1 : j, b = j + 1 < len && j + 1 < seg.reference_m.size() ? j + 1 : j;
        double v = 0.0;
        if (b > a && std::isfinite(seg.reference_m[a]) && std::isfinite(seg.reference_m[b]))
          v = (seg.reference_m[b] - seg.reference_m[a]) / (static_cast<double>(b - a) * ts);
        x[s][j] = seg.reference_m[j] - v * m0.hall_delay_s;
      }
    }
  };

  // Without a ruler: the array, its readings corrected by the fit so far.
  HallArray array(motor, table);
  const double pitch = motor.magnet_pitch_m;
  auto corrected = [&](const RawSample& in, RawSample& outs) {
    outs = in;
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (!fit[k].ok) continue;
      const double y = in.hall_v[k];
      if (!(y > lo && y < hi)) continue;
      outs.hall_v[k] = mid + (y - mid - fit[k].offset_v) / fit[k].gain;
    }
  };
  double last_shift2 = 0.0;
  std::size_t last_shift_n = 0;
  std::vector<std::size_t> anchors(recording.size(), static_cast<std::size_t>(-1));
  std::vector<double> anchors_x(recording.size(), 0.0);
  auto positions_from_array = [&](int round) {
    last_shift2 = 0.0;
    last_shift_n = 0;
    RawSample c;
    for (std::size_t s = 0; s < recording.size(); ++s) {
      const auto& seg = recording[s];
      const std::size_t len = seg.samples.size();
      std::vector<double> prev = x[s];
      x[s].assign(len, std::nan(""));
      if (len == 0) continue;
      auto common_mode = [&](const RawSample& raw) {
        return m0.coil_field_v_per_mps2 * (raw.accel_valid ? acceleration(raw) : 0.0);
      };
      // The anchor: of samples spread over the segment, the one placed most decisively,
      // well inside the stretch the slow passes made (near the sweep's ends the table
      // rests on the accelerometer's bridge, and a recording starting there was placed a
      // whole period off). Tracked forward and back from it.
      const double in_lo = (m0.trusted_span_known() ? m0.table_trusted_from_m : table.start_m) + pitch;
      const double in_hi = (m0.trusted_span_known() ? m0.table_trusted_to_m : table.end_m()) - pitch;
      // One sample's match cannot tell the periods apart (the drift not corrected
      // yet weighs more than the track's signature: motor 1 of the population was
      // placed 15 periods off), so each candidate place, in every period of the
      // table, is scored over samples tracked from it until the carriage has crossed
      // kScorePitches magnet periods: the signature of several magnets adds up where
      // the drift, the same in every period, does not tell them apart. The anchors
      // are chosen again in the second round, on readings the first one corrected.
      constexpr double kScorePitches = 4.0;
      // Scored on every few samples: as many as keep the carriage within 1/32 of a
      // period from one to the next (the solve converges from within about 1/8).
      auto window_score = [&](std::size_t j0, double x0) {
        double guess = x0, sum = 0.0, moved = 0.0;
        std::size_t used = 0, tried = 0, stride = 1;
        for (std::size_t j = j0; j < len && moved < kScorePitches * pitch; j += stride) {
          ++tried;
          corrected(seg.samples[j], c);
          const HallFix f = array.solve(c, guess, common_mode(seg.samples[j]));
          if (!f.ok || f.out_of_table || f.sensors_used < 1) {
            stride = 1;
            continue;
          }
          sum += f.chi2 / f.sensors_used;
          ++used;
          const double step = std::abs(f.position_m - guess);
          moved += step;
          guess = f.position_m;
          const double per_sample = step / static_cast<double>(stride);
          stride = per_sample > 0.0 ? static_cast<std::size_t>(std::clamp(pitch / 32.0 / per_sample, 1.0, 64.0)) : 64;
        }
        return moved >= 0.5 * kScorePitches * pitch && 2 * used > tried ? sum / static_cast<double>(used)
                                                                          : std::numeric_limits<double>::infinity();
      };
      std::size_t anchor = anchors[s];
      double anchor_x = anchors_x[s];
      if (anchor < len && round > 1) {
        corrected(seg.samples[anchor], c);
        const HallFix f = array.acquire(c, anchor_x - 0.5 * pitch, anchor_x + 0.5 * pitch, common_mode(seg.samples[anchor]));
        if (f.ok && !f.out_of_table) anchor_x = f.position_m;
      } else {
        // Of the candidates, the most decisive: the largest ratio of the runner-up's
        // score to the best's (a place with a strong signature).
        double best_margin = 0.0;
        anchor = len;
        constexpr int kAnchorCandidates = 8;
        for (int q = 0; q < kAnchorCandidates; ++q) {
          const std::size_t j = static_cast<std::size_t>((q + 0.5) * static_cast<double>(len) / kAnchorCandidates);
          corrected(seg.samples[j], c);
          const HallFix f = array.acquire(c, table.start_m, table.end_m(), common_mode(seg.samples[j]));
          if (!f.ok || f.out_of_table || f.sensors_used < 2) continue;
          double best = std::numeric_limits<double>::infinity(), second = best, best_x = 0.0;
          const int k_lo = -static_cast<int>(std::floor((f.position_m - table.start_m) / pitch));
          const int k_hi = static_cast<int>(std::floor((table.end_m() - f.position_m) / pitch));
          for (int k = k_lo; k <= k_hi; ++k) {
            const double x0 = f.position_m + k * pitch;
            if (x0 < table.start_m || x0 > table.end_m()) continue;
            const double score = window_score(j, x0);
            if (score < best) {
              second = best;
              best = score;
              best_x = x0;
            } else if (score < second) {
              second = score;
            }
          }
          if (!std::isfinite(best) || best_x < in_lo || best_x > in_hi) continue;
          const double margin = std::isfinite(second) ? second / std::max(best, 1e-12) : 1.0;
          if (anchor >= len || margin > best_margin) {
            best_margin = margin;
            anchor = j;
            anchor_x = best_x;
          }
        }
        if (anchor >= len) continue;
        anchors[s] = anchor;
        anchors_x[s] = anchor_x;
      }
      auto track = [&](std::size_t from, int dir) {
        double guess = anchor_x;
        for (std::size_t j = from; j < len; j = dir > 0 ? j + 1 : (j == 0 ? len : j - 1)) {
          const RawSample& raw = seg.samples[j];
          const double cm = common_mode(raw);
          corrected(raw, c);
          HallFix f = array.solve(c, guess, cm);
          if (!f.ok) f = array.acquire(c, guess - pitch, guess + pitch, cm);
          if (!f.ok || f.out_of_table) continue;
          x[s][j] = guess = f.position_m;
          if (j < prev.size() && std::isfinite(prev[j])) {
            last_shift2 += (prev[j] - guess) * (prev[j] - guess);
            ++last_shift_n;
          }
        }
      };
      track(anchor, +1);
      if (anchor > 0) track(anchor - 1, -1);
    }
  };

  // Every sample at a known place inside the table and out of strong acceleration
  // (the coil field's common mode): the table's values and slopes there, and the
  // sensors (`usable` bits) read out of saturation where the table is too.
  auto for_each_sample = [&](auto&& fn) {
    std::array<double, kMaxHalls> tv{}, sv{};
    for (std::size_t sg = 0; sg < recording.size(); ++sg) {
      const auto& seg = recording[sg];
      for (std::size_t j = 0; j < seg.samples.size(); ++j) {
        const double xs = x[sg][j];
        if (!std::isfinite(xs) || !table.contains(xs)) continue;
        const RawSample& raw = seg.samples[j];
        if (!raw.accel_valid) continue;
        const double acc = acceleration(raw);
        if (std::abs(acc) > config.max_accel_mps2) continue;
        table.evaluate_sensors(n, xs, tv.data(), sv.data());
        std::uint32_t usable = 0;
        for (int i = 0; i < n; ++i) {
          const double y = raw.hall_v[static_cast<std::size_t>(i)], t = tv[static_cast<std::size_t>(i)];
          if ((raw.hall_valid_mask >> i & 1u) && y > lo && y < hi && t > lo + guard && t < hi - guard)
            usable |= 1u << i;
        }
        fn(raw, tv, sv, m0.coil_field_v_per_mps2 * acc, usable);
      }
    }
  };

  auto fit_all = [&]() {
    std::array<Sums, kMaxHalls> sums{};
    for_each_sample([&](const RawSample& raw, const std::array<double, kMaxHalls>& tv,
                        const std::array<double, kMaxHalls>&, double cm, std::uint32_t usable) {
      for (int i = 0; i < n; ++i) {
        const auto k = static_cast<std::size_t>(i);
        if (usable >> i & 1u) sums[k].add(tv[k] - mid, raw.hall_v[k] - cm - mid);
      }
    });
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      fit[k] = solve_fit(sums[k], config.min_samples);
    }
  };

  // Without a ruler, the positions come from the same readings: a sensor's
  // residual is partly a position error, which the array's other sensors share
  // through their slopes. One Gauss-Newton step of every sensor's offset and gain
  // together, with each sample's position error taken out as a nuisance (the
  // residuals projected off the slopes' direction): fitting sensor by sensor against
  // positions the fit itself moved converges by micrometres per round.
  auto fit_jointly = [&]() {
    const int p = 2 * n;  // delta_i at 2i, g_i at 2i + 1
    Eigen::MatrixXd a = Eigen::MatrixXd::Zero(p, p);
    Eigen::VectorXd b = Eigen::VectorXd::Zero(p);
    std::array<int, kMaxHalls> count{};
    double rss = 0.0, dof = 0.0;
    std::array<double, kMaxHalls> theta_d{}, theta_g{};
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      theta_d[k] = fit[k].ok ? fit[k].offset_v : 0.0;
      theta_g[k] = fit[k].ok ? fit[k].gain : 1.0;
    }
    for_each_sample([&](const RawSample& raw, const std::array<double, kMaxHalls>& tv,
                        const std::array<double, kMaxHalls>& sv, double cm, std::uint32_t usable) {
        std::array<double, kMaxHalls> r{}, u{}, sl{};
        int used[kMaxHalls];
        int m = 0;
        double ss = 0.0, sr = 0.0;
        for (int i = 0; i < n; ++i) {
          const auto k = static_cast<std::size_t>(i);
          if (!(usable >> i & 1u)) continue;
          u[k] = tv[k] - mid;
          sl[k] = theta_g[k] * sv[k];
          r[k] = (raw.hall_v[k] - cm - mid) - (theta_d[k] + theta_g[k] * u[k]);
          ss += sl[k] * sl[k];
          sr += sl[k] * r[k];
          used[m++] = i;
        }
        if (m < 2 || !(ss > 0.0)) return;
        // J^T J - w w^T / s's and J^T r - w s'r / s's, w = J^T s.
        for (int q = 0; q < m; ++q) {
          const int i = used[q];
          const auto k = static_cast<std::size_t>(i);
          ++count[k];
          a(2 * i, 2 * i) += 1.0;
          a(2 * i, 2 * i + 1) += u[k];
          a(2 * i + 1, 2 * i) += u[k];
          a(2 * i + 1, 2 * i + 1) += u[k] * u[k];
          b(2 * i) += r[k];
          b(2 * i + 1) += u[k] * r[k];
          for (int q2 = 0; q2 < m; ++q2) {
            const int i2 = used[q2];
            const auto k2 = static_cast<std::size_t>(i2);
            const double c = sl[k] * sl[k2] / ss;
            a(2 * i, 2 * i2) -= c;
            a(2 * i, 2 * i2 + 1) -= c * u[k2];
            a(2 * i + 1, 2 * i2) -= c * u[k];
            a(2 * i + 1, 2 * i2 + 1) -= c * u[k] * u[k2];
          }
          b(2 * i) -= sl[k] * sr / ss;
          b(2 * i + 1) -= u[k] * sl[k] * sr / ss;
          rss += r[k] * r[k];
        }
        rss -= sr * sr / ss;
        dof += m - 1;
    });
    // A sensor with too few readings keeps its data-sheet values: pinned by a stiff prior.
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      const double w = count[k] >= config.min_samples ? 1e-9 : 1e9;
      a(2 * i, 2 * i) += w;
      a(2 * i + 1, 2 * i + 1) += w;
    }
    const Eigen::LDLT<Eigen::MatrixXd> ldlt(a);
    const Eigen::VectorXd step = ldlt.solve(b);
    const Eigen::MatrixXd cov = ldlt.solve(Eigen::MatrixXd::Identity(p, p));
    const double var = dof > 2.0 * p ? std::max(0.0, rss) / (dof - 2.0 * p) : 0.0;
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      SensorFit f;
      f.samples = count[k];
      f.offset_v = theta_d[k] + step(2 * i);
      f.gain = theta_g[k] + step(2 * i + 1);
      f.offset_se_v = std::sqrt(std::max(0.0, var * cov(2 * i, 2 * i)));
      f.gain_se = std::sqrt(std::max(0.0, var * cov(2 * i + 1, 2 * i + 1)));
      f.residual_v = std::sqrt(var);
      f.ok = count[k] >= config.min_samples && std::isfinite(f.gain) && std::isfinite(f.offset_v) && f.gain > 0.5 &&
             f.gain < 1.5;
      fit[k] = f;
    }
  };

  if (ruler) {
    positions_from_ruler();
    fit_all();
  } else {
    // A first guess of each sensor's gain and offset from the readings' quartiles
    // against the table's (the rails clip only the tails): a motor 15 K warm has
    // lost 3 % of its field, tens of mV where the track's signature is a few, and
    // no period matches until that is corrected.
    auto quartiles = [](std::vector<double>& v, double& q1, double& q2, double& q3) {
      auto at = [&](double share) {
        const auto k = static_cast<std::ptrdiff_t>(share * static_cast<double>(v.size() - 1));
        std::nth_element(v.begin(), v.begin() + k, v.end());
        return v[static_cast<std::size_t>(k)];
      };
      q1 = at(0.25);
      q2 = at(0.5);
      q3 = at(0.75);
    };
    std::vector<double> tv, rv;
    for (int i = 0; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      tv.assign(table.v.begin() + static_cast<std::ptrdiff_t>(k * static_cast<std::size_t>(table.points)),
                table.v.begin() + static_cast<std::ptrdiff_t>((k + 1) * static_cast<std::size_t>(table.points)));
      rv.clear();
      for (const auto& seg : recording)
        for (const auto& raw : seg.samples)
          if (raw.hall_valid_mask >> i & 1u) rv.push_back(raw.hall_v[k]);
      if (tv.size() < 4 || rv.size() < static_cast<std::size_t>(config.min_samples)) continue;
      double t1, t2, t3, r1, r2, r3;
      quartiles(tv, t1, t2, t3);
      quartiles(rv, r1, r2, r3);
      if (!(t3 - t1 > 0.0)) continue;
      SensorFit& f = fit[k];
      f.gain = std::clamp((r3 - r1) / (t3 - t1), 0.8, 1.2);
      // The offsets' drift (a few mV) is left to the fit: the readings' median moves
      // with the track's own shape by more than that.
      (void)r2;
      (void)t2;
      f.offset_v = 0.0;
      f.ok = true;
    }
    const int rounds = std::max(1, config.rounds);
    for (int r = 0; r < rounds; ++r) {
      positions_from_array(r);
      fit_jointly();
    }
    report.last_round_shift_m = last_shift_n ? std::sqrt(last_shift2 / static_cast<double>(last_shift_n)) : 0.0;
  }

  // The common gain: the geometric mean of the fitted sensors' gains.
  double log_sum = 0.0;
  int fitted = 0;
  for (int i = 0; i < n; ++i) {
    const auto& f = fit[static_cast<std::size_t>(i)];
    report.samples[static_cast<std::size_t>(i)] = f.samples;
    if (!f.ok) continue;
    log_sum += std::log(f.gain);
    ++fitted;
  }
  report.sensors_fitted = fitted;
  if (fitted < 2) {
    char buf[256];
    std::snprintf(buf, sizeof buf,
                  "only %d sensor(s) had %d or more readings out of saturation over the "
                  "calibrated stretch; record the motor moving over its travel (a calibration run will do)",
                  fitted, config.min_samples);
    error = buf;
    return false;
  }
  const double common = std::exp(log_sum / fitted);
  report.common_gain = common - 1.0;

  const auto& f = motor.filter;
  const double common_tc_ds = f.magnet_remanence_tc_per_k + f.hall_gain_tc_per_k;
  double rise = 0.0;
  if (temp_n > 0 && std::isfinite(m0.temperature_c)) {
    rise = temp_sum / static_cast<double>(temp_n) - m0.temperature_c;
    report.rise_reported = true;
  } else if (std::abs(common_tc_ds) > 0.0) {
    rise = report.common_gain / common_tc_ds;
  }
  report.rise_k = rise;
  if (!(std::abs(rise) >= config.min_rise_k)) {
    char buf[320];
    std::snprintf(buf, sizeof buf,
                  "the recording is %.1f K from the calibration's temperature (%s); record it "
                  "at least %.0f K warmer or colder than the calibration was",
                  rise, report.rise_reported ? "as the sensor node reported" : "as the sensors' common gain reads it",
                  config.min_rise_k);
    error = buf;
    return false;
  }

  out = m0;
  out.thermal_known = true;
  out.thermal_rise_k = rise;
  if (report.rise_reported) {
    out.common_tc_per_k = report.common_gain / rise;
    // One averaged reading of the node (its offset: a tenth of a kelvin) against the rise.
    out.common_tc_rel_std = 0.1 / std::abs(rise);
  } else {
    out.common_tc_per_k = std::nan("");
    out.common_tc_rel_std = std::nan("");
  }
  for (int i = 0; i < kMaxHalls; ++i) {
    const auto k = static_cast<std::size_t>(i);
    out.hall_gain_tc_per_k[k] = out.hall_offset_tc_v_per_k[k] = 0.0;
    out.hall_gain_tc_std_per_k[k] = out.hall_offset_tc_std_v_per_k[k] = 0.0;
    if (i >= n) continue;  // no such sensor
    out.hall_gain_tc_std_per_k[k] = f.hall_gain_tc_std_per_k;
    out.hall_offset_tc_std_v_per_k[k] = f.hall_offset_tc_std_v_per_k;
    const auto& s = fit[k];
    if (!s.ok) {
      char buf[200];
      std::snprintf(buf, sizeof buf,
                    "sensor %d: %d readings out of saturation, too few; it keeps the data sheet's spread", i,
                    s.samples);
      report.notes.emplace_back(buf);
      continue;
    }
    const double gamma = s.gain / common - 1.0;
    report.gain_change[k] = gamma;
    report.offset_change_v[k] = s.offset_v;
    report.residual_v[k] = s.residual_v;
    const double gtc = gamma / rise, otc = s.offset_v / rise;
    out.hall_gain_tc_per_k[k] = gtc;
    out.hall_offset_tc_v_per_k[k] = otc;
    const double lin = config.linearity_rel_std;
    // The fit's own uncertainty, and how far from linear a sensor may be: a share of
    // its coefficient, and at least that share of the data sheet's spread.
    out.hall_gain_tc_std_per_k[k] = std::sqrt(std::pow(s.gain_se / (common * std::abs(rise)), 2) +
                                              std::pow(lin * gtc, 2) + std::pow(lin * f.hall_gain_tc_std_per_k, 2));
    out.hall_offset_tc_std_v_per_k[k] = std::sqrt(std::pow(s.offset_se_v / std::abs(rise), 2) + std::pow(lin * otc, 2) +
                                                  std::pow(lin * f.hall_offset_tc_std_v_per_k, 2));
  }
  return true;
}

}  // namespace ve::core
