#include "calibration_service.hpp"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <functional>

#include <spdlog/spdlog.h>

#include "config/calibration_file.hpp"
#include "core/identification.hpp"
#include "dds_io.hpp"
#include "realtime.hpp"
#include "reports.hpp"
#include "sim/calibration_run.hpp"

namespace ve::app {

namespace {

std::int64_t realtime_ns() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

const char* driver_name(config::DriverConfig::Kind k) {
  switch (k) {
    case config::DriverConfig::Kind::sim: return "sim";
    case config::DriverConfig::Kind::replay: return "replay";
    case config::DriverConfig::Kind::socketcan: return "socketcan";
  }
  return "?";
}

// Progress of the whole job: recording takes most of the time.
constexpr double kRecordingShare = 0.85;
constexpr double kIdentifyingAt = 0.85;
constexpr double kWritingAt = 0.95;
/// Status updates while recording: at most this often.
constexpr std::int64_t kStatusPeriodNs = 200000000;

}  // namespace

CalibrationService::CalibrationService(const config::MachineConfig& machine, CalibrationStatusWriter& status)
    : machine_(machine), status_(status) {}

CalibrationService::~CalibrationService() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (running_.load()) {
    spdlog::warn("calibration of axis id {} still running at shutdown: aborting it", running_axis_);
    abort_.store(true);
  }
  if (worker_.joinable()) worker_.join();
}

std::string CalibrationService::output_path(const config::AxisConfig& axis, const std::string& machine_source) {
  if (!axis.calibration_file.empty()) return axis.calibration_file;
  const std::string name = "calibration/" + axis.motor.name + ".cal.yaml";
  if (machine_source.empty() || machine_source[0] == '<') return name;  // embedded default: the working directory
  return (std::filesystem::path(machine_source).parent_path() / name).string();
}

void CalibrationService::publish(std::uint32_t axis_id, std::uint32_t state, std::uint64_t request_id, double progress,
                                 const std::string& message, const std::string& calibration_id, double residual_m) {
  ve::dds::CalibrationStatus s;
  s.axis_id(axis_id);
  s.state(state);
  s.request_id(request_id);
  s.update_time_ns(realtime_ns());
  s.progress(progress);
  s.residual_rms_m(residual_m);
  s.calibration_id(calibration_id);
  s.message(message);
  if (!status_.write(s)) spdlog::warn("calibration: cannot publish the status of axis id {}", axis_id);
}

void CalibrationService::handle(const ve::dds::CalibrationCommand& c) {
  std::lock_guard<std::mutex> lock(mutex_);
  const std::uint32_t id = c.axis_id();
  const std::uint64_t req = c.request_id();
  const std::string by = c.requested_by().empty() ? std::string("?") : c.requested_by();
  switch (c.command()) {
    case ve::dds::CALIBRATION_CMD_START: {
      const config::AxisConfig* axis = nullptr;
      for (const auto& a : machine_.axes)
        if (a.id == id) axis = &a;
      if (axis == nullptr) {
        spdlog::warn("calibration request {} from {}: no axis with id {}", req, by, id);
        publish(id, ve::dds::CALIBRATION_STATE_FAILED, req, 0.0,
                "failed: no axis with id " + std::to_string(id) + " in machine '" + machine_.name + "'");
        return;
      }
      if (axis->driver.kind != config::DriverConfig::Kind::sim) {
        spdlog::warn("calibration request {} from {}: axis '{}' uses the {} driver", req, by, axis->name,
                     driver_name(axis->driver.kind));
        publish(id, ve::dds::CALIBRATION_STATE_FAILED, req, 0.0,
                "failed: axis '" + axis->name + "' uses the " + driver_name(axis->driver.kind) +
                    " driver; calibration over DDS needs the simulator (its exact position is the reference). "
                    "On a real machine, record the calibration motion with a reference ruler and run "
                    "`virtual-encoder calibrate --log`");
        return;
      }
      if (running_.load()) {
        spdlog::warn("calibration request {} from {} for axis id {}: busy with request {} (axis id {})", req, by, id,
                     running_request_, running_axis_);
        publish(id, ve::dds::CALIBRATION_STATE_FAILED, req, 0.0,
                "failed: busy: calibration request " + std::to_string(running_request_) + " of axis id " +
                    std::to_string(running_axis_) + " is running (one at a time per process)");
        return;
      }
      if (worker_.joinable()) worker_.join();  // the previous one has finished
      Job job;
      job.axis = *axis;
      job.request_id = req;
      job.sweep_speed_mps = c.sweep_speed_mps();
      job.sweep_acceleration_mps2 = c.sweep_acceleration_mps2();
      abort_.store(false);
      running_.store(true);
      running_axis_ = id;
      running_request_ = req;
      spdlog::info("calibration request {} from {}: starting on axis '{}' (id {})", req, by, axis->name, id);
      worker_ = std::thread(&CalibrationService::work, this, std::move(job));
      return;
    }
    case ve::dds::CALIBRATION_CMD_ABORT:
      if (running_.load() && running_axis_ == id) {
        spdlog::info("calibration: abort of axis id {} requested by {} (request {})", id, by, req);
        abort_.store(true);
      } else {
        // No status: the axis' last status (e.g. a result) stays what late joiners see.
        spdlog::info("calibration: abort for axis id {} from {} ignored: no calibration of it is running", id, by);
      }
      return;
    case ve::dds::CALIBRATION_CMD_APPLY:
      publish(id, ve::dds::CALIBRATION_STATE_FAILED, req, 0.0,
              "failed: apply is not supported while running; a new calibration takes effect on the next start");
      return;
    default:
      publish(id, ve::dds::CALIBRATION_STATE_FAILED, req, 0.0,
              "failed: unknown command " + std::to_string(c.command()));
      return;
  }
}

