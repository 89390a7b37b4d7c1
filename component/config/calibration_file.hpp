// Calibration files: a Hall table measured on one motor, stored as YAML with a
// human-readable header and a checksum, so a damaged file or one made for
// another motor is refused instead of silently degrading the position.
#pragma once

#include <string>
#include <vector>

#include "config/loader.hpp"
#include "core/hall_table.hpp"
#include "core/motor.hpp"

namespace ve::config {

/// Value of the `format:` key that marks a calibration file.
inline constexpr const char* kCalibrationFormat = "virtual-encoder-calibration";
inline constexpr int kCalibrationVersion = 1;

struct CalibrationLoad {
  core::Calibration calibration;    ///< usable only when ok()
  std::vector<ConfigError> errors;  ///< each says which: corrupt, other motor, incompatible sensor layout, unsupported version
  bool ok() const { return errors.empty(); }
};

/// Loads and verifies a calibration for `expected`: format marker, version,
/// motor name, Hall count and magnet pitch must match, the table must be
/// complete and its checksum must equal the stored `id`.
CalibrationLoad load_calibration_file(const std::string& path, const core::MotorConfig& expected);

/// Dates a new calibration (created_utc = now, UTC) and names it (id = its checksum).
void stamp_calibration(core::Calibration& cal);

/// The file's text. `id` is core::calibration_checksum(cal); an empty
/// cal.info.created_utc is written as the current time.
std::string format_calibration(const core::Calibration& cal);

/// Replaces `path` atomically (temp file in the same directory, fsync, rename,
/// fsync of the directory): afterwards the file is either the old one or the
/// complete new one, also across a power loss. Refuses a table that is not
/// valid(), whose sensor count differs from info.hall_count, or whose non-empty
/// info.id is not its checksum. On failure returns false with `error` set,
/// leaves the previous file untouched and removes the temp file.
/// Now, as ISO 8601 UTC ("2026-11-22T09:30:00Z").
std::string now_utc();

bool write_calibration_file_atomic(const std::string& path, const core::Calibration& cal, std::string& error);

}  // namespace ve::config
