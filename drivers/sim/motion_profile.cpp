#include "sim/motion_profile.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace ve::sim {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

double sign_of(double x) { return static_cast<double>((x > 0.0) - (x < 0.0)); }

std::string fmt(const char* format, double a, double b = 0.0, double c = 0.0) {
  char buf[256];
  std::snprintf(buf, sizeof buf, format, a, b, c);
  return buf;
}

bool fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

/// Rest-to-rest move over `distance_m` (signed) with speed and acceleration limits.
struct Trapezoid {
  double accel_s = 0.0;   ///< duration of the acceleration and of the deceleration ramp
  double cruise_s = 0.0;  ///< duration at peak speed (0: triangular move)
  double a_mps2 = 0.0;    ///< signed acceleration of the first ramp
};

Trapezoid trapezoid(double distance_m, double vmax, double amax) {
  Trapezoid tr;
  const double d = std::abs(distance_m);
  if (d == 0.0) return tr;
  tr.a_mps2 = sign_of(distance_m) * amax;
  if (d >= vmax * vmax / amax) {
    tr.accel_s = vmax / amax;
    tr.cruise_s = (d - vmax * vmax / amax) / vmax;
  } else {
    tr.accel_s = std::sqrt(d / amax);
  }
  return tr;
}

/// Rest-to-rest jerk-limited move (S-curve) over `distance_m` (signed): phases of
/// jerk +j, 0, -j (accelerate), cruise, -j, 0, +j (decelerate).
struct SCurve {
  double jerk_s = 0.0;    ///< duration of each of the four jerk phases
  double accel_s = 0.0;   ///< duration of each constant-acceleration phase (0: peak acceleration < amax)
  double cruise_s = 0.0;  ///< duration at peak speed (0: peak speed < vmax)
  double j_mps3 = 0.0;    ///< signed jerk of the first phase
  double a_peak_mps2 = 0.0;  ///< signed
  double v_peak_mps = 0.0;   ///< signed
};

SCurve scurve(double distance_m, double vmax, double amax, double jmax) {
  SCurve m;
  const double d = std::abs(distance_m);
  if (d == 0.0) return m;
  const double dir = sign_of(distance_m);
  const double aa = amax * amax;
  // Distance of a full accelerate + decelerate pair up to peak speed v (the S-curve is
  // symmetric, so the mean speed of each half is v / 2).
  auto pair_distance = [&](double v) { return v * (v * jmax >= aa ? v / amax + amax / jmax : 2.0 * std::sqrt(v / jmax)); };
  double v = vmax;
  bool cruise = true;
  if (d < pair_distance(vmax)) {
    cruise = false;
    if (d >= 2.0 * aa * amax / (jmax * jmax)) {
      // amax reached: v^2 + (amax^2 / j) v - amax d = 0, in the cancellation-free form.
      const double b = aa / jmax;
      v = 2.0 * amax * d / (b + std::sqrt(b * b + 4.0 * amax * d));
    } else {
      // Not even amax: four jerk phases only, d = 2 j Tj^3.
      const double tj = std::cbrt(d / (2.0 * jmax));
      v = jmax * tj * tj;
    }
  }
  double a_peak;
  if (v * jmax >= aa) {
    a_peak = amax;
    m.jerk_s = amax / jmax;
    m.accel_s = std::max(0.0, v / amax - amax / jmax);
  } else {
    m.jerk_s = std::sqrt(v / jmax);
    a_peak = jmax * m.jerk_s;
  }
  if (cruise) m.cruise_s = std::max(0.0, (d - pair_distance(v)) / v);
  m.j_mps3 = dir * jmax;
  m.a_peak_mps2 = dir * a_peak;
  m.v_peak_mps = dir * v;
  return m;
}

// Multisine frequency ratios: square roots of 2, 3, 5, 7 (over 2), so no ratio of two
// of them is rational and the sum never repeats. Equal velocity shares.
constexpr int kSines = MotionProfile::kMaxSines;
const std::array<double, kSines> kSineRatio = {0.70710678118654752, 0.86602540378443865,
                                               1.11803398874989485, 1.32287565553229530};
constexpr double kSineShare = 1.0 / kSines;

/// Ratios narrowed towards 1 by `spread` in [0, 1].
double sine_ratio(int k, double spread) { return 1.0 + spread * (kSineRatio[static_cast<std::size_t>(k)] - 1.0); }

