// Wiring of one configured axis: its sensor source, its calibration (or the
// nominal table) and its estimation pipeline. Built once at start-up; all
// allocation happens here, none in the sample loop.
#pragma once

#include <memory>
#include <string>

#include "VirtualEncoder.h"
#include "config/machine_config.hpp"
#include "core/hall_table.hpp"
#include "core/pipeline.hpp"
#include "source.hpp"

namespace ve::app {

struct AxisSetup {
  config::AxisConfig config;
  core::Calibration calibration;  ///< info.id empty: nominal table
  bool calibrated = false;
  std::unique_ptr<drivers::SensorSource> source;
  std::unique_ptr<core::AxisPipeline> pipeline;
};

enum class SourceTiming { as_configured, as_fast_as_possible };

/// Loads the calibration named by the axis config (or the nominal table when it
/// names none) and checks it belongs to this motor. Returns false with every
/// problem in `error` (one per line, file:line:column first).
bool load_axis_calibration(const config::AxisConfig& axis, core::Calibration& out, bool& calibrated,
                           std::string& error);

/// The sensor source the axis config names.
/// `error` about axis `name`, starting with "axis 'NAME': " once (the drivers' own
/// messages already name their axis; others do not).
std::string axis_error(const std::string& name, const std::string& error);

std::unique_ptr<drivers::SensorSource> make_source(const config::AxisConfig& axis, SourceTiming timing,
                                                   std::string& error);

/// `kept_position_m`: signature homing, the position kept at the last clean shutdown
/// (the axis starts homed there; its first motion checks it), or null.
core::PipelineConfig pipeline_config(const config::AxisConfig& axis, const core::Calibration& calibration,
                                     bool calibrated, const double* kept_position_m = nullptr);

/// Everything for one axis; nullptr-free on success.
bool build_axis(const config::AxisConfig& axis, SourceTiming timing, AxisSetup& out, std::string& error);

/// Encoder-equivalent output: SI estimate -> DDS sample with counts.
void fill_state(const core::EncoderEstimate& est, const config::AxisConfig& axis, std::uint64_t sequence,
                ve::dds::EncoderState& out);

ve::dds::AxisDescription describe_axis(const AxisSetup& axis, const config::MachineConfig& machine);

}  // namespace ve::app
