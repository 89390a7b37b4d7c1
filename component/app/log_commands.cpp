// `record` writes raw log v1 from any driver; `evaluate` runs the estimator
// causally over a log and compares it with the log's truth.
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <string>

#include "axis.hpp"
#include "commands.hpp"
#include "config/calibration_file.hpp"
#include "config/loader.hpp"
#include "core/error_stats.hpp"
#include "core/status.hpp"
#include "replay/raw_log.hpp"
#include "replay/replay_source.hpp"
#include "reports.hpp"
#include "signals.hpp"

namespace ve::app {

namespace {

bool load(const std::string& path, config::MachineConfig& out) {
  auto result = path.empty() ? config::load_embedded_default() : config::load_machine_file(path);
  for (const auto& e : result.errors) std::fprintf(stderr, "%s\n", e.to_string().c_str());
  if (!result.ok()) return false;
  out = std::move(result.config);
  return true;
}

const config::AxisConfig* axis_named(const config::MachineConfig& m, const std::string& name) {
  if (name.empty()) return m.axes.empty() ? nullptr : &m.axes.front();
  for (const auto& a : m.axes)
    if (a.name == name) return &a;
  return nullptr;
}

}  // namespace

int record_command(const RecordOptions& options) {
  config::MachineConfig machine;
  if (!load(options.config, machine)) return 2;
  const config::AxisConfig* axis = axis_named(machine, options.axis);
  if (axis == nullptr) {
    std::fprintf(stderr, "no axis '%s' in %s\n", options.axis.c_str(), machine.source.c_str());
    return 2;
  }
  std::string error;
  auto source = make_source(*axis, options.fast ? SourceTiming::as_fast_as_possible : SourceTiming::as_configured, error);
  if (!source) {
    std::fprintf(stderr, "axis '%s': %s\n", axis->name.c_str(), error.c_str());
    return 2;
  }
  // The first sample tells which optional columns the source fills.
  core::RawSample s;
  // A live source (a CAN bus) may take a moment to deliver its first sample.
  auto st = source->read(s);
  for (int i = 0; st == drivers::ReadStatus::timeout && i < 250 && !wait_for_termination(0.0); ++i) st = source->read(s);
  if (st != drivers::ReadStatus::ok) {
    std::fprintf(stderr, "the source gave no sample: %s\n", source->last_error().c_str());
    return 1;
  }
  double reference = 0.0;
  replay::RawLogWriter::Columns cols;
  cols.hall_count = axis->motor.hall.count;
  cols.accel_base = s.accel_base_valid;
  cols.temperature = s.temperature_valid;
  cols.reference = source->reference_position(reference);
  cols.truth = source->truth() != nullptr;
  char rate[32];
  std::snprintf(rate, sizeof rate, "%g", axis->motor.sample_rate_hz);
  replay::RawLogWriter writer;
  if (!writer.open(options.out, cols,
                   {{"sample_rate_hz", rate},
                    {"motor", axis->motor.name},
                    {"machine", machine.name},
                    {"axis", axis->name},
                    {"source", source->describe()}},
                   error)) {
    std::fprintf(stderr, "cannot write %s: %s\n", options.out.c_str(), error.c_str());
    return 1;
  }
  const std::int64_t t0 = s.t_ns;
  const bool tty = isatty(STDERR_FILENO);
  std::uint64_t n = 0;
  int code = 0;
  auto last_check = std::chrono::steady_clock::now();
  while (st == drivers::ReadStatus::ok) {
    const bool has_ref = cols.reference && source->reference_position(reference);
    if (!writer.write(s, cols.truth ? source->truth() : nullptr, has_ref ? &reference : nullptr)) {
      std::fprintf(stderr, "\nrecording stopped: %s\n", writer.error().c_str());
      code = 1;
      break;
    }
    ++n;
    if (options.duration_s > 0 && static_cast<double>(s.t_ns - t0) * 1e-9 >= options.duration_s) break;
    // Ctrl-C ends the recording cleanly; checked a few times a second, not per sample.
    const auto now = std::chrono::steady_clock::now();
    if (now - last_check > std::chrono::milliseconds(200)) {
      last_check = now;
      if (wait_for_termination(0.0)) break;
      if (tty) std::fprintf(stderr, "\rrecording %s: %.1f s, %llu samples", options.out.c_str(),
                            static_cast<double>(s.t_ns - t0) * 1e-9, static_cast<unsigned long long>(n));
    }
    st = source->read(s);
    // A silent moment on a live source is not the end of the recording.
    while (st == drivers::ReadStatus::timeout && !wait_for_termination(0.0)) st = source->read(s);
  }
  if (st == drivers::ReadStatus::error) {
    std::fprintf(stderr, "\nsource error: %s\n", source->last_error().c_str());
    code = 1;
  }
  if (tty) std::fprintf(stderr, "\n");
  if (!writer.close(error)) {
    std::fprintf(stderr, "cannot finish %s: %s\n", options.out.c_str(), error.c_str());
    return 1;
  }
  std::printf("recorded %llu samples (%.3f s) of axis '%s' to %s%s%s\n", static_cast<unsigned long long>(n),
              static_cast<double>(s.t_ns - t0) * 1e-9, axis->name.c_str(), options.out.c_str(),
              cols.truth ? ", with truth" : "", cols.reference ? ", with reference" : "");
  return code;
}

int evaluate_command(const EvaluateOptions& options) {
  config::MachineConfig machine;
  if (!load(options.config, machine)) return 2;
  const config::AxisConfig* found = axis_named(machine, options.axis);
  if (found == nullptr) {
    std::fprintf(stderr, "no axis '%s' in %s\n", options.axis.c_str(), machine.source.c_str());
    return 2;
  }
  config::AxisConfig axis = *found;
  if (!options.calibration.empty()) axis.calibration_file = options.calibration;
  if (options.home_m >= 0) axis.homing.position_m = options.home_m;
  core::Calibration cal;
  bool calibrated = false;
  std::string error;
  if (!load_axis_calibration(axis, cal, calibrated, error)) {
    std::fprintf(stderr, "%s", error.c_str());
    return 2;
  }
  replay::ReplaySource log(options.log, false);
  if (!log.ok()) {
    std::fprintf(stderr, "%s\n", log.last_error().c_str());
    return 2;
  }
  for (const auto& w : log.warnings()) std::fprintf(stderr, "warning: %s\n", w.c_str());
  if (log.meta().hall_count != axis.motor.hall.count) {
    std::fprintf(stderr, "%s: the log has %d Hall columns but motor '%s' has %d sensors\n", options.log.c_str(),
                 log.meta().hall_count, axis.motor.name.c_str(), axis.motor.hall.count);
    return 2;
  }
  if (!log.meta().has_truth) {
    std::fprintf(stderr, "%s: no truth columns (true_position_m, true_velocity_mps, true_acceleration_mps2) to "
                         "evaluate against\n", options.log.c_str());
    return 2;
  }
  double w0 = -1e300, w1 = 1e300;
  const bool windowed = log.meta().eval_window(w0, w1);

  std::FILE* est_out = nullptr;
  std::string est_tmp;
  if (!options.estimates.empty()) {
    est_tmp = options.estimates + ".partial";
    est_out = std::fopen(est_tmp.c_str(), "w");
    if (est_out == nullptr) {
      std::fprintf(stderr, "cannot write %s\n", est_tmp.c_str());
      return 1;
    }
    std::fprintf(est_out, "t_s,position_m,velocity_mps,position_std_m,velocity_std_mps,status\n");
  }

  core::AxisPipeline pipeline(pipeline_config(axis, cal, calibrated), cal.table);
  core::EstimateErrors e;
  core::RawSample s;
  std::uint64_t rows = 0;
  drivers::ReadStatus st;
  while ((st = log.read(s)) == drivers::ReadStatus::ok) {
    ++rows;
    const auto& est = pipeline.step(s);
    const double t = static_cast<double>(s.t_ns) * 1e-9;
    if (est_out)
      std::fprintf(est_out, "%.9f,%.9f,%.9f,%.3e,%.3e,%u\n", t, est.position_m, est.velocity_mps, est.position_std_m,
                   est.velocity_std_mps, est.status);
    const core::Truth* truth = log.truth();
    if (truth == nullptr || t < w0 || t > w1) continue;
    e.add(est.position_m - truth->position_m, est.position_std_m, est.velocity_mps - truth->velocity_mps,
          est.velocity_std_mps, (est.status & core::status::kValid) != 0);
  }
  if (st == drivers::ReadStatus::error) {
    std::fprintf(stderr, "%s\n", log.last_error().c_str());
    if (est_out) {
      std::fclose(est_out);
      std::remove(est_tmp.c_str());
    }
    return 2;
  }
  if (est_out) {
    const bool ok = std::fflush(est_out) == 0 && fsync(fileno(est_out)) == 0;
    std::fclose(est_out);
    if (!ok || std::rename(est_tmp.c_str(), options.estimates.c_str()) != 0) {
      std::fprintf(stderr, "cannot write %s\n", options.estimates.c_str());
      return 1;
    }
  }
  if (e.position_m.count() == 0) {
    std::fprintf(stderr, "no sample with truth inside the evaluation window\n");
    return 1;
  }
  const auto& p = e.position_m;
  const auto& v = e.velocity_mps;
  if (options.json) {
    std::printf("{\"log\": \"%s\", \"axis\": \"%s\", \"calibration\": \"%s\", \"samples\": %llu, \"evaluated\": %llu, "
                "\"window_s\": [%.9g, %.9g], "
                "\"position_um\": {\"rms\": %.6f, \"bias\": %.6f, \"std\": %.6f, \"max\": %.6f}, "
                "\"velocity_mmps\": {\"rms\": %.6f, \"bias\": %.6f, \"std\": %.6f, \"max\": %.6f}, "
                "\"coverage_2sigma\": {\"position\": %.4f, \"velocity\": %.4f}, \"not_valid\": %llu}\n",
                options.log.c_str(), axis.name.c_str(), calibrated ? cal.info.id.c_str() : "",
                static_cast<unsigned long long>(rows), static_cast<unsigned long long>(p.count()),
                windowed ? w0 : 0.0, windowed ? w1 : static_cast<double>(s.t_ns) * 1e-9, p.rms() * 1e6,
                p.bias() * 1e6, p.std_dev() * 1e6, p.max_abs() * 1e6, v.rms() * 1e3, v.bias() * 1e3,
                v.std_dev() * 1e3, v.max_abs() * 1e3, e.position_coverage(), e.velocity_coverage(),
                static_cast<unsigned long long>(e.not_valid));
  } else {
    std::printf("evaluated %llu of %llu samples of %s (axis '%s', %s)%s\n",
                static_cast<unsigned long long>(p.count()), static_cast<unsigned long long>(rows),
                options.log.c_str(), axis.name.c_str(),
                calibrated ? ("calibration " + cal.info.id).c_str() : "nominal table",
                windowed ? " within eval_window_s" : "");
    std::printf("  position error [um]:   rms %8.3f  bias %+8.3f  std %8.3f  max %8.3f   (+-2 sigma: %.1f %%)\n",
                p.rms() * 1e6, p.bias() * 1e6, p.std_dev() * 1e6, p.max_abs() * 1e6, 100 * e.position_coverage());
    std::printf("  velocity error [mm/s]: rms %8.4f  bias %+8.4f  std %8.4f  max %8.4f   (+-2 sigma: %.1f %%)\n",
                v.rms() * 1e3, v.bias() * 1e3, v.std_dev() * 1e3, v.max_abs() * 1e3, 100 * e.velocity_coverage());
    if (e.not_valid) std::printf("  %llu samples were not VALID\n", static_cast<unsigned long long>(e.not_valid));
  }
  return 0;
}

}  // namespace ve::app
