// Bad input in every file kind, as an operator editing YAML by hand or copying files
// between machines produces it, table-driven: machine, motor, calibration and CAN
// layout files, each case made from a good file by changing one key (or replacing
// the whole file: empty, a second document, binary, a FIFO, /dev/zero, a directory,
// too large, missing). Every case runs the real binary (`check`, and for unusable
// calibrations also `evaluate` and `run`) and asserts
//  - the exit-code class: `check` exits 1 when it finds a problem, the other
//    subcommands 2 for an input file they cannot use (docs/command-line.md),
//  - that the process exited by itself (no death by a signal, no hang: a watchdog),
//  - that the output names the file, and the field as FILE:LINE:COL: FIELD: where the
//    problem has a place in the file (plus, for most cases, what is wrong).
// The good files themselves pass (`check` exits 0), so each refusal is the case's own.
// Ranges and their reasons: docs/configuration-limits.md.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "config/calibration_file.hpp"
#include "core/hall_table.hpp"
#include "temp_dir.hpp"
#if __has_include("test_domain.hpp")
#include "test_domain.hpp"
#define VE_FILES_HAVE_TEST_DOMAIN 1
#endif

extern "C" char** environ;

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::string read_all(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void write_all(const fs::path& p, const std::string& text) {
  fs::create_directories(p.parent_path());
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out << text;
}

// ---------------------------------------------------------------------------
// Running the binary

struct Outcome {
  bool exited = false;  ///< ended by exit(), not by a signal or the watchdog
  int code = -1;
  int signal = 0;       ///< the signal that ended it, 0 if none
  bool hung = false;    ///< the watchdog had to kill it
  std::string out, err;
};

std::string describe(const Outcome& o) {
  std::string s = o.hung ? "HUNG (killed by the watchdog)"
                  : o.exited ? "exit " + std::to_string(o.code)
                             : "killed by signal " + std::to_string(o.signal);
  return s + "\n--- stdout:\n" + o.out.substr(0, 3000) + "\n--- stderr:\n" + o.err.substr(0, 3000);
}

/// Runs the binary in a process group of its own (killed as a whole by the watchdog),
/// stdin /dev/null, stdout and stderr to files in `dir`.
Outcome run_binary(const std::vector<std::string>& args, const fs::path& dir, std::chrono::seconds watchdog = 30s) {
  std::vector<std::string> full{VE_BINARY};
  full.insert(full.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : full) argv.push_back(a.data());
  argv.push_back(nullptr);
  const std::string out_path = (dir / "stdout.txt").string(), err_path = (dir / "stderr.txt").string();
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, out_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP);
  posix_spawnattr_setpgroup(&attr, 0);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, argv[0], &actions, &attr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attr);
  Outcome o;
  if (rc != 0) {
    o.err = "posix_spawn failed: " + std::string(std::strerror(rc));
    return o;
  }
  const auto end = std::chrono::steady_clock::now() + watchdog;
  int status = 0;
  for (;;) {
    const pid_t r = waitpid(pid, &status, WNOHANG);
    if (r == pid) break;
    if (std::chrono::steady_clock::now() > end) {
      kill(-pid, SIGKILL);
      waitpid(pid, &status, 0);
      o.hung = true;
      break;
    }
    std::this_thread::sleep_for(2ms);
  }
  kill(-pid, SIGKILL);  // anything the program left behind in its group
  if (!o.hung) {
    o.exited = WIFEXITED(status);
    o.code = o.exited ? WEXITSTATUS(status) : -1;
    o.signal = WIFSIGNALED(status) ? WTERMSIG(status) : 0;
  }
  o.out = read_all(out_path);
  o.err = read_all(err_path);
  return o;
}

// ---------------------------------------------------------------------------
// Good files, and one key of them changed

/// Replaces the value of `key` (a dotted path such as "hall.count" or
/// "axes[0].output.direction") in block-style YAML; false if the key is not there.
bool replace_key(std::string& text, const std::string& key, const std::string& value) {
  struct Level {
    int indent;
    std::string name;
  };
  std::vector<Level> stack;
  std::vector<int> item_count(64, -1);  // per indent: list items seen under the current parent
  std::size_t pos = 0;
  while (pos < text.size()) {
    const std::size_t eol = std::min(text.find('\n', pos), text.size());
    std::string line = text.substr(pos, eol - pos);
    std::size_t i = line.find_first_not_of(' ');
    if (i == std::string::npos || line[i] == '#') {
      pos = eol + 1;
      continue;
    }
    int indent = static_cast<int>(i);
    std::string rest = line.substr(i);
    if (rest.rfind("- ", 0) == 0) {
      while (!stack.empty() && stack.back().indent >= indent) stack.pop_back();
      const int n = ++item_count[static_cast<std::size_t>(indent)];
      if (!stack.empty()) stack.back().name += "[" + std::to_string(n) + "]";
      // the item's mapping: its keys sit at indent + 2
      indent += 2;
      rest = rest.substr(2);
      i += 2;
    }
    const std::size_t colon = rest.find(':');
    if (colon == std::string::npos) {
      pos = eol + 1;
      continue;
    }
    const std::string k = rest.substr(0, colon);
    while (!stack.empty() && stack.back().indent >= indent) {
      // leaving a list's parent: forget its item numbering
      stack.pop_back();
    }
    std::string path;
    for (const auto& l : stack) path += (path.empty() ? "" : ".") + l.name;
    path += (path.empty() ? "" : ".") + k;
    if (path == key) {
      text.replace(pos + i + colon + 1, eol - (pos + i + colon + 1), value.empty() ? "" : " " + value);
      return true;
    }
    std::string after = rest.substr(colon + 1);
    const std::size_t c = after.find(" #");
    if (c != std::string::npos) after = after.substr(0, c);
    if (after.find_first_not_of(' ') == std::string::npos) {
      stack.push_back({indent, k});
      for (std::size_t d = static_cast<std::size_t>(indent) + 1; d < item_count.size(); ++d) item_count[d] = -1;
    }
    pos = eol + 1;
  }
  return false;
}

