// The DDS interface as other programs see it, with the real `virtual-encoder run`
// in another process: the diagnostics topic, a late-joining subscriber learning
// the axis description (TRANSIENT_LOCAL), a three-axis machine whose instances
// have independent deadlines (one axis' sensor node silent for a second, the others not),
// and the XML profiles (deploy/dds-profiles.xml).
#include <gtest/gtest.h>

#include <cstdlib>

#include <fcntl.h>
#include <stdlib.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <vector>

#include "app/dds_io.hpp"
#include "core/status.hpp"
#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

using namespace std::chrono_literals;
using ve::test::ChildProcess;
using ve::test::kRealTimeFigures;
using ve::test::patience;
using ve::test::wait_until;

std::string data(const std::string& name) { return std::string(VE_SOURCE_DIR) + "/tests/integration/data/" + name; }
std::string profiles_file() { return std::string(VE_SOURCE_DIR) + "/deploy/dds-profiles.xml"; }

std::int64_t realtime_ns() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

/// A subscriber with the product's reader; keeps every diagnostics sample and
/// the states' per-axis last values.
struct Probe {
  std::unique_ptr<ve::app::DdsContext> ctx;
  std::unique_ptr<ve::app::StateReader> reader;
  std::mutex mutex;
  std::vector<ve::dds::Diagnostics> diagnostics;
  std::vector<ve::dds::EncoderState> states;  // the first few thousand
  std::map<std::uint32_t, std::uint64_t> state_count;

  Probe(int domain, double deadline_ms, const std::string& profiles = {}) {
    ve::app::DdsOptions o;
    o.domain = domain;
    o.participant_name = "integration-test-interface";
    o.profiles_file = profiles;
    std::string error;
    ctx = ve::app::DdsContext::create(o, error);
    if (!ctx) {
      ADD_FAILURE() << error;
      return;
    }
    states.reserve(20000);
    reader = std::make_unique<ve::app::StateReader>(
        *ctx, deadline_ms,
        [this](const ve::dds::EncoderState& s) {
          std::lock_guard<std::mutex> lock(mutex);
          if (states.size() < 20000) states.push_back(s);
          ++state_count[s.axis_id()];
        },
        [this](const ve::dds::Diagnostics& d) {
          std::lock_guard<std::mutex> lock(mutex);
          diagnostics.push_back(d);
        });
  }
  ~Probe() {
    reader.reset();
    ctx.reset();
  }
  bool ok() const { return reader && reader->ok(); }
  std::size_t diagnostics_of(std::uint32_t axis) {
    std::lock_guard<std::mutex> lock(mutex);
    std::size_t n = 0;
    for (const auto& d : diagnostics) n += d.axis_id() == axis;
    return n;
  }
  std::uint64_t states_of(std::uint32_t axis) {
    std::lock_guard<std::mutex> lock(mutex);
    return state_count[axis];
  }
  ve::app::AxisStats stats(std::uint32_t axis) {
    for (const auto& a : reader->snapshot())
      if (a.axis_id == axis) return a;
    return {};
  }
};

std::vector<std::string> run_args(const std::string& config, int domain, double duration_s, double wait_s) {
  std::vector<std::string> a{VE_BINARY, "run",      "--config",          config, "--domain", std::to_string(domain),
                             "--duration", std::to_string(duration_s)};
  if (wait_s > 0) {
    a.push_back("--wait-for-subscriber");
    a.push_back(std::to_string(wait_s));
  }
  return a;
}

