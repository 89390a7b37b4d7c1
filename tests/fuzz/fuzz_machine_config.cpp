// Fuzz target: machine files (YAML -> MachineConfig with file:line:col errors).
// A motor file next to it is valid, so the machine schema itself gets exercised.
#include <cstdint>
#include <fstream>

#include "config/loader.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string& machine = ve::fuzz::scratch_file("machine.yaml");
  static bool motor_written = [&] {
    std::ofstream(machine.substr(0, machine.rfind('/')) + "/motor.yaml") << "motor: fuzz\n";
    return true;
  }();
  (void)motor_written;
  if (!ve::fuzz::write_input(machine, data, size)) return 0;
  const auto result = ve::config::load_machine_file(machine);
  for (const auto& e : result.errors) (void)e.to_string();
  return 0;
}