/// sum A_k for sum A_k w_k = vmax, sum A_k w_k^2 = amax [m].
double sine_excursion(double vmax, double amax, double spread) {
  double mean = 0.0, mean_inverse = 0.0;
  for (int k = 0; k < kSines; ++k) {
    mean += kSineShare * sine_ratio(k, spread);
    mean_inverse += kSineShare / sine_ratio(k, spread);
  }
  return vmax * vmax / amax * mean * mean_inverse;
}

bool finite_all(const MotionProfileConfig& c) {
  for (double x : {c.start_m, c.velocity_mps, c.acceleration_mps2, c.max_velocity_mps,
                   c.max_acceleration_mps2, c.min_m, c.max_m, c.max_jerk_mps3, c.dwell_s})
    if (!std::isfinite(x)) return false;
  return true;
}

}  // namespace

const char* kind_name(MotionProfileConfig::Kind kind) {
  using K = MotionProfileConfig::Kind;
  switch (kind) {
    case K::standstill: return "standstill";
    case K::constant_velocity: return "constant_velocity";
    case K::constant_acceleration: return "constant_acceleration";
    case K::multisine: return "multisine";
    case K::shuttle: return "shuttle";
    case K::point_to_point: return "point_to_point";
  }
  return "unknown";
}

Kinematics MotionProfile::eval(const Segment& s, double t_s) {
  const double tau = t_s - s.t0_s;
  if (s.j_mps3 == 0.0)
    return {s.x0_m + (s.v0_mps + 0.5 * s.a_mps2 * tau) * tau, s.v0_mps + s.a_mps2 * tau, s.a_mps2};
  const double j = s.j_mps3;
  return {s.x0_m + (s.v0_mps + (0.5 * s.a_mps2 + (j / 6.0) * tau) * tau) * tau,
          s.v0_mps + (s.a_mps2 + 0.5 * j * tau) * tau, s.a_mps2 + j * tau, j};
}

Kinematics MotionProfile::at(double t_s) const {
  if (sine_count_ > 0) {
    Kinematics k{centre_m_, 0.0, 0.0};
    for (int i = 0; i < sine_count_; ++i) {
      const auto n = static_cast<std::size_t>(i);
      const double w = sine_omega_rps_[n];
      const double s = std::sin(w * t_s), c = std::cos(w * t_s);
      k.position_m += sine_amp_m_[n] * s;
      k.velocity_mps += sine_amp_m_[n] * w * c;
      k.acceleration_mps2 -= sine_amp_m_[n] * w * w * s;
      k.jerk_mps3 -= sine_amp_m_[n] * w * w * w * c;
    }
    return k;
  }
  if (t_s < 0.0) return {initial_.position_m + initial_.velocity_mps * t_s, initial_.velocity_mps, 0.0};
  if (cycle_count_ > 0 && t_s >= cycle_start_s_) {
    const double tau = std::fmod(t_s - cycle_start_s_, period_s_);
    int i = cycle_count_ - 1;
    while (i > 0 && tau < cycle_[static_cast<std::size_t>(i)].t0_s) --i;
    return eval(cycle_[static_cast<std::size_t>(i)], tau);
  }
  int i = lead_count_ - 1;
  while (i > 0 && t_s < lead_[static_cast<std::size_t>(i)].t0_s) --i;
  return eval(lead_[static_cast<std::size_t>(i)], t_s);
}