const char* kMotor =
    "motor: test-motor\n"
    "magnet_pitch_m: 0.012\n"
    "travel_m: 0.1\n"
    "sample_rate_hz: 4000\n"
    "hall:\n"
    "  count: 4\n"
    "  spacing_m: 0.0015\n"
    "  offset_v: 2.5\n"
    "  amplitude_v: 3.5355339059327378\n"
    "  noise_v: 0.0006\n"
    "  saturation_margin_v: 0.05\n"
    "adc:\n"
    "  bits: 12\n"
    "  min_v: 0.0\n"
    "  max_v: 5.0\n"
    "accelerometer:\n"
    "  noise_mps2: 0.02\n"
    "  range_mps2: 160\n"
    "filter:\n"
    "  jerk_std_mps3: 20\n"
    "  hall_position_floor_m: 2.0e-7\n"
    "  hall_systematic_std_m: 2.0e-8\n"
    "  gate_sigma: 6\n"
    "  initial_position_std_m: 1.0e-3\n"
    "  initial_velocity_std_mps: 1.0\n"
    "  initial_acceleration_std_mps2: 10\n"
    "  snap_std_mps4: 2.0e4\n"
    "  accel_bias_std_mps2: 0.1\n"
    "  accel_bias_random_walk_mps2_per_sqrt_s: 1.0e-3\n"
    "  accel_scale_std: 0\n"
    "  accel_scale_random_walk_per_sqrt_s: 0\n"
    "  accel_spike_mps2: 60\n"
    "  hall_rejections_before_reset: 3\n"
    "  vibration_random_walk_mps2_per_sqrt_s: 0.01\n"
    "  use_frame_accelerometer: true\n"
    "  steady_jerk_std_mps3: 0.02\n"
    "  steady_position_walk_m_per_sqrt_s: 7.0e-7\n"
    "  steady_hall_position_floor_m: 1.0e-7\n"
    "  steady_jerk_limit_mps3: 0.5\n"
    "  steady_hold_s: 0.02\n"
    "  steady_exit_cusum: 8\n"
    "  accel_bias_step_cusum: 40\n"
    "  accel_bias_step_std_mps2: 1\n"
    "  valid_position_accuracy_m: 100e-6\n"
    "  valid_velocity_accuracy_mps: 20e-3\n"
    "  valid_confidence_sigma: 2\n"
    "  sensor_readmit_s: 0.25\n"
    "  sensor_readmit_sigma: 4\n"
    "  hall_adaptation: true\n"
    "  hall_gain_random_walk_per_sqrt_s: 2e-4\n"
    "  hall_offset_random_walk_v_per_sqrt_s: 0.05e-3\n"
    "  hall_gain_initial_std: 0.001\n"
    "  hall_offset_initial_std_v: 0.0003\n"
    "  hall_drift_cusum: 40\n"
    "  hall_gain_limit: 0.1\n"
    "  hall_offset_limit_v: 0.1\n";

/// A machine with one simulated axis on motor.yaml; CALIBRATION is replaced by a line
/// naming the calibration file (or by nothing).
const char* kMachine =
    "machine: test-machine\n"
    "dds:\n"
    "  domain: 0\n"
    "  deadline_ms: 5\n"
    "axes:\n"
    "  - name: x\n"
    "    id: 1\n"
    "    motor: motor.yaml\n"
    "CALIBRATION"
    "    driver:\n"
    "      type: sim\n"
    "      realtime: false\n"
    "      noise_seed: 1\n"
    "      profile:\n"
    "        type: shuttle\n"
    "        start_m: 0.05\n"
    "        velocity_mps: 0.1\n"
    "        acceleration_mps2: 1\n"
    "        max_velocity_mps: 0.2\n"
    "        max_acceleration_mps2: 2\n"
    "        min_m: 0.01\n"
    "        max_m: 0.09\n"
    "        max_jerk_mps3: 250\n"
    "        dwell_s: 0.1\n"
    "      faults: []\n"
    "      imperfections:\n"
    "        track_seed: 7\n"
    "        magnet_strength_std: 0\n"
    "        magnet_placement_std_m: 0\n"
    "        field_third_harmonic: 0\n"
    "        sensor_placement_std_m: 0\n"
    "        sensor_gain_std: 0\n"
    "        sensor_offset_std_v: 0\n"
    "        hall_delay_s: 0\n"
    "        coil_field_v_per_mps2: 0\n"
    "        accel_bias_mps2: 0\n"
    "        accel_scale_error: 0\n"
    "        accel_bias_random_walk_mps2_per_sqrt_s: 0\n"
    "        accel_delay_s: 0\n"
    "        frame_reaction_ratio: 0\n"
    "        frame_vibration_mps2: 0\n"
    "        frame_vibration_hz: 35\n"
    "        frame_accelerometer: false\n"
    "      temperature:\n"
    "        profile: constant\n"
    "        delta_k: 0\n"
    "        start_s: 0\n"
    "        duration_s: 0\n"
    "        magnet_remanence_per_k: -0.0012\n"
    "        hall_gain_tc_per_k: -0.001\n"
    "        hall_gain_tc_std_per_k: 0.0003\n"
    "        hall_offset_tc_std_v_per_k: 0.0003\n"
    "        reference_c: 25\n"
    "        report: false\n"
    "        report_noise_k: 0.1\n"
    "        report_resolution_k: 0.0625\n"
    "    output:\n"
    "      counts_per_m: 1.0e7\n"
    "      direction: 1\n"
    "      preset_counts: 0\n"
    "      publish_divider: 1\n"
    "    homing:\n"
    "      mode: startup_position\n"
    "      position_m: 0.05\n"
    "realtime:\n"
    "  sample_thread_priority: 0\n"
    "  lock_memory: false\n"
    "  required: false\n"
    "  sample_loop: shared\n";

/// The socketcan axis of a machine, its frame layout in layout.yaml.
const char* kCanMachine =
    "machine: test-can\n"
    "axes:\n"
    "  - name: x\n"
    "    motor: motor.yaml\n"
    "    driver:\n"
    "      type: socketcan\n"
    "      interface: vcan0\n"
    "      layout: layout.yaml\n"
    "      timeout_ms: 20\n"
    "    homing:\n"
    "      mode: startup_position\n"
    "      position_m: 0.05\n";

std::string signal_block(const char* name, int start, int length, bool is_signed, const char* scale) {
  return std::string("  ") + name + ":\n    start_bit: " + std::to_string(start) + "\n    length: " +
         std::to_string(length) + "\n    byte_order: little_endian\n    signed: " + (is_signed ? "true" : "false") +
         "\n    scale: " + scale + "\n    offset: 0\n";
}

std::string layout_text() {
  return "layout: test-layout\n"
         "can_id: 0x400\n"
         "extended_id: false\n"
         "fd: false\n"
         "frame_length: 8\n"
         "samples_per_frame: 1\n"
         "sample_stride_bits: 0\n"
         "sample_rate_hz: 4000\n"
         "hall_count: 4\n"
         "signals:\n" +
         signal_block("hall_0", 0, 12, false, "0.0012210012210012210") +
         signal_block("hall_1", 12, 12, false, "0.0012210012210012210") +
         signal_block("hall_2", 24, 12, false, "0.0012210012210012210") +
         signal_block("hall_3", 36, 12, false, "0.0012210012210012210") +
         signal_block("accel", 48, 16, true, "0.005") +
         "  sequence:\n    start_bit: 0\n    length: 8\n    in_can_id: true\n";
}

