// A calibration recording from a raw log v1 with a reference column: the same
// identification as a live run, from a file (a real machine's commissioning
// recording, or `virtual-encoder record` of the simulator).
#pragma once

#include <string>
#include <vector>

#include "core/identification.hpp"

namespace ve::app {

/// Reads every row with a reference position; a gap in time (a missing row, or
/// rows without reference) starts a new segment, since the reference's speed and
/// acceleration are differentiated per segment. False with `error` on a malformed
/// log, a missing ref_position_m column or a Hall count other than `hall_count`.
bool read_calibration_log(const std::string& path, int hall_count, std::vector<core::ReferenceSegment>& segments,
                          std::string& error);

/// The same for calibration without a reference: every row, split into segments
/// at gaps in time. `has_reference` tells whether the log has a ref_position_m
/// column; when it has, the reference is read too (rows without one are skipped).
bool read_calibration_log_any(const std::string& path, int hall_count, std::vector<core::ReferenceSegment>& segments,
                              bool& has_reference, std::string& error);

}  // namespace ve::app
