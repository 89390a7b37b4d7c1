// Two real processes over a real DDS stack: `virtual-encoder run` publishes, this
// test subscribes with the product's own reader (as `monitor` does) and checks
// what arrives: sequence, values against the simulator's truth, the axis
// description, the deadline when the publisher stalls, and a clean shutdown.
#include <gtest/gtest.h>

#include <fcntl.h>

#include <atomic>
#include <fstream>
#include <iterator>

#include <cmath>
#include <memory>
#include <mutex>
#include <regex>
#include <vector>

#include "config/loader.hpp"
#include "core/status.hpp"
#include "app/dds_io.hpp"
#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"
#include "sim/motion_profile.hpp"

#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

namespace {

using namespace std::chrono_literals;
using ve::test::ChildProcess;
using ve::test::kRealTimeFigures;
using ve::test::patience;
using ve::test::wait_until;

std::string data(const std::string& name) { return std::string(VE_SOURCE_DIR) + "/tests/integration/data/" + name; }

/// Collects every received sample (the callback runs on the DDS listener thread).
struct Collector {
  std::mutex mutex;
  std::vector<ve::dds::EncoderState> samples;
  Collector() { samples.reserve(200000); }
  void operator()(const ve::dds::EncoderState& s) {
    std::lock_guard<std::mutex> lock(mutex);
    samples.push_back(s);
  }
  std::size_t size() {
    std::lock_guard<std::mutex> lock(mutex);
    return samples.size();
  }
  std::vector<ve::dds::EncoderState> copy() {
    std::lock_guard<std::mutex> lock(mutex);
    return samples;
  }
};

struct Subscriber {
  std::unique_ptr<ve::app::DdsContext> ctx;
  std::unique_ptr<ve::app::StateReader> reader;
  Collector collector;
  Subscriber(int domain, double deadline_ms) {
    ve::app::DdsOptions o;
    o.domain = domain;
    o.participant_name = "integration-test";
    std::string error;
    ctx = ve::app::DdsContext::create(o, error);
    if (!ctx) return;
    reader = std::make_unique<ve::app::StateReader>(*ctx, deadline_ms,
                                                    [this](const ve::dds::EncoderState& s) { collector(s); });
  }
  ~Subscriber() {
    reader.reset();
    ctx.reset();
  }
};

std::vector<std::string> run_args(const std::string& config, int domain, double duration_s) {
  return {VE_BINARY,  "run", "--config", config, "--domain", std::to_string(domain), "--duration",
          std::to_string(duration_s), "--wait-for-subscriber", "10"};
}

TEST(DdsRoundTrip, TwoProcessesSequenceValuesDescriptionDeadlineAndShutdown) {
  const ve::test::RealTimeSlot real_time;  // needs its CPU to judge what it does (speed.hpp)
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  // What the reader logs is kept (a gap, once over, with when it began and how long) as
  // well as shown. The default logger is replaced before the reader's threads exist and
  // restored after they have ended (spdlog's default logger may not be swapped while
  // another thread logs through it); the kept lines are read under the sink's lock.
  const auto kept = std::make_shared<spdlog::sinks::ringbuffer_sink_mt>(1000);
  const auto previous_logger = spdlog::default_logger();
  spdlog::set_default_logger(std::make_shared<spdlog::logger>(
      "roundtrip", spdlog::sinks_init_list{kept, std::make_shared<spdlog::sinks::stderr_sink_mt>()}));
  struct Restore {
    std::shared_ptr<spdlog::logger> logger;
    ~Restore() { spdlog::set_default_logger(logger); }
  } restore{previous_logger};
  Subscriber sub(domain, 20.0);
  ASSERT_TRUE(sub.reader && sub.reader->ok());
  ChildProcess pub(run_args(data("standstill.yaml"), domain, 60), (dir.path / "run.log").string());
  ASSERT_TRUE(pub.started());

  ASSERT_TRUE(wait_until([&] { return sub.reader->matched_writers() > 0; }, patience(15s))) << pub.log();
  ASSERT_TRUE(wait_until([&] { return sub.collector.size() >= 4000; }, patience(20s))) << pub.log();

  // Sequence: strictly increasing, and on loopback essentially nothing lost (a figure
  // of the real-time stream: judged at real speed only, see speed.hpp).
  const auto samples = sub.collector.copy();
  std::uint64_t gaps = 0;
  for (std::size_t i = 1; i < samples.size(); ++i) {
    ASSERT_GT(samples[i].sequence_number(), samples[i - 1].sequence_number());
    ASSERT_GT(samples[i].sample_time_ns(), samples[i - 1].sample_time_ns());
    gaps += samples[i].sequence_number() - samples[i - 1].sequence_number() - 1;
  }
  if (kRealTimeFigures) {
    EXPECT_LT(gaps, samples.size() / 100) << "more than 1 % of the samples lost on loopback";
  }

  // Values: the simulated carriage stands at 0.3 m.
  double sum_sq = 0.0;
  int n = 0;
  for (const auto& s : samples) {
    EXPECT_EQ(s.axis_id(), 1u);
    if (s.sequence_number() < 400) continue;  // 0.1 s to converge
    ASSERT_TRUE(s.status() & ve::core::status::kValid) << ve::core::status_to_string(s.status());
    ASSERT_TRUE(s.status() & ve::core::status::kHomed);
    EXPECT_FALSE(s.status() & ve::core::status::kCalibrated);
    EXPECT_EQ(s.position_counts(), std::llround(s.position_m() * 1e7) + 1000);
    EXPECT_EQ(s.velocity_counts_per_s(), std::llround(s.velocity_mps() * 1e7));
    EXPECT_GT(s.position_std_m(), 0.0);
    EXPECT_LT(s.position_std_m(), 5e-6);
    sum_sq += (s.position_m() - 0.3) * (s.position_m() - 0.3);
    EXPECT_LT(std::abs(s.velocity_mps()), 0.01);
    ++n;
  }
  ASSERT_GT(n, 1000);
  const double rms_um = std::sqrt(sum_sq / n) * 1e6;
  EXPECT_LT(rms_um, 5.0);
  std::printf("[ figures  ] standstill via DDS: %d samples, position error %.3f um RMS, %llu lost\n", n, rms_um,
              static_cast<unsigned long long>(gaps));

  // The axis description arrives (transient-local, reliable).
  ASSERT_TRUE(wait_until(
      [&] {
        for (const auto& a : sub.reader->snapshot())
          if (a.have_description) return true;
        return false;
      },
      patience(10s)));
  for (const auto& a : sub.reader->snapshot()) {
    if (!a.have_description) continue;
    EXPECT_EQ(a.description.name(), "x");
    EXPECT_EQ(a.description.motor(), "sim-12mm");
    EXPECT_DOUBLE_EQ(a.description.counts_per_m(), 1e7);
  }

  // Stall the publisher (a real stall: the process is stopped) longer than the
  // requested deadline; the subscriber must see the deadline missed while it is
  // stopped. At real speed that is 20 ms after the last sample; the stall lasts at
  // least 300 ms, and as long as it takes a subscriber slowed by a sanitizer to work
  // through what it had received before (up to patience(3s)).
  const auto missed_before = sub.reader->deadline_missed_total();
  pub.signal(SIGSTOP);
  const auto stall_start = std::chrono::steady_clock::now();
  std::this_thread::sleep_for(300ms);
  wait_until([&] { return sub.reader->deadline_missed_total() > missed_before; }, patience(3s));
  const auto missed_during = sub.reader->deadline_missed_total();
  const double stall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - stall_start).count();
  pub.signal(SIGCONT);
  EXPECT_GT(missed_during, missed_before) << "a " << stall_ms << " ms stall did not raise the 20 ms requested deadline";
  bool per_axis = false;
  for (const auto& a : sub.reader->snapshot()) per_axis = per_axis || (a.axis_id == 1 && a.deadline_missed > 0);
  EXPECT_TRUE(per_axis) << "the miss is not attributed to axis 1";