/// The motor of kMotor, as the calibration code sees it.
ve::core::MotorConfig test_motor() {
  ve::core::MotorConfig m;
  m.name = "test-motor";
  m.travel_m = 0.1;
  return m;
}

/// A calibration of test_motor() (the nominal table), id = its checksum.
ve::core::Calibration good_calibration() {
  const ve::core::MotorConfig m = test_motor();
  ve::core::Calibration cal;
  cal.info.motor = m.name;
  cal.info.hall_count = m.hall.count;
  cal.info.magnet_pitch_m = m.magnet_pitch_m;
  cal.info.method = "reference";
  cal.info.created_utc = "2026-11-25T12:00:00Z";
  cal.table = ve::core::nominal_hall_table(m);
  cal.info.id = ve::core::calibration_checksum(cal);
  return cal;
}

// ---------------------------------------------------------------------------
// The cases

enum class Kind { machine, motor, calibration, layout };

const char* file_name(Kind k) {
  switch (k) {
    case Kind::machine: return "machine.yaml";
    case Kind::motor: return "motor.yaml";
    case Kind::calibration: return "x.cal.yaml";
    case Kind::layout: return "layout.yaml";
  }
  return "?";
}

struct Case {
  std::string name;   ///< for messages
  Kind kind;
  std::string key;    ///< key changed ("" when the whole file is replaced)
  std::string value;  ///< its new text, or the whole file
  std::string field;  ///< the field the message must name ("" for a problem without one)
  std::string expect; ///< text the message must contain ("" for none beyond file and field)
  /// How the file is replaced: text (key or whole), or a special file in its place.
  enum class Special { none, whole, fifo, dev_zero, directory, missing, sparse_huge } special = Special::none;
  /// Only for calibrations: the file written by the program itself (a valid checksum)
  /// from good_calibration() changed by `mutate`.
  void (*mutate)(ve::core::Calibration&) = nullptr;
  bool also_run_and_evaluate = false;
  /// The file the message must name when it is not the changed one (a cross-check
  /// reported in the machine file).
  std::string named_file;
  /// A second key changed too (a consistency check between two keys).
  std::string key2, value2;
};

/// Values that are wrong for every number; each numeric key gets all of `always` and
/// one of `rotating` (so every kind of bad text meets every file kind).
const std::vector<std::pair<std::string, std::string>> kAlways = {
    {"nan", "expected a"}, {"1e999", "1e999"}, {"[1, 2]", "expected"}};
const std::vector<std::pair<std::string, std::string>> kRotating = {
    {".inf", "expected a"}, {"-.inf", "expected a"}, {"abc", "expected"},
    {"\"5\"", "expected"},         {"{a: 1}", "expected"},         {"", "expected"},
    {"0x10", "expected"},          {"1,5", "expected"},            {"true", "expected"}};

struct NumberKey {
  const char* key;
  std::vector<const char*> out_of_range;  ///< values outside the key's range
};

void add_number_cases(std::vector<Case>& cases, Kind kind, const std::string& prefix_in_message,
                      const std::vector<NumberKey>& keys, const std::string& key_prefix = "") {
  static std::size_t rotate = 0;
  for (const auto& k : keys) {
    const std::string key = key_prefix + k.key;
    const std::string field = prefix_in_message + k.key;
    for (const char* v : k.out_of_range)
      cases.push_back({std::string(file_name(kind)) + " " + key + " = " + v, kind, key, v, field, "out of range"});
    for (const auto& [v, why] : kAlways)
      cases.push_back({std::string(file_name(kind)) + " " + key + " = " + v, kind, key, v, field, why});
    const auto& [v, why] = kRotating[rotate++ % kRotating.size()];
    cases.push_back({std::string(file_name(kind)) + " " + key + " = '" + v + "'", kind, key, v, field, why});
  }
}

std::vector<Case> motor_cases() {
  std::vector<Case> c;
  add_number_cases(c, Kind::motor, "",
                   {{"magnet_pitch_m", {"0", "-0.012", "1e-300", "2"}},
                    {"travel_m", {"0", "-1", "1e12", "1e-9"}},
                    {"sample_rate_hz", {"99", "1e9", "0"}},
                    {"hall.count", {"0", "9", "-1"}},
                    {"hall.spacing_m", {"0", "-0.0015", "5"}},
                    {"hall.offset_v", {"-100", "1e300"}},
                    {"hall.amplitude_v", {"0", "-1", "1e6"}},
                    {"hall.noise_v", {"-0.001", "10"}},
                    {"hall.saturation_margin_v", {"-1", "3"}},
                    {"adc.bits", {"7", "25", "64"}},
                    {"adc.min_v", {"-1e300", "51"}},
                    {"adc.max_v", {"1e300", "-51"}},
                    {"accelerometer.noise_mps2", {"-1", "1e9"}},
                    {"accelerometer.range_mps2", {"0", "-160", "1e9"}},
                    {"filter.jerk_std_mps3", {"0", "1e30"}},
                    {"filter.hall_position_floor_m", {"-1e-7", "1"}},
                    {"filter.hall_systematic_std_m", {"-1", "0.5"}},
                    {"filter.gate_sigma", {"0", "1e9"}},
                    {"filter.initial_position_std_m", {"0", "1e9"}},
                    {"filter.initial_velocity_std_mps", {"0", "1e9"}},
                    {"filter.initial_acceleration_std_mps2", {"0", "1e9"}},
                    {"filter.snap_std_mps4", {"-1", "1e300"}},
                    {"filter.accel_bias_std_mps2", {"-0.1"}},
                    {"filter.accel_bias_random_walk_mps2_per_sqrt_s", {"-1e-3"}},
                    {"filter.accel_scale_std", {"0.6"}},
                    {"filter.accel_scale_random_walk_per_sqrt_s", {"-1"}},
                    {"filter.accel_spike_mps2", {"0"}},
                    {"filter.hall_rejections_before_reset", {"0", "1001"}},
                    {"filter.vibration_random_walk_mps2_per_sqrt_s", {"-0.01"}},
                    {"filter.steady_jerk_std_mps3", {"-0.02"}},
                    {"filter.steady_position_walk_m_per_sqrt_s", {"-1"}},
                    {"filter.steady_hall_position_floor_m", {"-1"}},
                    {"filter.steady_jerk_limit_mps3", {"0"}},
                    {"filter.steady_hold_s", {"0", "1e6"}},
                    {"filter.steady_exit_cusum", {"0"}},
                    {"filter.accel_bias_step_cusum", {"-40"}},
                    {"filter.accel_bias_step_std_mps2", {"0"}},
                    {"filter.valid_position_accuracy_m", {"0", "10"}},
                    {"filter.valid_velocity_accuracy_mps", {"0"}},
                    {"filter.valid_confidence_sigma", {"0.1", "11"}},
                    {"filter.sensor_readmit_s", {"0", "61"}},
                    {"filter.sensor_readmit_sigma", {"0.5"}},
                    {"filter.hall_gain_random_walk_per_sqrt_s", {"-2e-4"}},
                    {"filter.hall_offset_random_walk_v_per_sqrt_s", {"-1"}},
                    {"filter.hall_gain_initial_std", {"0.6"}},
                    {"filter.hall_offset_initial_std_v", {"2"}},
                    {"filter.hall_drift_cusum", {"-1"}},
                    {"filter.hall_gain_limit", {"0", "0.6"}},
                    {"filter.hall_offset_limit_v", {"0", "2"}}});
  // Consistency between keys.
  c.push_back({"motor offset_v outside the ADC range", Kind::motor, "hall.offset_v", "6", "hall.offset_v",
               "inside the ADC range"});
  c.push_back({"motor max_v not above min_v", Kind::motor, "adc.max_v", "0", "adc.max_v", "greater than min_v"});
  Case periods{"motor travel of 99000 periods", Kind::motor, "travel_m", "99", "travel_m", "magnet periods"};
  periods.key2 = "magnet_pitch_m";
  periods.value2 = "0.001";
  c.push_back(periods);
  c.push_back({"motor spacing puts sensors 1.5 m apart", Kind::motor, "hall.spacing_m", "0.5", "hall.spacing_m",
               "sensors span"});
  c.push_back({"motor offsets_m of 3 for 4 sensors", Kind::motor, "hall.spacing_m", "0.0015\n  offsets_m: [0, 0.001, 0.002]",
               "hall.offsets_m", "count is 4"});
  c.push_back({"motor offsets_m far away", Kind::motor, "hall.spacing_m", "0.0015\n  offsets_m: [0, 0.001, 0.002, 5]",
               "hall.offsets_m[3]", "out of range"});
  c.push_back({"motor hall.count as a float", Kind::motor, "hall.count", "2.5", "hall.count", "expected an integer"});
  c.push_back({"motor bits as a float", Kind::motor, "adc.bits", "12.5", "adc.bits", "expected an integer"});
  c.push_back({"motor unknown key", Kind::motor, "travel_m", "0.1\ntravel: 1", "travel", "did you mean 'travel_m'"});
  c.push_back({"motor duplicate key", Kind::motor, "travel_m", "0.1\ntravel_m: 0.2", "travel_m", "duplicate key"});
  c.push_back({"motor name empty", Kind::motor, "motor", "\"\"", "motor", "must not be empty"});
  c.push_back({"motor boolean as yes", Kind::motor, "filter.hall_adaptation", "yes", "filter.hall_adaptation",
               "expected true or false"});
  c.push_back({"motor accelerometer as a list", Kind::motor, "accelerometer.range_mps2",
               "160\nfilter_extra: [1, 2]", "filter_extra", "unknown key"});
  c.push_back({"motor 400-digit travel", Kind::motor, "travel_m", std::string(400, '9'), "travel_m", "(400 characters)"});
  return c;
}

