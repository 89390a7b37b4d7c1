// Files compiled into the binary (see deploy/cmake/embed_files.cmake, which
// generates the definition), so the default configuration needs no file on disk.
#pragma once

#include <map>
#include <string>

namespace ve::config {

/// Path relative to the repository root (e.g. "config/machines/sim.yaml") -> file content.
const std::map<std::string, std::string>& embedded_files();

}  // namespace ve::config