  // Publishing resumes after the stall.
  const auto after = sub.collector.size();
  EXPECT_TRUE(wait_until([&] { return sub.collector.size() > after + 400; }, patience(5s)));
  // The gap is logged once it is over: axis 1, no sample for at least the stall (less a
  // little: the last sample before it may have been on its way), when it began, and the
  // requested periods it cost (20 ms each). Shorter gaps of a loaded host before the
  // stall may be logged too: the stall is the longest.
  const std::regex gap_line(
      R"(monitor: axis id 1: no sample for ([0-9.]+) ms from [0-9]{2}:[0-9]{2}:[0-9]{2}\.[0-9]{6}: ([0-9]+) requested deadline period\(s\) missed)");
  std::string text;
  double gap_ms = -1.0;
  double gap_periods = -1.0;
  for (const auto& line : kept->last_formatted()) {
    text += line;
    std::smatch m;
    if (std::regex_search(line, m, gap_line) && std::stod(m[1].str()) > gap_ms) {
      gap_ms = std::stod(m[1].str());
      gap_periods = std::stod(m[2].str());
    }
  }
  ASSERT_GE(gap_ms, 0.0) << "no gap of axis 1 logged:\n" << text;
  EXPECT_GE(gap_ms, stall_ms - 50.0) << text;
  EXPECT_NEAR(gap_periods, std::floor(gap_ms / 20.0), 1.0) << text;  // the length is rounded in the text

