#include "commands.hpp"

#include <time.h>
#include <unistd.h>

#include <signal.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <climits>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <thread>
#include <vector>

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include "axis.hpp"
#include "canopen_io.hpp"
#include "calibration_log.hpp"
#include "calibration_service.hpp"
#include "command_line.hpp"
#include "config/atomic_file.hpp"
#include "config/calibration_file.hpp"
#include "config/kept_position.hpp"
#include "config/loader.hpp"
#include "core/status.hpp"
#include "core/identification.hpp"
#include "core/self_calibration.hpp"
#include "core/thermal_calibration.hpp"
#include "dds_io.hpp"
#include "realtime.hpp"
#include "reports.hpp"
#include "service.hpp"
#include "pacing.hpp"
#include "signals.hpp"
#include "sim/calibration_run.hpp"
#include "sim/sim_source.hpp"

namespace ve::app {

namespace {

/// Loads the machine file (or the embedded default) and prints every problem.
bool load_machine(const std::string& path, config::MachineConfig& out, const config::LoadOptions& load = {}) {
  auto result = path.empty() ? config::load_embedded_default(load) : config::load_machine_file(path, load);
  for (const auto& e : result.errors) std::fprintf(stderr, "%s\n", e.to_string().c_str());
  if (!result.ok()) {
    std::fprintf(stderr, "%zu problem(s) in the configuration\n", result.errors.size());
    return false;
  }
  out = std::move(result.config);
  return true;
}

/// The calibration's directory is created if missing; false (with a message naming
/// the path and the reason) when the file cannot be written there.
bool prepare_output(const std::string& path, const char* what) {
  const auto parent = std::filesystem::path(path).parent_path();
  std::error_code ec;
  if (!parent.empty() && !std::filesystem::is_directory(parent, ec)) {
    const std::string why = config::why_not_writable(path);  // a regular file in the way, say
    if (!why.empty() && std::filesystem::exists(parent, ec)) {
      std::fprintf(stderr, "cannot write the %s: %s\n", what, why.c_str());
      return false;
    }
    std::filesystem::create_directories(parent, ec);
    if (ec) {
      std::fprintf(stderr, "cannot write the %s '%s': cannot create directory '%s': %s\n", what, path.c_str(),
                   parent.c_str(), ec.message().c_str());
      return false;
    }
  }
  const std::string why = config::why_not_writable(path);
  if (!why.empty()) {
    std::fprintf(stderr, "cannot write the %s: %s\n", what, why.c_str());
    return false;
  }
  return true;
}

/// Whether two paths name the same existing file.
bool same_file(const std::string& a, const std::string& b) {
  std::error_code ec;
  return std::filesystem::equivalent(a, b, ec) && !ec;
}

/// A job a signal ended before it was done: nothing was written.
int interrupted(const char* what) {
  std::fprintf(stderr, "\n%s interrupted by %s: nothing written\n", what,
               termination_signal() == SIGTERM ? "SIGTERM" : "SIGINT");
  return interrupted_exit_code();
}

const config::AxisConfig* find_axis(const config::MachineConfig& m, const std::string& name) {
  if (name.empty()) return m.axes.empty() ? nullptr : &m.axes.front();
  for (const auto& a : m.axes)
    if (a.name == name) return &a;
  return nullptr;
}

std::int64_t clock_ns(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

/// Budget the diagnostics' ratios refer to (one sigma).
constexpr double kPositionStdBudgetM = 5.0e-6;
constexpr double kVelocityStdBudgetMps = 1.7e-3;
/// Diagnostics period per axis [ns] (also every sample_rate/10 samples).
constexpr std::int64_t kDiagnosticsPeriodNs = 100000000;

/// What one diagnostics sample summarises: fixed-size counters, reset per period.
struct DiagnosticsAccumulator {
  std::int64_t start_ns = 0;  ///< steady clock
  std::uint64_t samples = 0;
  double step_sum_ns = 0.0, step_max_ns = 0.0;
  std::uint64_t intervals = 0;
  double interval_sum_ns = 0.0, interval_sumsq_ns2 = 0.0, interval_max_ns = 0.0;
  std::uint64_t fixes = 0;
  double innovation_sumsq = 0.0, innovation_max_abs = 0.0;
  double sensors_used_sum = 0.0;
  int sensors_used_min = INT_MAX;
  std::uint32_t valid_and = ~0u;

  void reset(std::int64_t now_ns) {
    *this = DiagnosticsAccumulator{};
    start_ns = now_ns;
  }
};

/// Per-axis loop state shared with the status reporter.
struct AxisLoop {
  AxisSetup setup;
  int slot = -1;  ///< StateWriter::add_group
  std::atomic<std::uint64_t> samples{0};    ///< estimated
  std::atomic<std::uint64_t> published{0};  ///< state samples written (every publish_divider-th)
  std::atomic<std::uint64_t> write_failures{0};
  std::atomic<std::uint64_t> skipped{0};
  std::atomic<std::uint64_t> diagnostics_published{0};
  std::atomic<bool> finished{false};
  std::string end_reason;
  // Last published values, for the status line (torn reads are harmless here).
  std::atomic<double> position_m{0}, velocity_mps{0}, position_std_m{0}, velocity_std_mps{0};
  std::atomic<double> innovation_rms{0}, step_max_us{0};
  std::atomic<std::uint32_t> status{0};
  // CiA 406 node of this axis (`canopen:`), fed through `canopen_state` (the last
  // 1,024 estimates, 57 kB: made only for an axis with a node); both null without one.
  std::unique_ptr<canopen::SnapshotBox> canopen_state;
  std::unique_ptr<CanopenNodeIo> canopen;
};

void fill_diagnostics(const AxisLoop& loop, const DiagnosticsAccumulator& acc, const core::RawSample& sample,
                      const core::EncoderEstimate& est, const ve::dds::EncoderState& state,
                      const DeadlineCounters& deadline, std::uint64_t diag_sequence, std::int64_t now_ns,
                      ve::dds::Diagnostics& d) {
  const auto& motor = loop.setup.config.motor;
  const int halls = std::min(sample.hall_count, core::kMaxHalls);
  const std::uint32_t used_bits = halls >= 32 ? ~0u : ((1u << halls) - 1u);
  std::uint32_t saturated = 0;
  const double lo = motor.adc.min_v + motor.hall.saturation_margin_v;
  const double hi = motor.adc.max_v - motor.hall.saturation_margin_v;
  for (int i = 0; i < core::kMaxHalls; ++i) {
    const double v = i < halls ? sample.hall_v[static_cast<std::size_t>(i)] : 0.0;
    d.hall_volts()[static_cast<std::size_t>(i)] = v;
    if (i < halls && (v <= lo || v >= hi)) saturated |= 1u << i;
  }
  d.axis_id(loop.setup.config.id);
  d.status(est.status);
  d.hall_count(static_cast<std::uint32_t>(halls));
  d.hall_valid_mask(acc.valid_and & used_bits);
  d.hall_saturated_mask(saturated);
  d.hall_sensors_used_min(acc.sensors_used_min == INT_MAX ? 0u : static_cast<std::uint32_t>(acc.sensors_used_min));
  d.sequence_number(diag_sequence);
  d.state_sequence(state.sequence_number());
  d.sample_time_ns(state.sample_time_ns());
  d.publish_time_ns(clock_ns(CLOCK_REALTIME));
  d.period_samples(acc.samples);
  d.samples_total(state.sequence_number());  // published state samples
  d.samples_skipped_total(loop.skipped.load(std::memory_order_relaxed));
  d.write_failures_total(loop.write_failures.load(std::memory_order_relaxed));
  d.deadline_missed_total(deadline.missed.load(std::memory_order_relaxed));
  d.deadline_episodes_total(deadline.episodes.load(std::memory_order_relaxed));
  d.hall_sensors_used_mean(acc.fixes ? acc.sensors_used_sum / static_cast<double>(acc.fixes) : 0.0);
  d.innovation_rms(acc.fixes ? std::sqrt(acc.innovation_sumsq / static_cast<double>(acc.fixes)) : 0.0);
  d.innovation_max_abs(acc.innovation_max_abs);
  d.accel_bias_mps2(est.accel_bias_mps2);
  d.accel_scale(est.accel_scale);
  d.step_time_mean_us(acc.samples ? acc.step_sum_ns / static_cast<double>(acc.samples) * 1e-3 : 0.0);
  d.step_time_max_us(acc.step_max_ns * 1e-3);
  if (acc.intervals > 0) {
    const double n = static_cast<double>(acc.intervals);
    const double mean = acc.interval_sum_ns / n;
    d.arrival_period_mean_us(mean * 1e-3);
    d.arrival_jitter_us(std::sqrt(std::max(0.0, acc.interval_sumsq_ns2 / n - mean * mean)) * 1e-3);
  } else {
    d.arrival_period_mean_us(0.0);
    d.arrival_jitter_us(0.0);
  }
  d.arrival_interval_max_us(acc.interval_max_ns * 1e-3);
  const double period_s = static_cast<double>(now_ns - acc.start_ns) * 1e-9;
  d.sample_rate_hz(period_s > 0 ? static_cast<double>(acc.samples) / period_s : 0.0);
  d.position_std_m(est.position_std_m);
  d.velocity_std_mps(est.velocity_std_mps);
  d.position_std_ratio(est.position_std_m / kPositionStdBudgetM);
  d.velocity_std_ratio(est.velocity_std_mps / kVelocityStdBudgetMps);
}

/// A source silent this long (its reads time out) is said in the log, once; and again
/// when it sends again, as is a jump of this long in the samples' own times (a silence
/// the loop did not wait through, being behind).
constexpr std::int64_t kSilenceLoggedNs = 100000000;

/// One axis' sample path: a read of its source, the estimator step, the DDS write,
/// the diagnostics and the log lines about it. Everything it needs is allocated when
/// it is made (in its sample thread, before the first sample); step() allocates nothing.
class AxisRunner {
 public:
  AxisRunner(AxisLoop& loop, StateWriter& writer, DiagnosticsWriter& diagnostics, const std::atomic<bool>& stopping)
      : loop_(loop),
        writer_(writer),
        diagnostics_(diagnostics),
        stopping_(stopping),
        source_(*loop.setup.source),
        pipeline_(*loop.setup.pipeline),
        deadline_(writer.counters(loop.slot)),
        samples_per_diag_(static_cast<std::uint64_t>(
            std::max(1.0, std::round(loop.setup.config.motor.sample_rate_hz * kDiagnosticsPeriodNs * 1e-9)))),
        start_ns_(clock_ns(CLOCK_MONOTONIC)),
        publish_divider_(std::max(1, loop.setup.config.output.publish_divider)) {
    acc_.reset(start_ns_);
  }

  drivers::SensorSource& source() { return source_; }

  /// One read of the source and all that follows from it. False once the axis has
  /// ended (its source ended, failed or was stopped): finish() has been done.
  bool step() {
    const auto st = source_.read(sample_);
    if (st == drivers::ReadStatus::timeout) {
      const std::int64_t quiet_ns = clock_ns(CLOCK_MONOTONIC) - (last_arrival_ns_ != 0 ? last_arrival_ns_ : start_ns_);
      if (!silent_ && quiet_ns >= kSilenceLoggedNs) {
        silent_ = true;
        spdlog::warn("axis '{}': no sample for {:.0f} ms: the sensor source is silent", loop_.setup.config.name,
                     static_cast<double>(quiet_ns) * 1e-6);
      }
      return true;
    }
    if (st != drivers::ReadStatus::ok) {
      loop_.end_reason = st == drivers::ReadStatus::error ? source_.last_error() : std::string();
      finish();
      return false;
    }
    process();
    return true;
  }

  /// The axis leaves the loop. A source that ended by itself (not a shutdown): the
  /// instance leaves, so that its deadline no longer runs while the other axes go on.
  void finish() {
    if (!stopping_.load()) writer_.retire_axis(loop_.slot);
    loop_.finished.store(true);
  }

 private:
  void process() {
    AxisLoop& loop = loop_;
    const core::RawSample& sample = sample_;
    if (loop.canopen) loop.canopen_state->claim();
    const std::int64_t arrival_ns = clock_ns(CLOCK_MONOTONIC);
    const std::int64_t handover_rt_ns = clock_ns(CLOCK_REALTIME);
    if (loop.canopen) loop.canopen_state->begin(handover_rt_ns);  // a SYNC after this instant waits for it
    const std::int64_t sample_gap_ns = last_arrival_ns_ != 0 ? sample.t_ns - last_sample_t_ns_ : 0;
    if (silent_ || sample_gap_ns >= kSilenceLoggedNs) {
      silent_ = false;
      const std::int64_t waited_ns = arrival_ns - (last_arrival_ns_ != 0 ? last_arrival_ns_ : start_ns_);
      spdlog::info("axis '{}': samples again after {:.3f} s without any", loop.setup.config.name,
                   static_cast<double>(std::max(waited_ns, sample_gap_ns)) * 1e-9);
    }
    last_sample_t_ns_ = sample.t_ns;
    const core::EncoderEstimate& est = pipeline_.step(sample);
    if ((est.status ^ last_status_) & core::status::kHomed) {
      // Rare (start-up, a long gap): worth a line in the log.
      if (est.status & core::status::kHomed) {
        if (pipeline_.signature_homing().state() == core::SignatureHoming::State::homed)
          spdlog::info("axis '{}': homed by the magnet signature after {:.1f} mm of motion", loop.setup.config.name,
                       pipeline_.signature_homing().motion_m() * 1e3);
        else
          spdlog::info("axis '{}': homed", loop.setup.config.name);
      } else {
        spdlog::warn("axis '{}': not homed (position relative until homed again)", loop.setup.config.name);
      }
    }
    last_status_ = est.status;
    if (loop.canopen) {  // the CAN node's thread reads it; this loop never waits for it
      canopen::AxisSnapshot snap;
      snap.present = true;
      snap.t_ns = handover_rt_ns;  // the instant ve/encoder_state states as source_time_ns
      snap.position_m = est.position_m;
      snap.velocity_mps = est.velocity_mps;
      snap.acceleration_mps2 = est.acceleration_mps2;
      snap.status = est.status;
      loop.canopen_state->publish(snap);
    }
    if (--until_publish_ == 0) {  // output.publish_divider: every Nth estimate is published
      until_publish_ = publish_divider_;
      fill_state(est, loop.setup.config, ++sequence_, state_);
      state_.acceleration_std_mps2(est.acceleration_std_mps2);
      state_.source_time_ns(handover_rt_ns);
      state_.publish_time_ns(clock_ns(CLOCK_REALTIME));
      if (!writer_.write(loop.slot, state_)) loop.write_failures.fetch_add(1, std::memory_order_relaxed);
      loop.published.fetch_add(1, std::memory_order_relaxed);
    }
    loop.samples.fetch_add(1, std::memory_order_relaxed);
    if (est.samples_skipped) loop.skipped.fetch_add(est.samples_skipped, std::memory_order_relaxed);
    loop.position_m.store(est.position_m, std::memory_order_relaxed);
    loop.velocity_mps.store(est.velocity_mps, std::memory_order_relaxed);
    loop.position_std_m.store(est.position_std_m, std::memory_order_relaxed);
    loop.velocity_std_mps.store(est.velocity_std_mps, std::memory_order_relaxed);
    loop.status.store(est.status, std::memory_order_relaxed);

    // Diagnostics: fixed-size counters, no allocation per sample.
    DiagnosticsAccumulator& acc = acc_;
    const std::int64_t done_ns = clock_ns(CLOCK_MONOTONIC);
    const double step_ns = static_cast<double>(done_ns - arrival_ns);
    ++acc.samples;
    acc.step_sum_ns += step_ns;
    acc.step_max_ns = std::max(acc.step_max_ns, step_ns);
    if (last_arrival_ns_ != 0) {
      const double interval = static_cast<double>(arrival_ns - last_arrival_ns_);
      ++acc.intervals;
      acc.interval_sum_ns += interval;
      acc.interval_sumsq_ns2 += interval * interval;
      acc.interval_max_ns = std::max(acc.interval_max_ns, interval);
    }
    last_arrival_ns_ = arrival_ns;
    if (est.hall_sensors_used > 0) {
      ++acc.fixes;
      acc.innovation_sumsq += est.hall_innovation_sigma * est.hall_innovation_sigma;
      acc.innovation_max_abs = std::max(acc.innovation_max_abs, std::abs(est.hall_innovation_sigma));
      acc.sensors_used_sum += est.hall_sensors_used;
    }
    acc.sensors_used_min = std::min(acc.sensors_used_min, est.hall_sensors_used);
    acc.valid_and &= sample.hall_valid_mask;
    if (acc.samples >= samples_per_diag_ || done_ns - acc.start_ns >= kDiagnosticsPeriodNs) {
      fill_diagnostics(loop, acc, sample, est, state_, deadline_, ++diag_sequence_, done_ns, diag_);
      if (diagnostics_.write(diag_)) loop.diagnostics_published.fetch_add(1, std::memory_order_relaxed);
      loop.innovation_rms.store(diag_.innovation_rms(), std::memory_order_relaxed);
      loop.step_max_us.store(diag_.step_time_max_us(), std::memory_order_relaxed);
      writer_.poll_deadline_episode(loop.slot, clock_ns(CLOCK_MONOTONIC));
      acc.reset(clock_ns(CLOCK_MONOTONIC));
    }
  }

  AxisLoop& loop_;
  StateWriter& writer_;
  DiagnosticsWriter& diagnostics_;
  const std::atomic<bool>& stopping_;
  drivers::SensorSource& source_;
  core::AxisPipeline& pipeline_;
  const DeadlineCounters& deadline_;
  const std::uint64_t samples_per_diag_;
  const std::int64_t start_ns_;
  const int publish_divider_;
  core::RawSample sample_;
  ve::dds::EncoderState state_;
  ve::dds::Diagnostics diag_;
  std::uint64_t sequence_ = 0;
  std::uint64_t diag_sequence_ = 0;
  DiagnosticsAccumulator acc_;
  std::int64_t last_arrival_ns_ = 0;
  int until_publish_ = 1;  // the first estimate is published
  std::uint32_t last_status_ = 0;
  bool silent_ = false;  // said in the log: the source has sent nothing for kSilenceLoggedNs
  std::int64_t last_sample_t_ns_ = 0;
};

/// The axes one sample thread steps (realtime.sample_loop). Several axes share a
/// thread only when their sources are paced by the clock (the simulator in real
/// time), their rates divide the group's base rate and their CPUs are the same; an
/// axis whose source waits for its own frames is a group of one.
struct SampleGroup {
  std::vector<AxisLoop*> axes;
  double base_rate_hz = 0.0;  ///< the fastest member's rate: one wake-up per period of it
  bool shared_clock = false;  ///< the members' sources share one clock (all clock-paced)
  std::string thread_name;
  std::thread thread;
};

/// A single axis: its source paces the loop (a blocking read per sample).
/// Several: one wait per tick for the earliest due source, then every due axis in turn,
/// in the machine file's order and in the reverse order every other tick (GroupWriteOrder).
void group_loop(SampleGroup& group, StateWriter& writer, DiagnosticsWriter& diagnostics,
                const std::atomic<bool>& stopping) {
  std::vector<std::unique_ptr<AxisRunner>> runners;
  runners.reserve(group.axes.size());
  for (AxisLoop* loop : group.axes) runners.push_back(std::make_unique<AxisRunner>(*loop, writer, diagnostics, stopping));
  if (!group.shared_clock) {
    for (auto& r : runners)
      while (r->step()) {
      }
    return;
  }
  const std::size_t n = runners.size();
  std::vector<char> done(n, 0);
  std::vector<std::int64_t> due(n, 0);  // each source's next_due_ns() of this tick
  GroupWriteOrder order(n);
  std::size_t active = n;
  const std::int64_t start_ns = drivers::monotonic_ns();
  for (auto& r : runners)
    if (!r->source().share_clock(start_ns))  // not expected: the grouping chose clock-paced sources
      spdlog::warn("sample thread '{}': a source cannot share the group's clock; it paces itself", group.thread_name);
  while (active > 0) {
    std::int64_t due_ns = INT64_MAX;
    for (std::size_t i = 0; i < n; ++i) {
      if (done[i]) continue;
      due[i] = runners[i]->source().next_due_ns();  // unchanged by the wait below: nothing reads meanwhile
      due_ns = std::min(due_ns, due[i]);
    }
    if (!drivers::sleep_until(due_ns, stopping)) break;  // shutdown
    const std::int64_t now_ns = drivers::monotonic_ns();
    order.next_tick();  // forwards, then backwards: one deadline re-arm per tick (GroupWriteOrder)
    for (std::size_t k = 0; k < n; ++k) {
      const std::size_t i = order.at(k);
      if (done[i] || due[i] > now_ns) continue;
      if (!runners[i]->step()) {
        done[i] = 1;
        --active;
      }
    }
  }
  for (std::size_t i = 0; i < n; ++i)
    if (!done[i]) runners[i]->finish();
}

/// Whether an axis' source is paced by the clock alone, so that it can share a sample thread.
bool clock_paced(const config::AxisConfig& axis) {
  return axis.driver.kind == config::DriverConfig::Kind::sim && axis.driver.sim.realtime;
}

/// The sample threads of `run`: with realtime.sample_loop `shared`, the clock-paced
/// axes in groups of one base rate (every member's rate divides it) and one CPU set,
/// in the machine file's order; every other axis alone.
std::vector<std::unique_ptr<SampleGroup>> plan_groups(const std::vector<std::unique_ptr<AxisLoop>>& loops,
                                                      const config::RealtimeConfig& realtime) {
  std::vector<std::unique_ptr<SampleGroup>> groups;
  const bool shared = realtime.sample_loop == config::RealtimeConfig::SampleLoop::shared;
  // Fastest first, so that each group's first member sets its base rate.
  std::vector<AxisLoop*> order;
  for (const auto& l : loops) order.push_back(l.get());
  std::stable_sort(order.begin(), order.end(), [](const AxisLoop* a, const AxisLoop* b) {
    return a->setup.config.motor.sample_rate_hz > b->setup.config.motor.sample_rate_hz;
  });
  for (AxisLoop* l : order) {
    const auto& axis = l->setup.config;
    const double rate = axis.motor.sample_rate_hz;
    SampleGroup* into = nullptr;
    if (shared && clock_paced(axis)) {
      for (auto& g : groups) {
        if (!g->shared_clock || realtime.cpus_for(g->axes.front()->setup.config.name) != realtime.cpus_for(axis.name))
          continue;
        const double ratio = g->base_rate_hz / rate;
        if (std::abs(ratio - std::round(ratio)) <= 1e-9 * ratio) {
          into = g.get();
          break;
        }
      }
    }
    if (into == nullptr) {
      groups.push_back(std::make_unique<SampleGroup>());
      into = groups.back().get();
      into->base_rate_hz = rate;
      into->shared_clock = shared && clock_paced(axis);
    }
    into->axes.push_back(l);
  }
  // The machine file's order within and across groups, for the log and the threads.
  auto index_of = [&](const AxisLoop* l) {
    for (std::size_t i = 0; i < loops.size(); ++i)
      if (loops[i].get() == l) return i;
    return loops.size();
  };
  for (auto& g : groups)
    std::sort(g->axes.begin(), g->axes.end(),
              [&](const AxisLoop* a, const AxisLoop* b) { return index_of(a) < index_of(b); });
  std::sort(groups.begin(), groups.end(), [&](const auto& a, const auto& b) {
    return index_of(a->axes.front()) < index_of(b->axes.front());
  });
  for (auto& g : groups) {
    const std::string& first = g->axes.front()->setup.config.name;
    g->thread_name = g->axes.size() == 1 ? "ve-" + first : "ve-" + first + "+" + std::to_string(g->axes.size() - 1);
  }
  return groups;
}

}  // namespace

// ------------------------------------------------------------------- run

namespace {

/// Signature homing with a state file: start homed at the position kept at the last
/// clean shutdown (the file is removed as it is read: a position is used once).
void use_kept_position(AxisSetup& setup) {
  const auto& axis = setup.config;
  if (axis.homing.mode != config::HomingConfig::Mode::signature || axis.homing.state_file.empty() ||
      !setup.calibrated)
    return;
  config::KeptPosition kept;
  std::string why;
  switch (config::take_kept_position(axis.homing.state_file, axis.name, axis.motor.name, setup.calibration.info.id, kept,
                                     why, axis.motor.travel_m)) {
    case config::KeptRead::none:
      spdlog::info("axis '{}': no position kept from a clean shutdown; homing by the magnet signature on the "
                   "first move",
                   axis.name);
      return;
    case config::KeptRead::refused:
      spdlog::warn("axis '{}': kept position not used: {}; homing by the magnet signature on the first move",
                   axis.name, why);
      return;
    case config::KeptRead::ok: break;
  }
  setup.pipeline = std::make_unique<core::AxisPipeline>(
      pipeline_config(axis, setup.calibration, setup.calibrated, &kept.position_m), setup.calibration.table);
  spdlog::info("axis '{}': starting homed at {:.6f} m, kept at the clean shutdown of {} (the first move checks it "
               "against the magnet signature)",
               axis.name, kept.position_m, kept.saved_utc);
}

/// At a clean shutdown: keep the position of a homed axis for the next start.
void keep_position(const AxisSetup& setup) {
  const auto& axis = setup.config;
  if (axis.homing.mode != config::HomingConfig::Mode::signature || axis.homing.state_file.empty() ||
      !setup.calibrated)
    return;
  const auto& est = setup.pipeline->last();
  if (!(est.status & core::status::kHomed) || !(est.status & core::status::kValid)) {
    spdlog::info("axis '{}': not homed at shutdown; no position kept", axis.name);
    return;
  }
  const config::KeptPosition k{axis.name, axis.motor.name, setup.calibration.info.id, est.position_m, config::now_utc()};
  std::string error;
  if (config::write_kept_position(axis.homing.state_file, k, error))
    spdlog::info("axis '{}': position {:.6f} m kept in {}", axis.name, est.position_m, axis.homing.state_file);
  else
    spdlog::error("axis '{}': cannot keep the position: {}", axis.name, error);
}

}  // namespace

int run_command(const RunOptions& options) {
  config::MachineConfig machine;
  if (!load_machine(options.config, machine)) return 2;
  if (options.domain) machine.dds.domain = *options.domain;

  std::vector<std::unique_ptr<AxisLoop>> loops;
  for (const auto& axis : machine.axes) {
    auto loop = std::make_unique<AxisLoop>();
    std::string error;
    if (!build_axis(axis, SourceTiming::as_configured, loop->setup, error)) {
      std::fprintf(stderr, "%s\n", axis_error(axis.name, error).c_str());
      return 2;
    }
    use_kept_position(loop->setup);
    if (axis.canopen.enabled) {
      loop->canopen_state = std::make_unique<canopen::SnapshotBox>();
      loop->canopen = std::make_unique<CanopenNodeIo>(axis, *loop->canopen_state);
      if (!loop->canopen->ok()) {
        std::fprintf(stderr, "%s\n", loop->canopen->last_error().c_str());
        return 2;
      }
    }
    loops.push_back(std::move(loop));
  }

  // Real time (the machine file's `realtime:`): memory is locked here and every
  // setting is tried once; each sample thread takes its CPUs and priority before its
  // first sample. Fast DDS's threads inherit the priority of the thread that creates
  // its entities: this one, from begin_dds_threads() to end_dds_threads().
  std::vector<std::string> axis_names;
  for (const auto& loop : loops) axis_names.push_back(loop->setup.config.name);
  Realtime realtime(machine.realtime, axis_names);
  if (!realtime.ok()) return 1;
  for (const auto& loop : loops)
    for (const pthread_t t : loop->setup.source->helper_threads())
      realtime.adopt_source_thread(t, loop->setup.config.name);
  struct DdsThreadsScope {
    Realtime& rt;
    bool open = true;
    explicit DdsThreadsScope(Realtime& r) : rt(r) { rt.begin_dds_threads(); }
    void end() {
      if (open) rt.end_dds_threads();
      open = false;
    }
    ~DdsThreadsScope() { end(); }
  } dds_threads(realtime);

  DdsOptions dds_options;
  dds_options.domain = machine.dds.domain;
  dds_options.profiles_file = machine.dds.profiles_file;
  dds_options.statistics = machine.dds.statistics;
  dds_options.participant_name = "virtual-encoder/" + machine.name;
  std::string error;
  auto ctx = DdsContext::create(dds_options, error);
  if (!ctx) {
    spdlog::error("{}", error);
    return 1;
  }
  int exit_code = 0;
  std::atomic<bool> stopping{false};
  {
    // VE_DDS_STATE_NO_DEADLINE=1 (measurements only, docs/dds-interface.md): the state writers
    // offer no deadline, which readers that request one (ve_state_reader) do not match.
    const char* no_deadline = std::getenv("VE_DDS_STATE_NO_DEADLINE");
    const bool offer_deadline = no_deadline == nullptr || std::string(no_deadline) != "1";
    if (!offer_deadline)
      spdlog::warn("VE_DDS_STATE_NO_DEADLINE=1: the state writers offer no deadline (for measurements only; "
                   "readers that request one do not match)");
    StateWriter state_writer(*ctx, offer_deadline ? machine.dds.deadline_ms : HUGE_VAL);
    DescriptionWriter description_writer(*ctx);
    DiagnosticsWriter diagnostics_writer(*ctx);
    if (!state_writer.ok() || !description_writer.ok() || !diagnostics_writer.ok()) {
      spdlog::error("cannot create the DDS writers (check the QoS in the profiles file)");
      return 1;
    }
    // The sample threads and their axes; each thread's axes share one state writer
    // (dds.state_writer: per_group), or each axis has its own (per_axis).
    const auto groups = plan_groups(loops, machine.realtime);
    for (const auto& g : groups) {
      std::vector<StateWriter::AxisName> members;
      for (const AxisLoop* l : g->axes) members.push_back({l->setup.config.id, l->setup.config.name});
      if (machine.dds.state_writer == config::DdsConfig::StateWriters::per_axis) {
        std::vector<int> slots;
        for (const auto& m : members) slots.push_back(state_writer.add_axis(m.axis_id, m.name));
        for (std::size_t i = 0; i < g->axes.size(); ++i) g->axes[i]->slot = slots[i];
      } else {
        const auto slots = state_writer.add_group(members);
        for (std::size_t i = 0; i < slots.size(); ++i) g->axes[i]->slot = slots[i];
      }
      for (const AxisLoop* l : g->axes)
        if (l->slot < 0) {
          spdlog::error("cannot create the DDS state writer of axis '{}'", l->setup.config.name);
          return 1;
        }
    }
    for (const auto& loop : loops) description_writer.write(describe_axis(loop->setup, machine));

    // Calibration over DDS: commands in, status out; the work runs in the
    // service's own thread, never in an axis thread. Declared in this order so
    // that the reader (and its callbacks) goes first, then the service (joining
    // its worker), then the status writer.
    CalibrationStatusWriter calibration_status(*ctx);
    CalibrationService calibration_service(machine, calibration_status);
    CalibrationCommandReader calibration_commands(
        *ctx, [&calibration_service](const ve::dds::CalibrationCommand& c) { calibration_service.handle(c); });
    if (!calibration_status.ok() || !calibration_commands.ok()) {
      spdlog::error("cannot create the DDS calibration reader/writer (check the QoS in the profiles file)");
      return 1;
    }
    dds_threads.end();  // every DDS entity exists: the rest of this thread's work is at normal priority
    spdlog::info("calibration over DDS: commands on '{}', status on '{}' (simulator axes; a new calibration takes "
                 "effect on the next start)",
                 kCalibrationCommandTopic, kCalibrationStatusTopic);

    spdlog::info("machine '{}' from {}: {} axis/axes on DDS domain {}, topics '{}', '{}', '{}', offered deadline {} ms",
                 machine.name, machine.source, loops.size(), machine.dds.domain, kStateTopic, kDiagnosticsTopic,
                 kDescriptionTopic, state_writer.deadline_ms());
    spdlog::info("DDS QoS: {}", ctx->participant_from_profile() || state_writer.from_profile()
                                    ? "XML profiles" + (machine.dds.profiles_file.empty()
                                                            ? std::string(" (FASTRTPS_DEFAULT_PROFILES_FILE)")
                                                            : " from " + machine.dds.profiles_file)
                                    : std::string("built-in (no profiles file loaded)"));
    for (const auto& loop : loops) {
      const auto& s = loop->setup;
      spdlog::info("axis '{}' (id {}): {} | motor {} | {}", s.config.name, s.config.id, s.source->describe(),
                   s.config.motor.name,
                   s.calibrated ? "calibration " + s.calibration.info.id : std::string("nominal table (not calibrated)"));
      if (loop->canopen) spdlog::info("axis '{}': {}", s.config.name, loop->canopen->describe());
    }
    if (options.wait_for_subscriber_s > 0) {
      const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(options.wait_for_subscriber_s);
      bool stop = false;
      while (!stop && state_writer.matched_readers() == 0 && std::chrono::steady_clock::now() < until)
        stop = wait_for_termination(0.01);
      if (stop) {
        spdlog::info("termination signal before start");
        return 0;
      }
      spdlog::info("{} subscriber(s) matched; starting", state_writer.matched_readers());
    }
    for (auto& loop : loops)
      if (loop->canopen) loop->canopen->start(machine.realtime);  // boot-up; no estimate yet (6503h position error)
    for (const auto& g : groups) {
      std::string names;
      for (const AxisLoop* l : g->axes) names += (names.empty() ? "'" : ", '") + l->setup.config.name + "'";
      if (g->axes.size() > 1)
        spdlog::info("sample thread '{}': {} axes {} in one loop at {:g} Hz (one wake-up per tick)", g->thread_name,
                     g->axes.size(), names, g->base_rate_hz);
      else
        spdlog::info("sample thread '{}': axis {} alone at {:g} Hz ({})", g->thread_name, names, g->base_rate_hz,
                     machine.realtime.sample_loop == config::RealtimeConfig::SampleLoop::per_axis
                         ? "realtime.sample_loop: per_axis"
                         : !clock_paced(g->axes.front()->setup.config) ? "its source paces it"
                                                                       : "no other axis shares its rate and CPUs");
    }
    for (auto& g : groups)
      g->thread = std::thread([&realtime, &state_writer, &diagnostics_writer, &stopping, g = g.get()] {
        realtime.enter_sample_thread(g->axes.front()->setup.config.name, g->thread_name);
        group_loop(*g, state_writer, diagnostics_writer, stopping);
      });

    // systemd: ready only once every axis publishes; the watchdog is petted only
    // while every sample loop keeps making progress.
    ServiceNotifier service;
    bool announced = false;
    std::vector<std::uint64_t> pet_counts(loops.size(), 0);
    auto all_progressed = [&]() {
      bool ok = true;
      for (std::size_t i = 0; i < loops.size(); ++i) {
        const auto n = loops[i]->samples.load();
        ok = ok && n > pet_counts[i] && !loops[i]->finished.load();
        pet_counts[i] = n;
      }
      return ok;
    };

    const auto start = std::chrono::steady_clock::now();
    std::vector<std::uint64_t> last_counts(loops.size(), 0);
    auto last_report = start;
    auto next_status = start + std::chrono::duration<double>(options.status_period_s);
    for (;;) {
      const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      double wait = std::chrono::duration<double>(next_status - std::chrono::steady_clock::now()).count();
      if (!announced) wait = std::min(wait, 0.01);
      if (service.watchdog_period_s() > 0) wait = std::min(wait, service.watchdog_period_s());
      if (options.duration_s > 0) wait = std::min(wait, std::max(0.0, options.duration_s - elapsed));
      // Sources that end (a replayed log) are noticed within a tenth of a second,
      // not at the next status line.
      wait = std::min(wait, 0.1);
      if (wait_for_termination(std::max(wait, 0.001))) {
        spdlog::info("termination signal: stopping");
        break;
      }
      if (!announced) {
        bool publishing = true;
        for (const auto& l : loops) publishing = publishing && l->samples.load() > 0;
        if (publishing) {
          announced = true;
          all_progressed();
          service.ready("publishing " + std::to_string(loops.size()) + " axis/axes on DDS domain " +
                        std::to_string(machine.dds.domain));
        }
      } else if (service.watchdog_period_s() > 0 && all_progressed()) {
        service.watchdog();
      }
      bool sources_ended = true;
      for (const auto& l : loops) sources_ended = sources_ended && l->finished.load();
      if (std::chrono::steady_clock::now() < next_status && !sources_ended &&
          !(options.duration_s > 0 &&
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >= options.duration_s))
        continue;
      next_status += std::chrono::duration<double>(options.status_period_s);
      const auto now = std::chrono::steady_clock::now();
      const double dt = std::chrono::duration<double>(now - last_report).count();
      last_report = now;
      for (std::size_t i = 0; i < loops.size(); ++i) {
        auto& l = *loops[i];
        const auto n = l.samples.load();
        spdlog::info("{:>4} x={:+11.6f} m v={:+9.5f} m/s sx={:6.2f} um sv={:6.3f} mm/s rate={:6.0f} Hz "
                     "missed={} skipped={} innov={:.2f} step-max={:.0f} us [{}]",
                     l.setup.config.name, l.position_m.load(), l.velocity_mps.load(), l.position_std_m.load() * 1e6,
                     l.velocity_std_mps.load() * 1e3, dt > 0 ? (n - last_counts[i]) / dt : 0.0,
                     state_writer.deadline_missed(l.setup.config.id), l.skipped.load(), l.innovation_rms.load(),
                     l.step_max_us.load(), core::status_to_string(l.status.load()));
        last_counts[i] = n;
      }
      if (sources_ended) {
        spdlog::info("all sources ended");
        break;
      }
      if (options.duration_s > 0 &&
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >= options.duration_s)
        break;
    }
    service.stopping();
    stopping.store(true);
    for (auto& loop : loops) loop->setup.source->stop();
    for (auto& g : groups)
      if (g->thread.joinable()) g->thread.join();
    for (auto& loop : loops) {
      if (loop->canopen) {
        loop->canopen->stop();
        spdlog::info("axis '{}': canopen: {}", loop->setup.config.name, loop->canopen->stats());
      }
      if (!loop->end_reason.empty()) {
        spdlog::error("axis '{}': {}", loop->setup.config.name, loop->end_reason);
        exit_code = 1;
      }
    }
    for (auto& loop : loops) {
      keep_position(loop->setup);
      const auto& c = state_writer.counters(loop->slot);
      spdlog::info("axis '{}': {} samples estimated, {} published ({} refused by Fast DDS), {} diagnostics, offered "
                   "deadline missed {} times in {} episode(s) ({} early report(s) of Fast DDS not counted)",
                   loop->setup.config.name, loop->samples.load(), loop->published.load(), loop->write_failures.load(),
                   loop->diagnostics_published.load(), c.missed.load(), c.episodes.load(), c.early_reports.load());
      const std::string driver_stats = loop->setup.source->stats();
      if (!driver_stats.empty()) spdlog::info("axis '{}': driver: {}", loop->setup.config.name, driver_stats);
    }
    spdlog::info("published {} samples; offered deadline missed {} times",
                 [&] {
                   std::uint64_t n = 0;
                   for (auto& l : loops) n += l->published.load();
                   return n;
                 }(),
                 state_writer.deadline_missed_total());
  }  // writers deleted here, before the participant
  ctx.reset();
  return exit_code;
}

// ------------------------------------------------------------------- check

/// Prints `text`, one problem per line, and returns how many lines it had.
static std::size_t print_problems(const std::string& text, const std::string& prefix = "") {
  std::size_t n = 0;
  std::size_t at = 0;
  while (at < text.size()) {
    std::size_t end = text.find('\n', at);
    if (end == std::string::npos) end = text.size();
    if (end > at) {
      std::printf("%s%.*s\n", prefix.c_str(), static_cast<int>(end - at), text.c_str() + at);
      ++n;
    }
    at = end + 1;
  }
  return n;
}

int check_command(const CheckOptions& options) {
  auto result = options.config.empty() ? config::load_embedded_default() : config::load_machine_file(options.config);
  std::size_t problems = result.errors.size();
  for (const auto& e : result.errors) std::printf("%s\n", e.to_string().c_str());
  if (result.ok()) {
    // Every problem of every axis is printed and counted: each of its calibration file's,
    // and its driver's as well when the calibration has problems too.
    for (const auto& axis : result.config.axes) {
      core::Calibration cal;
      bool calibrated = false;
      std::string error;
      const bool cal_ok = load_axis_calibration(axis, cal, calibrated, error);
      std::size_t axis_problems = 0;
      if (!cal_ok) {
        const std::size_t n = print_problems(error);
        axis_problems += n > 0 ? n : 1;
        if (n == 0) std::printf("%s: axis '%s': calibration refused\n", result.config.source.c_str(), axis.name.c_str());
      }
      error.clear();
      auto source = make_source(axis, SourceTiming::as_fast_as_possible, error);
      if (!source) {
        // The driver's message names the axis itself, or not.
        const std::string axis_prefix = "axis '" + axis.name + "': ";
        const std::string prefix =
            result.config.source + ": " + (error.rfind(axis_prefix, 0) == 0 ? std::string() : axis_prefix);
        const std::size_t n = print_problems(error, prefix);
        axis_problems += n > 0 ? n : 1;
        if (n == 0) std::printf("%sthe driver cannot start\n", prefix.c_str());
      }
      problems += axis_problems;
      if (axis_problems > 0) continue;
      std::printf("axis '%s' (id %u): motor %s, %d Halls, %.0f Hz, %s, %s\n", axis.name.c_str(), axis.id,
                  axis.motor.name.c_str(), axis.motor.hall.count, axis.motor.sample_rate_hz, source->describe().c_str(),
                  calibrated ? ("calibration " + cal.info.id + " (" + cal.info.method + ", " + cal.info.created_utc + ")").c_str()
                             : "no calibration: nominal table");
    }
  }
  if (problems > 0) {
    std::printf("%zu problem(s)\n", problems);
    return 1;
  }
  std::printf("OK: machine '%s' (%s), %zu axis/axes\n", result.config.name.c_str(), result.config.source.c_str(),
              result.config.axes.size());
  return 0;
}

// ------------------------------------------------------------------- calibrate

/// The recording a calibration is made from (`what`: "calibration" or "thermal
/// calibration"): read from --log, or recorded live on the simulator `sim`. Returns
/// -1 with `segments` filled (and whether the log has a ruler column), or the
/// command's exit code once it has said why not.
template <class Progress>
static int acquire_calibration_run(const CalibrateOptions& options, const config::AxisConfig& axis,
                                   const sim::SimConfig& sim, const std::string& what, Progress& progress, bool tty,
                                   std::vector<core::ReferenceSegment>& segments, bool& has_reference) {
  std::string error;
  has_reference = false;
  if (!options.log.empty()) {
    if (!read_calibration_log_any(options.log, axis.motor.hall.count, segments, has_reference, error)) {
      if (termination_requested()) return interrupted(("reading the " + what + " log").c_str());
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
    long rows = 0;
    for (const auto& seg : segments) rows += static_cast<long>(seg.samples.size());
    if (rows < 1000) {
      std::fprintf(stderr, "%s: %ld usable rows: too short for a %s%s\n", options.log.c_str(), rows, what.c_str(),
                   has_reference ? "" : " (and it has no ref_position_m column)");
      return 2;
    }
  } else {
    sim::CalibrationRunConfig run;
    run.sweep_speed_mps = options.sweep_speed_mps;
    run.sweep_acceleration_mps2 = options.sweep_acceleration_mps2;
    if (!sim::record_calibration_run(axis.motor, sim, run, segments, error,
                                     [&](double f) { progress("recording", f); }, &termination_flag())) {
      if (termination_requested()) return interrupted(("the " + what + " run").c_str());
      std::fprintf(stderr, "\n%s run failed: %s\n", what.c_str(), error.c_str());
      return 1;
    }
    if (tty) std::fprintf(stderr, "\n");
  }
  if (termination_requested()) return interrupted(("the " + what + " run").c_str());
  return -1;
}

/// calibrate --thermal: the axis' calibration (at `out`) gains each Hall sensor's
/// temperature coefficients, fitted from a calibration run recorded some kelvin away
/// from it (a log, or live on the simulator run that much warmer). The table and the
/// rest of the sensor model are kept as they are.
template <class Progress>
static int thermal_calibrate(const CalibrateOptions& options, const config::AxisConfig& axis, const std::string& out,
                             Progress& progress, bool tty) {
  const auto base = config::load_calibration_file(out, axis.motor);
  if (!base.ok()) {
    std::fprintf(stderr, "%s\nthermal calibration needs the axis' calibration first (calibrate without --thermal)\n",
                 config::to_string(base.errors).c_str());
    return 2;
  }
  // On the simulator the same run, that much warmer (or colder) than its calibration.
  sim::SimConfig sim = axis.driver.sim;
  sim.temperature.profile = sim::TemperatureConfig::Profile::constant;
  sim.temperature.offset_k += options.sim_temperature_rise_k;
  sim.temperature.delta_k = 0.0;
  std::vector<core::ReferenceSegment> segments;
  bool has_reference = false;
  if (const int code =
          acquire_calibration_run(options, axis, sim, "thermal calibration", progress, tty, segments, has_reference);
      code >= 0)
    return code;
  if (!options.log.empty() && !has_reference)
    std::fprintf(stderr, "%s has no ref_position_m column: positions from the Hall array itself\n",
                 options.log.c_str());
  std::string error;
  core::Calibration cal = base.calibration;
  core::ThermalCalibrationReport report;
  if (!core::fit_thermal_coefficients(axis.motor, base.calibration, segments, {}, cal.model, report, error)) {
    std::fprintf(stderr, "thermal calibration failed%s%s: %s\n", options.log.empty() ? "" : ": ",
                 options.log.c_str(), error.c_str());
    return 1;
  }
  config::stamp_calibration(cal);
  // The names are the user's, of any length: not through a fixed buffer.
  std::string text = fmt::format(
      "thermal calibration of axis '{}' (motor {}): the recording is {:+.2f} K from the calibration ({}), "
      "the sensors' common gain {:+.3f} %\n",
      axis.name, axis.motor.name, report.rise_k,
      report.rise_reported ? "the sensor node's temperature" : "read from the sensors' common gain",
      100.0 * report.common_gain);
  char buf[256];
  if (std::isfinite(cal.model.common_tc_per_k)) {
    std::snprintf(buf, sizeof buf, "  common gain %+.4f %%/K (+-%.1f %%)\n", 100.0 * cal.model.common_tc_per_k,
                  100.0 * cal.model.common_tc_rel_std);
    text += buf;
  }
  for (int i = 0; i < axis.motor.hall.count && i < core::kMaxHalls; ++i) {
    const auto k = static_cast<std::size_t>(i);
    std::snprintf(buf, sizeof buf,
                  "  sensor %d: offset %+.4f +- %.4f mV/K, gain %+.4f +- %.4f %%/K (readings %d, residual %.2f mV)\n", i,
                  1e3 * cal.model.hall_offset_tc_v_per_k[k], 1e3 * cal.model.hall_offset_tc_std_v_per_k[k],
                  100.0 * cal.model.hall_gain_tc_per_k[k], 100.0 * cal.model.hall_gain_tc_std_per_k[k],
                  report.samples[k], 1e3 * report.residual_v[k]);
    text += buf;
  }
  for (const auto& n : report.notes) text += "  note: " + n + "\n";
  if (termination_requested()) return interrupted("the thermal calibration");
  if (!config::write_calibration_file_atomic(out, cal, error)) {
    std::printf("%s", text.c_str());
    std::fprintf(stderr, "calibration NOT written: %s\n", error.c_str());
    return 1;
  }
  const std::string report_path = out + ".thermal.txt";
  const bool report_written = write_text_file_atomic(report_path, text, error);
  if (!report_written) std::fprintf(stderr, "report NOT written: %s\n", error.c_str());
  std::printf("%s", text.c_str());
  std::printf("calibration %s (with the thermal coefficients) written to %s", cal.info.id.c_str(), out.c_str());
  if (report_written) std::printf(" (report: %s)", report_path.c_str());
  std::printf("\n");
  return report_written ? 0 : 1;
}

int calibrate_command(const CalibrateOptions& options) {
  config::MachineConfig machine;
  // The calibration file is what this command writes: it need not exist yet.
  config::LoadOptions load;
  load.calibration_must_exist = false;
  if (!load_machine(options.config, machine, load)) return 2;
  const config::AxisConfig* found = find_axis(machine, options.axis);
  if (found == nullptr) {
    std::fprintf(stderr, "no axis '%s' in %s\n", options.axis.c_str(), machine.source.c_str());
    return 2;
  }
  const config::AxisConfig& axis = *found;
  if (options.log.empty() && axis.driver.kind != config::DriverConfig::Kind::sim) {
    std::fprintf(stderr,
                 "axis '%s': live calibration needs the simulator driver (its exact position is the reference); "
                 "for a real machine, record the calibration motion with a reference ruler and pass --log\n",
                 axis.name.c_str());
    return 2;
  }
  std::string out = options.out;
  if (out.empty()) out = axis.calibration_file;
  if (out.empty()) out = "calibration/" + axis.motor.name + ".cal.yaml";
  if (!options.log.empty() && same_file(options.log, out)) {
    std::fprintf(stderr, "--out %s is the log being read (--log %s): choose another calibration file\n", out.c_str(),
                 options.log.c_str());
    return 2;
  }
  // Where the calibration goes is checked before the work, not after minutes of it.
  if (!prepare_output(out, "calibration file")) return 1;
  const bool tty = isatty(STDERR_FILENO);
  int last_percent = -1;
  auto progress = [&](const char* phase, double fraction) {
    const int percent = static_cast<int>(100.0 * fraction);
    if (!tty || percent == last_percent) return;
    last_percent = percent;
    std::fprintf(stderr, "\r%-10s [%-50s] %3d%%", phase, std::string(static_cast<std::size_t>(percent / 2), '#').c_str(),
                 percent);
  };

  if (options.thermal) return thermal_calibrate(options, axis, out, progress, tty);

  // The motion: a slow sweep over the whole travel and back, then fast multisine
  // motion; the simulator's exact position plays the reference ruler (unless
  // --no-reference, which never reads it).
  std::vector<core::ReferenceSegment> segments;
  bool has_reference = false;
  if (const int code =
          acquire_calibration_run(options, axis, axis.driver.sim, "calibration", progress, tty, segments, has_reference);
      code >= 0)
    return code;
  bool no_reference = options.no_reference;
  if (!options.log.empty() && !has_reference && !no_reference) {
    std::fprintf(stderr, "%s has no ref_position_m column: calibrating without a reference\n", options.log.c_str());
    no_reference = true;
  }
  std::string error;

  core::Calibration cal;
  core::IdentificationReport report;
  core::SelfCalibrationReport self_report;
  if (no_reference) {
    core::SelfCalibrationConfig sc;
    sc.hall_delay_s = options.hall_delay_us * 1e-6;
    sc.accel_delay_s = options.accel_delay_us * 1e-6;
    if (tty) std::fprintf(stderr, "identifying without a reference ...\n");
    if (!core::identify_without_reference(axis.motor, segments, sc, cal, self_report, error)) {
      std::fprintf(stderr, "calibration failed%s%s: %s\n", options.log.empty() ? "" : ": ", options.log.c_str(),
                   error.c_str());
      return 1;
    }
    report = self_report.identification;
  } else if (!core::identify_with_reference(axis.motor, segments, core::IdentificationConfig{}, cal, report, error)) {
    std::fprintf(stderr, "calibration failed%s%s: %s\n", options.log.empty() ? "" : ": ", options.log.c_str(),
                 error.c_str());
    return 1;
  }
  config::stamp_calibration(cal);
  if (termination_requested()) return interrupted("the calibration");

  const core::SelfCalibrationReport* self = no_reference ? &self_report : nullptr;
  const std::string summary = format_identification_report(axis, cal, report, {}, self);
  if (!report.good && !options.force) {
    std::printf("%s", summary.c_str());
    std::fprintf(stderr, "calibration NOT written: the result is poor (see above); --force writes it anyway\n");
    return 1;
  }
  if (!report.good) {
    // --force writes a poor result only if `run` and `evaluate` would load it:
    // try it as they read it, from a scratch file beside the output.
    const std::string probe = out + ".force-check.tmp";
    std::string why;
    config::register_scratch_file(probe);
    if (!config::write_calibration_file_atomic(probe, cal, why)) {
      why = "it cannot be written as a calibration file: " + why;
    } else {
      const auto loaded = config::load_calibration_file(probe, axis.motor);
      if (!loaded.ok()) why = "run and evaluate would refuse it: " + config::to_string(loaded.errors);
    }
    std::error_code ignored;
    std::filesystem::remove(probe, ignored);
    config::unregister_scratch_file(probe);
    if (!why.empty()) {
      std::printf("%s", summary.c_str());
      std::fprintf(stderr, "calibration NOT written, even with --force: %s\n", why.c_str());
      return 1;
    }
  }
  if (termination_requested()) return interrupted("the calibration");
  if (!config::write_calibration_file_atomic(out, cal, error)) {
    std::fprintf(stderr, "calibration NOT written: %s\n", error.c_str());
    return 1;
  }
  const std::string report_path = out + ".report.txt";
  std::string plot_error;
  const auto plots = write_calibration_plots(out, cal, report, plot_error);
  if (!plot_error.empty()) std::fprintf(stderr, "plot(s) NOT written: %s\n", plot_error.c_str());
  const bool report_written =
      write_text_file_atomic(report_path, format_identification_report(axis, cal, report, plots, self), error);
  if (!report_written) std::fprintf(stderr, "report NOT written: %s\n", error.c_str());
  std::printf("%s", summary.c_str());
  std::printf("calibration %s written to %s", cal.info.id.c_str(), out.c_str());
  if (report_written) std::printf(" (report: %s)", report_path.c_str());
  std::printf("\n");
  // The calibration is in place; a report or plot that could not be written still fails the job.
  return report_written && plot_error.empty() ? 0 : 1;
}

// ------------------------------------------------------------------- monitor

int monitor_command(const MonitorOptions& options) {
  config::MachineConfig machine;
  if (!load_machine(options.config, machine)) return 2;
  DdsOptions dds_options;
  dds_options.domain = options.domain.value_or(machine.dds.domain);
  dds_options.profiles_file = machine.dds.profiles_file;
  dds_options.participant_name = "virtual-encoder-monitor";
  std::string error;
  auto ctx = DdsContext::create(dds_options, error);
  if (!ctx) {
    spdlog::error("{}", error);
    return 1;
  }
  const double deadline_ms = options.deadline_ms > 0 ? options.deadline_ms : 2.0 * machine.dds.deadline_ms;
  // A reader that stops reading (`monitor --csv | head`) ends the monitor quietly: no
  // death by SIGPIPE, the failed write is seen and the loop stops with exit code 0.
  std::signal(SIGPIPE, SIG_IGN);
  std::atomic<int> write_errno{0};  // the first failed write to stdout, 0 while none
  auto note_write = [&write_errno](int rc) {
    if (rc < 0) {
      int expected = 0;
      write_errno.compare_exchange_strong(expected, errno != 0 ? errno : EIO);
    }
  };
  std::mutex out_mutex;
  StateReader::Callback csv_row;
  if (options.csv) {
    std::printf("axis_id,sequence,sample_time_ns,status,position_counts,velocity_counts_per_s,position_m,"
                "velocity_mps,acceleration_mps2,position_std_m,velocity_std_mps,acceleration_std_mps2,source_time_ns,"
                "publish_time_ns\n");
    csv_row = [&out_mutex, &note_write, &write_errno](const ve::dds::EncoderState& s) {
      std::lock_guard<std::mutex> lock(out_mutex);
      if (write_errno.load() != 0) return;
      note_write(std::printf("%u,%llu,%lld,0x%08x,%lld,%lld,%.9f,%.6f,%.4f,%.3e,%.3e,%.3e,%lld,%lld\n", s.axis_id(),
                  static_cast<unsigned long long>(s.sequence_number()), static_cast<long long>(s.sample_time_ns()),
                  s.status(), static_cast<long long>(s.position_counts()),
                  static_cast<long long>(s.velocity_counts_per_s()), s.position_m(), s.velocity_mps(),
                  s.acceleration_mps2(), s.position_std_m(), s.velocity_std_mps(), s.acceleration_std_mps2(),
                  static_cast<long long>(s.source_time_ns()), static_cast<long long>(s.publish_time_ns())));
    };
  }
  int exit_code = 0;
  {
    StateReader reader(*ctx, deadline_ms, csv_row);
    if (!reader.ok()) {
      spdlog::error("cannot create the DDS readers");
      return 1;
    }
    const bool tty = isatty(STDOUT_FILENO) && !options.csv;
    if (!options.csv) {
      std::printf("monitoring DDS domain %d, topic '%s' (requested deadline %.0f ms); Ctrl-C to stop\n",
                  dds_options.domain, kStateTopic, deadline_ms);
      // A log gets the legend once, at the top; a terminal below every redraw.
      if (!tty) std::printf("%s\n", kMonitorTableLegend);
    }
    // Whether stdout still takes what is written: false once a write or a flush failed.
    auto output_open = [&] {
      std::lock_guard<std::mutex> lock(out_mutex);
      note_write(std::fflush(stdout) == 0 ? 0 : -1);
      if (write_errno.load() == 0 && std::ferror(stdout)) note_write(-1);
      return write_errno.load() == 0;
    };
    const auto start = std::chrono::steady_clock::now();
    auto last_print = start - std::chrono::hours(1);
    // Matching is logged (stderr), so that a monitor that receives nothing says
    // whether it found no encoder or found one that sends nothing.
    int matched = 0;
    auto log_matching = [&] {
      if (const int m = reader.matched_writers(); m != matched) {
        spdlog::info("monitor: {} state writer(s) matched on domain {}", m, dds_options.domain);
        matched = m;
      }
    };
    // State samples lost on the way (Fast DDS saw a gap in a writer's RTPS sequence
    // numbers), logged at most once a second: a sequence gap with none of these was
    // never sent by its encoder.
    std::uint64_t lost_logged = 0;
    auto last_lost_log = start - std::chrono::hours(1);
    auto log_lost = [&] {
      const std::uint64_t lost = reader.samples_lost();
      const auto now = std::chrono::steady_clock::now();
      if (lost == lost_logged || now - last_lost_log < std::chrono::seconds(1)) return;
      spdlog::warn("monitor: {} state sample(s) lost on the way since the last report ({} in all): sent by an "
                   "encoder, never received here (network, or this host's socket buffer)",
                   lost - lost_logged, lost);
      lost_logged = lost;
      last_lost_log = now;
    };
    for (;;) {
      log_matching();
      log_lost();
      const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      if (options.duration_s > 0 && elapsed >= options.duration_s) break;
      double wait = options.refresh_s;
      if (options.duration_s > 0) wait = std::min(wait, options.duration_s - elapsed);
      const bool stop = wait_for_termination(std::max(wait, 0.001));
      log_matching();
      if (stop) break;
      if (options.csv) {
        if (!output_open()) break;
        continue;
      }
      const auto now = std::chrono::steady_clock::now();
      // A log (not a terminal) gets one table per second instead of a redraw.
      if (!tty && now - last_print < std::chrono::seconds(1)) continue;
      last_print = now;
      const auto axes = reader.snapshot();
      if (tty) std::printf("\x1b[H\x1b[2J");
      // dl-miss: deadline misses this monitor saw (requested) / the encoder reported (offered).
      // innov: RMS normalised Hall innovation (~1 healthy); bias: accelerometer bias;
      // step: longest estimator+publish step of the last diagnostics period.
      std::printf("%-10s %14s %12s %9s %10s %8s %13s %8s %6s %10s %9s  %s\n", "axis", "position[mm]", "vel[mm/s]",
                  "sx[um]", "sv[mm/s]", "rate[Hz]", "dl-miss(r/o)", "gaps", "innov", "bias[m/s2]", "step[us]",
                  "status");
      for (const auto& a : axes) {
        const std::string name = a.have_description ? a.description.name() + "(" + std::to_string(a.axis_id) + ")"
                                                    : "id " + std::to_string(a.axis_id);
        const bool diag = a.diagnostics_received > 0;
        char misses[32];
        if (diag)
          std::snprintf(misses, sizeof misses, "%llu/%llu", static_cast<unsigned long long>(a.deadline_missed),
                        static_cast<unsigned long long>(a.diagnostics.deadline_missed_total()));
        else
          std::snprintf(misses, sizeof misses, "%llu/-", static_cast<unsigned long long>(a.deadline_missed));
        char innov[16] = "-", bias[16] = "-", step[16] = "-";
        if (diag) {
          std::snprintf(innov, sizeof innov, "%.2f", a.diagnostics.innovation_rms());
          std::snprintf(bias, sizeof bias, "%+.4f", a.diagnostics.accel_bias_mps2());
          std::snprintf(step, sizeof step, "%.0f", a.diagnostics.step_time_max_us());
        }
        if (a.received == 0) {
          // Described (or its diagnostics seen) but no state yet: nothing to show, and no
          // zeros that would read like a position at 0.
          std::printf("%-10s %14s %12s %9s %10s %8.0f %13s %8llu %6s %10s %9s  %s\n", name.c_str(), "-", "-", "-", "-",
                      a.rate_hz, misses, static_cast<unsigned long long>(a.sequence_gaps), innov, bias, step,
                      "waiting");
          continue;
        }
        std::printf("%-10s %14.4f %12.3f %9.3f %10.4f %8.0f %13s %8llu %6s %10s %9s  %s\n", name.c_str(),
                    a.last.position_m() * 1e3, a.last.velocity_mps() * 1e3, a.last.position_std_m() * 1e6,
                    a.last.velocity_std_mps() * 1e3, a.rate_hz, misses,
                    static_cast<unsigned long long>(a.sequence_gaps), innov, bias, step,
                    core::status_to_string(a.last.status()).c_str());
      }
      if (axes.empty()) std::printf("(no encoder on domain %d yet: is `virtual-encoder run` up?)\n", dds_options.domain);
      if (tty) std::printf("\n%s", kMonitorTableLegend);
      if (!output_open()) break;
    }
    if (write_errno.load() != 0) {
      // Not a failure when the reader has all it wanted; anything else is.
      const int e = write_errno.load();
      if (e == EPIPE) {
        spdlog::debug("monitor: stdout closed by its reader: stopping");
      } else {
        spdlog::error("monitor: cannot write to stdout: {}", std::strerror(e));
        exit_code = 1;
      }
    } else if (!options.csv)
      std::printf("received %llu samples; requested deadline missed %llu times; %llu lost on the way\n",
                  static_cast<unsigned long long>(reader.total_received()),
                  static_cast<unsigned long long>(reader.deadline_missed_total()),
                  static_cast<unsigned long long>(reader.samples_lost()));
  }
  ctx.reset();
  return exit_code;
}

}  // namespace ve::app