std::vector<Case> machine_cases() {
  std::vector<Case> c;
  add_number_cases(c, Kind::machine, "",
                   {{"dds.domain", {"-1", "233"}}, {"dds.deadline_ms", {"0", "1e9"}}});
  add_number_cases(c, Kind::machine, "axes[0].",
                   {{"output.counts_per_m", {"0", "-1e7", "1e99"}},
                    {"homing.position_m", {"-0.01", "0.2", "1e300"}},
                    {"driver.profile.start_m", {"-1", "5"}},
                    {"driver.profile.velocity_mps", {"1e6"}},
                    {"driver.profile.acceleration_mps2", {"-1e9"}},
                    {"driver.profile.max_velocity_mps", {"0"}},
                    {"driver.profile.max_acceleration_mps2", {"0", "1e9"}},
                    {"driver.profile.max_jerk_mps3", {"0"}},
                    {"driver.profile.dwell_s", {"-1", "1e9"}},
                    {"driver.profile.min_m", {"-1"}},
                    {"driver.profile.max_m", {"10"}},
                    {"driver.imperfections.magnet_strength_std", {"-0.1", "0.9"}},
                    {"driver.imperfections.magnet_placement_std_m", {"0.01"}},
                    {"driver.imperfections.field_third_harmonic", {"0.5"}},
                    {"driver.imperfections.sensor_placement_std_m", {"0.1"}},
                    {"driver.imperfections.sensor_gain_std", {"2"}},
                    {"driver.imperfections.sensor_offset_std_v", {"-1"}},
                    {"driver.imperfections.hall_delay_s", {"1"}},
                    {"driver.imperfections.coil_field_v_per_mps2", {"0.2"}},
                    {"driver.imperfections.accel_bias_mps2", {"1e9"}},
                    {"driver.imperfections.accel_scale_error", {"-1"}},
                    {"driver.imperfections.accel_bias_random_walk_mps2_per_sqrt_s", {"-1"}},
                    {"driver.imperfections.accel_delay_s", {"0.25"}},
                    {"driver.imperfections.frame_reaction_ratio", {"-2"}},
                    {"driver.imperfections.frame_vibration_mps2", {"-0.03"}},
                    {"driver.imperfections.frame_vibration_hz", {"0", "1e9"}},
                    {"driver.temperature.delta_k", {"150"}},
                    {"driver.temperature.start_s", {"-1"}},
                    {"driver.temperature.duration_s", {"-1"}},
                    {"driver.temperature.magnet_remanence_per_k", {"-0.012"}},
                    {"driver.temperature.hall_gain_tc_std_per_k", {"0.01"}},
                    {"driver.temperature.reference_c", {"-300"}},
                    {"driver.temperature.report_noise_k", {"-1"}},
                    {"driver.temperature.report_resolution_k", {"-0.0625"}}},
                   "axes[0].");
  // Integers (no "nan" text cases: those are covered above).
  for (const auto& [key, v, why] : std::vector<std::tuple<std::string, std::string, std::string>>{
           {"axes[0].output.direction", "0", "must be 1 or -1"},
           {"axes[0].output.direction", "2", "must be 1 or -1"},
           {"axes[0].output.direction", "1.0", "expected an integer"},
           {"axes[0].output.preset_counts", "10000000000000000", "out of range"},
           {"axes[0].output.preset_counts", "9223372036854775808", "out of range"},
           {"axes[0].output.publish_divider", "0", "out of range"},
           {"axes[0].output.publish_divider", "1001", "out of range"},
           {"axes[0].id", "-1", "out of range"},
           {"axes[0].id", "4294967296", "out of range"},
           {"axes[0].driver.noise_seed", "-1", "out of range"},
           {"axes[0].driver.noise_seed", "1.5", "expected an integer"},
           {"axes[0].driver.imperfections.track_seed", "nan", "expected an integer"},
           {"realtime.sample_thread_priority", "100", "must be in [0, 99]"},
           {"realtime.sample_thread_priority", "-1", "must be in [0, 99]"},
           {"dds.domain", "1.5", "expected an integer"},
           {"dds.domain", std::string(400, '9'), "(400 characters)"},
           {"dds.deadline_ms", "2.5", "whole number of milliseconds"},
           {"axes[0].name", "this-name-is-too-long", "1 to 15 characters"},
           {"axes[0].name", "\"a b\"", "may contain only"},
           {"axes[0].driver.type", "simulated", "is not one of"},
           {"axes[0].homing.mode", "bogus", "is not one of"},
           {"axes[0].driver.profile.type", "teleport", "is not one of"},
           {"axes[0].driver.realtime", "yes", "expected true or false"},
           {"realtime.lock_memory", "1", "expected true or false"},
           {"realtime.sample_loop", "per_group", "is not one of"},
           {"axes[0].driver.temperature.profile", "hot", "is not one of"},
       })
    c.push_back({"machine.yaml " + key + " = " + v, Kind::machine, key, v, key, why});
  // Cross-checks: faults on sensors the motor does not have, windows, kinds.
  const std::string f = "axes[0].driver.faults";
  c.push_back({"fault on sensor 7 of a 4-sensor motor", Kind::machine, f,
               "[{kind: hall_stuck_high, sensor: 7, start_s: 1}]", f + "[0].sensor", "has 4 Hall sensors"});
  c.push_back({"fault on sensor 4 of a 4-sensor motor", Kind::machine, f, "[{kind: hall_noisy, sensor: 4, magnitude: 0.1}]",
               f + "[0].sensor", "4 out of range [0, 3]"});
  c.push_back({"fault on sensor -1", Kind::machine, f, "[{kind: hall_stuck_low, sensor: -1}]", f + "[0].sensor",
               "out of range"});
  c.push_back({"fault on sensor 1e9", Kind::machine, f, "[{kind: hall_stuck_low, sensor: 1000000000}]",
               f + "[0].sensor", "out of range"});
  c.push_back({"fault ending before it starts", Kind::machine, f, "[{kind: hall_noisy, sensor: 1, start_s: 3, end_s: 1}]",
               f + "[0].end_s", "must be after start_s"});
  c.push_back({"fault starting at nan", Kind::machine, f, "[{kind: hall_noisy, sensor: 1, start_s: nan}]",
               f + "[0].start_s", "expected a number"});
  c.push_back({"fault starting at -1", Kind::machine, f, "[{kind: hall_noisy, sensor: 1, start_s: -1}]",
               f + "[0].start_s", "out of range"});
  c.push_back({"intermittent fault probability 2", Kind::machine, f,
               "[{kind: hall_intermittent, sensor: 1, magnitude: 2}]", f + "[0].magnitude", "out of range [0, 1]"});
  c.push_back({"fault of an unknown kind", Kind::machine, f, "[{kind: hall_melted, sensor: 1}]", f + "[0].kind",
               "is not one of"});
  c.push_back({"accelerometer fault with a sensor index", Kind::machine, f, "[{kind: accel_dead, sensor: 2}]",
               f + "[0].sensor", "only used with the hall_"});
  c.push_back({"silent node with a magnitude", Kind::machine, f,
               "[{kind: no_samples, start_s: 1, end_s: 2, magnitude: 1}]", f + "[0].magnitude",
               "not used with kind no_samples"});
  c.push_back({"silent node with a sensor index", Kind::machine, f, "[{kind: no_samples, sensor: 2}]",
               f + "[0].sensor", "only used with the hall_"});
  c.push_back({"silent node ending before it starts", Kind::machine, f,
               "[{kind: no_samples, start_s: 2, end_s: 1.5}]", f + "[0].end_s", "must be after start_s"});
  c.push_back({"five faults", Kind::machine, f,
               "[{kind: accel_dead}, {kind: accel_dead}, {kind: accel_dead}, {kind: accel_dead}, {kind: accel_dead}]",
               f, "at most 4"});
  c.push_back({"faults as a mapping", Kind::machine, f, "{kind: accel_dead}", f, "expected a list of faults"});
  c.push_back({"home NaN", Kind::machine, "axes[0].homing.position_m", ".nan", "axes[0].homing.position_m",
               "expected a number"});
  c.push_back({"start outside [min_m, max_m]", Kind::machine, "axes[0].driver.profile.start_m", "0.095",
               "axes[0].driver.profile.start_m", "outside [min_m, max_m]"});
  c.push_back({"min_m above max_m", Kind::machine, "axes[0].driver.profile.min_m", "0.095",
               "axes[0].driver.profile.max_m", "must be less than max_m"});
  c.push_back({"temperature rise beyond 100 K", Kind::machine, "axes[0].driver.temperature.delta_k", "60\n        offset_k: 60",
               "axes[0].driver.temperature.delta_k", "the temperature rise reaches 120 K"});
  c.push_back({"publish divider beyond the deadline", Kind::machine, "axes[0].output.publish_divider", "40",
               "axes[0].output.publish_divider", "at least two published periods"});
  c.push_back({"missing motor file", Kind::machine, "axes[0].motor", "nowhere.yaml", "axes[0].motor",
               "No such file or directory"});
  c.push_back({"motor is a directory", Kind::machine, "axes[0].motor", ".", "axes[0].motor", "Is a directory"});
  c.push_back({"motor is /dev/zero", Kind::machine, "axes[0].motor", "/dev/zero", "axes[0].motor",
               "not a regular file"});
  c.push_back({"profiles file is /dev/zero", Kind::machine, "dds.deadline_ms", "5\n  profiles_file: /dev/zero",
               "dds.profiles_file", "not a regular file"});
  c.push_back({"unknown statistics topic", Kind::machine, "dds.deadline_ms", "5\n  statistics: [LATENCY]",
               "dds.statistics[0]", "not a Fast DDS statistics topic"});
  c.push_back({"CPU that does not exist", Kind::machine, "realtime.required", "false\n  cpu_affinity: [100000]",
               "realtime.cpu_affinity[0]", ""});
  c.push_back({"unknown top-level key", Kind::machine, "machine", "test-machine\ncolour: red", "colour",
               "unknown key"});
  c.push_back({"signature homing without a calibration", Kind::machine, "axes[0].homing.mode", "signature",
               "axes[0].homing.mode", "needs a calibration"});
  c.push_back({"state file without signature homing", Kind::machine, "axes[0].homing.position_m",
               "0.05\n      state_file: x.state", "axes[0].homing.state_file", "only used with mode: signature"});
  c.push_back({"socketcan key on a sim axis", Kind::machine, "axes[0].driver.realtime", "false\n      interface: can0",
               "axes[0].driver.interface", "only used with type: socketcan"});
  return c;
}

