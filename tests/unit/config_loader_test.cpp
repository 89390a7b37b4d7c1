// Machine/motor file loading: every error must carry the right file, line,
// column and field, because that is what a user fixing a config file sees.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/stat.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "config/embedded.hpp"
#include "config/loader.hpp"
#include "../integration/temp_dir.hpp"

namespace ve::config {
namespace {

namespace fs = std::filesystem;

/// A scratch folder, removed with the test (tests/integration/temp_dir.hpp).
struct TempDir : ve::test::TempDir {
  TempDir() : ve::test::TempDir("ve_config_test") {}
};

constexpr const char* kMotor =
    "motor: test-motor\n"
    "magnet_pitch_m: 0.012\n"
    "travel_m: 1.0\n";

const ConfigError* find_field(const LoadResult& r, const std::string& field) {
  for (const auto& e : r.errors)
    if (e.field == field) return &e;
  return nullptr;
}

/// Asserts an error at exactly file:line:col for `field`, whose message contains `text`.
void expect_error(const LoadResult& r, const std::string& file, int line, int column, const std::string& field,
                  const std::string& text) {
  const ConfigError* e = find_field(r, field);
  ASSERT_NE(e, nullptr) << "no error for field '" << field << "'; errors:\n" << to_string(r.errors);
  EXPECT_EQ(e->file, file);
  EXPECT_EQ(e->line, line) << e->to_string();
  EXPECT_EQ(e->column, column) << e->to_string();
  EXPECT_NE(e->message.find(text), std::string::npos) << e->to_string();
}

TEST(ConfigError, FormatsLikeACompiler) {
  ConfigError e{"m.yaml", 3, 7, "axes[0].name", "must not be empty"};
  EXPECT_EQ(e.to_string(), "m.yaml:3:7: axes[0].name: must not be empty");
  ConfigError unreadable{"m.yaml", 0, 0, "", "cannot read machine file: No such file or directory"};
  EXPECT_EQ(unreadable.to_string(), "m.yaml: cannot read machine file: No such file or directory");
}

TEST(ConfigLoader, MinimalMachineUsesDefaults) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"
                              "  - name: x\n"
                              "    motor: m.yaml\n"
                              "  - name: y\n"
                              "    motor: m.yaml\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  ASSERT_EQ(r.config.axes.size(), 2u);
  EXPECT_EQ(r.config.source, path);
  EXPECT_EQ(r.config.axes[0].id, 1u);
  EXPECT_EQ(r.config.axes[1].id, 2u);
  EXPECT_EQ(r.config.axes[1].motor.name, "test-motor");
  EXPECT_EQ(r.config.axes[1].motor_file, dir.file("m.yaml"));
  EXPECT_EQ(r.config.dds.domain, 0);
  EXPECT_EQ(r.config.axes[0].driver.kind, DriverConfig::Kind::sim);
  EXPECT_EQ(r.config.axes[0].homing.mode, HomingConfig::Mode::startup_position);
}

TEST(ConfigLoader, MissingKeyPointsAtParentMapping) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "machine: t\n"     // 1
                              "axes:\n"          // 2
                              "  - name: x\n"    // 3  <- the axis mapping starts at "name"
                              "    id: 3\n");    // 4
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  expect_error(r, path, 3, 5, "axes[0].motor", "missing required key 'motor'");

  const auto no_axes = dir.write("empty.yaml", "machine: t\n");
  expect_error(load_machine_file(no_axes), no_axes, 1, 1, "axes", "missing required key 'axes'");
}

TEST(ConfigLoader, WrongTypePointsAtValue) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"                     // 1
                              "  - name: x\n"               // 2
                              "    motor: m.yaml\n"         // 3
                              "    output:\n"               // 4
                              "      counts_per_m: fast\n"  // 5
                              "      direction: \"1\"\n"    // 6
                              "    driver: sim\n"           // 7
                              "    homing: [1, 2]\n");      // 8
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 4u) << to_string(r.errors);
  expect_error(r, path, 5, 21, "axes[0].output.counts_per_m", "expected a number, got 'fast'");
  expect_error(r, path, 6, 18, "axes[0].output.direction", "expected an integer, got the string \"1\"");
  expect_error(r, path, 7, 13, "axes[0].driver", "expected a mapping");
  expect_error(r, path, 8, 13, "axes[0].homing", "expected a mapping");
}

TEST(ConfigLoader, UnknownKeyIsAnErrorWithSuggestion) {
  TempDir dir;
  const auto motor = dir.write("m.yaml",
                               "motor: test-motor\n"      // 1
                               "magnet_pich_m: 0.012\n"   // 2
                               "hall:\n"                  // 3
                               "  cont: 4\n"              // 4
                               "  colour: blue\n");       // 5
  const auto path = dir.write("machine.yaml",
                              "axes:\n"
                              "  - name: x\n"
                              "    motor: m.yaml\n"
                              "    output: {counts_per_m: 1.0e7, direktion: 1}\n");  // 4
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 4u) << to_string(r.errors);
  expect_error(r, motor, 2, 1, "magnet_pich_m", "did you mean 'magnet_pitch_m'?");
  expect_error(r, motor, 4, 3, "hall.cont", "did you mean 'count'?");
  expect_error(r, motor, 5, 3, "hall.colour", "unknown key 'colour' (valid keys here:");
  expect_error(r, path, 4, 35, "axes[0].output.direktion", "did you mean 'direction'?");
}

TEST(ConfigLoader, UnitSuffixOmittedSuggestsKeyWithUnit) {
  TempDir dir;
  const auto motor = dir.write("m.yaml", "motor: a\ntravel: 1.0\n");
  const auto path = dir.write("machine.yaml", "axes: [{name: x, motor: m.yaml}]\n");
  expect_error(load_machine_file(path), motor, 2, 1, "travel", "did you mean 'travel_m'?");
}

TEST(ConfigLoader, OutOfRangePointsAtValueAndNamesRange) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "dds:\n"                           // 1
                              "  domain: 300\n"                  // 2
                              "  deadline_ms: 2.5\n"             // 3
                              "axes:\n"                          // 4
                              "  - name: this-name-is-too-long\n"// 5
                              "    motor: m.yaml\n"              // 6
                              "    output: {direction: 2}\n"     // 7
                              "    homing: {position_m: 1.5}\n");// 8
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 5u) << to_string(r.errors);
  expect_error(r, path, 2, 11, "dds.domain", "300 out of range [0, 232]");
  expect_error(r, path, 3, 16, "dds.deadline_ms", "whole number of milliseconds");
  expect_error(r, path, 5, 11, "axes[0].name", "1 to 15 characters");
  expect_error(r, path, 7, 25, "axes[0].output.direction", "must be 1 or -1, got 2");
  expect_error(r, path, 8, 26, "axes[0].homing.position_m", "1.5 out of range [0, 1] m: outside the motor's travel");
}