TEST(DdsInterface, DiagnosticsRoundTripBetweenTwoProcesses) {
  const ve::test::RealTimeSlot real_time;  // needs its CPU to judge what it does (speed.hpp)
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  Probe probe(domain, 20.0);
  ASSERT_TRUE(probe.ok());
  ChildProcess pub(run_args(data("standstill.yaml"), domain, 60, 10), (dir.path / "run.log").string());
  ASSERT_TRUE(pub.started());
  ASSERT_TRUE(wait_until([&] { return probe.reader->matched_diagnostics_writers() > 0; }, patience(15s))) << pub.log();
  ASSERT_TRUE(wait_until([&] { return probe.diagnostics_of(1) >= 15; }, patience(15s))) << pub.log();

  std::vector<ve::dds::Diagnostics> diags;
  std::vector<ve::dds::EncoderState> states;
  {
    std::lock_guard<std::mutex> lock(probe.mutex);
    diags = probe.diagnostics;
    states = probe.states;
  }
  // About 10 Hz, consecutive, each summarising ~400 samples of the 4 kHz axis.
  for (std::size_t i = 1; i < diags.size(); ++i) {
    EXPECT_EQ(diags[i].sequence_number(), diags[i - 1].sequence_number() + 1) << "reliable: no diagnostics lost";
    EXPECT_GT(diags[i].state_sequence(), diags[i - 1].state_sequence());
  }
  const auto first_ns = diags.front().publish_time_ns();
  const auto last_ns = diags.back().publish_time_ns();
  const double rate = (diags.size() - 1) / ((last_ns - first_ns) * 1e-9);
  // The rates are figures of the real-time stream: judged at real speed only (speed.hpp).
  if (kRealTimeFigures) {
    EXPECT_NEAR(rate, 10.0, 2.0);
  }
  const auto& d = diags.back();
  EXPECT_EQ(d.axis_id(), 1u);
  EXPECT_TRUE(d.status() & ve::core::status::kValid) << ve::core::status_to_string(d.status());
  EXPECT_EQ(d.hall_count(), 4u);
  EXPECT_EQ(d.hall_valid_mask(), 0xFu);
  EXPECT_EQ(d.hall_saturated_mask() & ~0xFu, 0u);
  EXPECT_GE(d.hall_sensors_used_min(), 1u);
  EXPECT_GE(d.hall_sensors_used_mean(), 1.0);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_GE(d.hall_volts()[i], 0.0);
    EXPECT_LE(d.hall_volts()[i], 5.0);
  }
  for (std::size_t i = 4; i < 8; ++i) EXPECT_EQ(d.hall_volts()[i], 0.0);
  // Per period the rate is noisy on a loaded machine (a late real-time source catches
  // up in a burst); over all periods it is the axis' 4 kHz.
  EXPECT_LE(d.period_samples(), 400u);
  std::uint64_t samples = 0;
  for (std::size_t i = 1; i < diags.size(); ++i) samples += diags[i].period_samples();
  const double mean_rate = samples / ((last_ns - first_ns) * 1e-9);
  if (kRealTimeFigures) {
    EXPECT_NEAR(mean_rate, 4000.0, 400.0);
  }
  EXPECT_GT(d.sample_rate_hz(), 0.0);
  if (kRealTimeFigures) {
    EXPECT_NEAR(d.arrival_period_mean_us() * d.sample_rate_hz() * 1e-6, 1.0, 0.2);
  }
  EXPECT_GT(d.arrival_jitter_us(), 0.0);
  EXPECT_GE(d.arrival_interval_max_us(), d.arrival_period_mean_us());
  EXPECT_GT(d.step_time_mean_us(), 0.0);
  EXPECT_GE(d.step_time_max_us(), d.step_time_mean_us());
  EXPECT_GT(d.innovation_rms(), 0.05);
  EXPECT_LT(d.innovation_rms(), 5.0);
  EXPECT_GE(d.innovation_max_abs(), d.innovation_rms());
  EXPECT_TRUE(std::isfinite(d.accel_bias_mps2()));
  EXPECT_GT(d.accel_scale(), 0.5);
  EXPECT_GT(d.samples_total(), 4000u);
  EXPECT_EQ(d.write_failures_total(), 0u);
  EXPECT_DOUBLE_EQ(d.position_std_ratio(), d.position_std_m() / 5e-6);
  EXPECT_DOUBLE_EQ(d.velocity_std_ratio(), d.velocity_std_mps() / 1.7e-3);
  EXPECT_GT(d.position_std_ratio(), 0.0);
  EXPECT_LT(d.position_std_ratio(), 1.0);
  EXPECT_LT(std::llabs(realtime_ns() - d.publish_time_ns()), 5000000000LL);
  std::printf("[ figures  ] diagnostics: %zu at %.1f Hz (%.0f samples/s); innovation RMS %.2f, step mean/max %.1f/%.0f us, "
              "arrival jitter %.1f us, sigma/budget %.2f (position) %.2f (velocity), %llu offered misses\n",
              diags.size(), rate, mean_rate, d.innovation_rms(), d.step_time_mean_us(), d.step_time_max_us(),
              d.arrival_jitter_us(), d.position_std_ratio(), d.velocity_std_ratio(),
              static_cast<unsigned long long>(d.deadline_missed_total()));

  // The appended EncoderState fields: host timestamps and the acceleration sigma.
  ASSERT_GT(states.size(), 1000u);
  std::vector<double> latency_us;
  for (const auto& s : states) {
    ASSERT_GE(s.publish_time_ns(), s.source_time_ns());
    EXPECT_GT(s.acceleration_std_mps2(), 0.0);
    latency_us.push_back((s.publish_time_ns() - s.source_time_ns()) * 1e-3);
  }
  std::sort(latency_us.begin(), latency_us.end());
  std::printf("[ figures  ] handover -> publish (estimator step): p50 %.1f us, p99 %.1f us\n",
              latency_us[latency_us.size() / 2], latency_us[latency_us.size() * 99 / 100]);

  // The monitor's view of the same axis carries the diagnostics.
  const auto a = probe.stats(1);
  EXPECT_GT(a.diagnostics_received, 0u);
  EXPECT_EQ(a.diagnostics.axis_id(), 1u);

  pub.signal(SIGTERM);
  EXPECT_EQ(pub.wait_exit(patience(10s)), 0) << pub.log();
  EXPECT_NE(pub.log().find("diagnostics"), std::string::npos) << pub.log();
}

