// Replacing a file so that a crash or power loss at any moment leaves either the
// old file or the complete new one: a temporary file in the same directory,
// written and flushed, renamed over the target, then the directory flushed.
#pragma once

#include <sys/types.h>

#include <cstddef>
#include <string>

namespace ve::config {

/// Writes `text` to `path` atomically. A new file gets mode 0644; a replaced one keeps
/// its mode. Returns false with the reason in `error`, naming the path and the
/// system's reason (the target is then untouched and no temporary file is left,
/// unless only the final directory flush failed, which the message says). A target
/// that exists and is not a regular file (a directory, a device, a FIFO) is refused.
bool write_text_file_atomic(const std::string& path, const std::string& text, std::string& error);

/// Files being written that are not yet what their names promise (a temporary
/// beside its target, a recording's PATH.partial). When the process is ended on
/// a signal before the writer finishes, remove_scratch_files_for_exit() removes
/// them, so that an interrupted write leaves nothing behind. Thread-safe.
void register_scratch_file(const std::string& path);
void unregister_scratch_file(const std::string& path);
/// Removes every registered file and returns how many were removed. For a process
/// about to _exit: the registry stays locked afterwards, so no writer can add one.
std::size_t remove_scratch_files_for_exit();

/// "PATH: reason" for a path that cannot be written as a new or replaced regular
/// file: its directory is missing, not a directory, not writable, or the path
/// is a directory, a device or a FIFO. Empty when nothing speaks against it.
std::string why_not_writable(const std::string& path);

/// What a path that is not a regular file is, for messages ("a directory", "a
/// FIFO", ...), from its stat mode.
const char* file_kind(mode_t mode);

}  // namespace ve::config