TEST(ConfigLoader, MalformedYamlReportsParserPosition) {
  TempDir dir;
  const auto path = dir.write("machine.yaml",
                              "machine: t\n"        // 1
                              "axes:\n"             // 2
                              "  - name: x: y\n");  // 3  <- second ':' at column 12
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  EXPECT_EQ(r.errors[0].file, path);
  EXPECT_EQ(r.errors[0].line, 3);
  EXPECT_EQ(r.errors[0].column, 12);
  EXPECT_EQ(r.errors[0].field, "");
  EXPECT_EQ(r.errors[0].message, "malformed YAML: illegal map value");

  // An unclosed flow sequence is noticed where the next key starts.
  const auto unclosed = dir.write("unclosed.yaml",
                                  "machine: t\n"          // 1
                                  "axes: [1, 2\n"         // 2
                                  "dds: {domain: 0}\n");  // 3
  const LoadResult u = load_machine_file(unclosed);
  ASSERT_EQ(u.errors.size(), 1u) << to_string(u.errors);
  EXPECT_EQ(u.errors[0].to_string(), unclosed + ":3:4: malformed YAML: end of sequence flow not found");
}

TEST(ConfigLoader, ErrorInMotorFileNamesTheMotorFile) {
  TempDir dir;
  const auto motor = dir.write("motors/m.yaml",
                               "motor: test-motor\n"          // 1
                               "hall:\n"                      // 2
                               "  count: 9\n"                 // 3
                               "adc: {bits: 12, max_v: -1}\n" // 4
                               "sample_rate_hz: 10\n");       // 5
  const auto path = dir.write("machines/machine.yaml",
                              "axes:\n"
                              "  - name: x\n"
                              "    motor: ../motors/m.yaml\n");
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 3u) << to_string(r.errors);
  expect_error(r, motor, 3, 10, "hall.count", "9 out of range [1, 8] sensors");
  expect_error(r, motor, 4, 24, "adc.max_v", "must be greater than min_v");
  expect_error(r, motor, 5, 17, "sample_rate_hz", "10 out of range [100, 100000] Hz");
}

TEST(ConfigLoader, AllErrorsAreReportedInPositionOrder) {
  TempDir dir;
  const auto motor = dir.write("m.yaml", "motor: a\nhall: {offsets_m: [0, 0.001]}\n");
  const auto path = dir.write("machine.yaml",
                              "machine: t\n"                      // 1
                              "dds: {domain: -1, colour: red}\n"  // 2
                              "axes:\n"                           // 3
                              "  - name: x\n"                     // 4
                              "    motor: m.yaml\n"               // 5
                              "    driver:\n"                     // 6
                              "      type: simulated\n"           // 7
                              "      profile: {min_m: 0.9, max_m: 0.1}\n"  // 8
                              "  - name: x\n"                     // 9
                              "    id: 1\n"                       // 10
                              "    motor: m.yaml\n");             // 11
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 7u) << to_string(r.errors);
  expect_error(r, path, 2, 15, "dds.domain", "-1 out of range [0, 232]");
  expect_error(r, path, 2, 19, "dds.colour", "unknown key 'colour'");
  expect_error(r, path, 7, 13, "axes[0].driver.type", "'simulated' is not one of sim | replay");
  expect_error(r, path, 8, 36, "axes[0].driver.profile.max_m", "min_m (0.9) must be less than max_m (0.1)");
  expect_error(r, path, 9, 11, "axes[1].name", "duplicate axis name 'x'");
  expect_error(r, path, 10, 9, "axes[1].id", "duplicate id 1");
  expect_error(r, motor, 2, 19, "hall.offsets_m", "has 2 entries but count is 4");
  // Machine file first, then the motor file, each in position order.
  for (std::size_t i = 1; i < r.errors.size(); ++i) {
    const auto& a = r.errors[i - 1];
    const auto& b = r.errors[i];
    if (a.file == b.file) {
      EXPECT_LE(std::pair(a.line, a.column), std::pair(b.line, b.column));
    }
  }
  EXPECT_EQ(r.errors.back().file, motor);
  // A start position of 0.5 is outside [0.9, 0.1]; not reported because min/max already are.
}

TEST(ConfigLoader, SharedBrokenMotorIsReportedOnce) {
  TempDir dir;
  const auto motor = dir.write("m.yaml", "motor: a\ntravel_m: 0\n");
  const auto path = dir.write("machine.yaml", "axes:\n  - {name: x, motor: m.yaml}\n  - {name: y, motor: m.yaml}\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  expect_error(r, motor, 2, 11, "travel_m", "0 out of range [0.001, 100] m");
}

TEST(ConfigLoader, UnreadableFiles) {
  TempDir dir;
  const auto missing = dir.file("nope.yaml");
  const LoadResult r = load_machine_file(missing);
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_EQ(r.errors[0].file, missing);
  EXPECT_EQ(r.errors[0].line, 0);
  EXPECT_NE(r.errors[0].message.find(std::strerror(ENOENT)), std::string::npos) << r.errors[0].to_string();

  const auto path = dir.write("machine.yaml",
                              "axes:\n"                                 // 1
                              "  - name: x\n"                           // 2
                              "    motor: gone.yaml\n"                  // 3
                              "    calibration: x.cal.yaml\n"           // 4
                              "dds: {profiles_file: profiles.xml}\n");  // 5
  const LoadResult r2 = load_machine_file(path);
  EXPECT_EQ(r2.errors.size(), 3u) << to_string(r2.errors);
  expect_error(r2, path, 3, 12, "axes[0].motor", std::string("cannot read motor file 'gone.yaml'"));
  expect_error(r2, path, 4, 18, "axes[0].calibration", std::strerror(ENOENT));
  expect_error(r2, path, 5, 22, "dds.profiles_file", "cannot read 'profiles.xml'");
}

TEST(ConfigLoader, CalibrationMayBeMissingWhenAboutToBeCreated) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"
                              "  - name: x\n"
                              "    motor: m.yaml\n"
                              "    calibration: cal/x.cal.yaml\n");
  EXPECT_FALSE(load_machine_file(path).ok());
  LoadOptions options;
  options.calibration_must_exist = false;
  const LoadResult r = load_machine_file(path, options);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  EXPECT_EQ(r.config.axes[0].calibration_file, dir.file("cal/x.cal.yaml"));
  // Present but unreadable (here: a directory) is still an error.
  std::filesystem::create_directories(dir.file("cal/x.cal.yaml"));
  expect_error(load_machine_file(path, options), path, 4, 18, "axes[0].calibration", "Is a directory");
}

TEST(ConfigLoader, ReferencedFilesResolveRelativeToMachineFile) {
  TempDir dir;
  dir.write("motors/m.yaml", kMotor);
  dir.write("calibration/x.cal.yaml", "format: virtual-encoder-calibration\n");
  dir.write("logs/run.csv", "t\n");
  dir.write("deploy/profiles.xml", "<profiles/>\n");
  const auto path = dir.write("machines/machine.yaml",
                              "dds: {profiles_file: ../deploy/profiles.xml}\n"
                              "axes:\n"
                              "  - name: x\n"
                              "    motor: ../motors/m.yaml\n"
                              "    calibration: ../calibration/x.cal.yaml\n"
                              "  - name: y\n"
                              "    motor: ../motors/m.yaml\n"
                              "    driver: {type: replay, log: ../logs/run.csv}\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  EXPECT_EQ(r.config.dds.profiles_file, dir.file("deploy/profiles.xml"));
  EXPECT_EQ(r.config.axes[0].motor_file, dir.file("motors/m.yaml"));
  EXPECT_EQ(r.config.axes[0].calibration_file, dir.file("calibration/x.cal.yaml"));
  EXPECT_EQ(r.config.axes[1].driver.kind, DriverConfig::Kind::replay);
  EXPECT_EQ(r.config.axes[1].driver.replay_path, dir.file("logs/run.csv"));
}

TEST(ConfigLoader, ReplayDriverNeedsLogAndRejectsSimKeys) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"                    // 1
                              "  - name: x\n"              // 2
                              "    motor: m.yaml\n"        // 3
                              "    driver:\n"              // 4
                              "      type: replay\n"       // 5
                              "      realtime: false\n"    // 6: pacing applies to replay too
                              "      noise_seed: 3\n");    // 7
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 2u) << to_string(r.errors);
  expect_error(r, path, 5, 7, "axes[0].driver.log", "missing required key 'log'");
  expect_error(r, path, 7, 7, "axes[0].driver.noise_seed", "only used with type: sim");
}

