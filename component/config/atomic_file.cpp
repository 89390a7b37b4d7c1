#include "config/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <set>

namespace ve::config {

namespace {

bool write_all(int fd, const std::string& text) {
  const char* p = text.data();
  std::size_t left = text.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    p += n;
    left -= static_cast<std::size_t>(n);
  }
  return true;
}

// Never destroyed: a forced exit may use them from another thread at any time.
std::mutex& scratch_mutex() {
  static auto* m = new std::mutex;
  return *m;
}
std::set<std::string>& scratch_files() {
  static auto* s = new std::set<std::string>;
  return *s;
}

}  // namespace

const char* file_kind(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

void register_scratch_file(const std::string& path) {
  std::lock_guard<std::mutex> lock(scratch_mutex());
  scratch_files().insert(path);
}

void unregister_scratch_file(const std::string& path) {
  std::lock_guard<std::mutex> lock(scratch_mutex());
  scratch_files().erase(path);
}

std::size_t remove_scratch_files_for_exit() {
  scratch_mutex().lock();  // held until the process ends
  std::size_t n = 0;
  for (const auto& p : scratch_files()) n += ::unlink(p.c_str()) == 0;
  scratch_files().clear();
  return n;
}

std::string why_not_writable(const std::string& path) {
  if (path.empty()) return "empty file name";
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0) {
    if (!S_ISREG(st.st_mode)) return "'" + path + "' is " + file_kind(st.st_mode) + ", not a regular file";
  } else if (errno != ENOENT) {
    return "'" + path + "': " + std::strerror(errno);  // ENOTDIR, EACCES, ELOOP, ENAMETOOLONG
  }
  std::string dir = std::filesystem::path(path).parent_path().string();
  if (dir.empty()) dir = ".";
  if (::stat(dir.c_str(), &st) != 0) return "directory '" + dir + "': " + std::strerror(errno);
  if (!S_ISDIR(st.st_mode)) return "'" + dir + "' is not a directory";
  if (::access(dir.c_str(), W_OK) != 0) return "directory '" + dir + "': " + std::strerror(errno);
  return std::string();
}

bool write_text_file_atomic(const std::string& path, const std::string& text, std::string& error) {
  if (path.empty()) {
    error = "cannot write a file with an empty name";
    return false;
  }
  struct stat st {};
  const bool exists = ::stat(path.c_str(), &st) == 0;
  if (exists && !S_ISREG(st.st_mode)) {
    error = "cannot write '" + path + "': it is " + file_kind(st.st_mode) + ", not a regular file";
    return false;
  }
  // Same directory as the target: rename() is atomic only within one file system.
  std::string tmp = path + ".tmp.XXXXXX";
  int fd = -1;
  {
    // Registered before it exists, so that a forced exit cannot miss it.
    std::lock_guard<std::mutex> lock(scratch_mutex());
    fd = ::mkostemp(tmp.data(), O_CLOEXEC);
    if (fd >= 0) scratch_files().insert(tmp);
  }
  if (fd < 0) {
    error = "cannot create a temporary file next to '" + path + "': " + std::strerror(errno);
    return false;
  }
  auto fail = [&](const std::string& what, int fd_to_close) {
    const int e = errno;
    if (fd_to_close >= 0) ::close(fd_to_close);
    ::unlink(tmp.c_str());
    unregister_scratch_file(tmp);
    error = what + ": " + std::strerror(e);
    return false;
  };
  // mkostemp creates 0600; keep the old file's permissions (or the usual 0644) so readers still can.
  const mode_t mode = exists ? (st.st_mode & 07777) : 0644;
  if (::fchmod(fd, mode) != 0) return fail("cannot set permissions of '" + tmp + "'", fd);
  if (!write_all(fd, text)) return fail("cannot write '" + path + "' (temporary '" + tmp + "')", fd);
  if (::fsync(fd) != 0) return fail("cannot flush '" + path + "' (temporary '" + tmp + "') to disk", fd);
  if (::close(fd) != 0) return fail("cannot write '" + path + "' (closing temporary '" + tmp + "')", -1);
  if (::rename(tmp.c_str(), path.c_str()) != 0) return fail("cannot replace '" + path + "'", -1);
  unregister_scratch_file(tmp);

  // The rename is durable only once the directory entry is on disk.
  std::string dir = std::filesystem::path(path).parent_path().string();
  if (dir.empty()) dir = ".";
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0 || (::fsync(dfd) != 0 && errno != EINVAL)) {
    const int e = errno;
    if (dfd >= 0) ::close(dfd);
    error = "'" + path + "' was replaced, but its directory could not be synced (may not survive a power loss): " +
            std::strerror(e);
    return false;
  }
  ::close(dfd);
  return true;
}

}  // namespace ve::config
