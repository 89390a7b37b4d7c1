#include "config/calibration_file.hpp"
#include "config/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <filesystem>

namespace ve::config {

namespace {

using schema::Map;
using schema::Value;

// Every refusal starts with one of these, so callers and users can tell a
// damaged file from one that belongs elsewhere.
constexpr const char* kCorrupt = "corrupt: ";
constexpr const char* kOtherMotor = "other motor: ";
constexpr const char* kLayout = "incompatible sensor layout: ";
constexpr const char* kVersion = "unsupported version: ";
constexpr const char* kNotCalibration = "not a calibration file: ";
/// A well-formed file (its checksum may even be right) whose table the estimator
/// cannot use for this motor.
constexpr const char* kUnusable = "unusable table: ";
constexpr const char* kUnreadable = "cannot read calibration file: ";

bool starts_with(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

/// The checksum rounds volts to this unit; the file stores exactly that many
/// decimals so a text round trip gives back the same checksum.
constexpr double kVoltUnit = 1e-6;

/// Most grid points per sensor: a 100 m travel at 1 mm per 10 points, or the longest
/// motor the motor file allows at its finest grid; keeps a damaged `points` from
/// asking for gigabytes.
constexpr int kMaxTablePoints = 10000000;
/// Grid step limits as fractions of the magnet pitch: coarser than pitch / 8 the cubic
/// interpolation is off by more than 1 % of a period; finer than pitch / 4096 it holds
/// nothing a 12-bit ADC can resolve and costs memory (the programs write pitch / 256).
constexpr double kMinPointsPerPitch = 8.0;
constexpr double kMaxPointsPerPitch = 4096.0;
/// A table row must vary by at least this much to carry a position [V].
constexpr double kMinRowSpanV = 1e-3;
/// Grid coverage tolerance [m]: the written grids reach the ends of the travel exactly.
constexpr double kCoverSlackM = 1e-9;

/// What makes a table usable by the estimator for `motor`, beyond its checksum: a grid
/// step that fits the magnet pitch, a grid that covers the whole travel, values a
/// sensor behind this ADC can produce, and rows that vary. Every problem is reported
/// at the key it concerns.
void check_table(Map& t, const Value& sensors, const core::HallTable& table, const core::MotorConfig& motor,
                 bool step_ok, bool start_ok, bool points_ok) {
  const double pitch = motor.magnet_pitch_m;
  if (step_ok && pitch > 0.0) {
    const double lo = pitch / kMaxPointsPerPitch, hi = pitch / kMinPointsPerPitch;
    if (!(table.step_m >= lo && table.step_m <= hi))
      t.value("step_m").error(kUnusable + schema::out_of_range(table.step_m, lo, hi, "m") + " (magnet pitch " +
                              schema::compact_number(pitch) + " m / 4096 .. / 8): " +
                              (table.step_m < lo ? "finer than any sensor resolves" : "too coarse to interpolate"));
  }
  if (step_ok && start_ok && points_ok && motor.travel_m > 0.0) {
    const double end = table.start_m + table.step_m * (table.points - 1);
    if (table.start_m > kCoverSlackM || end < motor.travel_m - kCoverSlackM) {
      const std::string covered = "[" + schema::compact_number(table.start_m) + ", " + schema::compact_number(end) + "]";
      const std::string travel = "[0, " + schema::compact_number(motor.travel_m) + "]";
      if (table.start_m > kCoverSlackM)
        t.value("start_m").error(std::string(kUnusable) + "the grid covers " + covered + " m, not the motor's travel " + travel +
                                 " m: start_m must be <= 0");
      else
        t.value("points").error(std::string(kUnusable) + "the grid covers " + covered + " m, not the motor's travel " + travel +
                                " m: points * step_m falls short by " +
                                schema::compact_number(motor.travel_m - end) + " m");
    }
  }
  if (!table.valid()) return;
  const double span = motor.adc.max_v - motor.adc.min_v;
  const double vlo = motor.adc.min_v - span, vhi = motor.adc.max_v + span;
  for (int s = 0; s < table.sensors; ++s) {
    const double* row = table.v.data() + static_cast<std::size_t>(s) * static_cast<std::size_t>(table.points);
    const auto [mn, mx] = std::minmax_element(row, row + table.points);
    const Value r = sensors.at(static_cast<std::size_t>(s));
    for (int k = 0; k < table.points; ++k) {
      if (!(row[k] >= vlo && row[k] <= vhi)) {
        r.error(std::string(kUnusable) + "value " + std::to_string(k) + ": " + schema::out_of_range(row[k], vlo, vhi, "V") +
                " (the ADC range [" + schema::compact_number(motor.adc.min_v) + ", " +
                schema::compact_number(motor.adc.max_v) + "] V widened by its span): not a Hall reading");
        break;
      }
    }
    if (*mx - *mn < kMinRowSpanV)
      r.error(std::string(kUnusable) + "the row varies by " + schema::compact_number(*mx - *mn) + " V over the travel (less than " +
              schema::compact_number(kMinRowSpanV) + " V): it carries no position");
  }
}

void read_table(Map t, core::HallTable& table, int hall_count, const core::MotorConfig& motor) {
  const bool start_ok = t.require("start_m", table.start_m, schema::in_range(-1000.0, 1000.0, "m"));
  const bool step_ok = t.require("step_m", table.step_m, schema::Check<double>([](const double& x) {
    return x > 0.0 && x <= 1.0 ? std::string()
                               : schema::compact_number(x) + " out of range (0, 1] m: the grid must increase along the travel";
  }));
  const bool points_ok = t.require("points", table.points, schema::in_range(4, kMaxTablePoints, "points"));
  const Value sensors = t.required("sensors");
  if (!sensors.present()) return;
  if (!sensors.is_sequence()) {
    sensors.error(std::string(kCorrupt) + "expected one sequence of values per sensor");
    return;
  }
  const std::size_t rows = sensors.size();
  if (hall_count > 0 && rows != static_cast<std::size_t>(hall_count))
    sensors.error(std::string(kCorrupt) + "table has " + std::to_string(rows) + " sensor rows but hall_count is " +
                  std::to_string(hall_count));
  // Rows are checked before the table is allocated: a damaged `points` must
  // not make us allocate gigabytes.
  std::vector<std::vector<double>> values(rows);
  bool rows_ok = points_ok;
  for (std::size_t s = 0; s < rows; ++s) {
    const Value r = sensors.at(s);
    if (!r.as(values[s])) {
      rows_ok = false;
    } else if (points_ok && values[s].size() != static_cast<std::size_t>(table.points)) {
      r.error(std::string(kCorrupt) + "sensor row has " + std::to_string(values[s].size()) +
              " values but points is " + std::to_string(table.points));
      rows_ok = false;
    }
  }
  // A table whose row count is not the sensor count is not filled in: it could not be
  // used, and its checksum would only repeat that the file is damaged.
  if (rows_ok && rows > 0 && (hall_count <= 0 || rows == static_cast<std::size_t>(hall_count))) {
    table.sensors = static_cast<int>(rows);
    table.v.clear();
    table.v.reserve(rows * static_cast<std::size_t>(table.points));
    for (const auto& row : values) table.v.insert(table.v.end(), row.begin(), row.end());
  }
  check_table(t, sensors, table, motor, step_ok, start_ok, points_ok);
}

/// True when the file's table and sensor model hash to its id: the program wrote it
/// as it is, so what is wrong with it makes it unusable, not damaged.
bool read_calibration(Map root, const core::MotorConfig& expected, core::Calibration& cal, std::size_t first_error,
                      const std::vector<ConfigError>& errors) {
  core::CalibrationInfo& info = cal.info;
  std::string format;
  const Value f = root.required("format");
  if (f.as(format) && format != kCalibrationFormat)
    f.error(std::string(kNotCalibration) + "format is '" + format + "', expected '" + kCalibrationFormat + "'");
  if (errors.size() != first_error) {
    root.discard();
    return false;
  }
  int version = 0;
  const Value ver = root.required("version");
  if (ver.as(version) && version != kCalibrationVersion)
    ver.error(std::string(kVersion) + "version " + std::to_string(version) + "; this program reads version " +
              std::to_string(kCalibrationVersion));
  if (errors.size() != first_error) {
    root.discard();
    return false;
  }

  const Value motor = root.required("motor");
  if (motor.as(info.motor) && info.motor != expected.name)
    motor.error(std::string(kOtherMotor) + "made for motor '" + info.motor + "', this axis has motor '" +
                expected.name + "'");
  const Value halls = root.required("hall_count");
  if (halls.as(info.hall_count) && info.hall_count != expected.hall.count)
    halls.error(std::string(kLayout) + "made for " + std::to_string(info.hall_count) +
                " Hall sensors, the motor has " + std::to_string(expected.hall.count));
  const Value pitch = root.required("magnet_pitch_m");
  if (pitch.as(info.magnet_pitch_m) &&
      std::abs(info.magnet_pitch_m - expected.magnet_pitch_m) > 1e-9 * std::abs(expected.magnet_pitch_m))
    pitch.error(std::string(kOtherMotor) + "made for a magnet pitch of " + schema::compact_number(info.magnet_pitch_m) +
                " m, the motor has " + schema::compact_number(expected.magnet_pitch_m) + " m");
  root.get("method", info.method);
  root.get("created_utc", info.created_utc);
  const Value id = root.required("id");
  id.as(info.id);

  {
    // Absent: ideal sensors (no delays, no coil field, unit scale, no bias).
    Map m = root.map("sensor_model");
    // The value is kept even when out of range, so that the checksum is computed over
    // what the file holds and a file the program wrote reads "unusable", not "corrupt".
    const auto model = [&m](const char* key, double& out, double lo, double hi, const char* unit) {
      if (m.get(key, out) && !(out >= lo && out <= hi)) m.value(key).error(schema::out_of_range(out, lo, hi, unit));
    };
    model("hall_delay_s", cal.model.hall_delay_s, 0.0, 0.01, "s");
    model("coil_field_v_per_mps2", cal.model.coil_field_v_per_mps2, -1.0, 1.0, "V/(m/s^2)");
    // Optional: files written before it was measured have none (taken as exact).
    model("coil_field_std_v_per_mps2", cal.model.coil_field_std_v_per_mps2, 0.0, 1.0, "V/(m/s^2)");
    model("accel_delay_s", cal.model.accel_delay_s, 0.0, 0.01, "s");
    // Optional: files written before it was measured have none (taken as exact).
    model("accel_delay_std_s", cal.model.accel_delay_std_s, 0.0, 0.01, "s");
    // Optional: written by calibrations without a ruler.
    model("hall_fix_excess_std_m", cal.model.hall_fix_excess_std_m, 0.0, 1e-3, "m");
    model("accel_bias_mps2", cal.model.accel_bias_mps2, -100.0, 100.0, "m/s^2");
    model("accel_scale", cal.model.accel_scale, 0.5, 2.0, "");
    model("frame_vibration_hz", cal.model.frame_vibration_hz, 0.0, 10000.0, "Hz");
    model("frame_vibration_mps2", cal.model.frame_vibration_mps2, 0.0, 1000.0, "m/s^2");
    // Optional: only when the sensor node reported its temperature during calibration.
    model("temperature_c", cal.model.temperature_c, -60.0, 200.0, "deg C");
    // Optional: only from a calibration without a ruler.
    model("track_scale_std", cal.model.track_scale_std, 0.0, 0.01, "");
    // Optional: files written before it was measured have none (taken as 0).
    model("table_noise_v", cal.model.table_noise_v, 0.0, 0.1, "V");
    // Optional, together: only from a calibration without a ruler.
    const bool from = m.get("table_trusted_from_m", cal.model.table_trusted_from_m);
    const bool to = m.get("table_trusted_to_m", cal.model.table_trusted_to_m);
    if (from != to) {
      m.value(from ? "table_trusted_from_m" : "table_trusted_to_m")
          .error(std::string("needs sensor_model.") + (from ? "table_trusted_to_m" : "table_trusted_from_m") +
                 " too (the stretch of the table its slow passes made)");
    } else if (from) {
      model("table_trusted_from_m", cal.model.table_trusted_from_m, -100.0, 100.0, "m");
      model("table_trusted_to_m", cal.model.table_trusted_to_m, -100.0, 100.0, "m");
      if (!(cal.model.table_trusted_from_m < cal.model.table_trusted_to_m))
        m.value("table_trusted_to_m").error("must be above sensor_model.table_trusted_from_m");
    }
    model("table_outside_std_m", cal.model.table_outside_std_m, 0.0, 0.01, "m");
  }
  {
    // Optional: only after a thermal calibration (thermal_calibration.hpp).
    if (root.has("thermal")) {
      Map t = root.map("thermal");
      auto& m = cal.model;
      m.thermal_known = true;
      if (t.require("rise_k", m.thermal_rise_k) && !(std::abs(m.thermal_rise_k) >= 1.0 && std::abs(m.thermal_rise_k) <= 100.0))
        t.value("rise_k").error(schema::compact_number(m.thermal_rise_k) +
                                " K: a thermal calibration is made 1 to 100 K from the calibration, either way");
      const bool tc = t.get("common_tc_per_k", m.common_tc_per_k);
      const bool tc_std = t.get("common_tc_rel_std", m.common_tc_rel_std);
      if (tc != tc_std)
        t.value(tc ? "common_tc_per_k" : "common_tc_rel_std")
            .error(std::string("needs thermal.") + (tc ? "common_tc_rel_std" : "common_tc_per_k") + " too");
      if (tc && !(std::abs(m.common_tc_per_k) <= 0.05))
        t.value("common_tc_per_k").error(schema::out_of_range(m.common_tc_per_k, -0.05, 0.05, "1/K"));
      if (tc_std && !(m.common_tc_rel_std >= 0.0 && m.common_tc_rel_std <= 1.0))
        t.value("common_tc_rel_std").error(schema::out_of_range(m.common_tc_rel_std, 0.0, 1.0, ""));
      // One number per sensor, each list as long as the motor has sensors.
      const auto per_sensor = [&](const char* key, std::array<double, core::kMaxHalls>& out, double lo, double hi,
                                  const char* unit) {
        const Value v = t.required(key);
        std::vector<double> list;
        if (!v.present() || !v.as(list)) return;
        if (info.hall_count > 0 && list.size() != static_cast<std::size_t>(info.hall_count)) {
          v.error(std::string(kCorrupt) + std::to_string(list.size()) + " values but hall_count is " +
                  std::to_string(info.hall_count));
          return;
        }
        for (std::size_t i = 0; i < list.size() && i < out.size(); ++i) {
          if (!(list[i] >= lo && list[i] <= hi)) {
            v.error("sensor " + std::to_string(i) + ": " + schema::out_of_range(list[i], lo, hi, unit));
            return;
          }
          out[i] = list[i];
        }
      };
      per_sensor("gain_tc_per_k", m.hall_gain_tc_per_k, -0.01, 0.01, "1/K");
      per_sensor("gain_tc_std_per_k", m.hall_gain_tc_std_per_k, 0.0, 0.01, "1/K");
      per_sensor("offset_tc_v_per_k", m.hall_offset_tc_v_per_k, -0.01, 0.01, "V/K");
      per_sensor("offset_tc_std_v_per_k", m.hall_offset_tc_std_v_per_k, 0.0, 0.01, "V/K");
    }
  }
  const Value table = root.required("table");
  if (table.present()) read_table(table.as_map(), cal.table, info.hall_count, expected);
  // The checksum is compared whenever the table could be read, also when it is
  // unusable for this motor: both problems are reported.
  if (id.present() && cal.table.valid()) {
    const std::string sum = core::calibration_checksum(cal);
    if (sum != info.id)
      id.error(std::string(kCorrupt) + "the calibration's checksum is " + sum + " but id is " + info.id +
               " (the file was damaged or edited)");
    return sum == info.id;
  }
  return false;
}

// ---- writing -------------------------------------------------------------------

void append_microvolts(std::string& out, double v) {
  // Same rounding as core::calibration_checksum, so the stored decimal reproduces it.
  const long long q = std::llround(v / kVoltUnit);
  const unsigned long long a = q < 0 ? static_cast<unsigned long long>(-q) : static_cast<unsigned long long>(q);
  if (q < 0) out += '-';
  char buf[32];
  auto r = std::to_chars(buf, buf + sizeof buf, a / 1000000ull);
  out.append(buf, r.ptr);
  out += '.';
  const unsigned long long frac = a % 1000000ull;
  char digits[6];
  unsigned long long x = frac;
  for (int i = 5; i >= 0; --i) {
    digits[i] = static_cast<char>('0' + x % 10);
    x /= 10;
  }
  out.append(digits, 6);
}

/// Plain when YAML would read it back as the same string, else double-quoted.
std::string yaml_string(const std::string& s) {
  bool plain = !s.empty() && std::isalpha(static_cast<unsigned char>(s.front())) && s.back() != ':';
  for (const char c : s)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == '.' || c == ':' || c == '+'))
      plain = false;
  for (const char* word : {"true", "false", "True", "False", "TRUE", "FALSE", "null", "Null", "NULL", "y", "n",
                           "yes", "no", "on", "off", "Y", "N", "Yes", "No", "On", "Off"})
    if (s == word) plain = false;
  if (plain) return s;
  std::string q = "\"";
  for (const char c : s) {
    if (c == '"' || c == '\\') {
      q += '\\';
      q += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02x", static_cast<unsigned char>(c));
      q += buf;
    } else {
      q += c;
    }
  }
  return q + "\"";
}

std::string check_writable(const core::Calibration& cal) {
  const core::HallTable& t = cal.table;
  if (!t.valid()) return "the table is not valid (needs >= 4 points, step_m > 0 and sensors * points values)";
  if (!std::isfinite(t.start_m) || !std::isfinite(t.step_m)) return "the table grid is not finite";
  for (const double x : t.v)
    if (!std::isfinite(x)) return "the table holds a value that is not finite";
  if (cal.info.motor.empty()) return "info.motor is empty";
  if (t.sensors != cal.info.hall_count)
    return "the table has " + std::to_string(t.sensors) + " sensors but info.hall_count is " +
           std::to_string(cal.info.hall_count);
  if (!(cal.info.magnet_pitch_m > 0.0)) return "info.magnet_pitch_m must be > 0";
  if (!cal.info.id.empty() && cal.info.id != core::calibration_checksum(cal))
    return "info.id " + cal.info.id + " is not the checksum of the calibration (" + core::calibration_checksum(cal) + ")";
  return {};
}

}  // namespace