TEST(ConfigLoader, StatisticsTopicsAreCheckedByName) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "dds:\n"                                                       // 1
                              "  statistics: [HISTORY_LATENCY_TOPIC, LATENCY, DATA_COUNT_TOPIC]\n"  // 2
                              "axes: [{name: x, motor: m.yaml}]\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  EXPECT_EQ(r.errors[0].line, 2);
  EXPECT_EQ(r.errors[0].column, 39);
  EXPECT_NE(r.errors[0].message.find("'LATENCY' is not a Fast DDS statistics topic"), std::string::npos)
      << r.errors[0].message;
  EXPECT_EQ(r.config.dds.statistics, (std::vector<std::string>{"HISTORY_LATENCY_TOPIC", "DATA_COUNT_TOPIC"}));
}

TEST(ConfigLoader, SimulatorFaultsAreLoadedAndChecked) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"                                                              // 1
                              "  - name: x\n"                                                        // 2
                              "    motor: m.yaml\n"                                                  // 3
                              "    driver:\n"                                                        // 4
                              "      type: sim\n"                                                    // 5
                              "      faults:\n"                                                      // 6
                              "        - {kind: hall_stuck_high, sensor: 1, start_s: 2.0}\n"         // 7
                              "        - {kind: accel_noisy, start_s: 1.0}\n"                        // 8
                              "        - {kind: hall_noisy, sensor: 2, start_s: 3, end_s: 1}\n"      // 9
                              "        - {kind: no_samples, start_s: 1.5, end_s: 2.5}\n");           // 10
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 2u) << to_string(r.errors);
  EXPECT_EQ(r.errors[0].line, 8);
  EXPECT_NE(r.errors[0].message.find("'accel_noisy' is not one of"), std::string::npos) << r.errors[0].message;
  EXPECT_EQ(r.errors[1].line, 9);
  EXPECT_NE(r.errors[1].message.find("end_s (1) must be after start_s (3)"), std::string::npos) << r.errors[1].message;
  const auto& sim = r.config.axes.at(0).driver.sim;
  ASSERT_GE(sim.fault_count, 1);
  EXPECT_EQ(sim.faults[0].kind, sim::FaultConfig::Kind::hall_stuck_high);
  EXPECT_EQ(sim.faults[0].sensor, 1);
  EXPECT_DOUBLE_EQ(sim.faults[0].start_s, 2.0);
  // A silent node: a window, no sensor, no magnitude (their misuse: BadInputFiles).
  ASSERT_EQ(sim.fault_count, 4);
  const sim::FaultConfig& silent = sim.faults[3];
  EXPECT_EQ(silent.kind, sim::FaultConfig::Kind::no_samples);
  EXPECT_DOUBLE_EQ(silent.start_s, 1.5);
  EXPECT_DOUBLE_EQ(silent.end_s, 2.5);
}

TEST(ConfigLoader, DuplicateKeyIsAnError) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "machine: a\n"                  // 1
                              "machine: b\n"                  // 2
                              "axes: [{name: x, motor: m.yaml}]\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  expect_error(r, path, 2, 1, "machine", "duplicate key 'machine' (first given at line 1)");
}

TEST(ConfigLoader, ProfileMustStayInsideTravel) {
  TempDir dir;
  dir.write("m.yaml", "motor: short\ntravel_m: 0.3\n");
  const auto path = dir.write("machine.yaml",
                              "axes:\n"                                          // 1
                              "  - name: x\n"                                    // 2
                              "    motor: m.yaml\n"                              // 3
                              "    driver:\n"                                    // 4
                              "      profile: {start_m: 0.1, min_m: 0.05, max_m: 0.5}\n"  // 5
                              "    homing: {position_m: 0.2}\n");                // 6
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  expect_error(r, path, 5, 51, "axes[0].driver.profile.max_m", "out of range [0, 0.3] m: outside the motor's travel");
}

TEST(ConfigLoader, SimImperfectionsAndPointToPointLoad) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"
                              "  - name: x\n"
                              "    motor: m.yaml\n"
                              "    driver:\n"
                              "      profile:\n"
                              "        type: point_to_point\n"
                              "        max_velocity_mps: 1.5\n"
                              "        max_jerk_mps3: 300\n"
                              "        dwell_s: 0.25\n"
                              "      imperfections:\n"
                              "        field_third_harmonic: -0.03\n"
                              "        coil_field_v_per_mps2: 0.001\n"
                              "        accel_bias_random_walk_mps2_per_sqrt_s: 1.0e-4\n"
                              "        accel_delay_s: 250.0e-6\n"
                              "        frame_reaction_ratio: -0.02\n"
                              "        frame_vibration_mps2: 0.03\n"
                              "        frame_vibration_hz: 50\n"
                              "        frame_accelerometer: true\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const sim::SimConfig& s = r.config.axes[0].driver.sim;
  EXPECT_EQ(s.profile.kind, sim::MotionProfileConfig::Kind::point_to_point);
  EXPECT_EQ(s.profile.max_velocity_mps, 1.5);
  EXPECT_EQ(s.profile.max_jerk_mps3, 300.0);
  EXPECT_EQ(s.profile.dwell_s, 0.25);
  const sim::ImperfectionConfig& im = s.imperfections;
  EXPECT_EQ(im.field_third_harmonic, -0.03);
  EXPECT_EQ(im.coil_field_v_per_mps2, 0.001);
  EXPECT_EQ(im.accel_bias_random_walk_mps2_per_sqrt_s, 1.0e-4);
  EXPECT_EQ(im.accel_delay_s, 250.0e-6);
  EXPECT_EQ(im.frame_reaction_ratio, -0.02);
  EXPECT_EQ(im.frame_vibration_mps2, 0.03);
  EXPECT_EQ(im.frame_vibration_hz, 50.0);
  EXPECT_TRUE(im.frame_accelerometer);

  // Omitted: the defaults, which are "off" (and a 35 Hz frequency for when it is turned on).
  const auto plain = dir.write("plain.yaml", "axes: [{name: x, motor: m.yaml}]\n");
  const LoadResult d = load_machine_file(plain);
  ASSERT_TRUE(d.ok()) << to_string(d.errors);
  const sim::SimConfig& ds = d.config.axes[0].driver.sim;
  EXPECT_EQ(ds.profile.max_jerk_mps3, 250.0);
  EXPECT_EQ(ds.profile.dwell_s, 0.1);
  EXPECT_EQ(ds.imperfections.field_third_harmonic, 0.0);
  EXPECT_EQ(ds.imperfections.coil_field_v_per_mps2, 0.0);
  EXPECT_EQ(ds.imperfections.accel_bias_random_walk_mps2_per_sqrt_s, 0.0);
  EXPECT_EQ(ds.imperfections.accel_delay_s, 0.0);
  EXPECT_EQ(ds.imperfections.frame_reaction_ratio, 0.0);
  EXPECT_EQ(ds.imperfections.frame_vibration_mps2, 0.0);
  EXPECT_EQ(ds.imperfections.frame_vibration_hz, 35.0);
  EXPECT_FALSE(ds.imperfections.frame_accelerometer);
}