std::vector<Case> layout_cases() {
  std::vector<Case> c;
  add_number_cases(c, Kind::layout, "",
                   {{"sample_rate_hz", {"0", "-4000", "1e9"}},
                    {"signals.hall_0.scale", {"1e300", "1e-300"}},
                    {"signals.accel.offset", {"1e300"}}});
  for (const auto& [key, v, field, why] : std::vector<std::tuple<std::string, std::string, std::string, std::string>>{
           {"frame_length", "65", "frame_length", "out of range"},
           {"frame_length", "-1", "frame_length", "out of range"},
           {"frame_length", "12", "frame_length", "classic CAN frame carries 0..8 bytes"},
           {"samples_per_frame", "0", "samples_per_frame", "out of range"},
           {"samples_per_frame", "33", "samples_per_frame", "out of range"},
           {"samples_per_frame", "2", "sample_stride_bits", "must be > 0 when samples_per_frame > 1"},
           {"sample_stride_bits", "513", "sample_stride_bits", "out of range"},
           {"hall_count", "0", "hall_count", "out of range"},
           {"hall_count", "9", "hall_count", "out of range"},
           {"hall_count", "3", "signals.hall_3", "beyond hall_count"},
           {"hall_count", "5", "signals", "missing (hall_count is 5)"},
           {"hall_count", std::string(400, '9'), "hall_count", "(400 characters)"},
           {"can_id", "0x800", "can_id", "does not fit a 11-bit identifier"},
           {"can_id", "0x20000000", "can_id", "expected an identifier"},
           {"can_id", "-1", "can_id", "expected an identifier"},
           {"can_id", "0x4G0", "can_id", "expected an identifier"},
           {"fd", "maybe", "fd", "expected true or false"},
           {"signals.hall_0.length", "0", "signals.hall_0.length", "out of range"},
           {"signals.hall_0.length", "33", "signals.hall_0.length", "out of range"},
           {"signals.hall_0.start_bit", "-1", "signals.hall_0.start_bit", "out of range"},
           {"signals.hall_0.start_bit", "512", "signals.hall_0.start_bit", "out of range"},
           {"signals.hall_0.start_bit", "60", "signals.hall_0", "outside the 8-byte frame"},
           {"signals.hall_1.start_bit", "6", "signals.hall_1", "overlaps another signal"},
           {"signals.hall_0.scale", "0", "signals.hall_0.scale", "must be non-zero"},
           {"signals.hall_0.byte_order", "middle_endian", "signals.hall_0.byte_order", "is not one of"},
           {"signals.hall_0.signed", "2", "signals.hall_0.signed", "expected true or false"},
           {"signals.accel.length", "1e3", "signals.accel.length", "expected an integer"},
           {"signals.sequence.length", "12", "signals.sequence", "outside the 11-bit identifier"},
       })
    c.push_back({"layout.yaml " + key + " = " + v.substr(0, 20), Kind::layout, key, v, field, why});
  // The layout and the motor must agree.
  Case rate{"layout rate differs from the motor's", Kind::layout, "sample_rate_hz", "8000", "axes[0].driver.layout",
            "differs from motor"};
  rate.named_file = "machine-can.yaml";
  c.push_back(rate);

  c.push_back({"layout unknown signal", Kind::layout, "hall_count", "4\nsignals_extra: 1", "signals_extra",
               "unknown key"});
  return c;
}