std::string now_utc() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

void stamp_calibration(core::Calibration& cal) {
  cal.info.created_utc = now_utc();
  cal.info.id = core::calibration_checksum(cal);
}

CalibrationLoad load_calibration_file(const std::string& path, const core::MotorConfig& expected) {
  CalibrationLoad r;
  bool checksum_ok = false;
  std::string text, why;
  if (!schema::read_text_file(path, text, why, schema::kMaxCalibrationFileBytes)) {
    r.errors.push_back({path, 0, 0, "", kUnreadable + why});
    return r;
  }
  {
    schema::Document doc(path, r.errors);
    if (doc.parse(text)) checksum_ok = read_calibration(doc.root(), expected, r.calibration, 0, r.errors);
  }
  // Generic problems (bad syntax, missing or mistyped keys) in a file this
  // program wrote mean it was damaged; a value out of range in a file whose
  // checksum holds was written so: the calibration is unusable for this motor.
  for (auto& e : r.errors)
    if (checksum_ok && e.message.find(" out of range ") != std::string::npos &&
        !starts_with(e.message, kUnusable))
      e.message = kUnusable + e.message;
  for (auto& e : r.errors)
    if (!starts_with(e.message, kCorrupt) && !starts_with(e.message, kOtherMotor) &&
        !starts_with(e.message, kLayout) && !starts_with(e.message, kVersion) &&
        !starts_with(e.message, kNotCalibration) && !starts_with(e.message, kUnusable) &&
        !starts_with(e.message, kUnreadable))
      e.message = kCorrupt + e.message;
  schema::sort_errors(r.errors);
  return r;
}

