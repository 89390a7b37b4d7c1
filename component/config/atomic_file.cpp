#include "config/atomic_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

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
}  // namespace

bool write_text_file_atomic(const std::string& path, const std::string& text, std::string& error) {
  // Same directory as the target: rename() is atomic only within one file system.
  std::string tmp = path + ".tmp.XXXXXX";
  const int fd = ::mkostemp(tmp.data(), O_CLOEXEC);
  if (fd < 0) {
    error = "cannot create a temporary file next to '" + path + "': " + std::strerror(errno);
    return false;
  }
  auto fail = [&](const std::string& what, int fd_to_close) {
    const int e = errno;
    if (fd_to_close >= 0) ::close(fd_to_close);
    ::unlink(tmp.c_str());
    error = what + ": " + std::strerror(e);
    return false;
  };
  // mkostemp creates 0600; keep the old file's permissions (or the usual 0644) so readers still can.
  struct stat st {};
  const mode_t mode = (::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode)) ? (st.st_mode & 07777) : 0644;
  if (::fchmod(fd, mode) != 0) return fail("cannot set permissions of '" + tmp + "'", fd);
  if (!write_all(fd, text)) return fail("cannot write '" + tmp + "'", fd);
  if (::fsync(fd) != 0) return fail("cannot flush '" + tmp + "' to disk", fd);
  if (::close(fd) != 0) return fail("cannot close '" + tmp + "'", -1);
  if (::rename(tmp.c_str(), path.c_str()) != 0) return fail("cannot replace '" + path + "'", -1);

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
