// `virtual-encoder check` prints and counts every problem of every axis: each problem
// of an axis' calibration file, and its driver's problem too when the calibration has
// problems as well (an axis with several problems once counted as one, and a refused
// calibration hid the driver's problem).
#include <gtest/gtest.h>

#include <stdlib.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "process.hpp"
#include "speed.hpp"
#include "temp_dir.hpp"
#include "test_domain.hpp"

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

/// A scratch folder, removed with the test.
struct ScratchDir : ve::test::TempDir {
  ScratchDir() : ve::test::TempDir("ve_it_check") {}
};

std::string source(const std::string& rel) { return std::string(VE_SOURCE_DIR) + "/" + rel; }

void write(const fs::path& p, const std::string& text) { std::ofstream(p) << text; }

/// Replaces the one occurrence of `from` in `text`.
void replace_once(std::string& text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  ASSERT_NE(at, std::string::npos) << from;
  text.replace(at, from.size(), to);
}

/// Replaces the value on the one line of `text` that starts with `key` (whatever the
/// shipped file holds there: a re-made calibration changes its numbers).
void replace_value(std::string& text, const std::string& key, const std::string& value) {
  const auto at = text.find(key);
  ASSERT_NE(at, std::string::npos) << key;
  ASSERT_EQ(text.find(key, at + 1), std::string::npos) << key << " is on more than one line";
  const auto end = text.find('\n', at + key.size());
  ASSERT_NE(end, std::string::npos) << key;
  text.replace(at + key.size(), end - at - key.size(), value);
}

/// The shipped calibration with four problems, each on its own line of the file.
void write_bad_calibration(const fs::path& p) {
  std::ifstream in(source("config/calibration/sim-realistic-x.cal.yaml"));
  std::stringstream s;
  s << in.rdbuf();
  std::string text = s.str();
  replace_once(text, "\nhall_count: 4\n", "\nhall_count: 3\n");               // layout, and the table's rows
  replace_value(text, "\n  accel_scale: ", "-1");                               // out of range
  replace_once(text, "\n  temperature_c: 25.000 ", "\n  temperature_c: abc ");    // not a number
  write(p, text);
}

/// A machine of one axis whose CAN interface does not exist: its driver cannot start,
/// on any host.
void write_unstartable_machine(const fs::path& p, const std::string& machine, const std::string& axis) {
  write(p,
        "machine: " + machine + "\n"
        "axes:\n"
        "  - name: " + axis + "\n"
        "    motor: " + source("config/motors/sim-12mm.yaml") + "\n"
        "    driver:\n"
        "      type: socketcan\n"
        "      interface: ve-none0\n"
        "      layout: " + source("config/can/classic-4hall.yaml") + "\n");
}

struct CheckRun {
  int code = -1;
  std::vector<std::string> lines;
  std::string text;
};

CheckRun check(const fs::path& machine, const fs::path& log) {
  ve::test::ChildProcess p({VE_BINARY, "check", "--config", machine.string()}, log.string());
  CheckRun r;
  EXPECT_TRUE(p.started());
  r.code = p.wait_exit(ve::test::patience(60s));
  r.text = p.log();
  std::istringstream in(r.text);
  for (std::string line; std::getline(in, line);) r.lines.push_back(line);
  return r;
}

std::size_t lines_starting(const CheckRun& r, const std::string& prefix) {
  std::size_t n = 0;
  for (const auto& l : r.lines) n += l.rfind(prefix, 0) == 0;
  return n;
}

