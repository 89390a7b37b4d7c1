#include "input_error.hpp"

namespace ve::core {

std::string InputError::to_string() const {
  std::string s = file;
  if (line > 0) s += ":" + std::to_string(line) + ":" + std::to_string(column);
  s += ": ";
  if (!field.empty()) s += field + ": ";
  s += message;
  return s;
}

std::string to_string(const std::vector<InputError>& errors) {
  std::string s;
  for (const auto& e : errors) s += e.to_string() + "\n";
  return s;
}

}  // namespace ve::core
