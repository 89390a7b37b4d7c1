// Status word carried by every published sample. The bit values are part of the
// DDS contract (idl/VirtualEncoder.idl repeats them); never renumber.
#pragma once

#include <cstdint>
#include <string>

namespace ve::core {

namespace status {
inline constexpr std::uint32_t kValid = 1u << 0;        ///< position and velocity may be used
inline constexpr std::uint32_t kCalibrated = 1u << 1;   ///< a calibration table is in use
inline constexpr std::uint32_t kHomed = 1u << 2;        ///< position is absolute on the travel
inline constexpr std::uint32_t kDegraded = 1u << 3;     ///< running with fewer sensors than configured
inline constexpr std::uint32_t kSensorFault = 1u << 4;  ///< at least one sensor is flagged
inline constexpr std::uint32_t kOutOfTravel = 1u << 5;  ///< position outside the calibrated travel
inline constexpr std::uint32_t kHallRejected = 1u << 6; ///< this sample's Hall position was not used
inline constexpr std::uint32_t kAccelFault = 1u << 7;   ///< accelerometer missing or saturated
/// Bits 16..23: Hall sensor i flagged (missing sample or reading outside the ADC range).
inline constexpr int kHallFaultShift = 16;
inline constexpr std::uint32_t hall_fault(int i) { return 1u << (kHallFaultShift + i); }
}  // namespace status

/// Compact human-readable form, e.g. "VALID|CAL|HOMED|H2".
std::string status_to_string(std::uint32_t word);

}  // namespace ve::core
