#include "commands.hpp"

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <thread>
#include <vector>

#include <spdlog/spdlog.h>

#include "axis.hpp"
#include "calibration_log.hpp"
#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "core/status.hpp"
#include "core/identification.hpp"
#include "dds_io.hpp"
#include "reports.hpp"
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

const config::AxisConfig* find_axis(const config::MachineConfig& m, const std::string& name) {
  if (name.empty()) return m.axes.empty() ? nullptr : &m.axes.front();
  for (const auto& a : m.axes)
    if (a.name == name) return &a;
  return nullptr;
}

/// Per-axis loop state shared with the status reporter.
struct AxisLoop {
  AxisSetup setup;
  std::thread thread;
  std::atomic<std::uint64_t> samples{0};
  std::atomic<std::uint64_t> write_failures{0};
  std::atomic<std::uint64_t> skipped{0};
  std::atomic<bool> finished{false};
  std::string end_reason;
  // Last published values, for the status line (torn reads are harmless here).
  std::atomic<double> position_m{0}, velocity_mps{0}, position_std_m{0}, velocity_std_mps{0};
  std::atomic<std::uint32_t> status{0};
};

void axis_loop(AxisLoop& loop, StateWriter& writer) {
  core::RawSample sample;
  ve::dds::EncoderState state;
  std::uint64_t sequence = 0;
  auto& source = *loop.setup.source;
  auto& pipeline = *loop.setup.pipeline;
  for (;;) {
    const auto st = source.read(sample);
    if (st == drivers::ReadStatus::timeout) continue;
    if (st != drivers::ReadStatus::ok) {
      loop.end_reason = st == drivers::ReadStatus::error ? source.last_error() : std::string();
      break;
    }
    const core::EncoderEstimate& est = pipeline.step(sample);
    fill_state(est, loop.setup.config, ++sequence, state);
    if (!writer.write(state)) loop.write_failures.fetch_add(1, std::memory_order_relaxed);
    loop.samples.fetch_add(1, std::memory_order_relaxed);
    if (est.samples_skipped) loop.skipped.fetch_add(est.samples_skipped, std::memory_order_relaxed);
    loop.position_m.store(est.position_m, std::memory_order_relaxed);
    loop.velocity_mps.store(est.velocity_mps, std::memory_order_relaxed);
    loop.position_std_m.store(est.position_std_m, std::memory_order_relaxed);
    loop.velocity_std_mps.store(est.velocity_std_mps, std::memory_order_relaxed);
    loop.status.store(est.status, std::memory_order_relaxed);
  }
  loop.finished.store(true);
}

}  // namespace

// ------------------------------------------------------------------- run

