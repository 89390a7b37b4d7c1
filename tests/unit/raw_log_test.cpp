// Raw log v1: writer -> reader round trip, the .partial/rename protocol, every
// error with its exact position, robustness on garbage, and the replay source
// (sequence, truth/reference per row, realtime pacing, stop()).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "config/loader.hpp"
#include "core/motor.hpp"
#include "replay/raw_log.hpp"
#include "replay/replay_source.hpp"
#include "sim/sim_source.hpp"

namespace {

using ve::core::RawSample;
using ve::core::Truth;
using ve::drivers::ReadStatus;
using ve::replay::LogError;
using ve::replay::RawLogMeta;
using ve::replay::RawLogReader;
using ve::replay::RawLogRow;
using ve::replay::RawLogWriter;
using ve::replay::ReplaySource;
using Next = RawLogReader::Next;

bool exists(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0;
}

std::string slurp(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

class TempDir {
 public:
  TempDir() {
    std::string tmpl = ::testing::TempDir() + "ve_raw_log_XXXXXX";
    char* d = ::mkdtemp(tmpl.data());
    EXPECT_NE(d, nullptr);
    dir_ = tmpl;
  }
  ~TempDir() { std::system(("rm -rf '" + dir_ + "'").c_str()); }
  std::string path(const std::string& name) const { return dir_ + "/" + name; }
  std::string write(const std::string& name, const std::string& text) const {
    const std::string p = path(name);
    std::ofstream(p, std::ios::binary) << text;
    return p;
  }

 private:
  std::string dir_;
};

std::string all(const RawLogReader& r) { return ve::replay::to_string(r.errors()); }

/// Exactly one error (at open or at the next row) with this position and field.
void expect_error(const std::vector<LogError>& errors, const std::string& file, int line, int column,
                  const std::string& field, const std::string& message_part) {
  ASSERT_FALSE(errors.empty());
  const LogError& e = errors.front();
  EXPECT_EQ(e.file, file);
  EXPECT_EQ(e.line, line) << e.to_string();
  EXPECT_EQ(e.column, column) << e.to_string();
  EXPECT_EQ(e.field, field) << e.to_string();
  EXPECT_NE(e.message.find(message_part), std::string::npos) << e.to_string();
}

/// Opens `text` and expects open() to fail with this one error first.
void expect_header_error(const std::string& text, int line, int column, const std::string& field,
                         const std::string& message_part) {
  TempDir dir;
  const std::string p = dir.write("bad.csv", text);
  RawLogReader r;
  EXPECT_FALSE(r.open(p));
  expect_error(r.errors(), p, line, column, field, message_part);
  RawLogRow row;
  EXPECT_EQ(r.next(row), Next::end);
}

/// Opens `text` (which must open fine), reads good rows, expects the first error
/// after `good_rows` rows.
void expect_row_error(const std::string& text, int good_rows, int line, int column, const std::string& field,
                      const std::string& message_part) {
  TempDir dir;
  const std::string p = dir.write("bad.csv", text);
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  RawLogRow row;
  for (int i = 0; i < good_rows; ++i) ASSERT_EQ(r.next(row), Next::row) << all(r);
  ASSERT_EQ(r.next(row), Next::error);
  expect_error(r.errors(), p, line, column, field, message_part);
  EXPECT_EQ(r.last_error().to_string(), r.errors().front().to_string());
}

const std::string kV1 = "# virtual-encoder raw log v1\n";
const std::string kHeader3 = "t_s,hall_0_v,accel_mps2\n";  // line 2 after kV1

RawSample sample(std::int64_t t_ns, int halls) {
  RawSample s;
  s.t_ns = t_ns;
  s.hall_count = halls;
  s.hall_valid_mask = (1u << halls) - 1u;
  for (int i = 0; i < halls; ++i) s.hall_v[static_cast<std::size_t>(i)] = 0.1234567 * (i + 1) + 1e-3 * t_ns * 1e-6;
  s.accel_mps2 = -3.25 + 1e-4 * static_cast<double>(t_ns % 977);
  s.accel_valid = true;
  return s;
}

// ---- format ------------------------------------------------------------------

TEST(RawLog, ErrorFormatMatchesConfigErrors) {
  const LogError e{"f.csv", 3, 7, "hall_0_v", "expected a number"};
  const ve::config::ConfigError c{"f.csv", 3, 7, "hall_0_v", "expected a number"};
  EXPECT_EQ(e.to_string(), c.to_string());
  EXPECT_EQ(e.to_string(), "f.csv:3:7: hall_0_v: expected a number");
  const LogError nopos{"f.csv", 0, 0, "", "cannot open"};
  const ve::config::ConfigError cnopos{"f.csv", 0, 0, "", "cannot open"};
  EXPECT_EQ(nopos.to_string(), cnopos.to_string());
}

TEST(RawLog, WriteReadRoundTrip) {
  TempDir dir;
  const std::string path = dir.path("run.csv");
  RawLogWriter w;
  std::string error;
  ASSERT_TRUE(w.open(path, {4, true, true, true},
                     {{"sample_rate_hz", "4000"}, {"motor", "sim-12mm"}, {"source", "sim(constant_velocity, 4 Halls)"},
                      {"eval_window_s", "0.5,2.5"}},
                     error))
      << error;

  std::vector<RawSample> written;
  std::vector<Truth> truths;
  std::vector<double> refs;
  for (int n = 0; n < 300; ++n) {
    RawSample s = sample(1000000000LL + 250000LL * n + (n % 7), 4);  // odd ns survive
    s.seq = static_cast<std::uint64_t>(n);
    if (n % 5 == 1) s.hall_valid_mask &= ~0x4u;  // hall 2 missing
    if (n % 11 == 3) s.accel_valid = false;
    s.accel_base_valid = n % 3 != 0;
    s.accel_base_mps2 = 0.001 * n - 0.1;
    if (n == 7) s.hall_v[0] = -0.0000004;  // rounds to -0.000000
    const Truth t{0.123456789012 + 1e-4 * n, -0.35 + 1e-5 * n, 12.3456789 - 0.01 * n};
    const double ref = 0.5 - 1e-6 * n;
    written.push_back(s);
    truths.push_back(t);
    refs.push_back(ref);
    ASSERT_TRUE(w.write(s, n % 4 == 2 ? nullptr : &t, n % 6 == 5 ? nullptr : &ref)) << w.error();
  }
  EXPECT_EQ(w.rows_written(), 300u);
  ASSERT_TRUE(w.close(error)) << error;

  RawLogReader r;
  ASSERT_TRUE(r.open(path)) << all(r);
  EXPECT_TRUE(r.warnings().empty());
  const RawLogMeta& m = r.meta();
  EXPECT_EQ(m.hall_count, 4);
  EXPECT_TRUE(m.has_accel_base);
  EXPECT_TRUE(m.has_reference);
  EXPECT_TRUE(m.has_truth);
  EXPECT_EQ(m.sample_rate_hz, 4000.0);
  EXPECT_EQ(m.values.at("motor"), "sim-12mm");
  EXPECT_EQ(m.values.at("source"), "sim(constant_velocity, 4 Halls)");
  EXPECT_EQ(m.values.at("hall_count"), "4");  // added by the writer
  double t0 = 0, t1 = 0;
  ASSERT_TRUE(m.eval_window(t0, t1));
  EXPECT_EQ(t0, 0.5);
  EXPECT_EQ(t1, 2.5);

  RawLogRow row;
  for (int n = 0; n < 300; ++n) {
    ASSERT_EQ(r.next(row), Next::row) << all(r);
    const RawSample& s = written[static_cast<std::size_t>(n)];
    const RawSample& g = row.sample;
    EXPECT_EQ(g.t_ns, s.t_ns) << n;  // exact, to the ns
    EXPECT_EQ(g.seq, static_cast<std::uint64_t>(n));
    EXPECT_EQ(g.hall_count, 4);
    EXPECT_EQ(g.hall_valid_mask, s.hall_valid_mask) << n;
    for (int i = 0; i < 4; ++i) {
      const auto k = static_cast<std::size_t>(i);
      if (s.hall_valid_mask >> i & 1u) {
        EXPECT_NEAR(g.hall_v[k], s.hall_v[k], 0.5e-6 + 1e-12) << n;
      } else {
        EXPECT_EQ(g.hall_v[k], 0.0);
      }
    }
    EXPECT_EQ(g.accel_valid, s.accel_valid) << n;
    if (s.accel_valid) {
      EXPECT_NEAR(g.accel_mps2, s.accel_mps2, 0.5e-6 + 1e-12);
    }
    EXPECT_EQ(g.accel_base_valid, s.accel_base_valid) << n;
    if (s.accel_base_valid) {
      EXPECT_NEAR(g.accel_base_mps2, s.accel_base_mps2, 0.5e-6 + 1e-12);
    }
    EXPECT_EQ(row.has_truth, n % 4 != 2) << n;
    if (row.has_truth) {
      const Truth& t = truths[static_cast<std::size_t>(n)];
      EXPECT_NEAR(row.truth.position_m, t.position_m, 0.5e-9 + 1e-15);
      EXPECT_NEAR(row.truth.velocity_mps, t.velocity_mps, 0.5e-9 + 1e-15);
      EXPECT_NEAR(row.truth.acceleration_mps2, t.acceleration_mps2, 0.5e-6 + 1e-12);
    }
    EXPECT_EQ(row.has_reference, n % 6 != 5) << n;
    if (row.has_reference) {
      EXPECT_NEAR(row.reference_position_m, refs[static_cast<std::size_t>(n)], 0.5e-9 + 1e-15);
    }
  }
  EXPECT_EQ(r.next(row), Next::end);
  EXPECT_EQ(r.next(row), Next::end);
  EXPECT_TRUE(r.errors().empty()) << all(r);
  EXPECT_EQ(r.rows(), 300u);
}

TEST(RawLog, WriterPrintsTheDocumentedFormat) {
  TempDir dir;
  const std::string path = dir.path("fmt.csv");
  RawLogWriter w;
  std::string error;
  ASSERT_TRUE(w.open(path, {2, false, true, false}, {{"motor", "m"}}, error)) << error;
  RawSample s = sample(1500000001LL, 2);
  s.hall_v = {1.25, -0.5};
  s.hall_valid_mask = 0x2;
  s.accel_mps2 = 9.80665;
  const double ref = 0.0123456789;
  ASSERT_TRUE(w.write(s, nullptr, &ref));
  s.t_ns = -250000000LL;  // not increasing
  EXPECT_FALSE(w.write(s, nullptr, nullptr));
  EXPECT_NE(w.error().find("does not increase"), std::string::npos) << w.error();
  ASSERT_TRUE(w.close(error)) << error;
  EXPECT_EQ(slurp(path),
            "# virtual-encoder raw log v1\n"
            "# motor=m\n"
            "# hall_count=2\n"
            "t_s,hall_0_v,hall_1_v,accel_mps2,ref_position_m\n"
            "1.500000001,,-0.500000,9.806650,0.012345679\n");
}

TEST(RawLog, TimeIsExactToTheNanosecond) {
  TempDir dir;
  const std::string path = dir.path("t.csv");
  RawLogWriter w;
  std::string error;
  ASSERT_TRUE(w.open(path, {1, false, false, false}, {}, error)) << error;
  const std::vector<std::int64_t> times = {-1500000001LL, -1LL, 0LL, 1LL, 999999999LL, 123456789012345678LL,
                                           8999999999999999999LL};
  for (std::int64_t t : times) ASSERT_TRUE(w.write(sample(t, 1), nullptr, nullptr)) << w.error();
  EXPECT_FALSE(w.write(sample(std::numeric_limits<std::int64_t>::max(), 1), nullptr, nullptr));  // > 9e9 s
  ASSERT_TRUE(w.close(error)) << error;
  const std::string text = slurp(path);
  EXPECT_NE(text.find("\n-1.500000001,"), std::string::npos) << text;
  EXPECT_NE(text.find("\n-0.000000001,"), std::string::npos) << text;
  EXPECT_NE(text.find("\n123456789.012345678,"), std::string::npos) << text;

  RawLogReader r;
  ASSERT_TRUE(r.open(path)) << all(r);
  RawLogRow row;
  for (std::int64_t t : times) {
    ASSERT_EQ(r.next(row), Next::row) << all(r);
    EXPECT_EQ(row.sample.t_ns, t);
  }
  EXPECT_EQ(r.next(row), Next::end);
}

TEST(RawLog, WriterRejectsWhatTheReaderWouldNotRead) {
  TempDir dir;
  RawLogWriter w;
  std::string error;
  EXPECT_FALSE(w.open(dir.path("a.csv"), {0, false, false, false}, {}, error));
  EXPECT_FALSE(error.empty());
  EXPECT_FALSE(w.open(dir.path("a.csv"), {9, false, false, false}, {}, error));
  EXPECT_FALSE(w.open(dir.path("a.csv"), {2, false, false, false}, {{"bad key", "x"}}, error));
  EXPECT_FALSE(w.open(dir.path("a.csv"), {2, false, false, false}, {{"k", "two\nlines"}}, error));
  EXPECT_FALSE(w.open(dir.path("a.csv"), {2, false, false, false}, {{"hall_count", "3"}}, error));
  EXPECT_FALSE(w.open(dir.path("no/such/dir/a.csv"), {2, false, false, false}, {}, error));
  EXPECT_FALSE(w.is_open());
  EXPECT_FALSE(exists(dir.path("a.csv.partial")));

  ASSERT_TRUE(w.open(dir.path("a.csv"), {2, false, false, true}, {}, error)) << error;
  RawSample s = sample(1000, 2);
  s.hall_v[1] = std::nan("");
  EXPECT_FALSE(w.write(s, nullptr, nullptr));
  s.hall_valid_mask = 0x1;  // a missing NaN is fine: nothing is printed
  EXPECT_TRUE(w.write(s, nullptr, nullptr)) << w.error();
  s.t_ns = 2000;
  const Truth bad{1.0, INFINITY, 0.0};
  EXPECT_FALSE(w.write(s, &bad, nullptr));
  s.hall_count = 3;
  EXPECT_FALSE(w.write(s, nullptr, nullptr));
  ASSERT_TRUE(w.close(error)) << error;
  EXPECT_FALSE(w.close(error));  // already closed
  EXPECT_FALSE(w.write(s, nullptr, nullptr));

  RawLogReader r;
  ASSERT_TRUE(r.open(dir.path("a.csv"))) << all(r);
  RawLogRow row;
  EXPECT_EQ(r.next(row), Next::row);
  EXPECT_EQ(row.sample.hall_valid_mask, 0x1u);
  EXPECT_EQ(r.next(row), Next::end);
}

TEST(RawLog, PartialFileIsRenamedOnlyOnClose) {
  TempDir dir;
  const std::string path = dir.path("rec.csv");
  const std::string partial = path + ".partial";
  RawLogWriter w;
  std::string error;
  ASSERT_TRUE(w.open(path, {3, false, false, false}, {{"sample_rate_hz", "4000"}}, error)) << error;
  EXPECT_EQ(w.partial_path(), partial);
  for (int n = 0; n < 100; ++n) ASSERT_TRUE(w.write(sample(n * 250000LL, 3), nullptr, nullptr));
  EXPECT_TRUE(exists(partial));
  EXPECT_FALSE(exists(path));
  ASSERT_TRUE(w.close(error)) << error;
  EXPECT_TRUE(exists(path));
  EXPECT_FALSE(exists(partial));

  RawLogReader r;
  ASSERT_TRUE(r.open(path)) << all(r);
  RawLogRow row;
  int rows = 0;
  while (r.next(row) == Next::row) ++rows;
  EXPECT_EQ(rows, 100);
}

TEST(RawLog, WithoutCloseThePartialIsLeftAndNeverRenamed) {
  TempDir dir;
  const std::string path = dir.path("crash.csv");
  {
    RawLogWriter w;
    std::string error;
    ASSERT_TRUE(w.open(path, {2, false, false, false}, {}, error)) << error;
    for (int n = 0; n < 10; ++n) ASSERT_TRUE(w.write(sample(n * 1000LL, 2), nullptr, nullptr));
  }
  EXPECT_FALSE(exists(path));
  ASSERT_TRUE(exists(path + ".partial"));
  // The evidence is readable: the buffered rows were written out.
  RawLogReader r;
  ASSERT_TRUE(r.open(path + ".partial")) << all(r);
  RawLogRow row;
  int rows = 0;
  while (r.next(row) == Next::row) ++rows;
  EXPECT_EQ(rows, 10);
}

// ---- reading hand-written files -------------------------------------------------

TEST(RawLog, MissingCellsAndOptionalColumns) {
  TempDir dir;
  const std::string p = dir.write("m.csv", kV1 +
                                               "# sample_rate_hz = 1000 \n"
                                               "# just a comment, not metadata\n"
                                               "accel_mps2 , t_s,hall_1_v,hall_0_v,ref_position_m\n"
                                               "0.5,0.001,1,2,\n"
                                               ",0.002,,2.5,0.25\n"
                                               "\n"
                                               "# a comment between rows\n"
                                               "1e-3, +0.003 ,-1.5E+0,.5,-0.125\n");
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  EXPECT_EQ(r.meta().sample_rate_hz, 1000.0);
  EXPECT_EQ(r.meta().values.size(), 1u);
  EXPECT_EQ(r.meta().hall_count, 2);
  EXPECT_FALSE(r.meta().has_truth);
  EXPECT_TRUE(r.meta().has_reference);
  EXPECT_FALSE(r.meta().has_accel_base);
  double t0, t1;
  EXPECT_FALSE(r.meta().eval_window(t0, t1));

  RawLogRow row;
  ASSERT_EQ(r.next(row), Next::row) << all(r);
  EXPECT_EQ(row.sample.t_ns, 1000000);
  EXPECT_EQ(row.sample.hall_valid_mask, 0x3u);
  EXPECT_EQ(row.sample.hall_v[0], 2.0);
  EXPECT_EQ(row.sample.hall_v[1], 1.0);
  EXPECT_TRUE(row.sample.accel_valid);
  EXPECT_EQ(row.sample.accel_mps2, 0.5);
  EXPECT_FALSE(row.sample.accel_base_valid);
  EXPECT_FALSE(row.has_reference);
  EXPECT_FALSE(row.has_truth);

  ASSERT_EQ(r.next(row), Next::row) << all(r);
  EXPECT_EQ(row.sample.seq, 1u);
  EXPECT_EQ(row.sample.hall_valid_mask, 0x1u);
  EXPECT_EQ(row.sample.hall_v[1], 0.0);
  EXPECT_FALSE(row.sample.accel_valid);
  EXPECT_TRUE(row.has_reference);
  EXPECT_EQ(row.reference_position_m, 0.25);

  ASSERT_EQ(r.next(row), Next::row) << all(r);
  EXPECT_EQ(row.sample.seq, 2u);
  EXPECT_EQ(row.sample.t_ns, 3000000);
  EXPECT_EQ(row.sample.hall_v[0], 0.5);
  EXPECT_EQ(row.sample.hall_v[1], -1.5);
  EXPECT_EQ(row.sample.accel_mps2, 1e-3);
  EXPECT_EQ(row.reference_position_m, -0.125);
  EXPECT_EQ(r.next(row), Next::end);
}

TEST(RawLog, UnknownColumnIsAWarningAndStillReads) {
  TempDir dir;
  const std::string p = dir.write("u.csv", kV1 + "t_s,hall_0_v,humidity_pct,accel_mps2\n"
                                                 "0.1,1.0,hot,2.0\n");
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  ASSERT_EQ(r.warnings().size(), 1u);
  EXPECT_EQ(r.warnings()[0], p + ":2:14: humidity_pct: unknown column; ignored");
  RawLogRow row;
  ASSERT_EQ(r.next(row), Next::row) << all(r);
  EXPECT_EQ(row.sample.hall_v[0], 1.0);
  EXPECT_EQ(row.sample.accel_mps2, 2.0);
  EXPECT_TRUE(r.errors().empty());
}

TEST(RawLog, NoVersionLineIsAWarning) {
  TempDir dir;
  const std::string p = dir.write("nv.csv", kHeader3 + "0,1,2\n");
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  ASSERT_EQ(r.warnings().size(), 1u);
  EXPECT_NE(r.warnings()[0].find("virtual-encoder raw log v1"), std::string::npos);
}

TEST(RawLog, CrlfAndByteOrderMarkAccepted) {
  TempDir dir;
  const std::string p = dir.write("crlf.csv", "\xEF\xBB\xBF# virtual-encoder raw log v1\r\n"
                                              "# motor=sim-12mm\r\n"
                                              "t_s,hall_0_v,accel_mps2\r\n"
                                              "0.5,1.25,\r\n"
                                              "0.75,,-2\r\n");
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  EXPECT_TRUE(r.warnings().empty());
  EXPECT_EQ(r.meta().values.at("motor"), "sim-12mm");
  RawLogRow row;
  ASSERT_EQ(r.next(row), Next::row) << all(r);
  EXPECT_EQ(row.sample.t_ns, 500000000);
  EXPECT_EQ(row.sample.hall_v[0], 1.25);
  EXPECT_FALSE(row.sample.accel_valid);  // the '\r' is not part of the cell
  ASSERT_EQ(r.next(row), Next::row) << all(r);
  EXPECT_EQ(row.sample.hall_valid_mask, 0u);
  EXPECT_EQ(row.sample.accel_mps2, -2.0);
  EXPECT_EQ(r.next(row), Next::end);
}

TEST(RawLog, LastLineWithoutNewline) {
  TempDir dir;
  const std::string p = dir.write("nonl.csv", kV1 + kHeader3 + "0,1,2\n1,1,3");
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  RawLogRow row;
  ASSERT_EQ(r.next(row), Next::row);
  ASSERT_EQ(r.next(row), Next::row);
  EXPECT_EQ(row.sample.accel_mps2, 3.0);
  EXPECT_EQ(r.next(row), Next::end);
}

TEST(RawLog, FixtureInTestData) {
  const std::string p = std::string(VE_SOURCE_DIR) + "/tests/unit/data/raw_log_v1_small.csv";
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  EXPECT_EQ(r.meta().hall_count, 4);
  EXPECT_TRUE(r.meta().has_truth);
  EXPECT_TRUE(r.meta().has_reference);
  EXPECT_EQ(r.meta().sample_rate_hz, 4000.0);
  RawLogRow row;
  int rows = 0;
  while (r.next(row) == Next::row) {
    EXPECT_EQ(row.sample.t_ns, rows * 250000LL);
    ++rows;
  }
  EXPECT_EQ(rows, 8);
  EXPECT_TRUE(r.errors().empty()) << all(r);
}

// ---- errors, each at its exact position -----------------------------------------

TEST(RawLog, ErrorCannotOpen) {
  RawLogReader r;
  EXPECT_FALSE(r.open("/nonexistent/dir/log.csv"));
  expect_error(r.errors(), "/nonexistent/dir/log.csv", 0, 0, "", "cannot open");
}

TEST(RawLog, ErrorNoHeader) {
  expect_header_error("", 1, 1, "", "no header line");
  expect_header_error(kV1 + "# motor=x\n\n", 4, 1, "", "no header line");
}

TEST(RawLog, ErrorMissingRequiredColumns) {
  expect_header_error(kV1 + "hall_0_v,accel_mps2\n", 2, 1, "t_s", "required column missing");
  expect_header_error(kV1 + "t_s,accel_mps2\n", 2, 1, "hall_0_v", "required column missing");
  expect_header_error(kV1 + "t_s,hall_0_v\n", 2, 1, "accel_mps2", "required column missing");
  // All of them are reported.
  TempDir dir;
  RawLogReader r;
  EXPECT_FALSE(r.open(dir.write("x.csv", kV1 + "foo\n")));
  EXPECT_EQ(r.errors().size(), 3u) << all(r);
}

TEST(RawLog, ErrorDuplicateColumn) {
  expect_header_error(kV1 + "t_s,hall_0_v,accel_mps2,hall_0_v\n", 2, 25, "hall_0_v", "duplicate column (first at column 5)");
  expect_header_error(kV1 + "t_s,hall_0_v,accel_mps2,t_s\n", 2, 25, "t_s", "duplicate column");
}

TEST(RawLog, ErrorHallColumnsNotContiguous) {
  expect_header_error(kV1 + "t_s,hall_0_v,hall_2_v,accel_mps2,hall_3_v\n", 2, 14, "hall_2_v",
                      "hall_1_v is missing");
  expect_header_error(kV1 + "t_s,hall_1_v,accel_mps2\n", 2, 5, "hall_1_v", "hall_0_v is missing");
  expect_header_error(kV1 + "t_s,hall_0_v,hall_8_v,accel_mps2\n", 2, 14, "hall_8_v", "hall_0_v .. hall_7_v");
  expect_header_error(kV1 + "t_s,hall_0_v,hall_01_v,accel_mps2\n", 2, 14, "hall_01_v", "hall_0_v .. hall_7_v");
}

TEST(RawLog, ErrorVersionNotV1) {
  expect_header_error("# virtual-encoder raw log v2\n" + kHeader3, 1, 27, "version", "'v2'");
  expect_header_error("#virtual-encoder raw log\n" + kHeader3, 1, 25, "version", "this reader reads v1");
}

TEST(RawLog, ErrorIncompleteTruthColumns) {
  expect_header_error(kV1 + "t_s,hall_0_v,accel_mps2,true_velocity_mps,true_position_m\n", 2, 25,
                      "true_acceleration_mps2", "come as a set");
}

TEST(RawLog, ErrorBadMetadata) {
  expect_header_error(kV1 + "# sample_rate_hz=fast\n" + kHeader3, 2, 18, "sample_rate_hz", "'fast'");
  expect_header_error(kV1 + "# eval_window_s=2,1\n" + kHeader3, 2, 17, "eval_window_s", "T0 < T1");
  expect_header_error(kV1 + "# hall_count=3\n" + kHeader3, 2, 14, "hall_count", "header (line 3) has 1 hall");
  expect_header_error(kV1 + "# hall_count=nine\n" + kHeader3, 2, 14, "hall_count", "expected an integer");
}

TEST(RawLog, ErrorNonNumericCell) {
  expect_row_error(kV1 + kHeader3 + "0.1,1.5,2\n0.2,abc,2\n", 1, 4, 5, "hall_0_v", "expected a number, got 'abc'");
  expect_row_error(kV1 + kHeader3 + "0.1,1.5, 2x \n", 0, 3, 10, "accel_mps2", "'2x'");
  expect_row_error(kV1 + kHeader3 + "0.1,0x10,2\n", 0, 3, 5, "hall_0_v", "expected a number");
  expect_row_error(kV1 + kHeader3 + "zero,1,2\n", 0, 3, 1, "t_s", "expected a number");
  expect_row_error(kV1 + kHeader3 + "0.1,1,\"2\"\n", 0, 3, 7, "accel_mps2", "expected a number");
}

TEST(RawLog, ErrorNanAndInf) {
  expect_row_error(kV1 + kHeader3 + "0.1,nan,2\n", 0, 3, 5, "hall_0_v", "must be finite");
  expect_row_error(kV1 + kHeader3 + "0.1,1,-inf\n", 0, 3, 7, "accel_mps2", "must be finite");
  expect_row_error(kV1 + kHeader3 + "inf,1,2\n", 0, 3, 1, "t_s", "must be finite");
  expect_row_error(kV1 + kHeader3 + "0.1,1,1e999\n", 0, 3, 7, "accel_mps2", "out of range");
  expect_row_error(kV1 + kHeader3 + "1e10,1,1\n", 0, 3, 1, "t_s", "out of range");
}

TEST(RawLog, ErrorWrongNumberOfCells) {
  expect_row_error(kV1 + kHeader3 + "0.1,1.5\n", 0, 3, 8, "accel_mps2", "row has 2 cells, the header has 3");
  expect_row_error(kV1 + kHeader3 + "0.1,1.5,2,7\n", 0, 3, 11, "", "row has 4 cells, the header has 3");
}

TEST(RawLog, ErrorTimeNotStrictlyIncreasing) {
  expect_row_error(kV1 + kHeader3 + "0.1,1,2\n0.2,1,2\n0.2,1,2\n", 2, 5, 1, "t_s",
                   "strictly increasing (at 1 ns resolution): 0.200000000 after 0.200000000 on line 4");
  expect_row_error(kV1 + kHeader3 + "0.1,1,2\n0.05,1,2\n", 1, 4, 1, "t_s", "strictly increasing");
  // Equal once rounded to the ns.
  expect_row_error(kV1 + kHeader3 + "0.1,1,2\n0.1000000001,1,2\n", 1, 4, 1, "t_s", "strictly increasing");
  expect_row_error(kV1 + kHeader3 + " ,1,2\n", 0, 3, 2, "t_s", "may not be empty");
}

TEST(RawLog, ErrorPartialTruthInARow) {
  const std::string h = kV1 + "t_s,hall_0_v,accel_mps2,true_position_m,true_velocity_mps,true_acceleration_mps2\n";
  expect_row_error(h + "0,1,2,0.1,0.2,0.3\n1,1,2,,,\n2,1,2,0.1,,0.3\n", 2, 5, 11, "true_velocity_mps",
                   "fill all three or none");
}

TEST(RawLog, ErrorLineTooLong) {
  const std::string long_line(ve::replay::kMaxLineBytes + 10, '1');
  expect_row_error(kV1 + kHeader3 + "0,1,2\n" + long_line + "\n", 1, 4, static_cast<int>(ve::replay::kMaxLineBytes) + 1,
                   "", "line longer than");
  // The reader goes on after the long line; a line of exactly the limit is fine.
  TempDir dir;
  std::string limit = "1,1," + std::string(ve::replay::kMaxLineBytes - 5, ' ') + "2";
  ASSERT_EQ(limit.size(), ve::replay::kMaxLineBytes);
  const std::string p = dir.write("long.csv", kV1 + kHeader3 + long_line + long_line + "\r\n" + limit + "\r\n" +
                                                  std::string(3 * ve::replay::kMaxLineBytes, 'x'));
  RawLogReader r;
  ASSERT_TRUE(r.open(p)) << all(r);
  RawLogRow row;
  EXPECT_EQ(r.next(row), Next::error);
  EXPECT_EQ(r.last_error().line, 3);
  ASSERT_EQ(r.next(row), Next::row) << all(r);
  EXPECT_EQ(row.sample.accel_mps2, 2.0);
  EXPECT_EQ(r.next(row), Next::error);
  EXPECT_EQ(r.last_error().line, 5);
  EXPECT_EQ(r.next(row), Next::end);
}

TEST(RawLog, ReadingGoesOnAfterARowError) {
  TempDir dir;
  const std::string p = dir.write("e.csv", kV1 + kHeader3 + "0,1,2\nx,1,2\n1,1,2\n");
  RawLogReader r;
  ASSERT_TRUE(r.open(p));
  RawLogRow row;
  ASSERT_EQ(r.next(row), Next::row);
  row.sample.accel_mps2 = 42.0;
  ASSERT_EQ(r.next(row), Next::error);
  EXPECT_EQ(row.sample.accel_mps2, 42.0);  // untouched on error
  ASSERT_EQ(r.next(row), Next::row);
  EXPECT_EQ(row.sample.seq, 1u);
  EXPECT_EQ(row.sample.t_ns, 1000000000);
  EXPECT_EQ(r.next(row), Next::end);
  EXPECT_EQ(r.error_count(), 1u);
}

TEST(RawLog, StoredErrorsAreBounded) {
  TempDir dir;
  std::string text = kV1 + kHeader3;
  for (int i = 0; i < 500; ++i) text += "bad\n";
  RawLogReader r;
  ASSERT_TRUE(r.open(dir.write("many.csv", text)));
  RawLogRow row;
  int errors = 0;
  for (Next n; (n = r.next(row)) != Next::end;) errors += n == Next::error;
  EXPECT_EQ(errors, 500);
  EXPECT_EQ(r.error_count(), 500u);
  EXPECT_EQ(r.errors().size(), ve::replay::kMaxStoredErrors + 1);
  EXPECT_EQ(r.last_error().line, 502);
}

TEST(RawLog, GarbageNeverCrashes) {
  TempDir dir;
  std::mt19937_64 rng(12345);
  const std::string alphabet = "0123456789.,-+eE \r\n#nainf_t_shall_0_vaccel_mps2\xEF\xBB\xBF\x00";
  const std::string good = kV1 + "t_s,hall_0_v,hall_1_v,accel_mps2,true_position_m,true_velocity_mps,"
                                 "true_acceleration_mps2,ref_position_m\n0.1,1,2,3,4,5,6,7\n";
  RawLogReader r;  // reused: open() starts afresh
  for (int trial = 0; trial < 300; ++trial) {
    std::string text;
    const int len = static_cast<int>(rng() % 2000);
    if (trial % 3 == 0) {
      text = good;  // mutate a valid file
      for (int k = 0; k < 1 + trial % 7; ++k) text[rng() % text.size()] = alphabet[rng() % alphabet.size()];
    } else {
      for (int k = 0; k < len; ++k)
        text += trial % 2 ? alphabet[rng() % alphabet.size()] : static_cast<char>(rng() & 0xff);
    }
    const std::string p = dir.write("g" + std::to_string(trial) + ".csv", text);  // new files: no ext4 flush on truncate
    if (r.open(p)) {
      RawLogRow row;
      int guard = 0;
      while (r.next(row) != Next::end) ASSERT_LT(++guard, 100000);
    } else {
      EXPECT_FALSE(r.errors().empty());
    }
  }
}

// ---- replay source ---------------------------------------------------------------

/// A log recorded from the simulator: 4 Halls, truth and reference, 4 kHz.
std::vector<RawSample> record_sim(const std::string& path, int rows, std::vector<Truth>* truths = nullptr) {
  ve::core::MotorConfig motor;
  ve::sim::SimConfig cfg;
  cfg.profile.kind = ve::sim::MotionProfileConfig::Kind::constant_velocity;
  cfg.profile.velocity_mps = 0.3;
  cfg.realtime = false;
  ve::sim::SimSource sim(motor, cfg);
  EXPECT_TRUE(sim.ok()) << sim.last_error();
  RawLogWriter w;
  std::string error;
  EXPECT_TRUE(w.open(path, {motor.hall.count, false, true, true},
                     {{"sample_rate_hz", "4000"}, {"source", sim.describe()}}, error))
      << error;
  std::vector<RawSample> out;
  for (int n = 0; n < rows; ++n) {
    RawSample s;
    EXPECT_EQ(sim.read(s), ReadStatus::ok);
    double ref = 0.0;
    const bool has_ref = sim.reference_position(ref) && n % 10 != 9;  // some rows without a reference
    EXPECT_TRUE(w.write(s, sim.truth(), has_ref ? &ref : nullptr)) << w.error();
    out.push_back(s);
    if (truths) truths->push_back(*sim.truth());
  }
  EXPECT_TRUE(w.close(error)) << error;
  return out;
}

TEST(Replay, SameSampleSequenceAsWritten) {
  TempDir dir;
  const std::string path = dir.path("sim.csv");
  std::vector<Truth> truths;
  const std::vector<RawSample> written = record_sim(path, 1000, &truths);

  ReplaySource src(path, false);
  ASSERT_TRUE(src.ok()) << src.last_error();
  EXPECT_TRUE(src.warnings().empty());
  EXPECT_EQ(src.meta().hall_count, 4);
  EXPECT_EQ(src.truth(), nullptr);
  double x = 0.0;
  EXPECT_FALSE(src.reference_position(x));
  RawSample s;
  for (std::size_t n = 0; n < written.size(); ++n) {
    ASSERT_EQ(src.read(s), ReadStatus::ok) << src.last_error();
    const RawSample& w = written[n];
    EXPECT_EQ(s.t_ns, w.t_ns);
    EXPECT_EQ(s.seq, n);
    EXPECT_EQ(s.hall_count, w.hall_count);
    EXPECT_EQ(s.hall_valid_mask, w.hall_valid_mask);
    for (int i = 0; i < w.hall_count; ++i)
      EXPECT_NEAR(s.hall_v[static_cast<std::size_t>(i)], w.hall_v[static_cast<std::size_t>(i)], 0.5e-6 + 1e-12);
    EXPECT_EQ(s.accel_valid, w.accel_valid);
    EXPECT_NEAR(s.accel_mps2, w.accel_mps2, 0.5e-6 + 1e-12);
    EXPECT_FALSE(s.accel_base_valid);
    const Truth* t = src.truth();
    ASSERT_NE(t, nullptr);
    EXPECT_NEAR(t->position_m, truths[n].position_m, 0.5e-9 + 1e-15);
    EXPECT_NEAR(t->velocity_mps, truths[n].velocity_mps, 0.5e-9 + 1e-15);
    EXPECT_NEAR(t->acceleration_mps2, truths[n].acceleration_mps2, 0.5e-6 + 1e-12);
    const bool has_ref = src.reference_position(x);
    EXPECT_EQ(has_ref, n % 10 != 9) << n;
    if (has_ref) {
      EXPECT_NEAR(x, truths[n].position_m, 0.5e-9 + 1e-15);
    }
  }
  EXPECT_EQ(src.read(s), ReadStatus::end_of_stream);
  EXPECT_EQ(src.read(s), ReadStatus::end_of_stream);
  EXPECT_EQ(src.describe(), "replay(" + path + ", 1000 rows read)");
  EXPECT_TRUE(src.last_error().empty());
}

TEST(RawLog, TemperatureColumnRoundTrip) {
  TempDir dir;
  const std::string path = dir.path("temp.csv");
  RawLogWriter::Columns cols;
  cols.hall_count = 2;
  cols.accel_base = true;
  cols.temperature = true;
  RawLogWriter w;
  std::string error;
  ASSERT_TRUE(w.open(path, cols, {{"sample_rate_hz", "1000"}}, error)) << error;
  std::vector<RawSample> written;
  for (int n = 0; n < 50; ++n) {
    RawSample s = sample(1000000LL * (n + 1), 2);
    s.accel_base_valid = true;
    s.temperature_valid = n % 7 != 3;  // some rows without a reading: empty cells
    s.temperature_c = 25.0 + 0.0625 * n - 3.0 * (n % 2);
    ASSERT_TRUE(w.write(s, nullptr, nullptr)) << w.error();
    written.push_back(s);
  }
  RawSample bad = sample(1000000LL * 60, 2);
  bad.temperature_valid = true;
  bad.temperature_c = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(w.write(bad, nullptr, nullptr));  // the reader would not read it
  ASSERT_TRUE(w.close(error)) << error;

  {
    std::ifstream in(path);
    std::string line;
    while (std::getline(in, line) && line[0] == '#') {
    }
    EXPECT_EQ(line, "t_s,hall_0_v,hall_1_v,accel_mps2,accel_base_mps2,temperature_c");
    ASSERT_TRUE(std::getline(in, line));
    EXPECT_NE(line.find(",25.000000"), std::string::npos) << line;
  }
  RawLogReader r;
  ASSERT_TRUE(r.open(path)) << all(r);
  EXPECT_TRUE(r.warnings().empty());
  EXPECT_TRUE(r.meta().has_temperature);
  RawLogRow row;
  for (const RawSample& s : written) {
    ASSERT_EQ(r.next(row), Next::row) << all(r);
    EXPECT_EQ(row.sample.temperature_valid, s.temperature_valid) << s.t_ns;
    EXPECT_EQ(row.sample.temperature_c, s.temperature_valid ? s.temperature_c : 0.0) << s.t_ns;
    EXPECT_TRUE(row.sample.accel_base_valid);
  }
  EXPECT_EQ(r.next(row), Next::end);
  EXPECT_TRUE(r.errors().empty()) << all(r);

  // A log without the column: no temperature, and the column may come in any order.
  const std::string plain = dir.write("plain.csv", kV1 +
                                                   "t_s,hall_0_v,accel_mps2\n"
                                                   "0.001,1,0\n");
  RawLogReader p;
  ASSERT_TRUE(p.open(plain)) << all(p);
  EXPECT_FALSE(p.meta().has_temperature);
  ASSERT_EQ(p.next(row), Next::row) << all(p);
  EXPECT_FALSE(row.sample.temperature_valid);
  const std::string first = dir.write("first.csv", kV1 +
                                                   "temperature_c,t_s,hall_0_v,accel_mps2\n"
                                                   " 31.5 ,0.001,1,0\n"
                                                   "x,0.002,1,0\n");
  RawLogReader f;
  ASSERT_TRUE(f.open(first)) << all(f);
  ASSERT_EQ(f.next(row), Next::row) << all(f);
  EXPECT_TRUE(row.sample.temperature_valid);
  EXPECT_EQ(row.sample.temperature_c, 31.5);
  EXPECT_EQ(f.next(row), Next::error);
  EXPECT_EQ(f.last_error().field, "temperature_c");
  EXPECT_EQ(f.last_error().column, 1);
}

TEST(Replay, ReportedTemperatureComesBack) {
  TempDir dir;
  const std::string path = dir.path("sim-temp.csv");
  ve::core::MotorConfig motor;
  ve::sim::SimConfig cfg;
  cfg.realtime = false;
  cfg.temperature.report = true;
  cfg.temperature.offset_k = 7.5;
  ve::sim::SimSource sim(motor, cfg);
  ASSERT_TRUE(sim.ok()) << sim.last_error();
  RawSample s;
  std::vector<RawSample> written;
  RawLogWriter w;
  std::string error;
  ASSERT_EQ(sim.read(s), ReadStatus::ok);
  RawLogWriter::Columns cols;
  cols.hall_count = motor.hall.count;
  cols.temperature = s.temperature_valid;  // as `record` decides
  ASSERT_TRUE(cols.temperature);
  ASSERT_TRUE(w.open(path, cols, {{"sample_rate_hz", "4000"}}, error)) << error;
  for (int n = 0; n < 200; ++n) {
    if (n > 0) {
      ASSERT_EQ(sim.read(s), ReadStatus::ok);
    }
    ASSERT_TRUE(w.write(s, nullptr, nullptr)) << w.error();
    written.push_back(s);
  }
  ASSERT_TRUE(w.close(error)) << error;
  ReplaySource src(path, false);
  ASSERT_TRUE(src.ok()) << src.last_error();
  for (const RawSample& x : written) {
    ASSERT_EQ(src.read(s), ReadStatus::ok) << src.last_error();
    EXPECT_TRUE(s.temperature_valid);
    EXPECT_EQ(s.temperature_c, x.temperature_c);  // multiples of 1/16 K print exactly
    EXPECT_NEAR(s.temperature_c, 32.5, 0.6);
  }
}

TEST(Replay, TruthAndReferenceFollowTheRow) {
  TempDir dir;
  const std::string p = dir.write("t.csv", kV1 +
                                               "t_s,hall_0_v,accel_mps2,ref_position_m,true_position_m,"
                                               "true_velocity_mps,true_acceleration_mps2\n"
                                               "0.0,1,2,0.5,0.1,0.2,0.3\n"
                                               "0.1,1,2,,,,\n"
                                               "0.2,1,2,0.7,0.4,0.5,0.6\n");
  ReplaySource src(p, false);
  ASSERT_TRUE(src.ok()) << src.last_error();
  RawSample s;
  double x = 0;
  ASSERT_EQ(src.read(s), ReadStatus::ok);
  ASSERT_NE(src.truth(), nullptr);
  EXPECT_EQ(src.truth()->velocity_mps, 0.2);
  ASSERT_TRUE(src.reference_position(x));
  EXPECT_EQ(x, 0.5);
  ASSERT_EQ(src.read(s), ReadStatus::ok);
  EXPECT_EQ(src.truth(), nullptr);
  EXPECT_FALSE(src.reference_position(x));
  ASSERT_EQ(src.read(s), ReadStatus::ok);
  ASSERT_NE(src.truth(), nullptr);
  EXPECT_EQ(src.truth()->acceleration_mps2, 0.6);
  ASSERT_TRUE(src.reference_position(x));
  EXPECT_EQ(x, 0.7);
  EXPECT_EQ(src.read(s), ReadStatus::end_of_stream);
}

TEST(Replay, BadHeaderIsNotOk) {
  TempDir dir;
  const std::string p = dir.write("h.csv", kV1 + "t_s,accel_mps2\n0,1\n");
  ReplaySource src(p, false);
  EXPECT_FALSE(src.ok());
  EXPECT_EQ(src.last_error(), p + ":2:1: hall_0_v: required column missing");
  RawSample s;
  EXPECT_EQ(src.read(s), ReadStatus::error);

  ReplaySource missing(dir.path("nope.csv"), false);
  EXPECT_FALSE(missing.ok());
  EXPECT_NE(missing.last_error().find("cannot open"), std::string::npos);
}

TEST(Replay, MalformedRowIsAnError) {
  TempDir dir;
  const std::string p = dir.write("r.csv", kV1 + kHeader3 + "0,1,2\n0.001,1,oops\n0.002,1,2\n");
  ReplaySource src(p, false);
  ASSERT_TRUE(src.ok());
  RawSample s;
  ASSERT_EQ(src.read(s), ReadStatus::ok);
  ASSERT_EQ(src.read(s), ReadStatus::error);
  EXPECT_EQ(src.last_error(), p + ":4:9: accel_mps2: expected a number, got 'oops'");
  EXPECT_EQ(src.read(s), ReadStatus::error);  // stays failed
  EXPECT_EQ(src.describe(), "replay(" + p + ", 1 rows read)");
}

TEST(Replay, RealtimePacesByTimestamps) {
  TempDir dir;
  const std::string path = dir.path("rt.csv");
  record_sim(path, 200);  // 4 kHz: the last row is due 49.75 ms after the first
  ReplaySource src(path, true);
  ASSERT_TRUE(src.ok()) << src.last_error();
  RawSample s;
  const auto start = std::chrono::steady_clock::now();
  int rows = 0;
  while (src.read(s) == ReadStatus::ok) ++rows;
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  EXPECT_EQ(rows, 200);
  // Paced: it cannot be faster than the log's own time span (no upper bound: a loaded
  // machine only makes it slower).
  EXPECT_GE(ms, 25.0);
}

TEST(Replay, StopInterruptsRealtime) {
  TempDir dir;
  // Two rows 10 s apart: the second read sleeps until stop() wakes it.
  const std::string p = dir.write("gap.csv", kV1 + kHeader3 + "0,1,2\n10,1,2\n");
  ReplaySource src(p, true);
  ASSERT_TRUE(src.ok());
  RawSample s;
  ASSERT_EQ(src.read(s), ReadStatus::ok);
  std::thread stopper([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    src.stop();
  });
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(src.read(s), ReadStatus::stopped);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  stopper.join();
  EXPECT_GE(ms, 40.0);
  // Woken by stop(), not by the row 10 s later.
  EXPECT_LT(ms, 5000.0);
  EXPECT_EQ(src.read(s), ReadStatus::stopped);
}

// Run by hand: --gtest_also_run_disabled_tests --gtest_filter='*ReadSpeed*'
TEST(RawLog, DISABLED_ReadSpeedMillionRows) {
  TempDir dir;
  const std::string path = dir.path("big.csv");
  constexpr int kRows = 1000000;
  {
    RawLogWriter w;
    std::string error;
    ASSERT_TRUE(w.open(path, {6, false, false, false}, {{"sample_rate_hz", "4000"}}, error)) << error;  // 8 columns
    const auto start = std::chrono::steady_clock::now();
    for (int n = 0; n < kRows; ++n) ASSERT_TRUE(w.write(sample(n * 250000LL, 6), nullptr, nullptr));
    ASSERT_TRUE(w.close(error)) << error;
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf("wrote %d rows x 8 columns in %.3f s\n", kRows, s);
  }
  struct stat st {};
  ::stat(path.c_str(), &st);
  RawLogReader r;
  ASSERT_TRUE(r.open(path));
  RawLogRow row;
  const auto start = std::chrono::steady_clock::now();
  int rows = 0;
  double sum = 0.0;
  while (r.next(row) == Next::row) {
    sum += row.sample.hall_v[0];
    ++rows;
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("read %d rows x 8 columns (%.1f MB) in %.3f s (%.0f rows/s, checksum %g)\n", rows,
              static_cast<double>(st.st_size) / 1e6, s, rows / s, sum);
  EXPECT_EQ(rows, kRows);
  EXPECT_LT(s, 2.0);
}

}  // namespace
