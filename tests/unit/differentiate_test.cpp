// The Savitzky-Golay derivatives that calibration takes of a position series: the
// sliding-sum implementation against the definition (a quadratic least-squares
// fit over each window, solved afresh), on a long series far from 0 (where
// rounding in sliding sums would show), for short and long windows.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "core/identification.hpp"

namespace {

/// The definition: for each centre, the quadratic through the window by least
/// squares, its first and second derivatives at the centre.
void direct(const std::vector<double>& x, double ts, int m, std::vector<double>& v, std::vector<double>& a) {
  const std::size_t n = x.size();
  v.assign(n, 0.0);
  a.assign(n, 0.0);
  double s2 = 0.0;
  for (int k = -m; k <= m; ++k) s2 += static_cast<double>(k) * k;
  const double mk = s2 / (2 * m + 1);
  double s4 = 0.0;
  for (int k = -m; k <= m; ++k) s4 += (k * k - mk) * (k * k - mk);
  for (std::size_t i = static_cast<std::size_t>(m); i + static_cast<std::size_t>(m) < n; ++i) {
    double c1 = 0.0, c2 = 0.0;
    for (int k = -m; k <= m; ++k) {
      const double d = x[static_cast<std::size_t>(static_cast<long>(i) + k)] - x[i];
      c1 += k * d;
      c2 += (k * k - mk) * d;
    }
    v[i] = c1 / s2 / ts;
    a[i] = 2.0 * c2 / s4 / (ts * ts);
  }
}

TEST(Differentiate, SlidingSumsAgreeWithTheWindowedFitEverywhere) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> noise(0.0, 1e-6);
  const double ts = 1.0 / 8300.0;
  std::vector<double> x(300000);
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double t = static_cast<double>(i) * ts;
    x[i] = 1.5 + 0.9 * std::sin(2.0 * t) + 0.02 * std::sin(40.0 * t) + noise(rng);
  }
  for (const int m : {1, 3, 20, 207}) {
    SCOPED_TRACE(m);
    std::vector<double> v0, a0, v1, a1;
    std::vector<char> valid;
    direct(x, ts, m, v0, a0);
    ve::core::differentiate(x, ts, m, v1, a1, valid);
    ASSERT_EQ(valid.size(), x.size());
    double dv = 0.0, da = 0.0;
    for (std::size_t i = 0; i < x.size(); ++i) {
      const bool inside = i >= static_cast<std::size_t>(m) && i + static_cast<std::size_t>(m) < x.size();
      ASSERT_EQ(valid[i] != 0, inside) << i;
      dv = std::max(dv, std::abs(v1[i] - v0[i]));
      da = std::max(da, std::abs(a1[i] - a0[i]));
    }
    // A micrometre of noise differentiated twice over 3 samples is tens of m/s^2;
    // the two computations agree to a billionth of a m/s^2.
    EXPECT_LE(dv, 1e-10);
    EXPECT_LE(da, 1e-8);
  }
}

TEST(Differentiate, AQuadraticComesOutExactly) {
  const double ts = 1e-4;
  std::vector<double> x(5000);
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double t = static_cast<double>(i) * ts;
    x[i] = 0.7 + 1.25 * t - 3.5 * t * t;  // v = 1.25 - 7 t, a = -7
  }
  std::vector<double> v, a;
  std::vector<char> valid;
  ve::core::differentiate(x, ts, 50, v, a, valid);
  for (std::size_t i = 50; i + 50 < x.size(); ++i) {
    const double t = static_cast<double>(i) * ts;
    ASSERT_NEAR(v[i], 1.25 - 7.0 * t, 1e-9) << i;
    ASSERT_NEAR(a[i], -7.0, 1e-5) << i;
  }
}

}  // namespace
