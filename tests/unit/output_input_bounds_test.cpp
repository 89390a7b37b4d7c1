// Files that are not what a reader or writer expects: a raw log that is a device,
// a directory or an endless line in a FIFO; outputs that are devices, directories or
// lie under a regular file. Each is refused or handled with the path and the reason,
// never by blocking, replacing a device node or leaving temporary files behind.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

#include "config/atomic_file.hpp"
#include "core/sample.hpp"
#include "replay/raw_log.hpp"
#include "../integration/temp_dir.hpp"

namespace {

namespace fs = std::filesystem;
using ve::replay::RawLogReader;
using ve::replay::RawLogWriter;

/// A scratch folder, removed with the test.
struct Dir : ve::test::TempDir {
  Dir() : ve::test::TempDir("ve_bounds") {}
};

std::size_t entries(const fs::path& dir) {
  std::size_t n = 0;
  for (const auto& e : fs::directory_iterator(dir)) n += e.path().filename() != "a_file";
  return n;
}

ve::core::RawSample sample(std::int64_t t_ns) {
  ve::core::RawSample s;
  s.t_ns = t_ns;
  s.hall_count = 2;
  s.hall_v[0] = 1.0;
  s.hall_v[1] = 2.0;
  s.hall_valid_mask = 3;
  s.accel_valid = true;
  return s;
}

TEST(InputBounds, RawLogReaderRefusesDevicesAndDirectoriesNamingThem) {
  Dir dir;
  for (const std::string& path : {std::string("/dev/zero"), std::string("/dev/null"), dir.path.string()}) {
    RawLogReader r;
    EXPECT_FALSE(r.open(path)) << path;
    const std::string all = ve::replay::to_string(r.errors());
    EXPECT_NE(all.find(path), std::string::npos) << all;
    EXPECT_NE(all.find("it is a"), std::string::npos) << all;
  }
}

TEST(InputBounds, RawLogReaderReadsAFifo) {
  Dir dir;
  const fs::path fifo = dir.path / "log";
  ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
  std::thread writer([&] {
    std::ofstream out(fifo);
    out << "# virtual-encoder raw log v1\nt_s,hall_0_v,accel_mps2\n0.001,1.5,0\n0.002,1.6,0\n";
  });
  RawLogReader r;
  ASSERT_TRUE(r.open(fifo.string())) << ve::replay::to_string(r.errors());
  ve::replay::RawLogRow row;
  int rows = 0;
  while (r.next(row) == RawLogReader::Next::row) ++rows;
  writer.join();
  EXPECT_EQ(rows, 2);
}

// A FIFO that delivers bytes without a line end (`cat /dev/zero > fifo`): the reader
// gives up after a bounded amount instead of reading for ever.
TEST(InputBounds, AnEndlessLineIsReadOnlyUpToABound) {
  Dir dir;
  const fs::path fifo = dir.path / "endless";
  ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    // Once the reader gives up, write() fails with EPIPE instead of a SIGPIPE for the test.
    sigset_t pipe;
    sigemptyset(&pipe);
    sigaddset(&pipe, SIGPIPE);
    pthread_sigmask(SIG_BLOCK, &pipe, nullptr);
    const int fd = open(fifo.c_str(), O_WRONLY);
    if (fd < 0) return;
    std::string chunk(1 << 16, 'x');
    while (!stop.load() && ::write(fd, chunk.data(), chunk.size()) > 0) {
    }
    close(fd);
  });
  RawLogReader r;
  EXPECT_FALSE(r.open(fifo.string()));
  const std::string all = ve::replay::to_string(r.errors());
  EXPECT_NE(all.find("line longer than"), std::string::npos) << all;
  stop.store(true);
  writer.join();
}

// /dev/null, a device, is written directly: never replaced by a regular file.
TEST(OutputBounds, RawLogWriterWritesADeviceDirectlyAndNeverReplacesIt) {
  RawLogWriter w;
  std::string error;
  ASSERT_TRUE(w.open("/dev/null", {2, false, false, false}, {}, error)) << error;
  EXPECT_TRUE(w.direct());
  for (int i = 0; i < 3000; ++i) ASSERT_TRUE(w.write(sample(1000 + i * 250000LL), nullptr, nullptr)) << w.error();
  ASSERT_TRUE(w.close(error)) << error;
  struct stat st {};
  ASSERT_EQ(stat("/dev/null", &st), 0);
  EXPECT_TRUE(S_ISCHR(st.st_mode));
  EXPECT_FALSE(fs::exists("/dev/null.partial"));
}

TEST(OutputBounds, RawLogWriterFullDeviceNamesTheReasonAndDiscardLeavesNothing) {
  Dir dir;
  RawLogWriter w;
  std::string error;
  ASSERT_TRUE(w.open("/dev/full", {2, false, false, false}, {}, error)) << error;
  bool failed = false;
  for (int i = 0; i < 10000 && !failed; ++i) failed = !w.write(sample(1000 + i * 250000LL), nullptr, nullptr);
  if (!failed) failed = !w.close(error);
  ASSERT_TRUE(failed);
  EXPECT_NE((w.error() + error).find("/dev/full"), std::string::npos) << w.error() << error;
  EXPECT_NE((w.error() + error).find("No space left on device"), std::string::npos) << w.error() << error;
  w.discard();

  RawLogWriter d;
  const fs::path out = dir.path / "r.csv";
  ASSERT_TRUE(d.open(out.string(), {2, false, false, false}, {}, error)) << error;
  ASSERT_TRUE(d.write(sample(1000), nullptr, nullptr));
  d.discard();
  EXPECT_FALSE(fs::exists(out));
  EXPECT_FALSE(fs::exists(out.string() + ".partial"));
}

TEST(OutputBounds, RawLogWriterRefusesADirectory) {
  Dir dir;
  RawLogWriter w;
  std::string error;
  EXPECT_FALSE(w.open(dir.path.string(), {2, false, false, false}, {}, error));
  EXPECT_NE(error.find(dir.path.string()), std::string::npos) << error;
  EXPECT_NE(error.find("directory"), std::string::npos) << error;
}

TEST(OutputBounds, AtomicWriteRefusesDevicesAndDirectoriesAndNamesThePathAndReason) {
  Dir dir;
  std::ofstream(dir.path / "a_file") << "x\n";
  struct Case {
    std::string path, reason;
  };
  for (const Case& c : {Case{"/dev/null", "character device"}, Case{dir.path.string(), "directory"},
                        Case{(dir.path / "a_file" / "x.yaml").string(), "Not a directory"},
                        Case{(dir.path / "no" / "x.yaml").string(), "No such file or directory"}}) {
    std::string error;
    EXPECT_FALSE(ve::config::write_text_file_atomic(c.path, "text\n", error)) << c.path;
    EXPECT_NE(error.find(c.path), std::string::npos) << error;
    EXPECT_NE(error.find(c.reason), std::string::npos) << error;
    EXPECT_NE(ve::config::why_not_writable(c.path), "") << c.path;
  }
  struct stat st {};
  ASSERT_EQ(stat("/dev/null", &st), 0);
  EXPECT_TRUE(S_ISCHR(st.st_mode));
  EXPECT_EQ(entries(dir.path), 0u);  // no temporary file left
  std::string error;
  EXPECT_TRUE(ve::config::write_text_file_atomic((dir.path / "ok.yaml").string(), "ok\n", error)) << error;
  EXPECT_EQ(ve::config::why_not_writable((dir.path / "ok.yaml").string()), "");
  EXPECT_EQ(entries(dir.path), 1u);
}

}  // namespace