TEST(ConfigLoader, BadSimImperfectionsPointAtTheValue) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"                                          // 1
                              "  - name: x\n"                                    // 2
                              "    motor: m.yaml\n"                              // 3
                              "    driver:\n"                                    // 4
                              "      profile:\n"                                 // 5
                              "        type: point_to_point\n"                   // 6
                              "        max_jerk_mps3: 0\n"                       // 7
                              "        dwell_s: -0.1\n"                          // 8
                              "      imperfections:\n"                           // 9
                              "        field_third_harmonic: 0.5\n"              // 10
                              "        coil_field_v_per_mps2: 0.2\n"             // 11
                              "        accel_bias_random_walk_mps2_per_sqrt_s: -1e-4\n"  // 12
                              "        accel_delay_s: 0.25\n"                    // 13
                              "        frame_reaction_ratio: -2\n"               // 14
                              "        frame_vibration_mps2: -0.03\n"            // 15
                              "        frame_vibration_hz: 0\n"                  // 16
                              "        frame_accelerometer: yes\n"               // 17
                              "        frame_vibration_freq_hz: 35\n");          // 18
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 11u) << to_string(r.errors);
  const std::string p = "axes[0].driver.profile.", i = "axes[0].driver.imperfections.";
  expect_error(r, path, 7, 24, p + "max_jerk_mps3", "0 out of range [0.001, 1e+07] m/s^3");
  expect_error(r, path, 8, 18, p + "dwell_s", "-0.1 out of range [0, 3600] s");
  expect_error(r, path, 10, 31, i + "field_third_harmonic", "0.5 out of range [-0.3, 0.3]");
  expect_error(r, path, 11, 32, i + "coil_field_v_per_mps2", "0.2 out of range [-0.1, 0.1] V/(m/s^2)");
  expect_error(r, path, 12, 49, i + "accel_bias_random_walk_mps2_per_sqrt_s", "out of range [0, 10] m/s^2/sqrt(s)");
  expect_error(r, path, 13, 24, i + "accel_delay_s", "0.25 out of range [0, 0.1] s");
  expect_error(r, path, 14, 31, i + "frame_reaction_ratio", "-2 out of range [-1, 1]");
  expect_error(r, path, 15, 31, i + "frame_vibration_mps2", "-0.03 out of range [0, 1000] m/s^2");
  expect_error(r, path, 16, 29, i + "frame_vibration_hz", "0 out of range [0.01, 10000] Hz");
  expect_error(r, path, 17, 30, i + "frame_accelerometer", "expected true or false, got 'yes'");
  expect_error(r, path, 18, 9, i + "frame_vibration_freq_hz", "did you mean 'frame_vibration_hz'?");

  // A bad profile type names the new kind among the allowed ones.
  const auto typo = dir.write("typo.yaml",
                              "axes:\n"                                     // 1
                              "  - name: x\n"                               // 2
                              "    motor: m.yaml\n"                         // 3
                              "    driver: {profile: {type: p2p}}\n");      // 4
  expect_error(load_machine_file(typo), typo, 4, 30, "axes[0].driver.profile.type",
               "standstill | constant_velocity | constant_acceleration | multisine | shuttle | point_to_point");
}

/// One axis on m.yaml, up to its `driver:` key (4 lines); the driver block follows.
const std::string kSimAxisDriver = "axes:\n  - name: x\n    motor: m.yaml\n    driver:\n";

TEST(ConfigLoader, SimTemperatureLoads) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              kSimAxisDriver +
                              "      temperature:\n"
                              "        profile: warmup\n"
                              "        delta_k: -12.5\n"
                              "        start_s: 2\n"
                              "        duration_s: 300\n"
                              "        offset_k: 10\n"
                              "        magnet_remanence_per_k: -0.0011\n"
                              "        hall_gain_tc_per_k: -0.0009\n"
                              "        hall_gain_tc_std_per_k: 0.0004\n"
                              "        hall_offset_tc_std_v_per_k: 0.0002\n"
                              "        reference_c: 22\n"
                              "        report: true\n"
                              "        report_noise_k: 0.05\n"
                              "        report_resolution_k: 0.125\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const sim::TemperatureConfig& t = r.config.axes[0].driver.sim.temperature;
  EXPECT_EQ(t.profile, sim::TemperatureConfig::Profile::warmup);
  EXPECT_EQ(t.delta_k, -12.5);
  EXPECT_EQ(t.start_s, 2.0);
  EXPECT_EQ(t.duration_s, 300.0);
  EXPECT_EQ(t.offset_k, 10.0);
  EXPECT_EQ(t.magnet_remanence_per_k, -0.0011);
  EXPECT_EQ(t.hall_gain_tc_per_k, -0.0009);
  EXPECT_EQ(t.hall_gain_tc_std_per_k, 0.0004);
  EXPECT_EQ(t.hall_offset_tc_std_v_per_k, 0.0002);
  EXPECT_EQ(t.reference_c, 22.0);
  EXPECT_TRUE(t.report);
  EXPECT_EQ(t.report_noise_k, 0.05);
  EXPECT_EQ(t.report_resolution_k, 0.125);

  // Omitted: no temperature change, datasheet-like coefficients, no report.
  const auto plain = dir.write("plain.yaml", "axes: [{name: x, motor: m.yaml}]\n");
  const LoadResult d = load_machine_file(plain);
  ASSERT_TRUE(d.ok()) << to_string(d.errors);
  const sim::TemperatureConfig& dt = d.config.axes[0].driver.sim.temperature;
  EXPECT_EQ(dt.profile, sim::TemperatureConfig::Profile::constant);
  EXPECT_EQ(dt.delta_k, 0.0);
  EXPECT_EQ(dt.offset_k, 0.0);
  EXPECT_EQ(dt.magnet_remanence_per_k, -0.0012);
  EXPECT_EQ(dt.reference_c, 25.0);
  EXPECT_FALSE(dt.report);

  // The block documented (commented out) in sim-realistic.yaml loads as written.
  std::ifstream shipped(std::string(VE_SOURCE_DIR) + "/config/machines/sim-realistic.yaml");
  std::string line, block;
  bool in_block = false;
  while (std::getline(shipped, line)) {
    if (line.rfind("      # temperature:", 0) == 0) in_block = true;
    else if (in_block && line.rfind("      #   ", 0) != 0) break;
    if (in_block) block += "      " + line.substr(8) + "\n";  // drop the "# "
  }
  ASSERT_FALSE(block.empty());
  const auto doc = dir.write("doc.yaml", kSimAxisDriver + block);
  const LoadResult e = load_machine_file(doc);
  ASSERT_TRUE(e.ok()) << to_string(e.errors) << block;
  const sim::TemperatureConfig& et = e.config.axes[0].driver.sim.temperature;
  EXPECT_EQ(et.profile, sim::TemperatureConfig::Profile::warmup);
  EXPECT_EQ(et.delta_k, 10.0);
  EXPECT_EQ(et.duration_s, 600.0);
  EXPECT_EQ(et.hall_gain_tc_std_per_k, sim::TemperatureConfig{}.hall_gain_tc_std_per_k);  // documents the defaults
  EXPECT_EQ(et.hall_offset_tc_std_v_per_k, sim::TemperatureConfig{}.hall_offset_tc_std_v_per_k);
  EXPECT_EQ(et.magnet_remanence_per_k, sim::TemperatureConfig{}.magnet_remanence_per_k);
  EXPECT_EQ(et.report_resolution_k, sim::TemperatureConfig{}.report_resolution_k);
}

