// Raw log: the product's file format for sensor recordings, with a streaming
// reader and a crash-safe writer.
//
// ===========================================================================
// Raw log format v1
// ===========================================================================
// CSV, UTF-8, lines end in '\n' ("\r\n" is accepted too; a UTF-8 byte order mark
// at the very start is skipped). Lines are at most kMaxLineBytes bytes long.
//
//   # virtual-encoder raw log v1
//   # sample_rate_hz=4000
//   # hall_count=4
//   # motor=sim-12mm
//   # source=sim(...)
//   # eval_window_s=0.5,2.5
//   t_s,hall_0_v,hall_1_v,hall_2_v,hall_3_v,accel_mps2,true_position_m,...
//   0.000000000,1.234567,,2.000000,0.500000,-0.012345,0.000000000,...
//
// 1. Optional leading comment lines, starting with '#'. The first should be
//    `# virtual-encoder raw log v1`; a version line naming any other version is
//    an error, a file without one is read as v1 with a warning. Comment lines of
//    the form `# key=value` (key: letters, digits, '_', '.', '-'; spaces around
//    key and value are dropped) are metadata; the last of repeated keys wins,
//    with a warning. Known keys, checked when present:
//      sample_rate_hz  nominal sample rate [Hz], a finite number > 0
//      hall_count      integer; must equal the number of hall columns
//      eval_window_s   "T0,T1": the part of the log an evaluation should score [s]
//    Any other key (motor, source, ...) is kept as text.
// 2. One header line: column names separated by ',', in any order (spaces
//    around a name are dropped):
//      t_s                     required: sample instant [s], strictly increasing
//                              (at 1 ns resolution: t_ns = llround(t_s * 1e9))
//      hall_0_v .. hall_{N-1}_v  required, contiguous from 0, N = 1..8: Hall
//                              outputs as read [V]
//      accel_mps2              required: accelerometer on the moving part [m/s^2]
//      accel_base_mps2         optional: accelerometer on the frame [m/s^2]
//      temperature_c           optional: temperature the sensor node reports [deg C]
//      ref_position_m          optional: reference ruler [m]
//      true_position_m, true_velocity_mps, true_acceleration_mps2
//                              optional, all three or none: ground truth
//    Any other column is ignored (with a warning) and its cells are not parsed.
// 3. One row per sample, with exactly as many cells as the header. Cells are
//    decimal numbers (an optional sign, optional exponent; spaces around them
//    are dropped). NaN and infinities are errors. An empty cell means that
//    sensor's sample is missing: an empty hall cell clears its bit in
//    hall_valid_mask, an empty accel cell makes accel_valid (accel_base_valid)
//    false, an empty temperature_c cell makes temperature_valid false, an
//    empty ref_position_m cell means no reference for that row, and truth is
//    present for a row only when its three cells are all filled (some but not
//    all filled is an error). t_s may not be empty. Blank lines and
//    further '#' lines after the header are skipped.
//
// Errors carry FILE:LINE:COL: FIELD: MESSAGE, like the configuration loader.
// Lines and columns are 1-based; columns count bytes (after the byte order mark).
//   no header                 line after the last line read, column 1, field ""
//   version line not v1       that line, column of the version word, field "version"
//   bad metadata value        that line, column of the value, field = the key
//   missing required column   header line, column 1, field = the column's name
//   duplicate column          header line, column of the second one, field = name
//   hall columns not contiguous  header line, column of the first hall column
//                             past the gap, field = its name
//   hall column out of range  (hall_8_v, hall_01_v) its column, field = its name
//   incomplete truth set      header line, column of a truth column present,
//                             field = the first truth column missing
//   line too long             that line, column kMaxLineBytes + 1, field ""
//   wrong number of cells     that row; too few: column just past the end of the
//                             line, field = the first column missing; too many:
//                             column of the first extra cell, field ""
//   non-numeric / NaN / inf / out of range   that cell's column (its first
//                             non-blank byte), field = the column's name
//   t_s empty or not strictly increasing     t_s cell, field "t_s"
//   partial truth in a row    that row, column of the first empty truth cell,
//                             field = its name
// ===========================================================================
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "core/input_error.hpp"
#include "core/sample.hpp"