// Calibration files written by the program (valid checksum) whose table is unusable.
void step_1e12(ve::core::Calibration& c) {
  c.table.step_m = 1e-12;
  c.table.points = 4;
  c.table.v.resize(4u * c.table.sensors);
  for (std::size_t i = 0; i < c.table.v.size(); ++i) c.table.v[i] = 1.0 + 0.5 * static_cast<double>(i % 4);
}
void short_grid(ve::core::Calibration& c) {
  const int keep = c.table.points / 2;
  std::vector<double> v;
  for (int s = 0; s < c.table.sensors; ++s)
    v.insert(v.end(), c.table.v.begin() + s * c.table.points, c.table.v.begin() + s * c.table.points + keep);
  c.table.v = v;
  c.table.points = keep;
}
void late_start(ve::core::Calibration& c) { c.table.start_m = 0.01; }
void coarse_step(ve::core::Calibration& c) {
  c.table.step_m = 0.012;
  c.table.points = 10;
  c.table.v.resize(10u * c.table.sensors);
}
void fine_step(ve::core::Calibration& c) { c.table.step_m = 0.012 / 10000.0; }
void huge_value(ve::core::Calibration& c) { c.table.v[17] = 1e6; }
void negative_value(ve::core::Calibration& c) { c.table.v[c.table.points + 3] = -40.0; }
void flat_row(ve::core::Calibration& c) {
  for (int k = 0; k < c.table.points; ++k) c.table.v[static_cast<std::size_t>(2 * c.table.points + k)] = 2.5;
}
void big_delay(ve::core::Calibration& c) { c.model.hall_delay_s = 0.5; }
void bad_scale(ve::core::Calibration& c) { c.model.accel_scale = 0.1; }
void three_sensors(ve::core::Calibration& c) {
  c.table.sensors = 3;
  c.table.v.resize(3u * c.table.points);
  c.info.hall_count = 3;
}

