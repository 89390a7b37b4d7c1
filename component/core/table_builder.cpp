#include "table_builder.hpp"

#include <cmath>
#include <limits>

namespace ve::core {

namespace {
constexpr int kMinSamplesPerNode = 3;
}

TableBuilder::TableBuilder(const MotorConfig& motor, int points_per_pitch) {
  grid_.step_m = motor.magnet_pitch_m / points_per_pitch;
  grid_.start_m = 0.0;
  grid_.points = static_cast<int>(std::ceil(motor.travel_m / grid_.step_m)) + 1;
  grid_.sensors = motor.hall.count;
  sums_.resize(static_cast<std::size_t>(grid_.points) * static_cast<std::size_t>(grid_.sensors));
}

void TableBuilder::add(double x_m, const RawSample& sample) {
  const double u = (x_m - grid_.start_m) / grid_.step_m;
  const int k_lo = static_cast<int>(std::floor(u));
  for (int k = k_lo; k <= k_lo + 1; ++k) {
    if (k < 0 || k >= grid_.points) continue;
    const double d = (x_m - (grid_.start_m + k * grid_.step_m)) / grid_.step_m;  // in steps, |d| <= 1
    const double w = 1.0 - std::abs(d);
    if (w <= 0.0) continue;
    for (int s = 0; s < grid_.sensors && s < sample.hall_count; ++s) {
      if (!(sample.hall_valid_mask >> s & 1u)) continue;
      auto& a = sums_[static_cast<std::size_t>(s) * grid_.points + k];
      const double y = sample.hall_v[s];
      a.w += w;
      a.wd += w * d;
      a.wdd += w * d * d;
      a.wy += w * y;
      a.wdy += w * d * y;
      ++a.n;
    }
  }
}

bool TableBuilder::finish(HallTable& out, std::string& error, bool allow_missing) const {
  out = grid_;
  out.v.assign(sums_.size(), 0.0);
  int missing = 0;
  double first_missing = -1.0;
  for (int s = 0; s < grid_.sensors; ++s) {
    for (int k = 0; k < grid_.points; ++k) {
      const auto& a = sums_[static_cast<std::size_t>(s) * grid_.points + k];
      const double det = a.w * a.wdd - a.wd * a.wd;
      double value;
      if (a.n >= kMinSamplesPerNode && det > 1e-12 * a.w * a.w) {
        // Weighted least squares y = c0 + c1 d; the node value is c0.
        value = (a.wdd * a.wy - a.wd * a.wdy) / det;
      } else if (a.n >= 1 && a.w > 0.0) {
        value = a.wy / a.w;  // all samples at one spot: take their mean
      } else {
        if (missing++ == 0) first_missing = grid_.start_m + k * grid_.step_m;
        value = std::numeric_limits<double>::quiet_NaN();
      }
      out.v[static_cast<std::size_t>(s) * grid_.points + k] = value;
    }
  }
  if (missing > 0 && !allow_missing) {
    error = std::to_string(missing) + " table nodes have no samples (first at " +
            std::to_string(first_missing * 1e3) + " mm): the sweep must cover the whole travel";
    return false;
  }
  return true;
}

double TableBuilder::coverage() const {
  int covered = 0;
  for (int k = 0; k < grid_.points; ++k)
    if (sums_[static_cast<std::size_t>(k)].n >= kMinSamplesPerNode) ++covered;
  return grid_.points > 0 ? static_cast<double>(covered) / grid_.points : 0.0;
}

}  // namespace ve::core
