// A problem found in a file a user gave the product (machine or motor YAML, raw sensor
// log, calibration file): where it is and what is wrong, for a message that names the
// file, line and field.
#pragma once

#include <string>
#include <vector>

namespace ve::core {

struct InputError {
  std::string file;
  int line = 0;       ///< 1-based; 0 = not tied to a position (e.g. unreadable file)
  int column = 0;     ///< 1-based, in bytes
  std::string field;  ///< the field: a dotted path in a YAML file, a column or key in a log; may be empty
  std::string message;

  /// "FILE:LINE:COL: FIELD: MESSAGE"; position and field are left out when unknown.
  std::string to_string() const;
};

/// All errors, one per line, in the to_string() form.
std::string to_string(const std::vector<InputError>& errors);

}  // namespace ve::core