TEST(DdsInterface, LateJoiningSubscriberReceivesTheAxisDescription) {
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  ChildProcess pub(run_args(data("standstill.yaml"), domain, 60, 0), (dir.path / "run.log").string());
  ASSERT_TRUE(pub.started());
  // Let the publisher write its description long before anyone listens.
  ASSERT_TRUE(wait_until([&] { return pub.log().find("rate=") != std::string::npos; }, patience(15s))) << pub.log();
  std::this_thread::sleep_for(1s);

  Probe probe(domain, 0.0);
  ASSERT_TRUE(probe.ok());
  ASSERT_TRUE(wait_until([&] { return probe.stats(1).have_description; }, patience(10s)))
      << "the late joiner did not receive the transient-local description\n"
      << pub.log();
  const auto a = probe.stats(1);
  EXPECT_EQ(a.description.axis_id(), 1u);
  EXPECT_EQ(a.description.name(), "x");
  EXPECT_EQ(a.description.machine(), "test-standstill");
  EXPECT_EQ(a.description.motor(), "sim-12mm");
  EXPECT_EQ(a.description.hall_count(), 4u);
  EXPECT_DOUBLE_EQ(a.description.sample_rate_hz(), 4000.0);
  EXPECT_DOUBLE_EQ(a.description.deadline_ms(), 5.0);
  EXPECT_EQ(a.description.calibration_id(), "");
  EXPECT_FALSE(a.description.software_version().empty());
  // And the live streams reach the late joiner too.
  EXPECT_TRUE(wait_until([&] { return probe.states_of(1) > 400 && probe.diagnostics_of(1) > 2; }, patience(10s)));
  // It counts the writers it matched, though they were there before its readers were
  // (matches made before the listener was attached gave no callback): the encoder's
  // one state writer of the axis and its diagnostics writer.
  EXPECT_EQ(probe.reader->matched_writers(), 1);
  EXPECT_EQ(probe.reader->matched_diagnostics_writers(), 1);

  pub.signal(SIGTERM);
  EXPECT_EQ(pub.wait_exit(patience(10s)), 0) << pub.log();
}