int run_command(const RunOptions& options) {
  config::MachineConfig machine;
  if (!load_machine(options.config, machine)) return 2;
  if (options.domain) machine.dds.domain = *options.domain;

  std::vector<std::unique_ptr<AxisLoop>> loops;
  for (const auto& axis : machine.axes) {
    auto loop = std::make_unique<AxisLoop>();
    std::string error;
    if (!build_axis(axis, SourceTiming::as_configured, loop->setup, error)) {
      std::fprintf(stderr, "axis '%s': %s\n", axis.name.c_str(), error.c_str());
      return 2;
    }
    loops.push_back(std::move(loop));
  }

  DdsOptions dds_options;
  dds_options.domain = machine.dds.domain;
  dds_options.profiles_file = machine.dds.profiles_file;
  dds_options.participant_name = "virtual-encoder/" + machine.name;
  std::string error;
  auto ctx = DdsContext::create(dds_options, error);
  if (!ctx) {
    spdlog::error("{}", error);
    return 1;
  }
  int exit_code = 0;
  {
    StateWriter state_writer(*ctx, machine.dds.deadline_ms);
    DescriptionWriter description_writer(*ctx);
    if (!state_writer.ok() || !description_writer.ok()) {
      spdlog::error("cannot create the DDS writers (check the QoS in the profiles file)");
      return 1;
    }
    for (const auto& loop : loops) description_writer.write(describe_axis(loop->setup, machine));

    spdlog::info("machine '{}' from {}: {} axis/axes on DDS domain {}, topic '{}', deadline {} ms", machine.name,
                 machine.source, loops.size(), machine.dds.domain, kStateTopic, machine.dds.deadline_ms);
    for (const auto& loop : loops) {
      const auto& s = loop->setup;
      spdlog::info("axis '{}' (id {}): {} | motor {} | {}", s.config.name, s.config.id, s.source->describe(),
                   s.config.motor.name,
                   s.calibrated ? "calibration " + s.calibration.info.id : std::string("nominal table (not calibrated)"));
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
    for (auto& loop : loops) loop->thread = std::thread(axis_loop, std::ref(*loop), std::ref(state_writer));

    const auto start = std::chrono::steady_clock::now();
    std::vector<std::uint64_t> last_counts(loops.size(), 0);
    auto last_report = start;
    for (;;) {
      const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      double wait = options.status_period_s;
      if (options.duration_s > 0) wait = std::min(wait, std::max(0.0, options.duration_s - elapsed));
      if (wait_for_termination(std::max(wait, 0.001))) {
        spdlog::info("termination signal: stopping");
        break;
      }
      const auto now = std::chrono::steady_clock::now();
      const double dt = std::chrono::duration<double>(now - last_report).count();
      last_report = now;
      bool all_finished = true;
      for (std::size_t i = 0; i < loops.size(); ++i) {
        auto& l = *loops[i];
        const auto n = l.samples.load();
        spdlog::info("{:>4} x={:+11.6f} m v={:+9.5f} m/s sx={:6.2f} um sv={:6.3f} mm/s rate={:6.0f} Hz "
                     "missed={} skipped={} [{}]",
                     l.setup.config.name, l.position_m.load(), l.velocity_mps.load(), l.position_std_m.load() * 1e6,
                     l.velocity_std_mps.load() * 1e3, dt > 0 ? (n - last_counts[i]) / dt : 0.0,
                     state_writer.deadline_missed(l.setup.config.id), l.skipped.load(),
                     core::status_to_string(l.status.load()));
        last_counts[i] = n;
        all_finished = all_finished && l.finished.load();
      }
      if (all_finished) {
        spdlog::info("all sources ended");
        break;
      }
      if (options.duration_s > 0 &&
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >= options.duration_s)
        break;
    }
    for (auto& loop : loops) loop->setup.source->stop();
    for (auto& loop : loops) {
      if (loop->thread.joinable()) loop->thread.join();
      if (!loop->end_reason.empty()) {
        spdlog::error("axis '{}': {}", loop->setup.config.name, loop->end_reason);
        exit_code = 1;
      }
    }
    spdlog::info("published {} samples; offered deadline missed {} times",
                 [&] {
                   std::uint64_t n = 0;
                   for (auto& l : loops) n += l->samples.load();
                   return n;
                 }(),
                 state_writer.deadline_missed_total());
  }  // writers deleted here, before the participant
  ctx.reset();
  return exit_code;
}

// ------------------------------------------------------------------- check

int check_command(const CheckOptions& options) {
  auto result = options.config.empty() ? config::load_embedded_default() : config::load_machine_file(options.config);
  std::size_t problems = result.errors.size();
  for (const auto& e : result.errors) std::printf("%s\n", e.to_string().c_str());
  if (result.ok()) {
    for (const auto& axis : result.config.axes) {
      core::Calibration cal;
      bool calibrated = false;
      std::string error;
      if (!load_axis_calibration(axis, cal, calibrated, error)) {
        std::printf("%s", error.c_str());
        ++problems;
        continue;
      }
      auto source = make_source(axis, SourceTiming::as_fast_as_possible, error);
      if (!source) {
        std::printf("%s: axis '%s': %s\n", result.config.source.c_str(), axis.name.c_str(), error.c_str());
        ++problems;
        continue;
      }
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

  const bool tty = isatty(STDERR_FILENO);
  int last_percent = -1;
  auto progress = [&](const char* phase, double fraction) {
    const int percent = static_cast<int>(100.0 * fraction);
    if (!tty || percent == last_percent) return;
    last_percent = percent;
    std::fprintf(stderr, "\r%-10s [%-50s] %3d%%", phase, std::string(static_cast<std::size_t>(percent / 2), '#').c_str(),
                 percent);
  };

  // The motion: a slow sweep over the whole travel and back, then fast multisine
  // motion; the simulator's exact position plays the reference ruler.
  sim::CalibrationRunConfig run;
  run.sweep_speed_mps = options.sweep_speed_mps;
  run.sweep_acceleration_mps2 = options.sweep_acceleration_mps2;
  std::vector<core::ReferenceSegment> segments;
  std::string error;
  if (!options.log.empty()) {
    if (!read_calibration_log(options.log, axis.motor.hall.count, segments, error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
  } else if (!sim::record_calibration_run(axis.motor, axis.driver.sim, run, segments, error,
                                          [&](double f) { progress("recording", f); })) {
    std::fprintf(stderr, "\ncalibration run failed: %s\n", error.c_str());
    return 1;
  }
  if (tty) std::fprintf(stderr, "\n");

  core::Calibration cal;
  core::IdentificationReport report;
  if (!core::identify_with_reference(axis.motor, segments, core::IdentificationConfig{}, cal, report, error)) {
    std::fprintf(stderr, "calibration failed: %s\n", error.c_str());
    return 1;
  }
  {
    const auto now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
    char buf[32];
    std::tm tm{};
    gmtime_r(&now, &tm);
    std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
    cal.info.created_utc = buf;
  }
  cal.info.id = core::calibration_checksum(cal);

  const std::string summary = format_identification_report(axis, cal, report);
  if (!report.good && !options.force) {
    std::printf("%s", summary.c_str());
    std::fprintf(stderr, "calibration NOT written: the result is poor (see above); --force writes it anyway\n");
    return 1;
  }
  const auto parent = std::filesystem::path(out).parent_path();
  if (!parent.empty()) std::filesystem::create_directories(parent);
  if (!config::write_calibration_file_atomic(out, cal, error)) {
    std::fprintf(stderr, "cannot write %s: %s\n", out.c_str(), error.c_str());
    return 1;
  }
  const std::string report_path = out + ".report.txt";
  if (!write_text_file_atomic(report_path, summary, error))
    std::fprintf(stderr, "warning: cannot write the report %s: %s\n", report_path.c_str(), error.c_str());
  std::printf("%s", summary.c_str());
  std::printf("calibration %s written to %s (report: %s)\n", cal.info.id.c_str(), out.c_str(), report_path.c_str());
  return 0;
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
  std::mutex out_mutex;
  StateReader::Callback csv_row;
  if (options.csv) {
    std::printf("axis_id,sequence,sample_time_ns,status,position_counts,velocity_counts_per_s,position_m,"
                "velocity_mps,acceleration_mps2,position_std_m,velocity_std_mps\n");
    csv_row = [&out_mutex](const ve::dds::EncoderState& s) {
      std::lock_guard<std::mutex> lock(out_mutex);
      std::printf("%u,%llu,%lld,0x%08x,%lld,%lld,%.9f,%.6f,%.4f,%.3e,%.3e\n", s.axis_id(),
                  static_cast<unsigned long long>(s.sequence_number()), static_cast<long long>(s.sample_time_ns()),
                  s.status(), static_cast<long long>(s.position_counts()),
                  static_cast<long long>(s.velocity_counts_per_s()), s.position_m(), s.velocity_mps(),
                  s.acceleration_mps2(), s.position_std_m(), s.velocity_std_mps());
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
    if (!options.csv)
      std::printf("monitoring DDS domain %d, topic '%s' (requested deadline %.0f ms); Ctrl-C to stop\n",
                  dds_options.domain, kStateTopic, deadline_ms);
    const auto start = std::chrono::steady_clock::now();
    auto last_print = start - std::chrono::hours(1);
    for (;;) {
      const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      if (options.duration_s > 0 && elapsed >= options.duration_s) break;
      double wait = options.refresh_s;
      if (options.duration_s > 0) wait = std::min(wait, options.duration_s - elapsed);
      if (wait_for_termination(std::max(wait, 0.001))) break;
      if (options.csv) {
        std::lock_guard<std::mutex> lock(out_mutex);
        std::fflush(stdout);
        continue;
      }
      const auto now = std::chrono::steady_clock::now();
      // A log (not a terminal) gets one table per second instead of a redraw.
      if (!tty && now - last_print < std::chrono::seconds(1)) continue;
      last_print = now;
      const auto axes = reader.snapshot();
      if (tty) std::printf("\x1b[H\x1b[2J");
      std::printf("%-10s %14s %12s %9s %10s %8s %9s %8s  %s\n", "axis", "position[mm]", "vel[mm/s]", "sx[um]",
                  "sv[mm/s]", "rate[Hz]", "dl-miss", "gaps", "status");
      for (const auto& a : axes) {
        const std::string name = a.have_description ? a.description.name() + "(" + std::to_string(a.axis_id) + ")"
                                                    : "id " + std::to_string(a.axis_id);
        std::printf("%-10s %14.4f %12.3f %9.3f %10.4f %8.0f %9llu %8llu  %s\n", name.c_str(), a.last.position_m() * 1e3,
                    a.last.velocity_mps() * 1e3, a.last.position_std_m() * 1e6, a.last.velocity_std_mps() * 1e3,
                    a.rate_hz, static_cast<unsigned long long>(a.deadline_missed),
                    static_cast<unsigned long long>(a.sequence_gaps), core::status_to_string(a.last.status()).c_str());
      }
      if (axes.empty()) std::printf("(no encoder on domain %d yet: is `virtual-encoder run` up?)\n", dds_options.domain);
      std::fflush(stdout);
    }
    if (!options.csv)
      std::printf("received %llu samples; requested deadline missed %llu times\n",
                  static_cast<unsigned long long>(reader.total_received()),
                  static_cast<unsigned long long>(reader.deadline_missed_total()));
  }
  ctx.reset();
  return exit_code;
}

}  // namespace ve::app
