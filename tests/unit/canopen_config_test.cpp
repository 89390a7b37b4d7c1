// The machine file's `canopen:` block: loaded into CanopenConfig, and every bad value
// reported with file, line and field (what `virtual-encoder check` prints).
#include <gtest/gtest.h>

#include <string>

#include "config/loader.hpp"
#include "../integration/temp_dir.hpp"

using namespace ve;

namespace {

std::string machine(const std::string& x_canopen, const std::string& y_canopen = "") {
  std::string m = "machine: co\naxes:\n";
  m += "  - name: x\n    motor: " VE_SOURCE_DIR "/config/motors/sim-12mm.yaml\n" + x_canopen;
  m += "  - name: y\n    motor: " VE_SOURCE_DIR "/config/motors/sim-12mm.yaml\n" + y_canopen;
  return m;
}

config::LoadResult load(const std::string& text, std::string& file) {
  static ve::test::TempDir dir("ve_canopen_config");
  file = dir.write("m.yaml", text);
  return config::load_machine_file(file);
}

/// The one error's text, which must name the file, `line` and `field`.
void expect_error(const std::string& text, int line, const std::string& field, const std::string& words) {
  std::string file;
  const auto r = load(text, file);
  ASSERT_FALSE(r.ok()) << text;
  const std::string all = config::to_string(r.errors);
  EXPECT_NE(all.find(file + ":" + std::to_string(line) + ":"), std::string::npos) << all;
  EXPECT_NE(all.find(field), std::string::npos) << all;
  EXPECT_NE(all.find(words), std::string::npos) << all;
}

}  // namespace

TEST(CanopenConfig, BlockLoads) {
  std::string file;
  const auto r = load(machine("    canopen:\n      interface: vcan0\n      node_id: 5\n      measuring_step_nm: 100\n"
                              "      transmission_type: 1\n      heartbeat_ms: 50\n      tpdo_mapping: [position, speed]\n",
                              "    canopen: {interface: vcan0, node_id: 6, transmission_type: 254, cyclic_timer_ms: 10}\n"),
                      file);
  ASSERT_TRUE(r.ok()) << config::to_string(r.errors);
  const auto& x = r.config.axes[0].canopen;
  EXPECT_TRUE(x.enabled);
  EXPECT_EQ(x.interface, "vcan0");
  EXPECT_EQ(x.node_id, 5);
  EXPECT_EQ(x.measuring_step_nm, 100u);
  EXPECT_EQ(x.transmission_type, 1);
  EXPECT_EQ(x.heartbeat_ms, 50);
  EXPECT_TRUE(x.map_speed);
  EXPECT_FALSE(x.speed_first);
  EXPECT_EQ(r.config.axes[1].canopen.cyclic_timer_ms, 10);
  const auto plain = load(machine(""), file);
  ASSERT_TRUE(plain.ok());
  EXPECT_FALSE(plain.config.axes[0].canopen.enabled);
}

TEST(CanopenConfig, BadValuesNameFileLineAndField) {
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 128\n"), 7, "axes[0].canopen.node_id", "128");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 0\n"), 7, "axes[0].canopen.node_id", "[1, 127]");
  expect_error(machine("    canopen:\n      node_id: 3\n"), 6, "axes[0].canopen.interface", "missing required key");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 3\n      measuring_step_nm: 0\n"), 8,
               "axes[0].canopen.measuring_step_nm", "nm");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 3\n      cyclic_timer_ms: 70000\n"), 8,
               "axes[0].canopen.cyclic_timer_ms", "65535");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 3\n      transmission_type: 241\n"), 8,
               "axes[0].canopen.transmission_type", "241");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 3\n      transmission_type: 254\n"), 8,
               "axes[0].canopen.transmission_type", "give cyclic_timer_ms a period > 0");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 3\n      tpdo_mapping: [position, angle]\n"),
               8, "axes[0].canopen.tpdo_mapping", "'angle'");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 3\n      bitrate_kbps: 300\n"), 8,
               "axes[0].canopen.bitrate_kbps", "300");
  expect_error(machine("    canopen:\n      interface: vcan0\n      node_id: 3\n      nodeid: 4\n"), 8, "nodeid",
               "unknown key");
}

TEST(CanopenConfig, DuplicateNodeIdOnOneInterfaceIsRefused) {
  expect_error(machine("    canopen: {interface: vcan0, node_id: 9}\n", "    canopen: {interface: vcan0, node_id: 9}\n"), 8,
               "axes[1].canopen.node_id", "duplicate node id 9 on interface 'vcan0' (also axes[0], axis 'x')");
  std::string file;
  const auto dup = load(machine("    canopen: {interface: vcan0, node_id: 9}\n", "    canopen: {interface: vcan0, node_id: 9}\n"), file);
  EXPECT_EQ(dup.errors.size(), 1u) << config::to_string(dup.errors);
  // The same id on another interface is another bus.
  const auto r = load(machine("    canopen: {interface: vcan0, node_id: 9}\n", "    canopen: {interface: vcan1, node_id: 9}\n"), file);
  EXPECT_TRUE(r.ok()) << config::to_string(r.errors);
}