std::vector<Case> calibration_cases() {
  std::vector<Case> c;
  const auto gen = [&c](const char* name, void (*m)(ve::core::Calibration&), const char* field, const char* why) {
    Case x{std::string("calibration (valid checksum): ") + name, Kind::calibration, "", "", field, why};
    x.mutate = m;
    x.also_run_and_evaluate = true;
    c.push_back(x);
  };
  gen("table step of 1e-12 m", step_1e12, "table.step_m", "unusable table");
  gen("grid covering half the travel", short_grid, "table.points", "not the motor's travel");
  gen("grid starting inside the travel", late_start, "table.start_m", "start_m must be <= 0");
  gen("grid step of a whole pitch", coarse_step, "table.step_m", "too coarse");
  gen("grid step of pitch / 10000", fine_step, "table.step_m", "finer than any sensor resolves");
  gen("a value of 1 MV", huge_value, "table.sensors[0]", "not a Hall reading");
  gen("a value of -40 V", negative_value, "table.sensors[1]", "not a Hall reading");
  gen("a flat row", flat_row, "table.sensors[2]", "carries no position");
  gen("a Hall delay of 0.5 s", big_delay, "sensor_model.hall_delay_s", "out of range [0, 0.01] s");
  gen("an accelerometer scale of 0.1", bad_scale, "sensor_model.accel_scale", "out of range [0.5, 2]");
  gen("three sensors for a 4-sensor motor", three_sensors, "hall_count", "incompatible sensor layout");
  // Edited by hand (the checksum then disagrees too; the edit is named first).
  for (const auto& [key, v, why] : std::vector<std::tuple<std::string, std::string, std::string>>{
           {"table.step_m", "0", "the grid must increase"},
           {"table.step_m", "-0.000046875", "the grid must increase"},
           {"table.step_m", "nan", "expected a number"},
           {"table.step_m", "1e999", "out of range"},
           {"table.start_m", "1e300", "out of range"},
           {"table.start_m", ".inf", "expected a number"},
           {"table.points", "3", "out of range"},
           {"table.points", "1000000000", "out of range"},
           {"table.points", "-5", "out of range"},
           {"table.points", std::string(400, '9'), "(400 characters)"},
           {"version", "2", "unsupported version"},
           {"version", "one", "expected an integer"},
           {"motor", "other-motor", "other motor"},
           {"hall_count", "8", "incompatible sensor layout"},
           {"magnet_pitch_m", "0.016", "other motor"},
           {"magnet_pitch_m", "nan", "expected a number"},
           {"format", "something-else", "not a calibration file"},
           {"id", "\"0000000000000000\"", "checksum"},
           {"sensor_model.hall_delay_s", "-1", "out of range"},
           {"sensor_model.coil_field_v_per_mps2", "5", "out of range"},
           {"sensor_model.accel_delay_s", "1e300", "out of range"},
           {"sensor_model.accel_bias_mps2", "nan", "expected a number"},
           {"sensor_model.frame_vibration_hz", "-1", "out of range"},
           {"sensor_model.frame_vibration_mps2", "1e9", "out of range"},
       })
    c.push_back({"x.cal.yaml " + key + " = " + v, Kind::calibration, key, v, key, why});
  c.push_back({"x.cal.yaml table.points = 100", Kind::calibration, "table.points", "100", "table.sensors[0]",
               "values but points is 100"});
  return c;
}

/// Whole files replaced, for every kind.
std::vector<Case> whole_file_cases() {
  std::vector<Case> c;
  using S = Case::Special;
  const std::pair<Kind, std::string> first_key[] = {
      {Kind::machine, "axes"}, {Kind::motor, "motor"}, {Kind::calibration, "format"}, {Kind::layout, "can_id"}};
  for (const auto& [kind, required] : first_key) {
    const std::string n = file_name(kind);
    auto add = [&](const std::string& what, const std::string& text, const std::string& field, const std::string& why,
                   S special = S::whole) {
      Case x{n + ": " + what, kind, "", text, field, why};
      x.special = special;
      c.push_back(x);
    };
    add("empty", "", required, "missing required key");
    add("only a comment", "# nothing here\n", required, "missing required key");
    add("a second YAML document", "GOOD\n---\nmachine: other\n", "", "a second YAML document");
    add("an empty second document", "GOOD\n---\n", "", "a second YAML document");
    add("a scalar", "42\n", "", "expected a mapping");
    add("a list", "- 1\n- 2\n", "", "expected a mapping");
    static const char kElfHeader[] = "\x7f" "ELF\x02\x01\x01\0\0\0\x03\0>\0\x01\0\0\0";
    add("binary bytes", std::string(kElfHeader, sizeof kElfHeader - 1), "", "");
    add("tab indentation", "GOOD\n\tbad: 1\n", "", "malformed YAML");
    add("an unclosed flow sequence", "GOOD\nx: [1, 2\n", "", "malformed YAML");
    add("deep nesting", std::string(20000, '[') + std::string(20000, ']') + "\n", "", "malformed YAML");
    add("a FIFO", "", "", "not a regular file (a FIFO)", S::fifo);
    add("/dev/zero", "", "", "not a regular file (a character device)", S::dev_zero);
    add("a directory", "", "", "Is a directory", S::directory);
    add("missing", "", "", "No such file or directory", S::missing);
    add("larger than the bound", "", "", "too large", S::sparse_huge);
  }
  return c;
}

// ---------------------------------------------------------------------------

class BadInputFiles : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new ve::test::TempDir("ve_bad_files");
    good_ = dir_->path / "good";
    fs::create_directories(good_);
    write_all(good_ / "motor.yaml", kMotor);
    write_all(good_ / "machine.yaml", machine_text(false));
    write_all(good_ / "machine-cal.yaml", machine_text(true));
    write_all(good_ / "layout.yaml", layout_text());
    write_all(good_ / "machine-can.yaml", kCanMachine);
    write_all(good_ / "x.cal.yaml", ve::config::format_calibration(good_calibration()));
    // A short raw log of the good machine for `evaluate`.
    const Outcome rec = run_binary({"record", "--config", (good_ / "machine.yaml").string(), "--out",
                                    (good_ / "raw.csv").string(), "--duration", "0.2", "--fast"},
                                   good_);
    record_ok_ = rec.exited && rec.code == 0 && fs::exists(good_ / "raw.csv");
    if (!record_ok_) record_log_ = describe(rec);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }

  static std::string machine_text(bool calibrated) {
    std::string m = kMachine;
    m.replace(m.find("CALIBRATION"), 11, calibrated ? "    calibration: x.cal.yaml\n" : "");
    return m;
  }

  /// A fresh directory with the good files; the case's file changed in it.
  static fs::path prepare(const Case& c, int index, std::string& config) {
    const fs::path d = dir_->path / ("case" + std::to_string(index));
    fs::create_directories(d);
    for (const char* f : {"motor.yaml", "machine.yaml", "machine-cal.yaml", "layout.yaml", "machine-can.yaml",
                          "x.cal.yaml"})
      fs::copy_file(good_ / f, d / f);
    config = (d / (c.kind == Kind::calibration ? "machine-cal.yaml"
                   : c.kind == Kind::layout    ? "machine-can.yaml"
                                               : "machine.yaml"))
                 .string();
    const fs::path target = d / file_name(c.kind);
    using S = Case::Special;
    if (c.mutate) {
      ve::core::Calibration cal = good_calibration();
      c.mutate(cal);
      cal.info.id = ve::core::calibration_checksum(cal);  // written by the program: a valid checksum
      write_all(target, ve::config::format_calibration(cal));
      return d;
    }
    const std::string good = read_all(target);
    switch (c.special) {
      case S::none: {
        std::string text = good;
        if (!replace_key(text, c.key, c.value)) ADD_FAILURE() << c.name << ": no key " << c.key << " in\n" << good;
        if (!c.key2.empty() && !replace_key(text, c.key2, c.value2))
          ADD_FAILURE() << c.name << ": no key " << c.key2 << " in\n" << good;
        write_all(target, text);
        break;
      }
      case S::whole: {
        std::string text = c.value;
        const auto at = text.find("GOOD");
        if (at != std::string::npos) text.replace(at, 4, good.substr(0, good.size() - 1));
        write_all(target, text);
        break;
      }
      case S::fifo:
        fs::remove(target);
        EXPECT_EQ(::mkfifo(target.c_str(), 0644), 0) << target;
        break;
      case S::dev_zero:
        fs::remove(target);
        fs::create_symlink("/dev/zero", target);
        break;
      case S::directory:
        fs::remove(target);
        fs::create_directory(target);
        break;
      case S::missing:
        fs::remove(target);
        break;
      case S::sparse_huge: {
        // A file larger than the kind's bound, sparse so the test writes nothing.
        fs::resize_file(target, c.kind == Kind::calibration ? (65u << 20) : (5u << 20));
        break;
      }
    }
    // The machine file named on the command line points at itself.
    if (c.kind == Kind::machine && c.special != S::none) config = target.string();
    return d;
  }

  static void run_cases(const std::vector<Case>& cases, int first_index);

  static ve::test::TempDir* dir_;
  static fs::path good_;
  static bool record_ok_;
  static std::string record_log_;
};