std::string format_calibration(const core::Calibration& cal) {
  const core::HallTable& t = cal.table;
  std::string out;
  out.reserve(512 + t.v.size() * 11);
  out += "# Hall sensor calibration for the virtual encoder. Do not edit: the table's\n";
  out += "# checksum must equal `id`, or the file is refused.\n";
  out += "format: ";
  out += kCalibrationFormat;
  out += "\nversion: " + std::to_string(kCalibrationVersion) + "\n";
  out += "motor: " + yaml_string(cal.info.motor) + "\n";
  out += "hall_count: " + std::to_string(cal.info.hall_count) + "\n";
  out += "magnet_pitch_m: " + schema::format_number(cal.info.magnet_pitch_m) + "\n";
  out += "method: " + yaml_string(cal.info.method.empty() ? std::string("unknown") : cal.info.method) + "\n";
  out += "created_utc: " + yaml_string(cal.info.created_utc.empty() ? now_utc() : cal.info.created_utc) + "\n";
  // Quoted: a hex string of digits only would otherwise read as a number in other YAML tools.
  out += "id: \"" + core::calibration_checksum(cal) + "\"   # checksum of the sensor model and the table\n";
  {
    const core::SensorModel& m = cal.model;
    char buf[1024];
    std::snprintf(buf, sizeof buf,
                  "sensor_model:   # identified by calibration; the estimator compensates these\n"
                  "  hall_delay_s: %.9f          # the Halls are sampled this long before the sample instant\n"
                  "  coil_field_v_per_mps2: %.9f # common-mode Hall offset per m/s^2 of acceleration (coil field)\n"
                  "  accel_delay_s: %.9f         # the accelerometer lags the sample instant by this\n"
                  "  accel_bias_mps2: %.7f       # reading = accel_scale * a + accel_bias_mps2\n"
                  "  accel_scale: %.9f\n"
                  "  frame_vibration_hz: %.6f    # a vibration of the frame the accelerometer feels (0: none)\n"
                  "  frame_vibration_mps2: %.7f\n",
                  m.hall_delay_s, m.coil_field_v_per_mps2, m.accel_delay_s, m.accel_bias_mps2, m.accel_scale,
                  m.frame_vibration_hz, m.frame_vibration_mps2);
    out += buf;
    if (m.coil_field_std_v_per_mps2 > 0.0) {
      std::snprintf(buf, sizeof buf,
                    "  coil_field_std_v_per_mps2: %.9f   # how well the calibration knows the coil field, one sigma\n",
                    m.coil_field_std_v_per_mps2);
      out += buf;
    }
    if (m.accel_delay_std_s > 0.0) {
      std::snprintf(buf, sizeof buf,
                    "  accel_delay_std_s: %.9f     # how well the calibration knows that delay, one sigma\n",
                    m.accel_delay_std_s);
      out += buf;
    }
    if (m.hall_fix_excess_std_m > 0.0) {
      std::snprintf(buf, sizeof buf,
                    "  hall_fix_excess_std_m: %.9f # what the table leaves in a fix beyond the sensors' noise\n",
                    m.hall_fix_excess_std_m);
      out += buf;
    }
    if (std::isfinite(m.temperature_c)) {
      std::snprintf(buf, sizeof buf, "  temperature_c: %.3f         # the sensor node's mean temperature during calibration\n",
                    m.temperature_c);
      out += buf;
    }
    if (m.table_noise_v > 0.0) {
      char buf[128];
      std::snprintf(buf, sizeof buf,
                    "  table_noise_v: %.7f        # the table's own noise at a node; sigma holds it where the carriage "
                    "stands\n",
                    m.table_noise_v);
      out += buf;
    }
    if (m.track_scale_std > 0.0) {
      out += "  track_scale_std: " + schema::format_number(m.track_scale_std) +
             "   # no ruler: one sigma of the table's scale; sigma grows by it per m from home\n";
    }
    if (m.trusted_span_known()) {
      out += "  table_trusted_from_m: " + schema::format_number(m.table_trusted_from_m) +
             "   # no ruler: the slow passes made the table from here\n";
      out += "  table_trusted_to_m: " + schema::format_number(m.table_trusted_to_m) + "   # to here\n";
      out += "  table_outside_std_m: " + schema::format_number(m.table_outside_std_m) +
             "   # beyond (the turnarounds) the table is good to this; never VALID there\n";
    }
  }
  if (cal.model.thermal_known) {
    const core::SensorModel& m = cal.model;
    out += "thermal:   # each Hall sensor's own temperature coefficients, from a thermal calibration\n";
    out += "  rise_k: " + schema::format_number(m.thermal_rise_k) +
           "   # the thermal recording was this much warmer than the calibration\n";
    if (std::isfinite(m.common_tc_per_k)) {
      out += "  common_tc_per_k: " + schema::format_number(m.common_tc_per_k) +
             "   # the gain all sensors share, per K, as measured\n";
      out += "  common_tc_rel_std: " + schema::format_number(m.common_tc_rel_std) + "\n";
    }
    const auto list = [&](const char* key, const std::array<double, core::kMaxHalls>& v, const char* comment) {
      out += std::string("  ") + key + ": [";
      for (int i = 0; i < cal.info.hall_count && i < core::kMaxHalls; ++i)
        out += (i ? ", " : "") + schema::format_number(v[static_cast<std::size_t>(i)]);
      out += std::string("]") + comment + "\n";
    };
    list("gain_tc_per_k", m.hall_gain_tc_per_k, "   # each sensor's gain beyond the common one [1/K]");
    list("gain_tc_std_per_k", m.hall_gain_tc_std_per_k, "");
    list("offset_tc_v_per_k", m.hall_offset_tc_v_per_k, "   # each sensor's offset [V/K]");
    list("offset_tc_std_v_per_k", m.hall_offset_tc_std_v_per_k, "");
  }
  out += "table:\n";
  // Shortest round-trip form: the grid comes back bit-identical.
  out += "  start_m: " + schema::format_number(t.start_m) + "\n";
  out += "  step_m: " + schema::format_number(t.step_m) + "\n";
  out += "  points: " + std::to_string(t.points) + "\n";
  out += "  sensors:   # volts, one sequence per sensor, grid point k at start_m + k * step_m\n";
  constexpr int kPerLine = 10;
  for (int s = 0; s < t.sensors; ++s) {
    out += "    - [";
    for (int k = 0; k < t.points; ++k) {
      if (k > 0) out += (k % kPerLine == 0) ? ",\n       " : ", ";
      append_microvolts(out, t.v[static_cast<std::size_t>(s) * static_cast<std::size_t>(t.points) +
                                 static_cast<std::size_t>(k)]);
    }
    out += "]\n";
  }
  return out;
}

bool write_calibration_file_atomic(const std::string& path, const core::Calibration& cal, std::string& error) {
  const std::string invalid = check_writable(cal);
  if (!invalid.empty()) {
    error = "refusing to write '" + path + "': " + invalid;
    return false;
  }
  const std::string text = format_calibration(cal);

  return write_text_file_atomic(path, text, error);
}

}  // namespace ve::config
