// The estimator's tuning as shipped: the motor file template's filter section, which
// the population's motors are given with their data sheets (not a property of the motor).
#pragma once

#include <gtest/gtest.h>

#include <string>

#include "config/loader.hpp"
#include "core/motor.hpp"

namespace ve::test {

inline core::FilterConfig shipped_tuning() {
  const auto loaded = config::load_machine_file(std::string(VE_SOURCE_DIR) + "/config/machines/sim.yaml");
  EXPECT_TRUE(loaded.ok()) << config::to_string(loaded.errors);
  return loaded.config.axes.at(0).motor.filter;
}

}  // namespace ve::test