  // SIGTERM: a clean exit with status 0.
  pub.signal(SIGTERM);
  EXPECT_EQ(pub.wait_exit(patience(10s)), 0) << pub.log();
  EXPECT_NE(pub.log().find("published"), std::string::npos) << pub.log();
}

// Samples that a writer sent and that never reached the reader (here: its socket buffer
// overflowed while its receive thread was held) are counted as lost on the way, one for
// each sequence gap: a reader can tell them from samples its encoder never sent.
TEST(DdsRoundTrip, SamplesDroppedAtAHeldReadersSocketAreCountedAsLostOnTheWay) {
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  // The shipped profiles with a 64 KiB receive buffer instead of 4 MiB (Fast DDS takes no
  // less than its largest message): about a hundred datagrams, tens of ms of the 4 kHz stream.
  std::ifstream in(std::string(VE_SOURCE_DIR) + "/deploy/dds-profiles.xml");
  std::string xml((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string big = "<receiveBufferSize>4194304</receiveBufferSize>";
  ASSERT_NE(xml.find(big), std::string::npos);
  xml.replace(xml.find(big), big.size(), "<receiveBufferSize>65536</receiveBufferSize>");
  ve::app::DdsOptions o;
  o.domain = domain;
  o.participant_name = "integration-test";
  o.profiles_file = dir.write("small-buffer.xml", xml);
  std::string error;
  auto ctx = ve::app::DdsContext::create(o, error);
  ASSERT_TRUE(ctx) << error;
  Collector collector;
  std::atomic<bool> hold{false};
  auto reader = std::make_unique<ve::app::StateReader>(*ctx, 0.0, [&](const ve::dds::EncoderState& s) {
    collector(s);
    if (hold.exchange(false)) std::this_thread::sleep_for(1s);  // the receive thread is held
  });
  ASSERT_TRUE(reader->ok());
  ChildProcess pub(run_args(data("standstill.yaml"), domain, 60), (dir.path / "run.log").string());
  ASSERT_TRUE(pub.started());
  ASSERT_TRUE(wait_until([&] { return collector.size() >= 400; }, patience(20s))) << pub.log();
  const auto lost_before = reader->samples_lost();
  hold = true;
  ASSERT_TRUE(wait_until([&] { return !hold.load(); }, patience(5s)));
  const auto resumed = collector.size();
  ASSERT_TRUE(wait_until([&] { return collector.size() > resumed + 400; }, patience(10s))) << pub.log();
  pub.signal(SIGSTOP);  // nothing more in flight while the two counts are read
  std::this_thread::sleep_for(100ms);
  const auto samples = collector.copy();
  const auto lost = reader->samples_lost();
  pub.signal(SIGCONT);
  std::uint64_t gaps = 0;
  for (std::size_t i = 1; i < samples.size(); ++i) gaps += samples[i].sequence_number() - samples[i - 1].sequence_number() - 1;
  // 1 s of a 4 kHz stream against a buffer of about a hundred datagrams: thousands lost at
  // real speed; under a sanitizer the publisher may not keep 4 kHz, but some are lost.
  EXPECT_GT(gaps, 0u);
  if (kRealTimeFigures) {
    EXPECT_GT(gaps, 1000u);
  }
  EXPECT_EQ(lost, gaps) << "lost on the way " << lost << " (before the hold: " << lost_before << "), sequence gaps "
                        << gaps;
  std::printf("[ figures  ] 1 s hold of the reader's receive thread, 64 KiB receive buffer: %llu samples lost on the "
              "way, %llu sequence gaps\n",
              static_cast<unsigned long long>(lost), static_cast<unsigned long long>(gaps));
  pub.signal(SIGTERM);
  EXPECT_EQ(pub.wait_exit(patience(10s)), 0) << pub.log();
  reader.reset();
  ctx.reset();
}

// The product's reader (`monitor`) asks Fast DDS for no deadline and checks the one it
// requests itself: it matches a writer offering a longer deadline, counts the whole periods
// of each gap between samples, and keeps counting while a writer is silent.
TEST(DdsRoundTrip, TheProductsReaderChecksItsOwnDeadlineAgainstALongerOffer) {
  const int domain = ve::test::dds_domain();
  ve::app::DdsOptions o;
  o.domain = domain;
  o.participant_name = "integration-test";
  std::string error;
  auto writer_ctx = ve::app::DdsContext::create(o, error);
  ASSERT_TRUE(writer_ctx) << error;
  auto reader_ctx = ve::app::DdsContext::create(o, error);
  ASSERT_TRUE(reader_ctx) << error;
  {
    ve::app::StateWriter writer(*writer_ctx, 50.0);  // offers 50 ms
    const auto slots = writer.add_group({{3, "z"}});
    ASSERT_EQ(slots.size(), 1u);
    ve::app::StateReader reader(*reader_ctx, 10.0);  // requests 10 ms, more than offered
    ASSERT_TRUE(reader.ok());
    ASSERT_TRUE(wait_until([&] { return reader.matched_writers() == 1 && writer.matched_readers() == 1; },
                           patience(15s)))
        << "a 10 ms reader of the product's did not match a 50 ms offer";
    ve::dds::EncoderState s{};
    s.axis_id(3);
    for (int i = 1; i <= 10; ++i) {
      s.sequence_number(static_cast<std::uint64_t>(i));
      EXPECT_TRUE(writer.write(slots[0], s));
      std::this_thread::sleep_for(40ms);
    }
    ASSERT_TRUE(wait_until([&] { return reader.total_received() == 10; }, patience(5s)));
    // Nine gaps of about 40 ms: 3-4 periods of 10 ms each, at least one each wherever the
    // samples were held on their way.
    EXPECT_GE(reader.deadline_missed_total(), 9u);
    // The writer silent since: the periods keep being counted with no sample arriving.
    const auto after_last = reader.deadline_missed_total();
    EXPECT_TRUE(wait_until([&] { return reader.deadline_missed_total() >= after_last + 5; }, patience(2s)))
        << after_last << " -> " << reader.deadline_missed_total();
    bool per_axis = false;
    for (const auto& a : reader.snapshot()) per_axis = per_axis || (a.axis_id == 3 && a.deadline_missed >= 9);
    EXPECT_TRUE(per_axis) << "the misses are not attributed to axis 3";
    std::printf("[ figures  ] 10 samples 40 ms apart, 10 ms requested against 50 ms offered: %llu periods missed\n",
                static_cast<unsigned long long>(reader.deadline_missed_total()));
  }
  reader_ctx.reset();
  writer_ctx.reset();
}

TEST(DdsRoundTrip, PublishedPositionAtOneMetrePerSecondIsWithinSpec) {
  const int domain = ve::test::dds_domain();
  ve::test::TempDir dir;
  auto loaded = ve::config::load_machine_file(data("constant_velocity.yaml"));
  ASSERT_TRUE(loaded.ok()) << ve::config::to_string(loaded.errors);
  const auto& axis = loaded.config.axes.at(0);
  std::string error;
  auto profile = ve::sim::MotionProfile::create(axis.driver.sim.profile, axis.motor.travel_m, &error);
  ASSERT_TRUE(profile) << error;
  const double window_s = profile->steady_duration_s();
  ASSERT_GT(window_s, 0.8);

  Subscriber sub(domain, 0.0);
  ASSERT_TRUE(sub.reader && sub.reader->ok());
  // The publisher waits for this subscriber: the constant-velocity phase lasts under a second.
  ChildProcess pub(run_args(data("constant_velocity.yaml"), domain, window_s + 1.0), (dir.path / "run.log").string());
  ASSERT_TRUE(pub.started());
  EXPECT_EQ(pub.wait_exit(30s), 0) << pub.log();
  const auto samples = sub.collector.copy();
  ASSERT_GT(samples.size(), 1000u) << "too few samples arrived; publisher log:\n" << pub.log();

  // Compare with the simulator's exact truth at each sample instant, over the
  // constant-velocity phase after 50 ms of convergence.
  double sum_sq = 0.0, sum_sq_v = 0.0, max_abs = 0.0;
  int n = 0;
  for (const auto& s : samples) {
    const double t = static_cast<double>(s.sample_time_ns()) * 1e-9;
    if (t < 0.05 || t > window_s) continue;
    const auto truth = profile->at(t);
    const double e = s.position_m() - truth.position_m;
    sum_sq += e * e;
    sum_sq_v += (s.velocity_mps() - truth.velocity_mps) * (s.velocity_mps() - truth.velocity_mps);
    max_abs = std::max(max_abs, std::abs(e));
    EXPECT_TRUE(s.status() & ve::core::status::kValid);
    // direction -1: counts run the other way.
    EXPECT_EQ(s.position_counts(), std::llround(-s.position_m() * 1e7));
    ++n;
  }
  ASSERT_GT(n, 1000) << "publisher log:\n" << pub.log();
  const double rms_um = std::sqrt(sum_sq / n) * 1e6;
  const double rms_v = std::sqrt(sum_sq_v / n) * 1e3;
  std::printf("[ figures  ] 1 m/s via DDS: %d samples, position error %.3f um RMS (max %.3f um), velocity %.3f mm/s RMS\n",
              n, rms_um, max_abs * 1e6, rms_v);
  EXPECT_LT(rms_um, 5.0);
}

}  // namespace