ve::test::TempDir* BadInputFiles::dir_ = nullptr;
fs::path BadInputFiles::good_;
bool BadInputFiles::record_ok_ = false;
std::string BadInputFiles::record_log_;

TEST_F(BadInputFiles, TheGoodFilesPass) {
  for (const char* m : {"machine.yaml", "machine-cal.yaml"}) {
    const Outcome o = run_binary({"check", "--config", (good_ / m).string()}, dir_->path);
    EXPECT_TRUE(o.exited && o.code == 0) << m << ": " << describe(o);
  }
  // The CAN machine loads; without SocketCAN in this kernel only the socket fails.
  const Outcome can = run_binary({"check", "--config", (good_ / "machine-can.yaml").string()}, dir_->path);
  EXPECT_TRUE(can.exited) << describe(can);
  EXPECT_EQ(can.out.find("layout.yaml:"), std::string::npos) << describe(can);
  EXPECT_EQ(can.out.find("motor.yaml:"), std::string::npos) << describe(can);
  EXPECT_TRUE(record_ok_) << record_log_;
}

/// Runs every case; each must be refused by name, without a crash or a hang.
void BadInputFiles::run_cases(const std::vector<Case>& cases, int first_index) {
  int index = first_index;
  int domain = -1;  // `run` is refused before it joins a domain; one is reserved all the same
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    std::string config;
    const fs::path d = prepare(c, index++, config);
    const std::string file = (d / (c.named_file.empty() ? std::string(file_name(c.kind)) : c.named_file)).string();

    const Outcome o = run_binary({"check", "--config", config}, d);
    ASSERT_FALSE(o.hung) << c.name << ": " << describe(o);
    EXPECT_EQ(o.signal, 0) << c.name << ": " << describe(o);
    EXPECT_TRUE(o.exited && o.code == 1) << c.name << " (check: 1 = problems found): " << describe(o);
    const std::string text = o.out + o.err;
    EXPECT_NE(text.find(file), std::string::npos) << c.name << ": the file is not named: " << describe(o);
    if (!c.field.empty()) {
      // FILE:LINE:COL: FIELD: ...
      const std::regex where(std::regex_replace(file, std::regex(R"([.^$|()\[\]{}*+?\\])"), R"(\$&)") +
                             R"(:[0-9]+:[0-9]+: )" +
                             std::regex_replace(c.field, std::regex(R"([.^$|()\[\]{}*+?\\])"), R"(\$&)") + ": ");
      EXPECT_TRUE(std::regex_search(text, where))
          << c.name << ": no '" << file << ":LINE:COL: " << c.field << ": ': " << describe(o);
    }
    if (!c.expect.empty())
      EXPECT_NE(text.find(c.expect), std::string::npos) << c.name << ": no '" << c.expect << "': " << describe(o);
    // A file the program wrote is refused for what it holds, not called damaged.
    if (c.mutate) EXPECT_EQ(text.find("checksum"), std::string::npos) << c.name << ": " << describe(o);
    // Never hundreds of digits: numbers are printed compactly.
    EXPECT_FALSE(std::regex_search(text, std::regex("[0-9]{41}"))) << c.name << ": " << describe(o);

    if (c.also_run_and_evaluate && record_ok_) {
      const Outcome ev = run_binary(
          {"evaluate", "--config", config, "--log", (good_ / "raw.csv").string()}, d);
      ASSERT_FALSE(ev.hung) << c.name << ": evaluate: " << describe(ev);
      EXPECT_EQ(ev.signal, 0) << c.name << ": evaluate: " << describe(ev);
      EXPECT_TRUE(ev.exited && ev.code == 2) << c.name << " (evaluate: 2 = unusable input): " << describe(ev);
      EXPECT_NE(ev.err.find(file), std::string::npos) << c.name << ": evaluate: " << describe(ev);
      EXPECT_NE(ev.err.find(c.expect), std::string::npos) << c.name << ": evaluate: " << describe(ev);

      if (domain < 0) {
#ifdef VE_FILES_HAVE_TEST_DOMAIN
        domain = ve::test::dds_domain();  // one per test, held while its processes may run
#else
        domain = 222;
#endif
      }
      const Outcome run = run_binary({"run", "--config", config, "--domain", std::to_string(domain), "--duration", "1"}, d);
      ASSERT_FALSE(run.hung) << c.name << ": run: " << describe(run);
      EXPECT_EQ(run.signal, 0) << c.name << ": run: " << describe(run);
      EXPECT_TRUE(run.exited && run.code == 2) << c.name << " (run: 2 = unusable input): " << describe(run);
      EXPECT_NE(run.err.find(file), std::string::npos) << c.name << ": run: " << describe(run);
      EXPECT_NE(run.err.find(c.expect), std::string::npos) << c.name << ": run: " << describe(run);
    }
    std::error_code ec;
    fs::remove_all(d, ec);
  }
}

// One test per file kind (each within ctest's per-test timeout under a sanitizer).
TEST_F(BadInputFiles, MotorFiles) { run_cases(motor_cases(), 0); }
TEST_F(BadInputFiles, MachineFiles) { run_cases(machine_cases(), 1000); }
TEST_F(BadInputFiles, CanLayoutFiles) { run_cases(layout_cases(), 2000); }
TEST_F(BadInputFiles, CalibrationFiles) { run_cases(calibration_cases(), 3000); }
TEST_F(BadInputFiles, WholeFilesOfEveryKind) { run_cases(whole_file_cases(), 4000); }

TEST_F(BadInputFiles, TheCorpusHasAtLeast220Cases) {
  std::size_t n = 0;
  for (auto&& part : {motor_cases(), machine_cases(), layout_cases(), calibration_cases(), whole_file_cases()})
    n += part.size();
  std::printf("[ info     ] %zu bad-file cases\n", n);
  EXPECT_GE(n, 220u);
}

}  // namespace
