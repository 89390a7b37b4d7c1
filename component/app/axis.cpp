#include "axis.hpp"

#include <algorithm>
#include <cmath>

#include "config/calibration_file.hpp"
#include "replay/replay_source.hpp"
#include "sim/sim_source.hpp"
#include "socketcan/socketcan_source.hpp"  // issue 6

namespace ve::app {

bool load_axis_calibration(const config::AxisConfig& axis, core::Calibration& out, bool& calibrated,
                           std::string& error) {
  if (axis.calibration_file.empty()) {
    out = core::Calibration{};
    out.info.motor = axis.motor.name;
    out.info.hall_count = axis.motor.hall.count;
    out.info.magnet_pitch_m = axis.motor.magnet_pitch_m;
    out.info.method = "nominal";
    out.table = core::nominal_hall_table(axis.motor);
    calibrated = false;
    return true;
  }
  auto loaded = config::load_calibration_file(axis.calibration_file, axis.motor);
  if (!loaded.ok()) {
    error.clear();
    for (const auto& e : loaded.errors) error += e.to_string() + "\n";
    return false;
  }
  out = std::move(loaded.calibration);
  calibrated = true;
  return true;
}

std::string axis_error(const std::string& name, const std::string& error) {
  const std::string prefix = "axis '" + name + "': ";
  return error.rfind(prefix, 0) == 0 ? error : prefix + error;
}

std::unique_ptr<drivers::SensorSource> make_source(const config::AxisConfig& axis, SourceTiming timing,
                                                   std::string& error) {
  switch (axis.driver.kind) {
    case config::DriverConfig::Kind::sim: {
      sim::SimConfig cfg = axis.driver.sim;
      if (timing == SourceTiming::as_fast_as_possible) cfg.realtime = false;
      auto source = std::make_unique<sim::SimSource>(axis.motor, cfg);
      if (!source->ok()) {
        error = "axis '" + axis.name + "': " + source->last_error();
        return nullptr;
      }
      return source;
    }
    case config::DriverConfig::Kind::replay: {
      auto source = std::make_unique<replay::ReplaySource>(
          axis.driver.replay_path, axis.driver.replay_realtime && timing == SourceTiming::as_configured);
      if (!source->ok()) {
        error = source->last_error();
        return nullptr;
      }
      if (source->meta().hall_count != axis.motor.hall.count) {
        error = axis.driver.replay_path + ": the log has " + std::to_string(source->meta().hall_count) +
                " Hall columns but motor '" + axis.motor.name + "' has " + std::to_string(axis.motor.hall.count) +
                " sensors";
        return nullptr;
      }
      return source;
    }
    // ---- socketcan driver (issue 6) ----
    case config::DriverConfig::Kind::socketcan: {
      socketcan::SocketCanOptions opt;
      opt.interface = axis.driver.socketcan.interface;
      opt.layout = axis.driver.socketcan.layout;
      opt.timeout_ms = axis.driver.socketcan.timeout_ms;
      auto source = std::make_unique<socketcan::SocketCanSource>(std::move(opt));
      if (!source->ok()) {
        error = "axis '" + axis.name + "': " + source->last_error();
        return nullptr;
      }
      return source;
    }
    // ---- end socketcan ----
  }
  error = "axis '" + axis.name + "': unknown driver";
  return nullptr;
}

core::PipelineConfig pipeline_config(const config::AxisConfig& axis, const core::Calibration& calibration,
                                     bool calibrated, const double* kept_position_m) {
  core::PipelineConfig p;
  p.motor = axis.motor;
  p.sensors = calibration.model;
  p.calibrated = calibrated;
  p.start_position_known = axis.homing.mode == config::HomingConfig::Mode::startup_position;
  p.start_position_m = axis.homing.position_m;
  if (axis.homing.mode == config::HomingConfig::Mode::signature) {
    p.signature_homing = calibrated;
    p.start_position_known = kept_position_m != nullptr;
    if (kept_position_m) p.start_position_m = *kept_position_m;
  }
  return p;
}

bool build_axis(const config::AxisConfig& axis, SourceTiming timing, AxisSetup& out, std::string& error) {
  out.config = axis;
  if (!load_axis_calibration(axis, out.calibration, out.calibrated, error)) return false;
  out.source = make_source(axis, timing, error);
  if (!out.source) return false;
  out.pipeline = std::make_unique<core::AxisPipeline>(
      pipeline_config(axis, out.calibration, out.calibrated),
                                                        out.calibration.table);
  return true;
}

void fill_state(const core::EncoderEstimate& est, const config::AxisConfig& axis, std::uint64_t sequence,
                ve::dds::EncoderState& out) {
  const double scale = axis.output.direction * axis.output.counts_per_m;
  out.axis_id(axis.id);
  out.status(est.status);
  out.sequence_number(sequence);
  out.sample_time_ns(est.t_ns);
  out.position_counts(std::llround(est.position_m * scale) + axis.output.preset_counts);
  out.velocity_counts_per_s(std::llround(est.velocity_mps * scale));
  out.position_m(est.position_m);
  out.velocity_mps(est.velocity_mps);
  out.acceleration_mps2(est.acceleration_mps2);
  out.position_std_m(est.position_std_m);
  out.velocity_std_mps(est.velocity_std_mps);
}

ve::dds::AxisDescription describe_axis(const AxisSetup& axis, const config::MachineConfig& machine) {
  ve::dds::AxisDescription d;
  d.axis_id(axis.config.id);
  d.hall_count(static_cast<std::uint32_t>(axis.config.motor.hall.count));
  d.counts_per_m(axis.config.output.counts_per_m);
  // The rate of this axis' ve/encoder_state stream (sensor rate / output.publish_divider).
  d.sample_rate_hz(axis.config.motor.sample_rate_hz / std::max(1, axis.config.output.publish_divider));
  d.deadline_ms(machine.dds.deadline_ms);
  d.direction(axis.config.output.direction);
  d.name(axis.config.name);
  d.machine(machine.name);
  d.motor(axis.config.motor.name);
  d.driver(axis.source ? axis.source->describe() : std::string("-"));
  d.calibration_id(axis.calibrated ? axis.calibration.info.id : std::string());
  d.software_version(VE_VERSION);
  return d;
}

}  // namespace ve::app