TEST(ConfigLoader, BadSimTemperaturePointsAtTheValue) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              kSimAxisDriver +                                    // 1-4
                              "      temperature:\n"                             // 5
                              "        profile: linear\n"                        // 6
                              "        delta_k: 150\n"                           // 7
                              "        start_s: -1\n"                            // 8
                              "        hall_gain_tc_std_per_k: 0.01\n"           // 9
                              "        magnet_remanence_per_k: -0.012\n"         // 10
                              "        report_resolution_k: -0.0625\n"           // 11
                              "        report: 1\n"                              // 12
                              "        offset_c: 10\n");                         // 13
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 8u) << to_string(r.errors);
  const std::string t = "axes[0].driver.temperature.";
  expect_error(r, path, 6, 18, t + "profile", "'linear' is not one of constant | step | ramp | warmup");
  expect_error(r, path, 7, 18, t + "delta_k", "150 out of range [-100, 100] K");
  expect_error(r, path, 8, 18, t + "start_s", "-1 out of range [0, 1e+09] s");
  expect_error(r, path, 9, 33, t + "hall_gain_tc_std_per_k", "0.01 out of range [0, 0.001] 1/K");
  expect_error(r, path, 10, 33, t + "magnet_remanence_per_k", "-0.012 out of range [-0.003, 0.003] 1/K");
  expect_error(r, path, 11, 30, t + "report_resolution_k", "-0.0625 out of range [0, 10] K");
  expect_error(r, path, 12, 17, t + "report", "expected true or false, got '1'");
  expect_error(r, path, 13, 9, t + "offset_c", "did you mean 'offset_k'?");

  // Cross-checks: the whole rise, and a ramp without a duration.
  const auto cross = dir.write("cross.yaml",
                               kSimAxisDriver + "      temperature: {profile: ramp, delta_k: 60, offset_k: 50}\n");  // 5
  const LoadResult c = load_machine_file(cross);
  EXPECT_EQ(c.errors.size(), 2u) << to_string(c.errors);
  expect_error(c, cross, 5, 45, t + "delta_k", "the temperature rise reaches 110 K: |offset_k| + |delta_k| must be <= 100");
  expect_error(c, cross, 5, 20, t + "duration_s", "duration_s (default) 0 must be > 0 for profile ramp");

  // Only the simulator has a temperature model.
  const auto replay = dir.write("replay.yaml",
                                "axes:\n"                                                   // 1
                                "  - name: x\n"                                             // 2
                                "    motor: m.yaml\n"                                       // 3
                                "    driver: {type: replay, log: r.csv, temperature: {}}\n");  // 4
  dir.write("r.csv", "t_s,hall_0_v,accel_mps2\n");
  expect_error(load_machine_file(replay), replay, 4, 40, "axes[0].driver.temperature", "only used with type: sim");
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

TEST(ConfigShipped, SimMachineLoadsClean) {
  const std::string path = std::string(VE_SOURCE_DIR) + "/config/machines/sim.yaml";
  const LoadResult r = load_machine_file(path);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const MachineConfig& c = r.config;
  EXPECT_EQ(c.name, "sim-single-axis");
  EXPECT_EQ(c.dds.domain, 0);
  EXPECT_EQ(c.dds.deadline_ms, 5.0);
  EXPECT_TRUE(c.dds.profiles_file.empty());
  ASSERT_EQ(c.axes.size(), 1u);
  const AxisConfig& x = c.axes[0];
  EXPECT_EQ(x.name, "x");
  EXPECT_EQ(x.id, 1u);
  EXPECT_TRUE(x.calibration_file.empty());
  EXPECT_EQ(x.driver.kind, DriverConfig::Kind::sim);
  EXPECT_TRUE(x.driver.sim.realtime);
  EXPECT_EQ(x.driver.sim.profile.kind, sim::MotionProfileConfig::Kind::multisine);
  EXPECT_EQ(x.driver.sim.profile.start_m, 0.5);
  EXPECT_EQ(x.driver.sim.profile.max_velocity_mps, 2.0);
  EXPECT_EQ(x.driver.sim.profile.max_acceleration_mps2, 10.0);
  EXPECT_EQ(x.homing.mode, HomingConfig::Mode::startup_position);
  EXPECT_EQ(x.homing.position_m, 0.5);
  const core::MotorConfig& m = x.motor;
  EXPECT_EQ(m.name, "sim-12mm");
  EXPECT_EQ(m.magnet_pitch_m, 0.012);
  EXPECT_EQ(m.travel_m, 1.0);
  EXPECT_EQ(m.sample_rate_hz, 4000.0);
  EXPECT_EQ(m.hall.count, 4);
  EXPECT_DOUBLE_EQ(m.hall.spacing_m, m.magnet_pitch_m / 8.0);
  EXPECT_DOUBLE_EQ(m.hall.amplitude_v, 2.5 * std::sqrt(2.0));
  EXPECT_EQ(m.hall.noise_v, 0.0006);
  EXPECT_EQ(m.adc.bits, 12);
  EXPECT_EQ(m.accelerometer.noise_mps2, 0.02);
}

