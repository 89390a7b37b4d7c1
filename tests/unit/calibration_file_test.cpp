// Calibration files: exact round trip, refusal of damaged or foreign files, and
// atomic replacement that never leaves a half-written calibration behind.
#include <gtest/gtest.h>

#include <algorithm>
#include <signal.h>
#include <stdlib.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "config/calibration_file.hpp"
#include "core/hall_table.hpp"

namespace ve::config {
namespace {

namespace fs = std::filesystem;

class CalibrationFile : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "ve-cal-test-XXXXXX").string();
    ASSERT_NE(::mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
    cal_.info.motor = motor_.name;
    cal_.info.hall_count = motor_.hall.count;
    cal_.info.magnet_pitch_m = motor_.magnet_pitch_m;
    cal_.info.method = "reference";
    cal_.info.created_utc = "2026-11-22T03:00:00Z";
    cal_.table = core::nominal_hall_table(motor_);
    cal_.info.id = core::calibration_checksum(cal_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::permissions(dir_, fs::perms::owner_all, fs::perm_options::add, ec);
    fs::remove_all(dir_, ec);
  }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  std::string write_good(const std::string& name = "x.cal.yaml") {
    std::string error;
    const std::string p = path(name);
    EXPECT_TRUE(write_calibration_file_atomic(p, cal_, error)) << error;
    return p;
  }

  static std::string slurp(const std::string& p) {
    std::ifstream in(p, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }
  static void spit(const std::string& p, const std::string& text) { std::ofstream(p, std::ios::binary) << text; }
  /// x.cal.yaml with sensor_model's `key` set to `value` is refused, naming the key.
  void expect_refused_with(const std::string& key, const std::string& value) {
    const std::string p = path("x.cal.yaml");
    std::string text = slurp(p);
    const auto at = text.find(key + ": ");
    ASSERT_NE(at, std::string::npos) << key;
    text.replace(at, text.find(' ', at + key.size() + 2) - at, key + ": " + value);
    spit(p, text);
    const CalibrationLoad bad = load_calibration_file(p, motor_);
    ASSERT_FALSE(bad.ok());
    EXPECT_NE(to_string(bad.errors).find("sensor_model." + key), std::string::npos) << to_string(bad.errors);
  }

  /// Names in the directory other than `keep`: leftover temp files.
  std::vector<std::string> others(const std::string& keep) const {
    std::vector<std::string> out;
    for (const auto& e : fs::directory_iterator(dir_))
      if (e.path().filename() != keep) out.push_back(e.path().filename().string());
    return out;
  }

  static ConfigError only_error(const CalibrationLoad& r) {
    EXPECT_EQ(r.errors.size(), 1u) << to_string(r.errors);
    return r.errors.empty() ? ConfigError{} : r.errors.front();
  }

  fs::path dir_;
  core::MotorConfig motor_;
  core::Calibration cal_;
};

TEST_F(CalibrationFile, RoundTripIsExactToOneMicrovolt) {
  const std::string p = write_good();
  const std::string text = slurp(p);
  EXPECT_EQ(text.rfind("# ", 0), 0u);
  EXPECT_NE(text.find("\nformat: virtual-encoder-calibration\nversion: 1\nmotor: sim-12mm\nhall_count: 4\n"),
            std::string::npos);
  EXPECT_NE(text.find("\nid: \"" + cal_.info.id + "\""), std::string::npos);

  const auto t0 = std::chrono::steady_clock::now();
  const CalibrationLoad r = load_calibration_file(p, motor_);
  const double load_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  std::printf("[ info     ] loading a %d-point x %d-sensor calibration (%zu bytes) took %.3f s\n",
              cal_.table.points, cal_.table.sensors, text.size(), load_s);
  RecordProperty("load_seconds", std::to_string(load_s));  // reported, not asserted: the machine may be loaded

  const core::Calibration& c = r.calibration;
  EXPECT_EQ(c.info.motor, cal_.info.motor);
  EXPECT_EQ(c.info.hall_count, cal_.info.hall_count);
  EXPECT_EQ(c.info.magnet_pitch_m, cal_.info.magnet_pitch_m);
  EXPECT_EQ(c.info.method, "reference");
  EXPECT_EQ(c.info.created_utc, "2026-11-22T03:00:00Z");
  EXPECT_EQ(c.info.id, cal_.info.id);
  EXPECT_EQ(core::calibration_checksum(c), cal_.info.id);
  EXPECT_EQ(c.table.start_m, cal_.table.start_m);  // bit-identical grid
  EXPECT_EQ(c.table.step_m, cal_.table.step_m);
  EXPECT_EQ(c.table.points, cal_.table.points);
  EXPECT_EQ(c.table.sensors, cal_.table.sensors);
  ASSERT_EQ(c.table.v.size(), cal_.table.v.size());
  double worst = 0.0;
  for (std::size_t i = 0; i < c.table.v.size(); ++i) worst = std::max(worst, std::abs(c.table.v[i] - cal_.table.v[i]));
  EXPECT_LE(worst, 0.5e-6 + 1e-12);
  EXPECT_TRUE(others("x.cal.yaml").empty());
}

TEST_F(CalibrationFile, ARulerLessCalibrationKeepsItsScaleUncertainty) {
  // Absent from a calibration with a ruler: the file and its checksum are as before.
  EXPECT_EQ(slurp(write_good("ruler.cal.yaml")).find("track_scale_std"), std::string::npos);
  cal_.info.method = "no-reference";
  cal_.model.track_scale_std = 12.345678e-6;
  cal_.info.id = core::calibration_checksum(cal_);
  core::Calibration ruler = cal_;
  ruler.model.track_scale_std = 0.0;
  EXPECT_NE(core::calibration_checksum(ruler), cal_.info.id);  // part of what the id names
  const CalibrationLoad r = load_calibration_file(write_good(), motor_);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  EXPECT_NEAR(r.calibration.model.track_scale_std, 12.345678e-6, 1e-15);
  EXPECT_EQ(core::calibration_checksum(r.calibration), cal_.info.id);
  // Out of its range: refused with the key.
  expect_refused_with("track_scale_std", "0.5");
}

TEST_F(CalibrationFile, KeepsTheTablesOwnNoiseAndReadsOlderFilesWithout) {
  // Older files have none: the file and its checksum are as before, read as 0.
  EXPECT_EQ(slurp(write_good("old.cal.yaml")).find("table_noise_v"), std::string::npos);
  cal_.model.table_noise_v = 0.0002713;  // to 0.1 uV, as identification rounds it
  cal_.info.id = core::calibration_checksum(cal_);
  core::Calibration older = cal_;
  older.model.table_noise_v = 0.0;
  EXPECT_NE(core::calibration_checksum(older), cal_.info.id);  // part of what the id names
  const CalibrationLoad r = load_calibration_file(write_good(), motor_);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  EXPECT_NEAR(r.calibration.model.table_noise_v, 0.0002713, 1e-15);
  EXPECT_EQ(core::calibration_checksum(r.calibration), cal_.info.id);
  // Out of its range: refused, naming the key.
  expect_refused_with("table_noise_v", "-0.001");
}

TEST_F(CalibrationFile, KeepsEachSensorsThermalCoefficients) {
  // Absent before a thermal calibration: the file and its checksum are as before.
  EXPECT_EQ(slurp(write_good("plain.cal.yaml")).find("thermal"), std::string::npos);
  const std::string plain_id = cal_.info.id;
  auto& m = cal_.model;
  m.thermal_known = true;
  m.thermal_rise_k = 14.794;
  m.common_tc_per_k = -0.0022;
  m.common_tc_rel_std = 0.0068;
  for (int i = 0; i < cal_.info.hall_count; ++i) {
    const auto k = static_cast<std::size_t>(i);
    m.hall_gain_tc_per_k[k] = 1e-4 * (i - 1.5);
    m.hall_gain_tc_std_per_k[k] = 3e-5;
    m.hall_offset_tc_v_per_k[k] = -2.5e-4 + 1e-4 * i;
    m.hall_offset_tc_std_v_per_k[k] = 3.1e-5;
  }
  cal_.info.id = core::calibration_checksum(cal_);
  EXPECT_NE(cal_.info.id, plain_id);  // part of what the id names
  const std::string p = write_good();
  const CalibrationLoad r = load_calibration_file(p, motor_);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  const auto& got = r.calibration.model;
  EXPECT_TRUE(got.thermal_known);
  EXPECT_EQ(got.thermal_rise_k, m.thermal_rise_k);
  EXPECT_EQ(got.common_tc_per_k, m.common_tc_per_k);
  EXPECT_EQ(got.common_tc_rel_std, m.common_tc_rel_std);
  EXPECT_EQ(got.hall_gain_tc_per_k, m.hall_gain_tc_per_k);  // shortest round-trip form: exact
  EXPECT_EQ(got.hall_gain_tc_std_per_k, m.hall_gain_tc_std_per_k);
  EXPECT_EQ(got.hall_offset_tc_v_per_k, m.hall_offset_tc_v_per_k);
  EXPECT_EQ(got.hall_offset_tc_std_v_per_k, m.hall_offset_tc_std_v_per_k);
  EXPECT_EQ(core::calibration_checksum(r.calibration), cal_.info.id);

  // A list one sensor short is refused, naming the file, the line and the key.
  std::string text = slurp(p);
  const auto at = text.find("  offset_tc_v_per_k: [");
  ASSERT_NE(at, std::string::npos);
  const auto comma = text.find(", ", at);
  const auto close = text.find(']', at);
  text.erase(text.rfind(", ", close), close - text.rfind(", ", close));
  ASSERT_LT(comma, close);
  spit(p, text);
  const CalibrationLoad bad = load_calibration_file(p, motor_);
  ASSERT_FALSE(bad.ok());
  const std::string why = to_string(bad.errors);
  EXPECT_NE(why.find("thermal.offset_tc_v_per_k"), std::string::npos) << why;
  EXPECT_NE(why.find("3 values but hall_count is 4"), std::string::npos) << why;
  const auto line = std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n') + 1;
  EXPECT_NE(why.find(p + ":" + std::to_string(line) + ":"), std::string::npos) << why << " (line " << line << ")";
}

TEST_F(CalibrationFile, ARulerLessCalibrationKeepsTheStretchItsPassesMade) {
  // Absent from a calibration with a ruler: the file and its checksum are as before.
  EXPECT_EQ(slurp(write_good("ruler.cal.yaml")).find("table_trusted"), std::string::npos);
  cal_.info.method = "no-reference";
  cal_.model.table_trusted_from_m = -0.0061834;
  cal_.model.table_trusted_to_m = 1.2438123;
  cal_.model.table_outside_std_m = 37.4e-6;
  cal_.info.id = core::calibration_checksum(cal_);
  core::Calibration moved = cal_;
  moved.model.table_trusted_from_m += 1e-6;
  EXPECT_NE(core::calibration_checksum(moved), cal_.info.id);  // part of what the id names
  const CalibrationLoad r = load_calibration_file(write_good(), motor_);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  EXPECT_EQ(r.calibration.model.table_trusted_from_m, -0.0061834);
  EXPECT_EQ(r.calibration.model.table_trusted_to_m, 1.2438123);
  EXPECT_NEAR(r.calibration.model.table_outside_std_m, 37.4e-6, 1e-15);
  EXPECT_EQ(core::calibration_checksum(r.calibration), cal_.info.id);
  // One end without the other, and an empty stretch: refused, naming the key.
  const std::string p = path("x.cal.yaml");
  const std::string good = slurp(p);
  std::string text = good;
  const auto at = text.find("  table_trusted_to_m: ");
  ASSERT_NE(at, std::string::npos);
  text.erase(at, text.find('\n', at) + 1 - at);
  spit(p, text);
  const CalibrationLoad half = load_calibration_file(p, motor_);
  ASSERT_FALSE(half.ok());
  EXPECT_NE(to_string(half.errors).find("sensor_model.table_trusted_from_m"), std::string::npos) << to_string(half.errors);
  text = good;
  const auto to = text.find("table_trusted_to_m: ");
  text.replace(to, text.find(' ', to + 20) - to, "table_trusted_to_m: -0.5");
  spit(p, text);
  const CalibrationLoad empty = load_calibration_file(p, motor_);
  ASSERT_FALSE(empty.ok());
  EXPECT_NE(to_string(empty.errors).find("sensor_model.table_trusted_to_m"), std::string::npos) << to_string(empty.errors);
}

TEST_F(CalibrationFile, RoundTripOfAnOddTable) {
  // Negative values, a non-zero start and a grid that is not a power of two.
  cal_.table.start_m = -0.0123456789;
  cal_.table.step_m = 1.0 / 3.0 * 1e-4;
  for (std::size_t i = 0; i < cal_.table.v.size(); i += 7) cal_.table.v[i] = -cal_.table.v[i] + 1e-7 * i;
  cal_.info.id.clear();
  cal_.info.motor = "motor with spaces: \"quoted\"";
  core::MotorConfig m = motor_;
  m.name = cal_.info.motor;
  m.travel_m = 0.6;  // the grid above ends at 0.699 m: it must cover the travel
  const std::string p = write_good();
  const CalibrationLoad r = load_calibration_file(p, m);
  ASSERT_TRUE(r.ok()) << to_string(r.errors);
  EXPECT_EQ(r.calibration.info.motor, m.name);
  EXPECT_EQ(r.calibration.table.start_m, cal_.table.start_m);
  EXPECT_EQ(r.calibration.table.step_m, cal_.table.step_m);
  EXPECT_EQ(r.calibration.info.id, core::calibration_checksum(cal_));
}

TEST_F(CalibrationFile, RefusesTruncatedFile) {
  const std::string p = write_good();
  const std::string text = slurp(p);
  spit(p, text.substr(0, text.size() / 2));  // cut inside a row
  const CalibrationLoad r = load_calibration_file(p, motor_);
  const ConfigError e = only_error(r);
  EXPECT_EQ(e.file, p);
  EXPECT_GT(e.line, 0);
  EXPECT_GT(e.column, 0);
  EXPECT_EQ(e.message.rfind("corrupt: ", 0), 0u) << e.to_string();

  // Cut at the end of the second row: the YAML is valid but the table is short.
  const std::size_t row3 = text.find("\n    - [", text.find("\n    - [", text.find("\n    - [") + 1) + 1);
  ASSERT_NE(row3, std::string::npos);
  spit(p, text.substr(0, row3 + 1));
  const CalibrationLoad r2 = load_calibration_file(p, motor_);
  const ConfigError e2 = only_error(r2);
  EXPECT_EQ(e2.field, "table.sensors");
  // The first row: the sensors sequence starts there.
  const auto first_row_line = 1 + std::count(text.begin(), text.begin() + text.find("\n    - [") + 1, '\n');
  EXPECT_EQ(e2.line, first_row_line);
  EXPECT_EQ(e2.column, 5);
  EXPECT_EQ(e2.message, "corrupt: table has 2 sensor rows but hall_count is 4");
}

TEST_F(CalibrationFile, RefusesChangedValue) {
  const std::string p = write_good();
  std::string text = slurp(p);
  const std::size_t at = text.find("2.", text.find("sensors:"));
  ASSERT_NE(at, std::string::npos);
  text[at + 7] = text[at + 7] == '9' ? '8' : '9';  // one microvolt digit of one value
  spit(p, text);
  const CalibrationLoad r = load_calibration_file(p, motor_);
  const ConfigError e = only_error(r);
  EXPECT_EQ(e.field, "id");
  EXPECT_EQ(e.line, 10);
  EXPECT_EQ(e.column, 5);
  EXPECT_EQ(e.message.rfind("corrupt: the calibration's checksum is ", 0), 0u) << e.to_string();
}

TEST_F(CalibrationFile, RefusesAnotherMotorsFile) {
  const std::string p = write_good();
  core::MotorConfig other = motor_;
  other.name = "lab-16mm";
  const ConfigError e = only_error(load_calibration_file(p, other));
  EXPECT_EQ(e.to_string(), p + ":5:8: motor: other motor: made for motor 'sim-12mm', this axis has motor 'lab-16mm'");

  other = motor_;
  other.magnet_pitch_m = 0.016;
  const ConfigError e2 = only_error(load_calibration_file(p, other));
  EXPECT_EQ(e2.field, "magnet_pitch_m");
  EXPECT_EQ(e2.line, 7);
  EXPECT_EQ(e2.message.rfind("other motor: ", 0), 0u) << e2.to_string();
}

TEST_F(CalibrationFile, RefusesDifferentHallCount) {
  const std::string p = write_good();
  core::MotorConfig three = motor_;
  three.hall.count = 3;
  const ConfigError e = only_error(load_calibration_file(p, three));
  EXPECT_EQ(e.to_string(),
            p + ":6:13: hall_count: incompatible sensor layout: made for 4 Hall sensors, the motor has 3");
}

TEST_F(CalibrationFile, RefusesOtherVersionAndOtherFiles) {
  const std::string p = write_good();
  std::string text = slurp(p);
  text.replace(text.find("version: 1"), 10, "version: 2");
  spit(p, text);
  const ConfigError e = only_error(load_calibration_file(p, motor_));
  EXPECT_EQ(e.to_string(), p + ":4:10: version: unsupported version: version 2; this program reads version 1");

  const std::string machine = path("machine.yaml");
  spit(machine, "machine: x\naxes: []\n");
  const ConfigError e2 = only_error(load_calibration_file(machine, motor_));
  EXPECT_EQ(e2.to_string(), machine + ":1:1: format: corrupt: missing required key 'format'");

  spit(machine, "format: something-else\n");
  const ConfigError e3 = only_error(load_calibration_file(machine, motor_));
  EXPECT_EQ(e3.message.rfind("not a calibration file: ", 0), 0u) << e3.to_string();

  const ConfigError e4 = only_error(load_calibration_file(path("missing.cal.yaml"), motor_));
  EXPECT_EQ(e4.line, 0);
  EXPECT_NE(e4.message.find("No such file or directory"), std::string::npos);
}

TEST_F(CalibrationFile, WriteRefusesInconsistentCalibration) {
  std::string error;
  core::Calibration bad = cal_;
  bad.info.id = "0000000000000000";
  EXPECT_FALSE(write_calibration_file_atomic(path("x.cal.yaml"), bad, error));
  EXPECT_NE(error.find("not the checksum"), std::string::npos) << error;
  bad = cal_;
  bad.info.hall_count = 3;
  EXPECT_FALSE(write_calibration_file_atomic(path("x.cal.yaml"), bad, error));
  bad = cal_;
  bad.table.v.pop_back();
  EXPECT_FALSE(write_calibration_file_atomic(path("x.cal.yaml"), bad, error));
  EXPECT_TRUE(others("").empty());
}

TEST_F(CalibrationFile, AtomicWriteKeepsOldFileWhenTargetIsADirectory) {
  const std::string target = path("target");
  fs::create_directory(target);
  spit(target + "/keep", "old");
  std::string error;
  EXPECT_FALSE(write_calibration_file_atomic(target, cal_, error));
  EXPECT_NE(error.find("s a directory"), std::string::npos) << error;
  EXPECT_TRUE(fs::is_directory(target));
  EXPECT_EQ(slurp(target + "/keep"), "old");
  EXPECT_EQ(others("target"), std::vector<std::string>{}) << "temp file left behind";
}

TEST_F(CalibrationFile, AtomicWriteKeepsOldFileWhenDirectoryIsUnwritable) {
  const std::string p = write_good();
  const std::string before = slurp(p);
  core::Calibration changed = cal_;
  changed.table.v[0] += 0.1;
  changed.info.id.clear();
  ASSERT_EQ(::chmod(dir_.c_str(), 0555), 0);
  // Root ignores directory permissions, so the write runs in a child that
  // gives them up first.
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    if (::geteuid() == 0 && ::setuid(65534) != 0) ::_exit(3);
    std::string error;
    const bool ok = write_calibration_file_atomic(p, changed, error);
    ::_exit(ok ? 1 : (error.find("Permission denied") != std::string::npos ? 0 : 2));
  }
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ::chmod(dir_.c_str(), 0755);
  ASSERT_TRUE(WIFEXITED(status));
  if (WEXITSTATUS(status) == 3) GTEST_SKIP() << "running as root without CAP_SETUID: cannot make a directory unwritable";
  EXPECT_EQ(WEXITSTATUS(status), 0) << "1: write succeeded, 2: failed for another reason than EACCES";
  EXPECT_EQ(slurp(p), before);
  EXPECT_TRUE(others("x.cal.yaml").empty());
}

TEST_F(CalibrationFile, AtomicWriteKeepsOldFileWhenWritingFails) {
  const std::string p = write_good();
  const std::string before = slurp(p);
  core::Calibration changed = cal_;
  changed.table.v[0] += 0.1;
  changed.info.id.clear();
  // A file size limit makes write() fail with EFBIG part way through the new file.
  struct rlimit old {};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &old), 0);
  void (*old_handler)(int) = ::signal(SIGXFSZ, SIG_IGN);
  struct rlimit small = old;
  small.rlim_cur = 4096;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);
  std::string error;
  const bool ok = write_calibration_file_atomic(p, changed, error);
  ::setrlimit(RLIMIT_FSIZE, &old);
  ::signal(SIGXFSZ, old_handler);
  EXPECT_FALSE(ok);
  EXPECT_NE(error.find("cannot write"), std::string::npos) << error;
  EXPECT_EQ(slurp(p), before);
  EXPECT_TRUE(others("x.cal.yaml").empty());
}

