// Texts for people: the calibration report, and small file helpers.
#pragma once

#include <string>

#include "config/machine_config.hpp"
#include "core/hall_table.hpp"
#include "core/identification.hpp"

namespace ve::app {

/// The calibration summary printed by `calibrate` and stored next to the file.
std::string format_identification_report(const config::AxisConfig& axis, const core::Calibration& cal,
                                         const core::IdentificationReport& report);

/// Temporary file in the same directory, fsync, rename, fsync of the directory.
bool write_text_file_atomic(const std::string& path, const std::string& text, std::string& error);

}  // namespace ve::app