std::optional<MotionProfile> MotionProfile::create(const MotionProfileConfig& cfg, double travel_m,
                                                   std::string* error) {
  using K = MotionProfileConfig::Kind;
  const char* name = kind_name(cfg.kind);
  auto bad = [&](const std::string& why) -> std::optional<MotionProfile> {
    fail(error, std::string("motion profile ") + name + ": " + why);
    return std::nullopt;
  };

  if (!finite_all(cfg) || !std::isfinite(travel_m)) return bad("parameters must be finite");
  if (!(travel_m > 0.0)) return bad(fmt("motor travel %g m must be positive", travel_m));
  // Small slack so that limits written in decimal still compare equal to the travel.
  const double slack = 1e-12;
  if (!(cfg.min_m >= -slack && cfg.max_m <= travel_m + slack && cfg.min_m < cfg.max_m))
    return bad(fmt("need 0 <= min_m (%g) < max_m (%g) <= travel (%g m)", cfg.min_m, cfg.max_m, travel_m));
  if (!(cfg.start_m >= cfg.min_m && cfg.start_m <= cfg.max_m))
    return bad(fmt("start_m %g m is outside [min_m, max_m] = [%g, %g] m", cfg.start_m, cfg.min_m, cfg.max_m));

  MotionProfile p;
  p.kind_ = cfg.kind;
  p.initial_ = {cfg.start_m, 0.0, 0.0};
  p.steady_duration_s_ = kInf;
  p.lead_count_ = 0;

  // Appends constant-acceleration segments that continue the previous state.
  struct Builder {
    Segment* segs;
    int cap;
    int& count;
    double t_s;
    Kinematics state;
    bool overflow = false;
    void add(double duration_s, double a_mps2) {
      if (!(duration_s > 0.0)) return;
      if (count == cap) { overflow = true; return; }
      segs[count] = {t_s, state.position_m, state.velocity_mps, a_mps2};
      t_s += duration_s;
      state = eval(segs[count], t_s);
      ++count;
    }
    /// Constant jerk from the current state (acceleration included).
    void add_jerk(double duration_s, double j_mps3) {
      if (!(duration_s > 0.0)) return;
      if (count == cap) { overflow = true; return; }
      segs[count] = {t_s, state.position_m, state.velocity_mps, state.acceleration_mps2, j_mps3};
      t_s += duration_s;
      state = eval(segs[count], t_s);
      state.jerk_mps3 = 0.0;
      ++count;
    }
    /// A seven-phase S-curve move ending at rest at `x_m`. The acceleration and the
    /// speed are set to their exact plateau values where a phase ends on one, so that
    /// rounding never lets them creep past the limits.
    void add_move(const SCurve& m, double x_m) {
      add_jerk(m.jerk_s, m.j_mps3);
      state.acceleration_mps2 = m.a_peak_mps2;
      add_jerk(m.accel_s, 0.0);
      add_jerk(m.jerk_s, -m.j_mps3);
      state.acceleration_mps2 = 0.0;
      state.velocity_mps = m.v_peak_mps;
      add_jerk(m.cruise_s, 0.0);
      add_jerk(m.jerk_s, -m.j_mps3);
      state.acceleration_mps2 = -m.a_peak_mps2;
      add_jerk(m.accel_s, 0.0);
      add_jerk(m.jerk_s, m.j_mps3);
      snap(x_m);
    }
    /// Ends a move at rest exactly at `x_m` (removes rounding of the ramps).
    void snap(double x_m) { state = {x_m, 0.0, 0.0}; }
    void hold() {
      if (count == cap) { overflow = true; return; }
      segs[count++] = {t_s, state.position_m, state.velocity_mps, 0.0};
    }
  };
  Builder lead{p.lead_.data(), kMaxLead, p.lead_count_, 0.0, p.initial_};

  const double vmax = cfg.max_velocity_mps;
  const double amax = cfg.max_acceleration_mps2;
  auto boundary = [&](double dir) { return dir > 0.0 ? cfg.max_m : cfg.min_m; };

  switch (cfg.kind) {
    case K::standstill:
      lead.hold();
      break;

    case K::constant_velocity: {
      const double v = cfg.velocity_mps;
      if (v == 0.0) return bad("velocity_mps must be non-zero (use standstill)");
      if (!(amax > 0.0)) return bad("max_acceleration_mps2 (braking) must be positive");
      const double dir = sign_of(v);
      const double end = boundary(dir);
      const double room = dir * (end - cfg.start_m);
      const double braking = v * v / (2.0 * amax);
      if (braking > room)
        return bad(fmt("braking from %g m/s at max_acceleration_mps2 needs %g m but there are only %g m "
                       "to the end of the travel",
                       v, braking, room));
      p.initial_.velocity_mps = v;
      lead.state = p.initial_;
      p.steady_duration_s_ = (room - braking) / std::abs(v);
      lead.add(p.steady_duration_s_, 0.0);
      lead.add(std::abs(v) / amax, -dir * amax);
      lead.snap(end);
      lead.hold();
      break;
    }

    case K::constant_acceleration: {
      const double a0 = cfg.acceleration_mps2, v0 = cfg.velocity_mps, x0 = cfg.start_m;
      if (a0 == 0.0) return bad("acceleration_mps2 must be non-zero (use constant_velocity)");
      if (!(amax > 0.0)) return bad("max_acceleration_mps2 (braking) must be positive");
      const double ab = amax;
      auto x_at = [&](double t) { return x0 + (v0 + 0.5 * a0 * t) * t; };
      auto v_at = [&](double t) { return v0 + a0 * t; };
      // Where braking at ab from (x, v) would come to rest.
      auto stop_point = [&](double t) { return x_at(t) + v_at(t) * std::abs(v_at(t)) / (2.0 * ab); };

      double t1 = -1.0;  // start of braking; < 0: not found yet
      double brake = ab;
      double t_zero = 0.0;  // velocity reaches zero here (or 0 when it starts at rest)
      if (v0 != 0.0) {
        const double dir = sign_of(v0);
        const double end = boundary(dir);
        const double room = dir * (end - x0);
        const bool opposing = a0 * dir < 0.0;
        t_zero = opposing ? -v0 / a0 : kInf;
        // While v keeps its sign, the stop point moves monotonically: g has one root at most.
        auto g = [&](double t) { return dir * (stop_point(t) - end); };
        if (g(0.0) >= 0.0) {
          if (!(opposing && v0 * v0 / (2.0 * std::abs(a0)) <= room)) {
            if (!(room > 0.0)) return bad("starts at the end of the travel moving outwards");
            t1 = 0.0;
            brake = v0 * v0 / (2.0 * room);  // harder than max_acceleration_mps2, but stops in time
          }
        } else {
          double hi = t_zero;
          if (hi == kInf) {
            hi = 1.0;
            while (g(hi) < 0.0 && hi < 1e12) hi *= 2.0;
          }
          if (g(hi) >= 0.0) {
            double lo = 0.0;
            for (int it = 0; it < 200; ++it) {
              const double mid = 0.5 * (lo + hi);
              if (mid <= lo || mid >= hi) break;
              (g(mid) >= 0.0 ? hi : lo) = mid;
            }
            t1 = lo;
          }
        }
      }
      if (t1 < 0.0 && t_zero == kInf) return bad("internal: no braking point found");
      if (t1 < 0.0) {
        // From rest at t_zero, accelerating at a0 towards the end it points to.
        const double dir = sign_of(a0);
        const double xz = x_at(t_zero);
        const double dist = std::max(0.0, dir * (boundary(dir) - xz));
        const double aa = std::abs(a0);
        t1 = t_zero + std::sqrt(2.0 * dist / (aa * (1.0 + aa / ab)));
      }
      p.initial_.velocity_mps = v0;
      lead.state = p.initial_;
      p.steady_duration_s_ = t1;
      lead.add(t1, a0);
      const double v1 = lead.state.velocity_mps;
      if (v1 != 0.0) {
        const double stop = lead.state.position_m + v1 * std::abs(v1) / (2.0 * brake);
        const double end = boundary(sign_of(v1));
        lead.add(std::abs(v1) / brake, -sign_of(v1) * brake);
        // The braking point was solved to stop at the end; drop the solver's rounding.
        lead.snap(std::abs(stop - end) < 1e-9 ? end : std::clamp(stop, cfg.min_m, cfg.max_m));
      } else {
        lead.snap(std::clamp(lead.state.position_m, cfg.min_m, cfg.max_m));
      }
      lead.hold();
      break;
    }

    case K::multisine: {
      if (!(vmax > 0.0) || !(amax > 0.0)) return bad("max_velocity_mps and max_acceleration_mps2 must be positive");
      const double room = std::min(cfg.start_m - cfg.min_m, cfg.max_m - cfg.start_m);
      if (sine_excursion(vmax, amax, 0.0) > room)
        return bad(fmt("needs at least max_velocity^2 / max_acceleration = %g m either side of start_m, "
                       "but [min_m, max_m] allows only %g m",
                       sine_excursion(vmax, amax, 0.0), room));
      // Widest frequency spread whose worst-case excursion still fits.
      double spread = 1.0;
      if (sine_excursion(vmax, amax, 1.0) > room) {
        double lo = 0.0, hi = 1.0;
        for (int it = 0; it < 100; ++it) {
          const double mid = 0.5 * (lo + hi);
          (sine_excursion(vmax, amax, mid) <= room ? lo : hi) = mid;
        }
        spread = lo;
      }
      double mean_ratio = 0.0;
      for (int k = 0; k < kSines; ++k) mean_ratio += kSineShare * sine_ratio(k, spread);
      const double omega = amax / vmax / mean_ratio;
      p.sine_count_ = kSines;
      p.centre_m_ = cfg.start_m;
      for (int k = 0; k < kSines; ++k) {
        const auto n = static_cast<std::size_t>(k);
        p.sine_omega_rps_[n] = omega * sine_ratio(k, spread);
        p.sine_amp_m_[n] = kSineShare * vmax / p.sine_omega_rps_[n];
      }
      p.initial_ = p.at(0.0);
      p.lead_count_ = 1;  // unused by at(); keeps the default invariant
      p.lead_[0] = {0.0, cfg.start_m, 0.0, 0.0};
      break;
    }

    case K::shuttle: {
      if (!(vmax > 0.0) || !(amax > 0.0)) return bad("max_velocity_mps and max_acceleration_mps2 must be positive");
      // Ties (within rounding) go to min_m first.
      const bool to_min_first = cfg.start_m - cfg.min_m <= cfg.max_m - cfg.start_m + 1e-12;
      const double first = to_min_first ? cfg.min_m : cfg.max_m;
      const double other = to_min_first ? cfg.max_m : cfg.min_m;
      const Trapezoid in = trapezoid(first - cfg.start_m, vmax, amax);
      lead.add(in.accel_s, in.a_mps2);
      lead.add(in.cruise_s, 0.0);
      lead.add(in.accel_s, -in.a_mps2);
      lead.snap(first);
      p.cycle_start_s_ = lead.t_s;

      Builder cycle{p.cycle_.data(), kMaxCycle, p.cycle_count_, 0.0, {first, 0.0, 0.0}};
      const Trapezoid out = trapezoid(other - first, vmax, amax);
      cycle.add(out.accel_s, out.a_mps2);
      cycle.add(out.cruise_s, 0.0);
      cycle.add(out.accel_s, -out.a_mps2);
      cycle.snap(other);
      cycle.add(out.accel_s, -out.a_mps2);
      cycle.add(out.cruise_s, 0.0);
      cycle.add(out.accel_s, out.a_mps2);
      if (cycle.overflow) return bad("internal: too many segments");
      p.period_s_ = cycle.t_s;
      if (!(p.period_s_ > 0.0)) return bad("min_m and max_m must differ");
      break;
    }

    case K::point_to_point: {
      const double jmax = cfg.max_jerk_mps3;
      if (!(vmax > 0.0) || !(amax > 0.0) || !(jmax > 0.0))
        return bad("max_velocity_mps, max_acceleration_mps2 and max_jerk_mps3 must be positive");
      if (!(cfg.dwell_s >= 0.0)) return bad(fmt("dwell_s %g must be >= 0", cfg.dwell_s));
      // The farther end first; ties (within rounding) go to max_m.
      const bool to_max_first = cfg.max_m - cfg.start_m >= cfg.start_m - cfg.min_m - 1e-12;
      const double first = to_max_first ? cfg.max_m : cfg.min_m;
      const double other = to_max_first ? cfg.min_m : cfg.max_m;
      lead.add_move(scurve(first - cfg.start_m, vmax, amax, jmax), first);
      p.cycle_start_s_ = lead.t_s;

      Builder cycle{p.cycle_.data(), kMaxCycle, p.cycle_count_, 0.0, {first, 0.0, 0.0}};
      cycle.add_jerk(cfg.dwell_s, 0.0);
      cycle.add_move(scurve(other - first, vmax, amax, jmax), other);
      cycle.add_jerk(cfg.dwell_s, 0.0);
      cycle.add_move(scurve(first - other, vmax, amax, jmax), first);
      if (cycle.overflow) return bad("internal: too many segments");
      p.period_s_ = cycle.t_s;
      if (!(p.period_s_ > 0.0)) return bad("min_m and max_m must differ");
      break;
    }
  }
  if (lead.overflow) return bad("internal: too many segments");
  return p;
}

}  // namespace ve::sim