namespace ve::replay {

/// The reader reads regular files and FIFOs (a pipe from another program); a
/// directory, a device (/dev/zero) or a socket is refused with the reason.
/// Longest line the reader accepts, in bytes, not counting the line end.
inline constexpr std::size_t kMaxLineBytes = 65536;
/// The reader keeps at most this many errors in errors(); later ones are counted
/// in error_count() and still reported through next() and last_error().
inline constexpr std::size_t kMaxStoredErrors = 100;

/// A problem in a raw log; `field` is the column name or metadata key.
using LogError = core::InputError;
/// All errors, one per line.
using core::to_string;

struct RawLogMeta {
  std::map<std::string, std::string> values;  ///< every `# key=value` line
  int hall_count = 0;                         ///< hall columns in the header
  bool has_accel_base = false;
  bool has_temperature = false;
  bool has_reference = false;
  bool has_truth = false;
  double sample_rate_hz = 0.0;  ///< from metadata; 0 when not given

  /// The `eval_window_s=T0,T1` metadata; false when absent or malformed.
  bool eval_window(double& t0, double& t1) const;
};

struct RawLogRow {
  core::RawSample sample;  ///< seq = row index (0-based), t_ns = llround(t_s * 1e9)
  bool has_truth = false;
  core::Truth truth{};
  bool has_reference = false;
  double reference_position_m = 0.0;
};

/// Streaming reader: holds one buffer, however long the log.
class RawLogReader {
 public:
  RawLogReader();
  ~RawLogReader();
  RawLogReader(const RawLogReader&) = delete;
  RawLogReader& operator=(const RawLogReader&) = delete;

  /// Reads the comments and the header. False: errors() says why (all header
  /// problems are reported, not only the first). Can be called again to reopen.
  bool open(const std::string& path);
  const RawLogMeta& meta() const { return meta_; }
  const std::string& path() const { return path_; }

  enum class Next { row, end, error };
  /// The next row. Does not allocate once the reader is open (except to record an
  /// error). On error `row` is left untouched, the error is appended and the next
  /// call goes on with the following line; end is returned for ever after EOF, a
  /// read error or a failed open().
  Next next(RawLogRow& row);

  const std::vector<LogError>& errors() const { return errors_; }
  /// Most recent error (also when errors() is full); empty message if none.
  const LogError& last_error() const { return last_error_; }
  /// Errors seen in total, including those not stored.
  std::size_t error_count() const { return error_count_; }
  const std::vector<std::string>& warnings() const { return warnings_; }
  /// Rows returned so far.
  std::uint64_t rows() const { return rows_; }

 private:
  enum class Role : std::uint8_t { ignored, t, hall, accel, accel_base, temperature, ref, true_pos, true_vel, true_acc };
  struct Column {
    Role role = Role::ignored;
    int hall = 0;  // role == hall
  };
  enum class Line { ok, eof, too_long };

  void reset();
  void close_fd();
  Line next_line();  // sets line_ / line_len_ / line_no_
  bool fill();       // more bytes into buf_; false at EOF or on a read error
  void add_error(std::int64_t line, int column, std::string field, std::string message);
  void add_warning(std::int64_t line, int column, std::string field, std::string message);
  bool parse_metadata(const char* text, std::size_t len, bool& saw_version);
  bool parse_header(const char* text, std::size_t len);
  bool parse_row(const char* text, std::size_t len);  // into row_

  std::string path_;
  int fd_ = -1;
  bool eof_ = false;   // no more bytes from the file
  bool done_ = false;  // next() returns end
  std::vector<char> buf_;
  std::size_t begin_ = 0, end_ = 0;  // unread bytes are buf_[begin_, end_)
  const char* line_ = nullptr;
  std::size_t line_len_ = 0;
  std::int64_t line_no_ = 0;  // LogError::line saturates at INT_MAX

