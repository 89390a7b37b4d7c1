// The realistic simulated machines (config/machines/sim-realistic*.yaml),
// calibrated once per test binary from a simulated calibration run.
#pragma once

#include <gtest/gtest.h>

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "config/loader.hpp"
#include "core/identification.hpp"
#include "core/pipeline.hpp"
#include "sim/calibration_run.hpp"

namespace ve::test {

struct Realistic {
  ve::config::AxisConfig axis;
  ve::core::Calibration cal;
  ve::core::IdentificationReport report;
};

inline const Realistic& realistic(const std::string& machine_file) {
  static std::map<std::string, Realistic> cache;
  auto it = cache.find(machine_file);
  if (it != cache.end()) return it->second;
  Realistic r;
  const auto loaded = ve::config::load_machine_file(std::string(VE_SOURCE_DIR) + "/config/machines/" + machine_file);
  EXPECT_TRUE(loaded.ok()) << ve::config::to_string(loaded.errors);
  r.axis = loaded.config.axes.at(0);
  std::vector<ve::core::ReferenceSegment> segments;
  std::string error;
  EXPECT_TRUE(ve::sim::record_calibration_run(r.axis.motor, r.axis.driver.sim, {}, segments, error)) << error;
  EXPECT_TRUE(ve::core::identify_with_reference(r.axis.motor, segments, {}, r.cal, r.report, error)) << error;
  return cache.emplace(machine_file, std::move(r)).first->second;
}

/// The estimator of a realistic machine on its calibration, started at `start_m`.
inline ve::core::AxisPipeline calibrated_pipeline(const Realistic& r, double start_m) {
  ve::core::PipelineConfig pc;
  pc.motor = r.axis.motor;
  pc.sensors = r.cal.model;
  pc.calibrated = true;
  pc.start_position_m = start_m;
  return ve::core::AxisPipeline(pc, r.cal.table);
}

}  // namespace ve::test