// Two axes: x has a calibration with four problems; y has the same calibration and a
// CAN interface that does not exist (its driver cannot start, on any host). Nine
// problems: 4 + 4 + 1, each printed on its own line, and counted.
TEST(Check, CountsAndPrintsEveryProblemOfEveryAxis) {
  ScratchDir dir;
  ASSERT_FALSE(dir.path.empty());
  const fs::path cal = dir.path / "bad.cal.yaml";
  write_bad_calibration(cal);
  const fs::path machine = dir.path / "machine.yaml";
  write(machine,
        "machine: several-problems\n"
        "axes:\n"
        "  - name: x\n"
        "    motor: " + source("config/motors/sim-12mm.yaml") + "\n"
        "    calibration: " + cal.string() + "\n"
        "    driver: {type: sim}\n"
        "  - name: y\n"
        "    motor: " + source("config/motors/sim-12mm.yaml") + "\n"
        "    calibration: " + cal.string() + "\n"
        "    driver:\n"
        "      type: socketcan\n"
        "      interface: ve-none0\n"
        "      layout: " + source("config/can/classic-4hall.yaml") + "\n");
  const CheckRun r = check(machine, dir.path / "check.log");
  EXPECT_EQ(r.code, 1) << r.text;
  EXPECT_EQ(lines_starting(r, cal.string() + ":"), 8u) << r.text;
  EXPECT_EQ(lines_starting(r, machine.string() + ": axis 'y': "), 1u) << r.text;
  // The driver's message names its axis once.
  EXPECT_EQ(r.text.find("axis 'y': axis 'y'"), std::string::npos) << r.text;
  EXPECT_NE(r.text.find("\n9 problem(s)\n"), std::string::npos) << r.text;
  for (const char* field : {"hall_count", "sensor_model.accel_scale", "sensor_model.temperature_c", "table.sensors"})
    EXPECT_NE(r.text.find(field), std::string::npos) << field << " not reported:\n" << r.text;
}

// One axis with one problem is still one problem, and a clean machine none.
TEST(Check, OneProblemIsOneAndACleanMachineHasNone) {
  ScratchDir dir;
  ASSERT_FALSE(dir.path.empty());
  const fs::path machine = dir.path / "machine.yaml";
  write_unstartable_machine(machine, "one-problem", "x");
  CheckRun r = check(machine, dir.path / "check.log");
  EXPECT_EQ(r.code, 1) << r.text;
  EXPECT_EQ(lines_starting(r, machine.string() + ": axis 'x': "), 1u) << r.text;
  EXPECT_NE(r.text.find("\n1 problem(s)\n"), std::string::npos) << r.text;

  r = check(source("config/machines/sim-realistic.yaml"), dir.path / "check-clean.log");
  EXPECT_EQ(r.code, 0) << r.text;
  EXPECT_EQ(r.text.find("problem(s)"), std::string::npos) << r.text;
  EXPECT_NE(r.text.find("OK: machine"), std::string::npos) << r.text;
}


// `record` and `run` name the axis of a driver that cannot start once: the driver's
// message already starts with "axis 'NAME': " (they printed "axis 'y': axis 'y': ...").
TEST(DriverError, RecordAndRunNameTheAxisOnce) {
  ScratchDir dir;
  ASSERT_FALSE(dir.path.empty());
  const fs::path machine = dir.path / "machine.yaml";
  write_unstartable_machine(machine, "no-interface", "y");
  const std::vector<std::vector<std::string>> commands = {
      {VE_BINARY, "record", "--config", machine.string(), "--out", (dir.path / "rec.csv").string(), "--duration", "1"},
      {VE_BINARY, "run", "--config", machine.string(), "--domain", std::to_string(ve::test::dds_domain()), "--duration",
       "1"}};
  for (const auto& argv : commands) {
    ve::test::ChildProcess p(argv, (dir.path / (argv[1] + ".log")).string());
    ASSERT_TRUE(p.started());
    EXPECT_EQ(p.wait_exit(ve::test::patience(60s)), 2) << argv[1] << ":\n" << p.log();
    const std::string log = p.log();
    EXPECT_NE(log.find("axis 'y': "), std::string::npos) << argv[1] << ":\n" << log;
    EXPECT_EQ(log.find("axis 'y': axis 'y'"), std::string::npos) << argv[1] << ":\n" << log;
  }
}

}  // namespace
