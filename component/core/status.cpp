#include "status.hpp"

#include "sample.hpp"

namespace ve::core {

std::string status_to_string(std::uint32_t word) {
  struct Named {
    std::uint32_t bit;
    const char* name;
  };
  static constexpr Named kNames[] = {
      {status::kValid, "VALID"},       {status::kCalibrated, "CAL"},
      {status::kHomed, "HOMED"},       {status::kDegraded, "DEGRADED"},
      {status::kSensorFault, "FAULT"}, {status::kOutOfTravel, "OUT_OF_TRAVEL"},
      {status::kHallRejected, "HALL_REJ"}, {status::kAccelFault, "ACC_FAULT"},
  };
  std::string out;
  for (const auto& n : kNames) {
    if (word & n.bit) {
      if (!out.empty()) out += '|';
      out += n.name;
    }
  }
  for (int i = 0; i < kMaxHalls; ++i) {
    if (word & status::hall_fault(i)) {
      if (!out.empty()) out += '|';
      out += 'H';
      out += static_cast<char>('0' + i);
    }
  }
  return out.empty() ? "-" : out;
}

}  // namespace ve::core
