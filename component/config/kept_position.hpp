// The position an axis kept at its last clean shutdown (homing.mode: signature,
// homing.state_file). Read and removed at the next start, so a position kept once
// is used once: after a crash, or once the process has run, there is none, and
// the axis homes by the magnet signature on its first move.
#pragma once

#include <string>

namespace ve::config {

struct KeptPosition {
  std::string axis;
  std::string motor;
  std::string calibration_id;  ///< the calibration the position was measured with
  double position_m = 0.0;
  std::string saved_utc;
};

std::string format_kept_position(const KeptPosition& k);

/// Writes the file atomically (temporary file, fsync, rename).
bool write_kept_position(const std::string& path, const KeptPosition& k, std::string& error);

enum class KeptRead { none, ok, refused };

/// Reads `path` and removes it. `none`: there is no such file. `refused`: the file is
/// unreadable, malformed or for another axis, motor or calibration; `why` says which
/// (file, line and field where there is one). `ok`: `out` holds it. With travel_m > 0 a
/// position outside [0, travel_m] is refused too. Every `why` starts with the path.
KeptRead take_kept_position(const std::string& path, const std::string& axis, const std::string& motor,
                            const std::string& calibration_id, KeptPosition& out, std::string& why,
                            double travel_m = 0.0);

}  // namespace ve::config