TEST(ConfigShipped, RealisticSimMachinesLoadClean) {
  for (const bool frame : {false, true}) {
    const std::string path = std::string(VE_SOURCE_DIR) + "/config/machines/" +
                             (frame ? "sim-realistic-frame-accel.yaml" : "sim-realistic.yaml");
    SCOPED_TRACE(path);
    const LoadResult r = load_machine_file(path);
    ASSERT_TRUE(r.ok()) << to_string(r.errors);
    ASSERT_EQ(r.config.axes.size(), 1u);
    const AxisConfig& x = r.config.axes[0];
    EXPECT_EQ(x.motor.name, "sim-12mm");
    // Each ships with its calibration, made by `virtual-encoder calibrate`.
    EXPECT_EQ(x.calibration_file, std::string(VE_SOURCE_DIR) + "/config/calibration/" +
                                      (frame ? "sim-realistic-frame-accel-x.cal.yaml" : "sim-realistic-x.cal.yaml"));
    EXPECT_EQ(x.homing.mode, HomingConfig::Mode::startup_position);
    EXPECT_EQ(x.homing.position_m, 0.5);
    const sim::SimConfig& s = x.driver.sim;
    EXPECT_EQ(s.profile.kind, sim::MotionProfileConfig::Kind::multisine);
    EXPECT_EQ(s.profile.max_velocity_mps, 2.0);
    EXPECT_EQ(s.profile.max_acceleration_mps2, 10.0);
    const sim::ImperfectionConfig& im = s.imperfections;
    EXPECT_EQ(im.track_seed, 7u);
    EXPECT_EQ(im.magnet_strength_std, 0.015);
    EXPECT_EQ(im.magnet_placement_std_m, 20e-6);
    EXPECT_EQ(im.field_third_harmonic, 0.03);
    EXPECT_EQ(im.sensor_placement_std_m, 50e-6);
    EXPECT_EQ(im.sensor_gain_std, 0.03);
    EXPECT_EQ(im.sensor_offset_std_v, 0.020);
    EXPECT_EQ(im.hall_delay_s, 20e-6);
    EXPECT_EQ(im.coil_field_v_per_mps2, 0.001);
    EXPECT_EQ(im.accel_bias_mps2, 0.05);
    EXPECT_EQ(im.accel_bias_random_walk_mps2_per_sqrt_s, 1e-4);
    EXPECT_EQ(im.accel_scale_error, 0.005);
    EXPECT_EQ(im.accel_delay_s, 250e-6);
    EXPECT_EQ(im.frame_reaction_ratio, -0.02);
    EXPECT_EQ(im.frame_vibration_mps2, 0.03);
    EXPECT_EQ(im.frame_vibration_hz, 35.0);
    EXPECT_EQ(im.frame_accelerometer, frame);
  }
}

void expect_same_motor(const core::MotorConfig& a, const core::MotorConfig& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.magnet_pitch_m, b.magnet_pitch_m);
  EXPECT_EQ(a.travel_m, b.travel_m);
  EXPECT_EQ(a.sample_rate_hz, b.sample_rate_hz);
  EXPECT_EQ(a.hall.count, b.hall.count);
  EXPECT_EQ(a.hall.offsets_m, b.hall.offsets_m);
  EXPECT_EQ(a.hall.spacing_m, b.hall.spacing_m);
  EXPECT_EQ(a.hall.offset_v, b.hall.offset_v);
  EXPECT_EQ(a.hall.amplitude_v, b.hall.amplitude_v);
  EXPECT_EQ(a.hall.noise_v, b.hall.noise_v);
  EXPECT_EQ(a.hall.saturation_margin_v, b.hall.saturation_margin_v);
  EXPECT_EQ(a.adc.bits, b.adc.bits);
  EXPECT_EQ(a.adc.min_v, b.adc.min_v);
  EXPECT_EQ(a.adc.max_v, b.adc.max_v);
  EXPECT_EQ(a.accelerometer.noise_mps2, b.accelerometer.noise_mps2);
  EXPECT_EQ(a.accelerometer.range_mps2, b.accelerometer.range_mps2);
  EXPECT_EQ(a.filter.jerk_std_mps3, b.filter.jerk_std_mps3);
  EXPECT_EQ(a.filter.hall_position_floor_m, b.filter.hall_position_floor_m);
  EXPECT_EQ(a.filter.gate_sigma, b.filter.gate_sigma);
  EXPECT_EQ(a.filter.initial_position_std_m, b.filter.initial_position_std_m);
  EXPECT_EQ(a.filter.initial_velocity_std_mps, b.filter.initial_velocity_std_mps);
  EXPECT_EQ(a.filter.initial_acceleration_std_mps2, b.filter.initial_acceleration_std_mps2);
}

TEST(ConfigShipped, EmbeddedDefaultEqualsOnDiskFiles) {
  for (const char* f : {"config/machines/sim.yaml", "config/motors/sim-12mm.yaml"}) {
    const auto it = embedded_files().find(f);
    ASSERT_NE(it, embedded_files().end()) << f;
    EXPECT_EQ(it->second, read_file(std::string(VE_SOURCE_DIR) + "/" + f)) << f << " is stale in the build";
  }
  const LoadResult e = load_embedded_default();
  ASSERT_TRUE(e.ok()) << to_string(e.errors);
  const LoadResult d = load_machine_file(std::string(VE_SOURCE_DIR) + "/config/machines/sim.yaml");
  ASSERT_TRUE(d.ok()) << to_string(d.errors);
  EXPECT_EQ(e.config.source, "<embedded>/config/machines/sim.yaml");
  EXPECT_EQ(e.config.name, d.config.name);
  EXPECT_EQ(e.config.dds.domain, d.config.dds.domain);
  EXPECT_EQ(e.config.dds.deadline_ms, d.config.dds.deadline_ms);
  EXPECT_EQ(e.config.dds.profiles_file, d.config.dds.profiles_file);
  ASSERT_EQ(e.config.axes.size(), d.config.axes.size());
  for (std::size_t i = 0; i < e.config.axes.size(); ++i) {
    const AxisConfig& a = e.config.axes[i];
    const AxisConfig& b = d.config.axes[i];
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.id, b.id);
    EXPECT_EQ(a.motor_file, "");  // embedded: nothing on disk to open
    expect_same_motor(a.motor, b.motor);
    EXPECT_EQ(a.calibration_file, b.calibration_file);
    EXPECT_EQ(a.driver.kind, b.driver.kind);
    const auto& sa = a.driver.sim;
    const auto& sb = b.driver.sim;
    EXPECT_EQ(sa.realtime, sb.realtime);
    EXPECT_EQ(sa.noise_seed, sb.noise_seed);
    EXPECT_EQ(sa.profile.kind, sb.profile.kind);
    EXPECT_EQ(sa.profile.start_m, sb.profile.start_m);
    EXPECT_EQ(sa.profile.max_velocity_mps, sb.profile.max_velocity_mps);
    EXPECT_EQ(sa.profile.max_acceleration_mps2, sb.profile.max_acceleration_mps2);
    EXPECT_EQ(sa.profile.min_m, sb.profile.min_m);
    EXPECT_EQ(sa.profile.max_m, sb.profile.max_m);
    EXPECT_EQ(sa.imperfections.track_seed, sb.imperfections.track_seed);
    EXPECT_EQ(a.output.counts_per_m, b.output.counts_per_m);
    EXPECT_EQ(a.output.direction, b.output.direction);
    EXPECT_EQ(a.output.preset_counts, b.output.preset_counts);
    EXPECT_EQ(a.homing.mode, b.homing.mode);
    EXPECT_EQ(a.homing.position_m, b.homing.position_m);
  }
}

TEST(ConfigLoader, PublishDividerMustLeaveTheDeadlineTwoPublishedPeriods) {
  TempDir dir;
  dir.write("m.yaml", std::string(kMotor) + "sample_rate_hz: 4000\n");
  const auto ok = dir.write("ok.yaml",
                            "dds: {deadline_ms: 5}\n"
                            "axes:\n"
                            "  - name: x\n"
                            "    motor: m.yaml\n"
                            "    output: {publish_divider: 8}\n");
  const LoadResult good = load_machine_file(ok);
  ASSERT_TRUE(good.ok()) << to_string(good.errors);
  EXPECT_EQ(good.config.axes[0].output.publish_divider, 8);

  const auto bad = dir.write("bad.yaml",
                             "dds: {deadline_ms: 5}\n"                  // 1
                             "axes:\n"                                  // 2
                             "  - name: x\n"                            // 3
                             "    motor: m.yaml\n"                      // 4
                             "    output: {publish_divider: 12}\n"      // 5
                             "  - name: y\n"                            // 6
                             "    id: 2\n"                              // 7
                             "    motor: m.yaml\n"                      // 8
                             "    output: {publish_divider: 0}\n");     // 9
  const LoadResult r = load_machine_file(bad);
  EXPECT_EQ(r.errors.size(), 2u) << to_string(r.errors);
  expect_error(r, bad, 5, 31, "axes[0].output.publish_divider", "at least two published periods");
  expect_error(r, bad, 9, 31, "axes[1].output.publish_divider", "0 out of range [1, 1000] samples");
}