TEST_F(CalibrationFile, AtomicWriteKeepsPermissionsOfReplacedFile) {
  const std::string p = write_good();
  ASSERT_EQ(::chmod(p.c_str(), 0640), 0);
  const std::string p2 = write_good();
  struct stat st {};
  ASSERT_EQ(::stat(p2.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0640u);
}

/// Written by the program (valid checksum) after `change`: refused for use, by reason.
TEST_F(CalibrationFile, UnusableTablesAreRefusedEvenWithAValidChecksum) {
  struct Bad {
    const char* what;
    void (*change)(core::Calibration&);
    const char* field;
    const char* message;
  };
  const Bad bad[] = {
      {"step of 1e-12 m", [](core::Calibration& c) { c.table.step_m = 1e-12; }, "table.step_m",
       "unusable table: 1e-12 out of range [2.92969e-06, 0.0015] m (magnet pitch 0.012 m / 4096 .. / 8): finer than "
       "any sensor resolves"},
      {"step of a whole pitch", [](core::Calibration& c) { c.table.step_m = 0.012; }, "table.step_m",
       "too coarse to interpolate"},
      {"grid starting inside the travel", [](core::Calibration& c) { c.table.start_m = 0.001; }, "table.start_m",
       "unusable table: the grid covers [0.001, 1.00103] m, not the motor's travel [0, 1] m: start_m must be <= 0"},
      {"grid ending short of the travel", [](core::Calibration& c) { c.table.start_m = -0.01; }, "table.points",
       "points * step_m falls short by 0.00996875 m"},
      {"a value far beyond the ADC", [](core::Calibration& c) { c.table.v[5] = 1e6; }, "table.sensors[0]",
       "unusable table: value 5: 1e+06 out of range [-5, 10] V"},
      {"a flat row",
       [](core::Calibration& c) {
         for (int k = 0; k < c.table.points; ++k) c.table.v[static_cast<std::size_t>(3 * c.table.points + k)] = 1.0;
       },
       "table.sensors[3]", "unusable table: the row varies by 0 V"},
      {"a Hall delay of 0.5 s", [](core::Calibration& c) { c.model.hall_delay_s = 0.5; }, "sensor_model.hall_delay_s",
       "unusable table: 0.5 out of range [0, 0.01] s"},
  };
  for (const Bad& b : bad) {
    core::Calibration c = cal_;
    b.change(c);
    c.info.id = core::calibration_checksum(c);
    const std::string p = path("bad.cal.yaml");
    spit(p, format_calibration(c));
    const CalibrationLoad r = load_calibration_file(p, motor_);
    // One error, or two for a tiny step (the grid then also misses the travel).
    ASSERT_GE(r.errors.size(), 1u) << b.what;
    ASSERT_LE(r.errors.size(), 2u) << b.what << ":\n" << to_string(r.errors);
    const ConfigError& e = r.errors[0];
    EXPECT_EQ(e.field, b.field) << b.what << ": " << e.to_string();
    EXPECT_GT(e.line, 0) << b.what;
    EXPECT_NE(e.message.find(b.message), std::string::npos) << b.what << ": " << e.to_string();
    for (const auto& x : r.errors) EXPECT_EQ(x.message.rfind("unusable table: ", 0), 0u) << x.to_string();
  }
}

TEST_F(CalibrationFile, ASecondDocumentAndEndlessFilesAreRefused) {
  const std::string p = write_good();
  spit(p, slurp(p) + "---\nformat: virtual-encoder-calibration\n");
  const ConfigError e = only_error(load_calibration_file(p, motor_));
  EXPECT_NE(e.message.find("a second YAML document"), std::string::npos) << e.to_string();

  const ConfigError z = only_error(load_calibration_file("/dev/zero", motor_));
  EXPECT_EQ(z.to_string(), "/dev/zero: cannot read calibration file: not a regular file (a character device)");

  const std::string fifo = path("fifo.cal.yaml");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0644), 0);
  const ConfigError f = only_error(load_calibration_file(fifo, motor_));
  EXPECT_NE(f.message.find("not a regular file (a FIFO)"), std::string::npos) << f.to_string();

  const std::string big = path("big.cal.yaml");
  spit(big, "");
  fs::resize_file(big, schema::kMaxCalibrationFileBytes + 1);
  const ConfigError g = only_error(load_calibration_file(big, motor_));
  EXPECT_NE(g.message.find("too large"), std::string::npos) << g.to_string();
}

TEST_F(CalibrationFile, ShippedCalibrationsAreUsable) {
  for (const char* f : {"sim-realistic-x.cal.yaml", "sim-realistic-frame-accel-x.cal.yaml"}) {
    const CalibrationLoad r = load_calibration_file(std::string(VE_SOURCE_DIR) + "/config/calibration/" + f, motor_);
    EXPECT_TRUE(r.ok()) << f << ":\n" << to_string(r.errors);
  }
}

}  // namespace
}  // namespace ve::config
