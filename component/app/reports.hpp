// Texts for people: the calibration report, and small file helpers.
#pragma once

#include <string>
#include <vector>

#include "config/atomic_file.hpp"
#include "config/machine_config.hpp"
#include "core/hall_table.hpp"
#include "core/identification.hpp"
#include "core/self_calibration.hpp"

namespace ve::app {

/// The calibration summary printed by `calibrate` and stored next to the file.
/// `plots` are the plot files written beside it (named in the text); `self`, for a
/// calibration without a reference, adds what that found and what it assumed.
std::string format_identification_report(const config::AxisConfig& axis, const core::Calibration& cal,
                                         const core::IdentificationReport& report,
                                         const std::vector<std::string>& plots = {},
                                         const core::SelfCalibrationReport* self = nullptr);

/// The report's plots, as SVG files named `<calibration_path>.<name>.svg`:
///  table-period       each sensor's table over one magnet period (mid-travel);
///  table-all-periods  each sensor's table over every period, folded onto one;
///  residuals          RMS of the sweep's readings about the table, versus position;
///  forward-backward   forward minus backward table as a position shift, versus position.
/// Written atomically; returns the paths written (those that failed are named in `error`).
std::vector<std::string> write_calibration_plots(const std::string& calibration_path, const core::Calibration& cal,
                                                 const core::IdentificationReport& report, std::string& error);

/// Temporary file in the same directory, fsync, rename, fsync of the directory.
using config::write_text_file_atomic;

}  // namespace ve::app
