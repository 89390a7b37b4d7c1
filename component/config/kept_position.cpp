#include "config/kept_position.hpp"

#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "config/atomic_file.hpp"
#include "config/calibration_file.hpp"
#include "config/loader.hpp"

namespace ve::config {

std::string format_kept_position(const KeptPosition& k) {
  char pos[64];
  std::snprintf(pos, sizeof pos, "%.9f", k.position_m);
  return "# virtual-encoder kept position v1: written at a clean shutdown, read and removed at the next start\n"
         "axis: " + k.axis + "\nmotor: " + k.motor + "\ncalibration_id: \"" + k.calibration_id +
         "\"\nposition_m: " + pos + "\nsaved_utc: " + k.saved_utc + "\n";
}

bool write_kept_position(const std::string& path, const KeptPosition& k, std::string& error) {
  return write_text_file_atomic(path, format_kept_position(k), error);
}

KeptRead take_kept_position(const std::string& path, const std::string& axis, const std::string& motor,
                            const std::string& calibration_id, KeptPosition& out, std::string& why,
                            double travel_m) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec) && !ec) return KeptRead::none;
  // Bounded, regular files only: a FIFO or a device named as the state file must not
  // hang or exhaust the start-up (it is not removed either: it is not ours).
  std::string text;
  if (!schema::read_text_file(path, text, why)) {
    why = path + ": cannot read: " + why;
    return KeptRead::refused;
  }
  // Used once: whatever it says, the next start must not see it again.
  if (std::remove(path.c_str()) != 0) {
    why = path + ": cannot remove it after reading (" + std::strerror(errno) +
          "), so it could be used twice: not used";
    return KeptRead::refused;
  }
  try {
    const YAML::Node root = YAML::Load(text);
    int line = 0, column = 0;
    if (schema::second_yaml_document(text, line, column)) {
      why = path + ":" + std::to_string(line) + ": a second YAML document (after '---'): not a kept position "
            "written by this program";
      return KeptRead::refused;
    }
    if (!root.IsMap()) {
      why = path + ": not a mapping";
      return KeptRead::refused;
    }
    auto field = [&](const char* key, auto& value) {
      const YAML::Node n = root[key];
      if (!n) {
        why = path + ": missing field '" + key + "'";
        return false;
      }
      try {
        value = n.as<std::remove_reference_t<decltype(value)>>();
      } catch (const YAML::Exception&) {
        why = path + ":" + std::to_string(n.Mark().line + 1) + ": field '" + key + "' has the wrong type";
        return false;
      }
      return true;
    };
    if (!field("axis", out.axis) || !field("motor", out.motor) || !field("calibration_id", out.calibration_id) ||
        !field("position_m", out.position_m) || !field("saved_utc", out.saved_utc))
      return KeptRead::refused;
    if (!std::isfinite(out.position_m)) {
      why = path + ":" + std::to_string(root["position_m"].Mark().line + 1) + ": position_m is not a number";
      return KeptRead::refused;
    }
    if (travel_m > 0.0 && !(out.position_m >= 0.0 && out.position_m <= travel_m)) {
      why = path + ":" + std::to_string(root["position_m"].Mark().line + 1) +
            ": position_m: " + schema::out_of_range(out.position_m, 0.0, travel_m, "m") + " (the motor's travel)";
      return KeptRead::refused;
    }
    if (out.axis != axis) {
      why = path + ": kept for axis '" + out.axis + "', not '" + axis + "'";
      return KeptRead::refused;
    }
    if (out.motor != motor) {
      why = path + ": kept for motor '" + out.motor + "', not '" + motor + "'";
      return KeptRead::refused;
    }
    if (out.calibration_id != calibration_id) {
      why = path + ": measured with calibration " + out.calibration_id + ", the axis now uses " + calibration_id;
      return KeptRead::refused;
    }
  } catch (const YAML::Exception& e) {
    why = path + ":" + std::to_string(e.mark.line + 1) + ": " + e.msg;
    return KeptRead::refused;
  } catch (const std::exception& e) {
    why = path + ": " + e.what();
    return KeptRead::refused;
  }
  return KeptRead::ok;
}

}  // namespace ve::config
