// Block K against theory: the steady-state covariance the filter settles to must
// be the stabilising solution of the discrete algebraic Riccati equation, solved
// here independently with the structured doubling algorithm.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <random>

#include "core/fusion_filter.hpp"
#include "core/kalman.hpp"

namespace {

using Mat3 = Eigen::Matrix3d;

/// A priori steady-state covariance P = A P A' - A P C'(C P C' + R)^-1 C P A' + Q
/// by structured doubling (Chu et al.): quadratic convergence, no iteration of the
/// filter recursion itself.
Mat3 solve_filter_dare(const Mat3& a, const Eigen::Matrix<double, 2, 3>& c, const Eigen::Matrix2d& r, const Mat3& q) {
  Mat3 ak = a.transpose();
  Mat3 gk = c.transpose() * r.inverse() * c;
  Mat3 hk = q;
  for (int k = 0; k < 60; ++k) {
    const Mat3 w = (Mat3::Identity() + gk * hk).inverse();
    const Mat3 a_next = ak * w * ak;
    const Mat3 g_next = gk + ak * w * gk * ak.transpose();
    const Mat3 h_next = hk + ak.transpose() * hk * w * ak;
    const double change = (h_next - hk).norm() / h_next.norm();
    ak = a_next;
    gk = g_next;
    hk = h_next;
    if (change < 1e-15) break;
  }
  return hk;
}

struct Case {
  const char* name;
  double ts_s;
  double jerk_std_mps3;
  double hall_std_m;
  double accel_std_mps2;
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.name; }

class KalmanRiccati : public ::testing::TestWithParam<Case> {};

TEST_P(KalmanRiccati, SteadyStateCovarianceSolvesTheRiccatiEquation) {
  const Case c = GetParam();
  ve::core::KinematicKalman kf(c.ts_s, c.jerk_std_mps3);
  kf.reset(ve::core::KinematicKalman::Vec::Zero(), Mat3::Identity() * 1e-2);
  const double rx = c.hall_std_m * c.hall_std_m;
  const double ra = c.accel_std_mps2 * c.accel_std_mps2;
  Mat3 prior;
  for (int k = 0; k < 200000; ++k) {
    kf.predict();
    prior = kf.covariance();
    bool applied = false;
    kf.update(ve::core::KinematicKalman::kPos, 0.0, rx, 0.0, applied);
    kf.update(ve::core::KinematicKalman::kAcc, 0.0, ra, 0.0, applied);
  }
  Eigen::Matrix<double, 2, 3> cm;
  cm << 1, 0, 0, 0, 0, 1;
  Eigen::Matrix2d r = Eigen::Vector2d(rx, ra).asDiagonal();
  const Mat3 p_prior = solve_filter_dare(kf.transition(), cm, r, kf.process_noise());
  // A posteriori from the a priori solution: P+ = P - P C'(C P C' + R)^-1 C P.
  const Eigen::Matrix2d s = cm * p_prior * cm.transpose() + r;
  const Mat3 p_post = p_prior - p_prior * cm.transpose() * s.ldlt().solve(cm * p_prior);

  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      const double scale = std::sqrt(p_prior(i, i) * p_prior(j, j));
      EXPECT_NEAR(prior(i, j), p_prior(i, j), 1e-6 * scale) << c.name << " prior(" << i << "," << j << ")";
      const double scale_post = std::sqrt(p_post(i, i) * p_post(j, j));
      EXPECT_NEAR(kf.covariance()(i, j), p_post(i, j), 1e-6 * scale_post) << c.name << " post(" << i << "," << j << ")";
    }
  }
  // The fused position is better than the Hall position alone.
  EXPECT_LT(kf.covariance()(0, 0), rx) << c.name;
}