TEST(DdsInterface, ThreeAxesAreThreeInstancesWithIndependentDeadlines) {
  const ve::test::RealTimeSlot real_time;  // needs its CPU to judge what it does (speed.hpp)
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  const double requested_ms = 50.0;
  Probe probe(domain, requested_ms, profiles_file());
  ASSERT_TRUE(probe.ok());
  // The sensor node of axis y alone falls silent (a no_samples fault in the machine
  // file), 1.5 s after its first sample, for 1 s.
  ChildProcess pub(run_args(data("three_axes_y_silent.yaml"), domain, 60, 10), (dir.path / "run.log").string());
  ASSERT_TRUE(pub.started());
  ASSERT_TRUE(wait_until([&] { return probe.reader->matched_writers() > 0; }, patience(15s))) << pub.log();

  // Three instances, each with its own values.
  ASSERT_TRUE(wait_until([&] { return probe.states_of(1) > 400 && probe.states_of(2) > 400 && probe.states_of(3) > 400; },
                         patience(10s)))
      << pub.log();
  const double expected_m[4] = {0, 0.2, 0.4, 0.6};
  for (std::uint32_t id = 1; id <= 3; ++id)
    EXPECT_NEAR(probe.stats(id).last.position_m(), expected_m[id], 1e-4) << "axis " << id;

  // Axis y falls silent: its instance misses the requested deadline; x and z do not.
  ASSERT_TRUE(wait_until([&] { return probe.stats(2).deadline_missed > 0; }, patience(10s))) << pub.log();
  // Wait for the end of the silence and for y to publish again.
  ASSERT_TRUE(wait_until([&] { return pub.log().find("axis 'y': samples again after") != std::string::npos; },
                         patience(5s)))
      << pub.log();
  const auto y_after = probe.states_of(2);
  ASSERT_TRUE(wait_until([&] { return probe.states_of(2) > y_after + 2000; }, patience(5s))) << pub.log();
  // Diagnostics after the stall carry the offered misses per axis.
  ASSERT_TRUE(wait_until([&] { return probe.stats(2).diagnostics.deadline_missed_total() >= 100; }, patience(5s))) << pub.log();
  // The episode is over after 0.5 s without a miss.
  ASSERT_TRUE(wait_until([&] { return pub.log().find("axis 'y' (id 2): deadline episode") != std::string::npos; }, patience(5s)))
      << pub.log();
  std::this_thread::sleep_for(300ms);

  const auto x = probe.stats(1), y = probe.stats(2), z = probe.stats(3);
  std::printf("[ figures  ] requested %.0f ms: misses x=%llu y=%llu z=%llu; offered 5 ms (diagnostics): x=%llu "
              "(%llu episode(s)) y=%llu (%llu episode(s)) z=%llu (%llu episode(s))\n",
              requested_ms, static_cast<unsigned long long>(x.deadline_missed),
              static_cast<unsigned long long>(y.deadline_missed), static_cast<unsigned long long>(z.deadline_missed),
              static_cast<unsigned long long>(x.diagnostics.deadline_missed_total()),
              static_cast<unsigned long long>(x.diagnostics.deadline_episodes_total()),
              static_cast<unsigned long long>(y.diagnostics.deadline_missed_total()),
              static_cast<unsigned long long>(y.diagnostics.deadline_episodes_total()),
              static_cast<unsigned long long>(z.diagnostics.deadline_missed_total()),
              static_cast<unsigned long long>(z.diagnostics.deadline_episodes_total()));
  // A 1 s silence at a 50 ms requested deadline: about 20 misses for y. x and z have
  // none on a quiet machine; a shared, loaded one can delay any process by 50 ms
  // now and then, so they are compared with y in the same run, not with zero.
  // How many a 1 s silence makes is a real-time figure of the test process's own timers:
  // under ThreadSanitizer its 50 ms timer fires late (9 of the ~20 seen once); y is then
  // judged against x and z only.
  if (kRealTimeFigures) {
    EXPECT_GE(y.deadline_missed, 10u);
  }
  EXPECT_LT(x.deadline_missed * 5, y.deadline_missed);
  EXPECT_LT(z.deadline_missed * 5, y.deadline_missed);
  // The publisher's own (offered, 5 ms) view, through the diagnostics: y's 1 s silence
  // is ~200 misses. x and z have their own writers, but on a loaded 2-vCPU machine
  // any axis can now and then be scheduled later than 5 ms: they may miss, but an
  // order of magnitude less.
  const auto y_offered = y.diagnostics.deadline_missed_total();
  EXPECT_GE(y_offered, 100u);
  EXPECT_GE(y.diagnostics.deadline_episodes_total(), 1u);
  // The silence is one episode, not one per miss. Any axis can also have short episodes of
  // its own when the host delays its thread past 5 ms (x and z show how many this run
  // had: none on a quiet machine, a few under ThreadSanitizer); y may have as many more.
  const auto hiccup_episodes =
      std::max(x.diagnostics.deadline_episodes_total(), z.diagnostics.deadline_episodes_total());
  EXPECT_LE(y.diagnostics.deadline_episodes_total(), 3u + hiccup_episodes)
      << "a silence is one episode, not one per miss (x and z had " << x.diagnostics.deadline_episodes_total()
      << " and " << z.diagnostics.deadline_episodes_total() << ")";
  EXPECT_LT(x.diagnostics.deadline_missed_total() * 3, y_offered);
  EXPECT_LT(z.diagnostics.deadline_missed_total() * 3, y_offered);
  // Logged once per episode, per axis.
  const std::string log = pub.log();
  // The silence is logged for y, once, and for no other axis. (Its start is logged only when
  // the loop waited through it, which a loop held up for a second by the host does not; its
  // end always, from the jump in the sample times.)
  auto count = [&log](const std::string& text) {
    std::size_t n = 0;
    for (auto p = log.find(text); p != std::string::npos; p = log.find(text, p + 1)) ++n;
    return n;
  };
  EXPECT_EQ(count("axis 'y': samples again after"), 1u) << log;
  EXPECT_LE(count("axis 'y': no sample for "), 1u) << log;
  for (const char* other : {"axis 'x': ", "axis 'z': "}) {
    EXPECT_EQ(count(std::string(other) + "no sample for "), 0u) << log;
    EXPECT_EQ(count(std::string(other) + "samples again after"), 0u) << log;
  }
  EXPECT_NE(log.find("XML profiles"), std::string::npos) << log;
  // Each warning names its episode: they must be 1, 2, 3, ... once each. (Compared
  // with the episodes the last diagnostics sample counted, the log can be ahead by
  // the episodes that began after it; under ThreadSanitizer that was two.)
  std::size_t y_warnings = 0;
  const std::string y_warning = "axis 'y' (id 2): offered deadline of 5 ms missed";
  for (auto p = log.find(y_warning); p != std::string::npos; p = log.find(y_warning, p + 1)) {
    ++y_warnings;
    const auto e = log.find("(episode ", p);
    ASSERT_NE(e, std::string::npos) << log.substr(p, 200);
    EXPECT_EQ(std::strtoul(log.c_str() + e + 9, nullptr, 10), y_warnings)
        << "warnings must name episodes 1, 2, 3, ... once each\n" << log;
  }
  EXPECT_GE(y_warnings, 1u) << log;
  EXPECT_GE(y_warnings, y.diagnostics.deadline_episodes_total()) << log;
  EXPECT_LT(y_warnings * 20, y_offered) << "one warning per episode, not per miss\n" << log;

  pub.signal(SIGTERM);
  EXPECT_EQ(pub.wait_exit(patience(10s)), 0) << pub.log();
}

