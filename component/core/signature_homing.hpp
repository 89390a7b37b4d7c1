// Homing without a reference mark. A calibrated Hall table keeps every magnet
// period's own signature: each magnet's strength and the place of each boundary
// differ by a percent and tens of micrometres, 50 times what the Hall noise hides.
// Started in any period, the axis runs on a relative position; while it moves,
// every period of the travel is a candidate, and each Hall sample taken after
// another 1/32 pitch of motion is solved in every candidate period still in the
// race. The sensor residuals (chi-square) of the right period stay at the noise;
// those of a wrong one grow with each record. The axis is homed when one candidate
// fits and beats the runner-up by a wide margin.
//
// Fixed-size arrays; feeding a sample allocates nothing. A record costs one Hall
// solve per candidate still in the race: about 80 for a 1 m travel at the first
// record, a handful after a few records (the others are dropped once clearly out).
#pragma once

#include <array>
#include <cstdint>

#include "hall_array.hpp"
#include "sample.hpp"

namespace ve::core {

struct SignatureHomingTuning {
  double record_step_pitches = 1.0 / 32.0;  ///< motion between two records
  double min_motion_pitches = 0.5;          ///< motion before any decision
  /// The best candidate's chi-square sum must be lower than the runner-up's by this.
  double decision_margin_chi2 = 400.0;
  /// ... and its mean chi-square per record at most this (the table fits at all).
  double max_chi2_per_record = 30.0;
  /// Candidates whose sum exceeds the best one's by this are dropped.
  double drop_margin_chi2 = 4000.0;
  /// A saturated sensor far from its table value in a candidate period counts this much.
  double conflict_chi2 = 1000.0;
};

class SignatureHoming {
 public:
  static constexpr int kMaxCandidates = 4096;

  enum class State { idle, collecting, homed };

  SignatureHoming(double pitch_m, const SignatureHomingTuning& tuning = {});

  /// The Hall array (with the calibrated table) is passed to each call, not kept.
  /// Starts a search around relative position `x_rel_m` (the frame the filter runs in).
  /// Candidates: x_rel + k pitch inside the table, for every integer k.
  void start(const HallArray& hall, double x_rel_m);
  void stop() { state_ = State::idle; }

  /// One Hall sample taken when the filter placed the carriage at `x_rel_m` (at the
  /// Halls' own instant). Returns true on the sample that decides; then `offset_m()`
  /// is what to add to the relative position to make it absolute.
  bool feed(const HallArray& hall, const RawSample& sample, double x_rel_m, double common_mode_v,
            std::uint32_t use_mask);

  State state() const { return state_; }
  double offset_m() const { return offset_m_; }
  /// Motion since start() [m] (the distance moved, both directions added).
  double motion_m() const { return motion_m_; }
  int records() const { return records_; }
  int candidates_alive() const { return alive_; }
  /// Best and runner-up chi-square sums of the last record (diagnostics, tests).
  double best_chi2() const { return best_chi2_; }
  double runner_up_chi2() const { return second_chi2_; }

 private:
  double pitch_m_;
  SignatureHomingTuning tuning_;
  State state_ = State::idle;
  int n_ = 0;      ///< candidates in use
  int alive_ = 0;
  std::array<double, kMaxCandidates> shift_m_{};  ///< k pitch
  std::array<double, kMaxCandidates> chi2_{};
  std::array<double, kMaxCandidates> delta_m_{};  ///< last fix minus (x_rel + shift)
  std::array<bool, kMaxCandidates> alive_flag_{};
  double last_record_x_m_ = 0.0;
  double last_x_m_ = 0.0;
  double motion_m_ = 0.0;
  int records_ = 0;
  double offset_m_ = 0.0;
  double best_chi2_ = 0.0;
  double second_chi2_ = 0.0;
};

}  // namespace ve::core