INSTANTIATE_TEST_SUITE_P(Tunings, KalmanRiccati,
                         ::testing::Values(Case{"paper_4kHz", 1.0 / 4000, 60.0, 0.5e-6, 0.02},
                                           Case{"stiff_jerk", 1.0 / 4000, 2000.0, 0.5e-6, 0.02},
                                           Case{"soft_jerk_noisy_hall", 1.0 / 4000, 5.0, 5e-6, 0.05},
                                           Case{"slow_1kHz", 1.0 / 1000, 60.0, 1e-6, 0.01}),
                         [](const auto& info) { return std::string(info.param.name); });

TEST(KalmanGate, RejectsOutliersBeyondTheGateAndKeepsTheState) {
  ve::core::KinematicKalman kf(1.0 / 4000, 60.0);
  Mat3 p = Mat3::Zero();
  p.diagonal() << 1e-12, 1e-6, 1e-4;
  kf.reset(ve::core::KinematicKalman::Vec(0.1, 0.0, 0.0), p);
  kf.predict();
  bool applied = true;
  const double nu = kf.update(ve::core::KinematicKalman::kPos, 0.1 + 1e-3, 1e-12, 6.0, applied);
  EXPECT_FALSE(applied);
  EXPECT_GT(nu, 6.0);
  EXPECT_DOUBLE_EQ(kf.state()(0), 0.1);
  kf.update(ve::core::KinematicKalman::kPos, 0.1 + 1e-6, 1e-12, 6.0, applied);
  EXPECT_TRUE(applied);
  EXPECT_GT(kf.state()(0), 0.1);
}

// The calm-motion model on a constant speed: it is entered, the velocity it
// publishes is far better than the agile model's, and the published sigma (the
// covariance less what the calm model's own white jerk added) matches the error
// actually made over many noise draws, where the raw covariance overstates it.
TEST(FusionFilterCalm, PublishedSigmaMatchesTheErrorAtConstantSpeed) {
  const double ts = 1.0 / 4000, v = 1.0, hall_std = 0.3e-6, accel_std = 0.02;
  ve::core::FilterConfig tuning;
  tuning.steady_jerk_std_mps3 = 0.02;
  tuning.steady_position_walk_m_per_sqrt_s = 7e-7;
  ve::core::SensorModel model;
  model.accel_bias_mps2 = 0.05;
  double err2 = 0, pub2 = 0, raw2 = 0;
  int n = 0, calm = 0;
  for (int run = 0; run < 20; ++run) {
    std::mt19937_64 rng(1000 + run);
    std::normal_distribution<double> hall(0.0, hall_std), acc(0.0, accel_std);
    ve::core::FusionFilter kf(ts, tuning, model);
    kf.reset(0.1 + hall(rng), hall_std * hall_std, 0.05 + acc(rng), true);
    for (int k = 1; k < 4000; ++k) {
      const double x = 0.1 + v * k * ts;
      kf.predict();
      bool applied = false;
      kf.update_hall(x + hall(rng), hall_std * hall_std, 6.0, applied);
      kf.update_accel(0.05 + acc(rng), accel_std * accel_std, 0.0, applied);
      if (k < 2000) continue;  // from 0.5 s on
      const double e = kf.state()(ve::core::FusionFilter::kVel) - v;
      err2 += e * e;
      pub2 += kf.velocity_variance();
      raw2 += kf.covariance()(ve::core::FusionFilter::kVel, ve::core::FusionFilter::kVel);
      calm += kf.steady() ? 1 : 0;
      ++n;
    }
  }
  const double rms = std::sqrt(err2 / n), pub = std::sqrt(pub2 / n), raw = std::sqrt(raw2 / n);
  std::printf("[ figures  ] calm model at 1 m/s: velocity error RMS %.3f mm/s, published sigma %.3f mm/s, "
              "raw covariance %.3f mm/s, calm %.1f %% of the time\n",
              rms * 1e3, pub * 1e3, raw * 1e3, 100.0 * calm / n);
  EXPECT_EQ(calm, n);
  EXPECT_LT(rms, 0.005e-3);  // the agile model's floor here is about 0.025 mm/s
  EXPECT_LT(pub, raw);
  EXPECT_GT(pub / rms, 0.7);
  EXPECT_LT(pub / rms, 1.4);
}

}  // namespace