void CalibrationService::work(Job job) {
  // Below the axis threads: on a small machine the calibration takes the idle CPU only.
  // This thread is started from a Fast DDS receive thread (the command's callback),
  // whose real-time priority (realtime.dds_thread_priority) it would otherwise inherit.
  set_normal_scheduling();
  setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), 10);
  const config::AxisConfig& axis = job.axis;
  const std::uint32_t id = axis.id;
  const std::uint64_t req = job.request_id;
  const auto started = std::chrono::steady_clock::now();
  auto finish = [&](std::uint32_t state, double progress, const std::string& message, const std::string& cal_id = {},
                    double residual_m = 0.0) {
    publish(id, state, req, progress, message, cal_id, residual_m);
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
    if (state == ve::dds::CALIBRATION_STATE_DONE)
      spdlog::info("calibration of axis '{}' ({:.1f} s): {}", axis.name, s, message);
    else
      spdlog::warn("calibration of axis '{}' ({:.1f} s): {}", axis.name, s, message);
    running_.store(false);
  };

  sim::CalibrationRunConfig run;
  if (job.sweep_speed_mps > 0) run.sweep_speed_mps = job.sweep_speed_mps;
  if (job.sweep_acceleration_mps2 > 0) run.sweep_acceleration_mps2 = job.sweep_acceleration_mps2;
  const std::string out = output_path(axis, machine_.source);

  publish(id, ve::dds::CALIBRATION_STATE_RUNNING, req, 0.0,
          "recording: simulated calibration motion (sweep " + std::to_string(run.sweep_speed_mps * 1e3) +
              " mm/s over the travel and back, then fast motion)");
  std::int64_t last_status = realtime_ns();
  double recorded = 0.0;
  auto progress = [&](double f) {
    recorded = f;
    const std::int64_t now = realtime_ns();
    if (now - last_status < kStatusPeriodNs) return;
    last_status = now;
    publish(id, ve::dds::CALIBRATION_STATE_RUNNING, req, kRecordingShare * f, "recording");
  };
  std::vector<core::ReferenceSegment> segments;
  std::string error;
  if (!sim::record_calibration_run(axis.motor, axis.driver.sim, run, segments, error, progress, &abort_)) {
    if (error == sim::kCalibrationRunCancelled) {
      finish(ve::dds::CALIBRATION_STATE_ABORTED, kRecordingShare * recorded,
             "aborted: during recording; nothing written");
    } else {
      finish(ve::dds::CALIBRATION_STATE_FAILED, kRecordingShare * recorded, "failed: recording: " + error);
    }
    return;
  }

  publish(id, ve::dds::CALIBRATION_STATE_RUNNING, req, kIdentifyingAt, "identifying");
  core::Calibration cal;
  core::IdentificationReport report;
  const bool identified =
      core::identify_with_reference(axis.motor, segments, core::IdentificationConfig{}, cal, report, error);
  segments.clear();
  segments.shrink_to_fit();
  if (abort_.load()) {
    finish(ve::dds::CALIBRATION_STATE_ABORTED, kIdentifyingAt, "aborted: during identification; nothing written");
    return;
  }
  if (!identified) {
    finish(ve::dds::CALIBRATION_STATE_FAILED, kIdentifyingAt, "failed: identification: " + error);
    return;
  }
  config::stamp_calibration(cal);
  char figures[256];
  std::snprintf(figures, sizeof figures, "hall delay %.1f us, table residual %.2f mV, position residual %.2f um",
                report.hall_delay_s * 1e6, report.table_residual_mv, report.position_residual_um);
  const double residual_m = report.position_residual_um * 1e-6;
  if (!report.good) {
    std::string why;
    for (const auto& p : report.problems) why += (why.empty() ? "" : "; ") + p;
    finish(ve::dds::CALIBRATION_STATE_FAILED, kIdentifyingAt,
           "failed: verdict poor (" + why + "); " + figures + "; calibration " + cal.info.id + " not written",
           cal.info.id, residual_m);
    return;
  }

  publish(id, ve::dds::CALIBRATION_STATE_RUNNING, req, kWritingAt, "writing " + out, cal.info.id, residual_m);
  // Last point of no return: an abort up to here leaves the previous file as it was.
  if (abort_.load()) {
    finish(ve::dds::CALIBRATION_STATE_ABORTED, kWritingAt, "aborted: before writing; nothing written");
    return;
  }
  std::error_code ec;
  const auto parent = std::filesystem::path(out).parent_path();
  if (!parent.empty()) std::filesystem::create_directories(parent, ec);
  if (ec || !config::write_calibration_file_atomic(out, cal, error)) {
    finish(ve::dds::CALIBRATION_STATE_FAILED, kWritingAt,
           "failed: cannot write " + out + ": " + (ec ? ec.message() : error), cal.info.id, residual_m);
    return;
  }
  const std::string report_path = out + ".report.txt";
  std::string report_note = "report " + report_path;
  std::string plot_error;
  const auto plots = write_calibration_plots(out, cal, report, plot_error);
  if (!plot_error.empty()) spdlog::warn("calibration over DDS: cannot write a plot: {}", plot_error);
  if (!write_text_file_atomic(report_path, format_identification_report(axis, cal, report, plots), error))
    report_note = "report not written: " + error;
  else if (!plots.empty())
    report_note += " and " + std::to_string(plots.size()) + " plots beside it";
  finish(ve::dds::CALIBRATION_STATE_DONE, 1.0,
         "done: verdict good; calibration " + cal.info.id + "; " + figures + "; written to " + out + " (" + report_note +
             "); takes effect on the next start",
         cal.info.id, residual_m);
}

}  // namespace ve::app
