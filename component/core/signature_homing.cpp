#include "signature_homing.hpp"

#include <cmath>
#include <limits>

namespace ve::core {

SignatureHoming::SignatureHoming(double pitch_m, const SignatureHomingTuning& tuning)
    : pitch_m_(pitch_m), tuning_(tuning) {}

void SignatureHoming::start(const HallArray& hall, double x_rel_m) {
  const HallTable& t = hall.table();
  // Every whole number of pitches that keeps x_rel inside the table.
  const long k_lo = static_cast<long>(std::ceil((t.start_m - x_rel_m) / pitch_m_));
  const long k_hi = static_cast<long>(std::floor((t.end_m() - x_rel_m) / pitch_m_));
  n_ = 0;
  for (long k = k_lo; k <= k_hi && n_ < kMaxCandidates; ++k) {
    shift_m_[static_cast<std::size_t>(n_)] = static_cast<double>(k) * pitch_m_;
    chi2_[static_cast<std::size_t>(n_)] = 0.0;
    delta_m_[static_cast<std::size_t>(n_)] = 0.0;
    alive_flag_[static_cast<std::size_t>(n_)] = true;
    ++n_;
  }
  alive_ = n_;
  last_record_x_m_ = x_rel_m;
  last_x_m_ = x_rel_m;
  motion_m_ = 0.0;
  records_ = 0;
  offset_m_ = 0.0;
  best_chi2_ = second_chi2_ = 0.0;
  state_ = n_ > 0 ? State::collecting : State::idle;
}

bool SignatureHoming::feed(const HallArray& hall, const RawSample& sample, double x_rel_m, double common_mode_v,
                           std::uint32_t use_mask) {
  if (state_ != State::collecting) return false;
  motion_m_ += std::abs(x_rel_m - last_x_m_);
  last_x_m_ = x_rel_m;
  if (std::abs(x_rel_m - last_record_x_m_) < tuning_.record_step_pitches * pitch_m_) return false;
  last_record_x_m_ = x_rel_m;
  ++records_;

  const HallTable& t = hall.table();
  double best = std::numeric_limits<double>::infinity();
  double second = std::numeric_limits<double>::infinity();
  int best_i = -1;
  for (int i = 0; i < n_; ++i) {
    const auto u = static_cast<std::size_t>(i);
    if (!alive_flag_[u]) continue;
    const double guess = x_rel_m + shift_m_[u];
    // The carriage is on the track: a candidate that puts it beyond the table is out.
    if (guess < t.start_m || guess > t.end_m()) {
      alive_flag_[u] = false;
      --alive_;
      continue;
    }
    const HallFix f = hall.solve(sample, guess, common_mode_v, use_mask);
    if (f.out_of_table) {
      alive_flag_[u] = false;
      --alive_;
      continue;
    }
    chi2_[u] += f.chi2 + tuning_.conflict_chi2 * __builtin_popcount(f.conflict_mask);
    delta_m_[u] = f.position_m - guess;
    if (chi2_[u] < best) {
      second = best;
      best = chi2_[u];
      best_i = i;
    } else if (chi2_[u] < second) {
      second = chi2_[u];
    }
  }
  if (best_i < 0) {
    // Nothing fits anywhere (a table of another track?): start over from here.
    start(hall, x_rel_m);
    return false;
  }
  for (int i = 0; i < n_; ++i) {
    const auto u = static_cast<std::size_t>(i);
    if (alive_flag_[u] && chi2_[u] > best + tuning_.drop_margin_chi2) {
      alive_flag_[u] = false;
      --alive_;
    }
  }
  best_chi2_ = best;
  second_chi2_ = second;
  if (motion_m_ < tuning_.min_motion_pitches * pitch_m_) return false;
  if (best > tuning_.max_chi2_per_record * records_) return false;
  if (second - best < tuning_.decision_margin_chi2) return false;
  const auto b = static_cast<std::size_t>(best_i);
  offset_m_ = shift_m_[b] + delta_m_[b];
  state_ = State::homed;
  return true;
}

}  // namespace ve::core