TEST(ConfigLoader, SignatureHomingNeedsACalibrationAndOnlyItTakesAStateFile) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes:\n"                                                        // 1
                              "  - name: x\n"                                                  // 2
                              "    motor: m.yaml\n"                                            // 3
                              "    homing: {mode: signature, state_file: x.kept.yaml}\n"       // 4
                              "  - name: y\n"                                                  // 5
                              "    motor: m.yaml\n"                                            // 6
                              "    homing: {mode: startup_position, state_file: y.kept.yaml}\n");  // 7
  const LoadResult r = load_machine_file(path);
  EXPECT_EQ(r.errors.size(), 2u) << to_string(r.errors);
  expect_error(r, path, 4, 20, "axes[0].homing.mode", "signature homing needs a calibration");
  expect_error(r, path, 7, 50, "axes[1].homing.state_file", "only used with mode: signature");

  // With a calibration (it may be about to be created), the state file resolves
  // relative to the machine file.
  const auto ok = dir.write("ok.yaml",
                            "axes:\n"
                            "  - name: x\n"
                            "    motor: m.yaml\n"
                            "    calibration: x.cal.yaml\n"
                            "    homing: {mode: signature, state_file: state/x.kept.yaml}\n");
  LoadOptions opt;
  opt.calibration_must_exist = false;
  const LoadResult r2 = load_machine_file(ok, opt);
  ASSERT_TRUE(r2.ok()) << to_string(r2.errors);
  EXPECT_EQ(r2.config.axes[0].homing.mode, HomingConfig::Mode::signature);
  EXPECT_EQ(r2.config.axes[0].homing.state_file, dir.file("state/x.kept.yaml"));
}

}  // namespace
TEST(ConfigLoader, ValidAccuracyAndHallAdaptationKeysLoadAndAreChecked) {
  TempDir dir;
  const auto motor = dir.write("m.yaml",
                               "motor: a\n"
                               "filter:\n"
                               "  valid_position_accuracy_m: 5.0e-6\n"
                               "  valid_velocity_accuracy_mps: 1.7e-3\n"
                               "  hall_adaptation: false\n"
                               "  hall_gain_limit: 0.05\n"
                               "  sensor_readmit_s: 0.5\n");
  const auto path = dir.write("machine.yaml", "axes:\n  - {name: x, motor: m.yaml}\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const auto& f = r.config.axes.at(0).motor.filter;
  EXPECT_EQ(f.valid_position_accuracy_m, 5.0e-6);
  EXPECT_EQ(f.valid_velocity_accuracy_mps, 1.7e-3);
  EXPECT_FALSE(f.hall_adaptation);
  EXPECT_EQ(f.hall_gain_limit, 0.05);
  EXPECT_EQ(f.sensor_readmit_s, 0.5);

  const auto bad = dir.write("bad.yaml",
                             "motor: b\n"
                             "filter:\n"
                             "  valid_position_accuracy_m: -1\n"
                             "  valid_confidence_sigma: 20\n");
  const auto bad_machine = dir.write("bad-machine.yaml", "axes:\n  - {name: x, motor: bad.yaml}\n");
  const LoadResult b = load_machine_file(bad_machine);
  ASSERT_EQ(b.errors.size(), 2u) << to_string(b.errors);
  expect_error(b, bad, 3, 30, "filter.valid_position_accuracy_m", "out of range [1e-09, 1] m");
  expect_error(b, bad, 4, 27, "filter.valid_confidence_sigma", "out of range [0.5, 10] sigma");
}

TEST(ConfigLoader, TemperatureAndCommonGainKeysLoadAndAreChecked) {
  TempDir dir;
  const auto motor = dir.write("m.yaml",
                               "motor: a\n"
                               "filter:\n"
                               "  magnet_remanence_tc_per_k: -0.0004\n"
                               "  hall_gain_tc_per_k: -0.0008\n"
                               "  hall_offset_tc_std_v_per_k: 0.0001\n"
                               "  hall_common_gain_initial_std: 0.02\n");
  const auto path = dir.write("machine.yaml", "axes:\n  - {name: x, motor: m.yaml}\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const auto& f = r.config.axes.at(0).motor.filter;
  EXPECT_EQ(f.magnet_remanence_tc_per_k, -0.0004);
  EXPECT_EQ(f.hall_gain_tc_per_k, -0.0008);
  EXPECT_EQ(f.hall_offset_tc_std_v_per_k, 0.0001);
  EXPECT_EQ(f.hall_common_gain_initial_std, 0.02);

  const auto bad = dir.write("bad.yaml",
                             "motor: b\n"
                             "filter:\n"
                             "  magnet_remanence_tc_per_k: -0.12\n"
                             "  hall_common_gain_initial_std: 0\n");
  const auto bad_machine = dir.write("bad-machine.yaml", "axes:\n  - {name: x, motor: bad.yaml}\n");
  const LoadResult b = load_machine_file(bad_machine);
  ASSERT_EQ(b.errors.size(), 2u) << to_string(b.errors);
  expect_error(b, bad, 3, 30, "filter.magnet_remanence_tc_per_k", "out of range [-0.01, 0.01] 1/K");
  expect_error(b, bad, 4, 33, "filter.hall_common_gain_initial_std", "out of range [1e-06, 0.5]");
}

}  // namespace ve::config

namespace ve::config {
namespace {

TEST(ConfigLoader, ExtremeMotorValuesAreRefusedWithCompactNumbersAllInOneRun) {
  TempDir dir;
  const auto motor = dir.write("m.yaml",
                               "motor: extreme\n"              // 1
                               "magnet_pitch_m: 1e-300\n"      // 2
                               "travel_m: 1e12\n"              // 3
                               "sample_rate_hz: 1e308\n"       // 4
                               "hall: {offset_v: 1e999}\n");   // 5
  const auto path = dir.write("machine.yaml", "axes: [{name: x, motor: m.yaml}]\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 4u) << to_string(r.errors);
  expect_error(r, motor, 2, 17, "magnet_pitch_m", "1e-300 out of range [0.001, 1] m");
  expect_error(r, motor, 3, 11, "travel_m", "1e+12 out of range [0.001, 100] m");
  expect_error(r, motor, 4, 17, "sample_rate_hz", "1e+308 out of range [100, 100000] Hz");
  expect_error(r, motor, 5, 18, "hall.offset_v", "number out of range: 1e999");
  for (const auto& e : r.errors) EXPECT_LT(e.to_string().size(), 160u) << e.to_string();
}

TEST(ConfigLoader, MotorValuesMustBeConsistent) {
  TempDir dir;
  const auto motor = dir.write("m.yaml",
                               "motor: inconsistent\n"                      // 1
                               "magnet_pitch_m: 0.001\n"                    // 2
                               "travel_m: 50\n"                             // 3
                               "hall: {saturation_margin_v: 3}\n");         // 4
  const auto path = dir.write("machine.yaml", "axes: [{name: x, motor: m.yaml}]\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 2u) << to_string(r.errors);
  expect_error(r, motor, 3, 11, "travel_m", "50000 magnet periods out of range [0, 10000]");
  expect_error(r, motor, 4, 29, "hall.saturation_margin_v", "3 out of range [0, 2.5] V: must be less than half");
}

TEST(ConfigLoader, CompactNumbersNeverHideADifferenceFromALimit) {
  EXPECT_EQ(schema::compact_number(1e-300), "1e-300");
  EXPECT_EQ(schema::compact_number(0.0015), "0.0015");
  EXPECT_EQ(schema::compact_number(-1e308), "-1e+308");
  EXPECT_EQ(schema::out_of_range(1.0000001, 0.0, 1.0, "m"), "1.0000001 out of range [0, 1] m");
  EXPECT_EQ(schema::out_of_range(7, 0, 3, ""), "7 out of range [0, 3]");
}

TEST(ConfigLoader, FaultOnASensorTheMotorDoesNotHaveIsRefused) {
  TempDir dir;
  dir.write("m.yaml", kMotor);  // 4 Hall sensors (the default)
  const auto path = dir.write("machine.yaml",
                              "axes:\n"                                                        // 1
                              "  - name: x\n"                                                  // 2
                              "    motor: m.yaml\n"                                            // 3
                              "    driver:\n"                                                  // 4
                              "      faults:\n"                                                // 5
                              "        - {kind: hall_stuck_high, sensor: 7, start_s: 1}\n"     // 6
                              "        - {kind: hall_stuck_low, sensor: 3}\n"                  // 7
                              "        - {kind: accel_dead, sensor: 1}\n"                      // 8
                              "        - {kind: hall_intermittent, sensor: 0, magnitude: 2}\n");  // 9
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 3u) << to_string(r.errors);
  expect_error(r, path, 6, 43, "axes[0].driver.faults[0].sensor",
               "7 out of range [0, 3] (Hall sensor index): motor 'test-motor' has 4 Hall sensors");
  expect_error(r, path, 8, 38, "axes[0].driver.faults[2].sensor", "only used with the hall_* fault kinds");
  expect_error(r, path, 9, 59, "axes[0].driver.faults[3].magnitude", "2 out of range [0, 1] (probability)");
}

TEST(ConfigLoader, ASecondYamlDocumentIsAnError) {
  TempDir dir;
  dir.write("m.yaml", kMotor);
  const auto path = dir.write("machine.yaml",
                              "axes: [{name: x, motor: m.yaml}]\n"  // 1
                              "---\n"                               // 2
                              "axes: [{name: y, motor: m.yaml}]\n"); // 3
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  EXPECT_EQ(r.errors[0].line, 2) << r.errors[0].to_string();  // its '---'
  EXPECT_NE(r.errors[0].message.find("a second YAML document"), std::string::npos) << r.errors[0].to_string();

  // An empty one after the marker counts too: it is where the marker is.
  const auto empty = dir.write("empty-second.yaml", "axes: [{name: x, motor: m.yaml}]\n---\n");
  const LoadResult e = load_machine_file(empty);
  ASSERT_EQ(e.errors.size(), 1u) << to_string(e.errors);
  EXPECT_EQ(e.errors[0].line, 2) << e.errors[0].to_string();

  // yaml-cpp's LoadAll() never returns on a lone ','; the loader does, with a plain error.
  const auto comma = dir.write("comma.yaml", ",\n---\n");
  EXPECT_FALSE(load_machine_file(comma).ok());

  // A leading marker opens the only document: accepted.
  const auto leading = dir.write("leading.yaml", "---\naxes: [{name: x, motor: m.yaml}]\n");
  EXPECT_TRUE(load_machine_file(leading).ok()) << to_string(load_machine_file(leading).errors);
}

TEST(ConfigLoader, NonRegularAndOversizedFilesAreRefusedAtOnce) {
  TempDir dir;
  const auto fifo = dir.file("fifo.yaml");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  // Returns at once: a FIFO without a writer is never opened blocking.
  const LoadResult f = load_machine_file(fifo);
  ASSERT_EQ(f.errors.size(), 1u);
  EXPECT_EQ(f.errors[0].to_string(), fifo + ": cannot read machine file: not a regular file (a FIFO)");

  const LoadResult z = load_machine_file("/dev/zero");
  ASSERT_EQ(z.errors.size(), 1u);
  EXPECT_NE(z.errors[0].message.find("not a regular file (a character device)"), std::string::npos);

  const auto big = dir.write("big.yaml", "");
  fs::resize_file(big, schema::kMaxConfigFileBytes + 1);
  const LoadResult b = load_machine_file(big);
  ASSERT_EQ(b.errors.size(), 1u);
  EXPECT_NE(b.errors[0].message.find("too large: 4194305 bytes, at most 4 MiB"), std::string::npos)
      << b.errors[0].to_string();

  // Referenced files: the reference is reported, naming the file.
  const auto path = dir.write("machine.yaml", "axes: [{name: x, motor: /dev/zero}]\n");
  const LoadResult m = load_machine_file(path);
  ASSERT_EQ(m.errors.size(), 1u) << to_string(m.errors);
  expect_error(m, path, 1, 25, "axes[0].motor", "not a regular file");
}

TEST(ConfigLoader, LongScalarsAreCutInMessages) {
  TempDir dir;
  const auto motor = dir.write("m.yaml", "motor: m\ntravel_m: " + std::string(400, '9') + "\n");
  const auto path = dir.write("machine.yaml", "axes: [{name: x, motor: m.yaml}]\n");
  const LoadResult r = load_machine_file(path);
  ASSERT_EQ(r.errors.size(), 1u) << to_string(r.errors);
  EXPECT_NE(r.errors[0].message.find("... (400 characters)"), std::string::npos) << r.errors[0].to_string();
  EXPECT_LT(r.errors[0].to_string().size(), 200u);
}

TEST(ConfigLoader, ShippedFilesPassTheRangeChecks) {
  for (const char* m : {"sim.yaml", "sim-realistic.yaml", "sim-realistic-frame-accel.yaml", "sim-3axis.yaml",
                        "can-classic.yaml", "can-fd.yaml", "can-node-cv.yaml"}) {
    const LoadResult r = load_machine_file(std::string(VE_SOURCE_DIR) + "/config/machines/" + m);
    EXPECT_TRUE(r.ok()) << m << ":\n" << to_string(r.errors);
  }
  for (const char* m : {"constant_velocity.yaml", "standstill.yaml", "statistics.yaml", "three_axes.yaml",
                        "three_axes_y_silent.yaml", "silent_node.yaml"}) {
    const LoadResult r = load_machine_file(std::string(VE_SOURCE_DIR) + "/tests/integration/data/" + m);
    EXPECT_TRUE(r.ok()) << m << ":\n" << to_string(r.errors);
  }
  EXPECT_TRUE(load_embedded_default().ok());
}

}  // namespace
}  // namespace ve::config
