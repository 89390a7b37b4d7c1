// Analytic motion profiles of the simulated carriage. Every profile is a closed-form
// function of time, so the simulator's truth is exact (no integration drift) and
// at() is O(1), allocation-free and safe to call from any thread.
#pragma once

#include <array>
#include <optional>
#include <string>

#include "sim/sim_config.hpp"

namespace ve::sim {

struct Kinematics {
  double position_m = 0.0;
  double velocity_mps = 0.0;
  double acceleration_mps2 = 0.0;
  double jerk_mps3 = 0.0;  ///< between segments (where it steps): the jerk of the segment that starts there
};

/// "standstill", "constant_velocity", ... (the enumerator's name).
const char* kind_name(MotionProfileConfig::Kind kind);

/// What each kind does (times from t = 0; before t = 0 every profile except
/// multisine continues with its t = 0 velocity and zero acceleration, which matters
/// only for delayed sensors at the first samples):
/// - standstill: at start_m forever.
/// - constant_velocity: x = start_m + v t until braking at max_acceleration_mps2
///   stops it exactly at max_m (v > 0) or min_m (v < 0); then it stands still.
/// - constant_acceleration: from start_m with velocity_mps, accelerates at
///   acceleration_mps2 (through zero velocity if the two have opposite signs) until
///   braking at max_acceleration_mps2 stops it exactly at min_m or max_m; then it
///   stands still. If even braking at once at max_acceleration_mps2 would overshoot,
///   it brakes at once, just as hard as needed (steady_duration_s() = 0).
/// - multisine: x = start_m + sum_k A_k sin(w_k t), four components at incommensurate
///   frequencies (ratios sqrt(2):sqrt(3):sqrt(5):sqrt(7) about a common centre,
///   narrowed if the travel is short). sum A_k w_k = max_velocity_mps and
///   sum A_k w_k^2 = max_acceleration_mps2, so neither bound is ever exceeded;
///   at t = 0 the carriage is at start_m at full speed max_velocity_mps (all
///   components in phase) and about a quarter period later the acceleration reaches
///   more than 85 % of its bound. sum A_k <= min(start_m - min_m, max_m - start_m).
/// - shuttle: trapezoidal moves (max_velocity_mps, max_acceleration_mps2, no dwell)
///   from rest at start_m to the nearer of min_m / max_m ("lead-in", zero length if
///   start_m is one of them), then back and forth between min_m and max_m forever:
///   first to the far end, then back; period_s() is one round trip.
/// - point_to_point: jerk-limited rest-to-rest moves (S-curve, seven phases: jerk
///   +J, 0, -J, cruise, -J, 0, +J with J = max_jerk_mps3, |a| <= max_acceleration_mps2,
///   |v| <= max_velocity_mps). From rest at start_m it moves at once (no dwell) to the
///   FARTHER of min_m / max_m (ties: max_m) -- the "lead-in"; then, periodically: dwell
///   dwell_s, move to the other end, dwell dwell_s, move back. period_s() is one round
///   trip including both dwells. A move too short to reach max_velocity_mps drops the
///   cruise and lowers the peak speed; one too short to reach max_acceleration_mps2
///   too drops the constant-acceleration phases (peak acceleration sqrt(v J) < the
///   bound). Each phase is an exact cubic in time; at() scans at most 16 segments.
class MotionProfile {
 public:
  /// Standstill at 0 m; use create() for a configured profile.
  MotionProfile() = default;

  /// Validates `cfg` against the motor's travel [0, travel_m] and builds the profile.
  /// On failure returns nullopt and, if `error` is given, says why. Called once at
  /// start-up; the profile is then a plain value.
  static std::optional<MotionProfile> create(const MotionProfileConfig& cfg, double travel_m,
                                             std::string* error = nullptr);

  Kinematics at(double t_s) const;

  MotionProfileConfig::Kind kind() const { return kind_; }

  /// constant_velocity / constant_acceleration: length of the constant phase from
  /// t = 0 (the window in which the profile is what its name says) [s].
  /// standstill, multisine, shuttle: +infinity (they never leave their pattern).
  double steady_duration_s() const { return steady_duration_s_; }

  /// shuttle, point_to_point: one round trip min_m -> max_m -> min_m (with both
  /// dwells) [s]; 0 for the others.
  double period_s() const { return period_s_; }
  /// shuttle, point_to_point: time of the lead-in move to the first end [s]; 0 otherwise.
  double lead_in_s() const { return cycle_start_s_; }

  /// multisine: components used (amplitude [m] and angular frequency [rad/s]).
  static constexpr int kMaxSines = 4;
  int sine_count() const { return sine_count_; }
  double sine_amplitude_m(int k) const { return sine_amp_m_[static_cast<std::size_t>(k)]; }
  double sine_omega_rps(int k) const { return sine_omega_rps_[static_cast<std::size_t>(k)]; }

 private:
  /// Constant jerk (usually 0: constant acceleration) from (t0_s, x0_m, v0_mps, a_mps2)
  /// on; the last one lasts forever.
  struct Segment {
    double t0_s = 0.0;
    double x0_m = 0.0;
    double v0_mps = 0.0;
    double a_mps2 = 0.0;
    double j_mps3 = 0.0;
  };
  static constexpr int kMaxLead = 8;    // point_to_point: a seven-phase move + hold slack
  static constexpr int kMaxCycle = 16;  // point_to_point: 2 x (dwell + seven phases)

  static Kinematics eval(const Segment& s, double t_s);

  MotionProfileConfig::Kind kind_ = MotionProfileConfig::Kind::standstill;
  double steady_duration_s_ = 0.0;

  std::array<Segment, kMaxLead> lead_{};
  int lead_count_ = 1;  // lead_[0] is always valid: standstill at 0 by default
  std::array<Segment, kMaxCycle> cycle_{};  // times relative to cycle_start_s_
  int cycle_count_ = 0;
  double cycle_start_s_ = 0.0;
  double period_s_ = 0.0;
  Kinematics initial_{};  // state at t = 0, extrapolated at constant velocity for t < 0

  double centre_m_ = 0.0;
  int sine_count_ = 0;
  std::array<double, kMaxSines> sine_amp_m_{};
  std::array<double, kMaxSines> sine_omega_rps_{};
};

}  // namespace ve::sim