  RawLogMeta meta_;
  int meta_hall_count_ = 0;  // `# hall_count=` (0: not given), checked against the header
  std::int64_t meta_hall_count_line_ = 0;
  int meta_hall_count_col_ = 0;
  std::vector<Column> columns_;
  std::vector<std::string> names_;
  RawLogRow row_;
  std::int64_t last_t_ns_ = 0;
  std::int64_t last_t_line_ = 0;
  std::uint64_t rows_ = 0;

  std::vector<LogError> errors_;
  LogError last_error_;
  std::size_t error_count_ = 0;
  std::vector<std::string> warnings_;
};

/// Writes to PATH.partial; close() flushes, fsyncs, renames it to PATH (replacing
/// any file there) and fsyncs the directory, so an interrupted recording never
/// leaves a file under PATH that looks complete. A PATH that exists and is not a
/// regular file or a directory (a FIFO, /dev/stdout, a terminal) is written
/// directly instead (direct() is true; there is no PATH.partial then).
class RawLogWriter {
 public:
  struct Columns {
    int hall_count = 0;  ///< 1..8
    bool accel_base = false;
    bool reference = false;
    bool truth = false;
    bool temperature = false;  ///< temperature_c (last: positional initialisers stay valid)
  };

  RawLogWriter() = default;
  RawLogWriter(const RawLogWriter&) = delete;
  RawLogWriter& operator=(const RawLogWriter&) = delete;
  /// Without close(): buffered rows are written to PATH.partial, which is left in
  /// place (a crash leaves evidence) and never renamed.
  ~RawLogWriter();

  /// Creates PATH.partial and writes the version line, `# key=value` for each
  /// metadata pair (in order; `hall_count` is added when not given) and the header.
  /// Keys must match [A-Za-z0-9_.-]+; neither keys nor values may hold a line break.
  bool open(const std::string& path, const Columns& cols,
            const std::vector<std::pair<std::string, std::string>>& metadata, std::string& error);

  /// One row. t_s is s.t_ns printed exactly (9 decimals); volts, accelerations and
  /// temperature with 6 decimals, positions and velocity with 9; a hall i >= s.hall_count,
  /// a cleared valid bit, accel(_base)_valid or temperature_valid false, a null truth or reference give
  /// empty cells. truth / reference are ignored when the columns were not asked
  /// for. False (nothing written; error() says why) when the writer is not open,
  /// s.hall_count exceeds the columns, t_ns does not increase, a value to write is
  /// not finite, or the file cannot be written.
  bool write(const core::RawSample& s, const core::Truth* truth, const double* reference_position_m);

  /// Flush, fsync, rename PATH.partial -> PATH, fsync the directory. False: the
  /// .partial is kept and PATH is not touched (unless the rename itself succeeded
  /// and only the directory fsync failed).
  bool close(std::string& error);

  /// Closes the file without finishing it and removes PATH.partial (a failed
  /// recording leaves nothing behind). Nothing to do when not open.
  void discard();

  bool is_open() const { return fd_ >= 0; }
  /// PATH is written directly (it is a FIFO or a device), without PATH.partial.
  bool direct() const { return direct_; }
  const std::string& error() const { return error_; }
  std::uint64_t rows_written() const { return rows_; }
  const std::string& path() const { return path_; }
  std::string partial_path() const { return path_ + ".partial"; }

 private:
  bool flush();
  bool fail(std::string message);

  std::string path_;
  int fd_ = -1;
  Columns cols_{};
  std::string buf_;
  std::string error_;
  std::uint64_t rows_ = 0;
  bool io_failed_ = false;  // a write to the file failed: nothing more is accepted
  bool direct_ = false;     // PATH itself is written (not a regular file)
  bool have_last_t_ = false;
  std::int64_t last_t_ns_ = 0;
};

}  // namespace ve::replay