TEST(DdsInterface, ProfilesFileGivesTheDocumentedQos) {
  const int domain = ve::test::dds_domain();
  ve::app::DdsOptions o;
  o.domain = domain;
  o.profiles_file = profiles_file();
  std::string error;
  auto ctx = ve::app::DdsContext::create(o, error);
  ASSERT_TRUE(ctx) << error;
  EXPECT_TRUE(ctx->participant_from_profile());
  {
    ve::app::StateWriter w(*ctx, 0.0);  // keep the profile's deadline
    ASSERT_TRUE(w.ok());
    EXPECT_TRUE(w.from_profile());
    EXPECT_DOUBLE_EQ(w.deadline_ms(), 5.0);
    ve::app::StateWriter w7(*ctx, 7.0);  // the machine's dds.deadline_ms wins
    ASSERT_TRUE(w7.ok());
    EXPECT_DOUBLE_EQ(w7.deadline_ms(), 7.0);
    ve::app::DiagnosticsWriter dw(*ctx);
    ASSERT_TRUE(dw.ok());
    EXPECT_TRUE(dw.from_profile());
    ve::app::StateReader r(*ctx, 10.0);
    EXPECT_TRUE(r.ok());
  }
  // Loading the same file again (a second context in one process) is harmless.
  auto ctx2 = ve::app::DdsContext::create(o, error);
  ASSERT_TRUE(ctx2) << error;
  EXPECT_TRUE(ctx2->participant_from_profile());
  ctx2.reset();
  ctx.reset();

  // Without profiles: the built-in QoS, same deadline.
  ve::app::DdsOptions plain;
  plain.domain = domain;
  auto ctx3 = ve::app::DdsContext::create(plain, error);
  ASSERT_TRUE(ctx3) << error;
  {
    ve::app::StateWriter w(*ctx3, 5.0);
    ASSERT_TRUE(w.ok());
    EXPECT_DOUBLE_EQ(w.deadline_ms(), 5.0);
  }
  ctx3.reset();
}

}  // namespace
