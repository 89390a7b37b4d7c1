// `virtual-encoder eds`: the electronic data sheet (CiA 306) of an axis' CiA 406 node,
// written from the dictionary the node serves (canopen::write_eds).
#include <cstdio>
#include <filesystem>

#include "canopen/node.hpp"
#include "canopen_io.hpp"
#include "command_line.hpp"
#include "commands.hpp"
#include "config/atomic_file.hpp"
#include "config/loader.hpp"

namespace ve::app {

int eds_command(const EdsOptions& options) {
  auto result = options.config.empty() ? config::load_embedded_default() : config::load_machine_file(options.config);
  for (const auto& e : result.errors) std::fprintf(stderr, "%s\n", e.to_string().c_str());
  if (!result.ok()) {
    std::fprintf(stderr, "%zu problem(s) in the configuration\n", result.errors.size());
    return kExitUsage;
  }
  const config::MachineConfig& machine = result.config;
  const config::AxisConfig* axis = nullptr;
  for (const auto& a : machine.axes)
    if (options.axis.empty() ? a.canopen.enabled : a.name == options.axis) {
      axis = &a;
      break;
    }
  if (!axis) {
    if (options.axis.empty())
      std::fprintf(stderr, "%s: no axis has a canopen: block\n", machine.source.c_str());
    else
      std::fprintf(stderr, "%s: no axis '%s'\n", machine.source.c_str(), options.axis.c_str());
    return kExitUsage;
  }
  if (!axis->canopen.enabled) {
    std::fprintf(stderr, "%s: axis '%s' has no canopen: block (no CANopen node)\n", machine.source.c_str(),
                 axis->name.c_str());
    return kExitUsage;
  }
  const std::string name =
      options.out.empty() ? machine.name + "-" + axis->name + ".eds" : std::filesystem::path(options.out).filename().string();
  const std::string text = canopen::write_eds(canopen_node_config(*axis), name,
                                              "machine '" + machine.name + "', axis '" + axis->name +
                                                  "': CiA 406 linear absolute encoder, node " +
                                                  std::to_string(axis->canopen.node_id) + " on " +
                                                  axis->canopen.interface);
  if (options.out.empty()) {
    std::fwrite(text.data(), 1, text.size(), stdout);
    return std::fflush(stdout) == 0 ? kExitOk : kExitFailed;
  }
  std::string error;
  if (!config::write_text_file_atomic(options.out, text, error)) {
    std::fprintf(stderr, "cannot write %s: %s\n", options.out.c_str(), error.c_str());
    return kExitFailed;
  }
  std::fprintf(stderr, "wrote %s (node %d, axis '%s')\n", options.out.c_str(), axis->canopen.node_id, axis->name.c_str());
  return kExitOk;
}

}  // namespace ve::app
