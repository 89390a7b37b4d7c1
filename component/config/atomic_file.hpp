// Replacing a file so that a crash or power loss at any moment leaves either the
// old file or the complete new one: a temporary file in the same directory,
// written and flushed, renamed over the target, then the directory flushed.
#pragma once

#include <string>

namespace ve::config {

/// Writes `text` to `path` atomically. A new file gets mode 0644; a replaced one keeps
/// its mode. Returns false with the reason in `error` (the target is then untouched,
/// unless only the final directory flush failed, which the message says).
bool write_text_file_atomic(const std::string& path, const std::string& text, std::string& error);

}  // namespace ve::config
