#include "replay/raw_log.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>
#include <system_error>

namespace ve::replay {

namespace {

constexpr std::size_t kReadBufferBytes = std::size_t{1} << 20;  // > 2 * (kMaxLineBytes + 2)
constexpr std::size_t kWriteFlushBytes = std::size_t{1} << 16;
/// An over-long line is skipped up to its end, but no further than this.
constexpr std::size_t kMaxSkipBytes = std::size_t{16} << 20;
constexpr const char* kVersionPrefix = "virtual-encoder raw log";
constexpr const char* kVersion = "v1";
constexpr std::int64_t kMaxAbsTimeS = 9000000000LL;  // |t_s| * 1e9 fits in int64

constexpr const char* kTrueNames[3] = {"true_position_m", "true_velocity_mps", "true_acceleration_mps2"};

bool is_blank(char c) { return c == ' ' || c == '\t'; }
bool is_digit(char c) { return c >= '0' && c <= '9'; }
bool is_key_char(char c) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || is_digit(c) || c == '_' || c == '.' || c == '-';
}

void trim(const char*& b, const char*& e) {
  while (b < e && is_blank(*b)) ++b;
  while (e > b && is_blank(e[-1])) --e;
}

/// Up to 40 bytes of a cell, quoted, with anything unprintable escaped.
std::string quote(const char* b, const char* e) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string s = "'";
  const std::size_t n = static_cast<std::size_t>(e - b);
  for (std::size_t i = 0; i < n && i < 40; ++i) {
    const auto c = static_cast<unsigned char>(b[i]);
    if (c >= 0x20 && c < 0x7f && c != '\\' && c != '\'') {
      s += static_cast<char>(c);
    } else if (c >= 0x80) {
      s += static_cast<char>(c);  // UTF-8 passes through
    } else {
      s += "\\x";
      s += kHex[c >> 4];
      s += kHex[c & 15];
    }
  }
  if (n > 40) s += "...";
  s += "'";
  return s;
}

enum class Num { ok, bad, not_finite, out_of_range };

Num parse_double(const char* b, const char* e, double& out) {
  if (b < e && *b == '+' && e - b > 1 && (is_digit(b[1]) || b[1] == '.')) ++b;
  if (b == e) return Num::bad;
  double x = 0.0;
  const std::from_chars_result r = std::from_chars(b, e, x, std::chars_format::general);
  if (r.ptr != e) return Num::bad;
  if (r.ec == std::errc::result_out_of_range) return Num::out_of_range;
  if (r.ec != std::errc()) return Num::bad;
  if (!std::isfinite(x)) return Num::not_finite;
  out = x;
  return Num::ok;
}

/// t_s -> ns. Plain decimals with at most 9 fraction digits (all the writer
/// produces) are converted exactly; anything else goes through double.
Num parse_time_ns(const char* b, const char* e, std::int64_t& ns) {
  const char* p = b;
  bool neg = false;
  if (p < e && (*p == '+' || *p == '-')) neg = *p++ == '-';
  std::int64_t ip = 0, frac = 0;
  int idig = 0, fdig = 0;
  bool exact = true;
  while (p < e && is_digit(*p)) {
    if (++idig > 10) {
      exact = false;
      break;
    }
    ip = ip * 10 + (*p++ - '0');
  }
  if (exact && p < e && *p == '.') {
    ++p;
    while (p < e && is_digit(*p)) {
      if (++fdig > 9) {
        exact = false;
        break;
      }
      frac = frac * 10 + (*p++ - '0');
    }
  }
  if (exact && p == e && idig + fdig > 0 && ip <= kMaxAbsTimeS) {
    for (int i = fdig; i < 9; ++i) frac *= 10;
    ns = ip * 1000000000LL + frac;
    if (neg) ns = -ns;
    return Num::ok;
  }
  double t = 0.0;
  const Num r = parse_double(b, e, t);
  if (r != Num::ok) return r;
  if (!(std::fabs(t) <= static_cast<double>(kMaxAbsTimeS))) return Num::out_of_range;
  ns = std::llround(t * 1e9);
  return Num::ok;
}

/// Writes t_ns as seconds with exactly 9 decimals into p (at least 32 bytes); returns the end.
char* put_t_ns(char* p, std::int64_t t_ns) {
  char* const limit = p + 32;
  const bool neg = t_ns < 0;
  const std::uint64_t a = neg ? 0 - static_cast<std::uint64_t>(t_ns) : static_cast<std::uint64_t>(t_ns);
  if (neg) *p++ = '-';
  p = std::to_chars(p, limit, a / 1000000000ULL).ptr;  // at most 11 digits
  *p++ = '.';
  std::uint64_t frac = a % 1000000000ULL;
  for (int i = 8; i >= 0; --i) {
    p[i] = static_cast<char>('0' + frac % 10);
    frac /= 10;
  }
  return p + 9;
}

std::string format_t_ns(std::int64_t t_ns) {
  char buf[32];
  return std::string(buf, put_t_ns(buf, t_ns));
}

std::string num_message(Num r, const char* b, const char* e) {
  switch (r) {
    case Num::not_finite: return "must be finite, got " + quote(b, e);
    case Num::out_of_range: return "number out of range: " + quote(b, e);
    default: return "expected a number, got " + quote(b, e);
  }
}

int col_of(const char* line, const char* p) { return static_cast<int>(p - line) + 1; }

int clamp_line(std::int64_t line) {
  return static_cast<int>(std::min<std::int64_t>(line, std::numeric_limits<int>::max()));
}

}  // namespace

// ---------------------------------------------------------------------------

bool RawLogMeta::eval_window(double& t0, double& t1) const {
  const auto it = values.find("eval_window_s");
  if (it == values.end()) return false;
  const std::string& v = it->second;
  const std::size_t comma = v.find(',');
  if (comma == std::string::npos) return false;
  const char* b0 = v.data();
  const char* e0 = v.data() + comma;
  const char* b1 = e0 + 1;
  const char* e1 = v.data() + v.size();
  trim(b0, e0);
  trim(b1, e1);
  double a = 0.0, b = 0.0;
  if (parse_double(b0, e0, a) != Num::ok || parse_double(b1, e1, b) != Num::ok || !(a < b)) return false;
  t0 = a;
  t1 = b;
  return true;
}

// ---------------------------------------------------------------------------
// Reader

RawLogReader::RawLogReader() = default;
RawLogReader::~RawLogReader() { close_fd(); }

void RawLogReader::close_fd() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void RawLogReader::reset() {
  close_fd();
  eof_ = false;
  done_ = false;
  begin_ = end_ = 0;
  line_ = nullptr;
  line_len_ = 0;
  line_no_ = 0;
  meta_ = RawLogMeta{};
  meta_hall_count_ = 0;
  meta_hall_count_line_ = 0;
  meta_hall_count_col_ = 0;
  columns_.clear();
  names_.clear();
  row_ = RawLogRow{};
  last_t_ns_ = 0;
  last_t_line_ = 0;
  rows_ = 0;
  errors_.clear();
  last_error_ = LogError{};
  error_count_ = 0;
  warnings_.clear();
}

void RawLogReader::add_warning(std::int64_t line, int column, std::string field, std::string message) {
  warnings_.push_back(LogError{path_, clamp_line(line), column, std::move(field), std::move(message)}.to_string());
}

void RawLogReader::add_error(std::int64_t line, int column, std::string field, std::string message) {
  last_error_ = LogError{path_, clamp_line(line), column, std::move(field), std::move(message)};
  ++error_count_;
  if (errors_.size() < kMaxStoredErrors) {
    errors_.push_back(last_error_);
  } else if (errors_.size() == kMaxStoredErrors) {
    errors_.push_back(LogError{path_, 0, 0, "", "too many errors; further ones are not listed"});
  }
}

bool RawLogReader::fill() {
  if (eof_) return false;
  if (begin_ > 0) {
    std::memmove(buf_.data(), buf_.data() + begin_, end_ - begin_);
    end_ -= begin_;
    begin_ = 0;
  }
  for (;;) {
    const ssize_t n = ::read(fd_, buf_.data() + end_, buf_.size() - end_);
    if (n > 0) {
      end_ += static_cast<std::size_t>(n);
      return true;
    }
    if (n == 0) {
      eof_ = true;
      return false;
    }
    if (errno == EINTR) continue;
    add_error(0, 0, "", std::string("read error: ") + std::strerror(errno));
    eof_ = true;
    done_ = true;
    begin_ = end_ = 0;  // never parse a line cut short by the error
    return false;
  }
}

RawLogReader::Line RawLogReader::next_line() {
  for (;;) {
    if (done_) return Line::eof;
    char* const base = buf_.data();
    const std::size_t avail = end_ - begin_;
    const void* nl = avail > 0 ? std::memchr(base + begin_, '\n', avail) : nullptr;
    if (nl != nullptr || (eof_ && avail > 0) || avail > kMaxLineBytes + 1) {
      ++line_no_;
      if (nl == nullptr && avail > kMaxLineBytes + 1) {
        // Over-long: drop everything up to and including the next '\n', but not
        // for ever (a pipe of /dev/zero has no line end): past kMaxSkipBytes the
        // rest of the input is not read.
        std::size_t skipped = 0;
        for (;;) {
          const void* skip = std::memchr(base + begin_, '\n', end_ - begin_);
          if (skip != nullptr) {
            begin_ = static_cast<std::size_t>(static_cast<const char*>(skip) - base) + 1;
            return Line::too_long;
          }
          skipped += end_ - begin_;
          begin_ = end_ = 0;
          if (skipped > kMaxSkipBytes) {
            eof_ = true;
            done_ = true;
            return Line::too_long;
          }
          if (!fill()) return done_ ? Line::eof : Line::too_long;
        }
      }
      const std::size_t stop = nl != nullptr ? static_cast<std::size_t>(static_cast<const char*>(nl) - base) : end_;
      line_ = base + begin_;
      line_len_ = stop - begin_;
      begin_ = nl != nullptr ? stop + 1 : stop;
      if (line_len_ > 0 && line_[line_len_ - 1] == '\r') --line_len_;
      if (line_len_ > kMaxLineBytes) return Line::too_long;
      return Line::ok;
    }
    if (eof_) return Line::eof;
    fill();
  }
}

bool RawLogReader::open(const std::string& path) {
  reset();
  path_ = path;
  fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) {
    add_error(0, 0, "", std::string("cannot open: ") + std::strerror(errno));
    done_ = true;
    return false;
  }
  struct stat st {};
  if (::fstat(fd_, &st) != 0 || !(S_ISREG(st.st_mode) || S_ISFIFO(st.st_mode))) {
    const char* kind = S_ISDIR(st.st_mode)                           ? "a directory"
                       : S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode) ? "a device"
                       : S_ISSOCK(st.st_mode)                       ? "a socket"
                                                                    : "not a regular file";
    add_error(0, 0, "", std::string("cannot read: it is ") + kind + ", not a raw log file (a regular file or a FIFO)");
    close_fd();
    done_ = true;
    return false;
  }
  if (buf_.size() < kReadBufferBytes) buf_.resize(kReadBufferBytes);

  bool saw_version = false, saw_header = false;
  for (;;) {
    const Line l = next_line();
    if (l == Line::eof) break;
    if (l == Line::too_long) {
      add_error(line_no_, static_cast<int>(kMaxLineBytes) + 1, "",
                "line longer than " + std::to_string(kMaxLineBytes) + " bytes");
      continue;
    }
    if (line_no_ == 1 && line_len_ >= 3 && std::memcmp(line_, "\xEF\xBB\xBF", 3) == 0) {
      line_ += 3;
      line_len_ -= 3;
    }
    const char* b = line_;
    const char* e = line_ + line_len_;
    trim(b, e);
    if (b == e) continue;
    if (line_[0] == '#') {
      parse_metadata(line_, line_len_, saw_version);
      continue;
    }
    parse_header(line_, line_len_);
    saw_header = true;
    break;
  }
  if (!saw_header && !done_) add_error(line_no_ + 1, 1, "", "no header line");
  if (!saw_version && saw_header)
    add_warning(0, 0, "", std::string("no '# ") + kVersionPrefix + " " + kVersion + "' line; read as " + kVersion);
  if (error_count_ > 0) {
    done_ = true;
    close_fd();
    return false;
  }
  row_.sample.hall_count = meta_.hall_count;
  return true;
}

bool RawLogReader::parse_metadata(const char* text, std::size_t len, bool& saw_version) {
  const char* end = text + len;
  const char* p = text + 1;
  while (p < end && is_blank(*p)) ++p;
  const std::size_t prefix_len = std::strlen(kVersionPrefix);
  if (static_cast<std::size_t>(end - p) >= prefix_len && std::memcmp(p, kVersionPrefix, prefix_len) == 0) {
    saw_version = true;
    const char* v = p + prefix_len;
    const char* ve = end;
    trim(v, ve);
    if (static_cast<std::size_t>(ve - v) != std::strlen(kVersion) || std::memcmp(v, kVersion, ve - v) != 0) {
      add_error(line_no_, col_of(text, v), "version",
                "unsupported raw log version " + quote(v, ve) + "; this reader reads " + kVersion);
      return false;
    }
    return true;
  }
  const char* kb = p;
  while (p < end && is_key_char(*p)) ++p;
  const char* ke = p;
  while (p < end && is_blank(*p)) ++p;
  if (kb == ke || p == end || *p != '=') return true;  // a plain comment
  const char* vb = p + 1;
  const char* vend = end;
  trim(vb, vend);
  std::string key(kb, ke);
  const int value_col = col_of(text, vb);

  if (key == "sample_rate_hz") {
    double rate = 0.0;
    if (parse_double(vb, vend, rate) != Num::ok || !(rate > 0.0)) {
      add_error(line_no_, value_col, key, "expected a number > 0, got " + quote(vb, vend));
      return false;
    }
    meta_.sample_rate_hz = rate;
  } else if (key == "hall_count") {
    const std::from_chars_result r = std::from_chars(vb, vend, meta_hall_count_);
    if (r.ec != std::errc() || r.ptr != vend || meta_hall_count_ < 1 || meta_hall_count_ > core::kMaxHalls) {
      meta_hall_count_ = 0;
      add_error(line_no_, value_col, key,
                "expected an integer 1.." + std::to_string(core::kMaxHalls) + ", got " + quote(vb, vend));
      return false;
    }
    meta_hall_count_line_ = line_no_;
    meta_hall_count_col_ = value_col;
  }
  auto [it, inserted] = meta_.values.emplace(key, std::string(vb, vend));
  if (!inserted) {
    it->second.assign(vb, vend);
    add_warning(line_no_, col_of(text, kb), key, "repeated metadata key; the last one wins");
  }
  if (key == "eval_window_s") {
    double t0 = 0.0, t1 = 0.0;
    if (!meta_.eval_window(t0, t1)) {
      add_error(line_no_, value_col, key, "expected T0,T1 with T0 < T1 [s], got " + quote(vb, vend));
      return false;
    }
  }
  return true;
}

bool RawLogReader::parse_header(const char* text, std::size_t len) {
  const std::int64_t line = line_no_;
  const char* const end = text + len;
  const std::size_t errors_before = error_count_;

  // Where each known column was first seen (1-based column; 0 = absent).
  int col_t = 0, col_accel = 0, col_base = 0, col_temp = 0, col_ref = 0;
  int col_true[3] = {0, 0, 0};
  int col_hall[core::kMaxHalls] = {};

  const char* b = text;
  for (;;) {
    const char* e = static_cast<const char*>(std::memchr(b, ',', static_cast<std::size_t>(end - b)));
    if (e == nullptr) e = end;
    const char* nb = b;
    const char* ne = e;
    trim(nb, ne);
    const int col = col_of(text, nb);
    std::string name(nb, ne);
    Column c;
    int* seen = nullptr;
    if (name == "t_s") {
      c.role = Role::t, seen = &col_t;
    } else if (name == "accel_mps2") {
      c.role = Role::accel, seen = &col_accel;
    } else if (name == "accel_base_mps2") {
      c.role = Role::accel_base, seen = &col_base;
    } else if (name == "temperature_c") {
      c.role = Role::temperature, seen = &col_temp;
    } else if (name == "ref_position_m") {
      c.role = Role::ref, seen = &col_ref;
    } else if (name == kTrueNames[0]) {
      c.role = Role::true_pos, seen = &col_true[0];
    } else if (name == kTrueNames[1]) {
      c.role = Role::true_vel, seen = &col_true[1];
    } else if (name == kTrueNames[2]) {
      c.role = Role::true_acc, seen = &col_true[2];
    } else if (name.size() > 7 && name.compare(0, 5, "hall_") == 0 && name.compare(name.size() - 2, 2, "_v") == 0 &&
               std::all_of(name.begin() + 5, name.end() - 2, is_digit)) {
      const std::string digits = name.substr(5, name.size() - 7);
      if (digits.size() > 1 || digits[0] - '0' >= core::kMaxHalls) {
        add_error(line, col, name,
                  "hall columns are hall_0_v .. hall_" + std::to_string(core::kMaxHalls - 1) + "_v");
      } else {
        c.role = Role::hall;
        c.hall = digits[0] - '0';
        seen = &col_hall[c.hall];
      }
    } else {
      add_warning(line, col, name, name.empty() ? "empty column name; column ignored" : "unknown column; ignored");
    }
    if (seen != nullptr) {
      if (*seen != 0) {
        add_error(line, col, name, "duplicate column (first at column " + std::to_string(*seen) + ")");
        c.role = Role::ignored;
      } else {
        *seen = col;
      }
    }
    columns_.push_back(c);
    names_.push_back(std::move(name));
    if (e == end) break;
    b = e + 1;
  }

  auto missing = [&](const char* name) { add_error(line, 1, name, "required column missing"); };
  if (col_t == 0) missing("t_s");
  int top = -1;
  for (int i = 0; i < core::kMaxHalls; ++i)
    if (col_hall[i] != 0) top = i;
  if (top < 0) {
    missing("hall_0_v");
  } else {
    int gap = -1;
    for (int i = 0; i < top && gap < 0; ++i)
      if (col_hall[i] == 0) gap = i;
    if (gap >= 0) {
      // Leftmost hall column past the gap.
      for (std::size_t k = 0; k < columns_.size(); ++k) {
        if (columns_[k].role == Role::hall && columns_[k].hall > gap) {
          add_error(line, col_hall[columns_[k].hall], names_[k],
                    "hall columns must be contiguous from hall_0_v; hall_" + std::to_string(gap) + "_v is missing");
          break;
        }
      }
    }
    meta_.hall_count = top + 1;
  }
  if (col_accel == 0) missing("accel_mps2");
  const int n_true = (col_true[0] != 0) + (col_true[1] != 0) + (col_true[2] != 0);
  if (n_true == 1 || n_true == 2) {
    int first_present = 0;
    for (int c : col_true)
      if (c != 0 && (first_present == 0 || c < first_present)) first_present = c;
    for (int k = 0; k < 3; ++k) {
      if (col_true[k] == 0) {
        add_error(line, first_present, kTrueNames[k],
                  "truth columns come as a set: true_position_m, true_velocity_mps and true_acceleration_mps2");
        break;
      }
    }
  }
  if (meta_hall_count_ != 0 && top >= 0 && meta_hall_count_ != meta_.hall_count) {
    add_error(meta_hall_count_line_, meta_hall_count_col_, "hall_count",
              "metadata says " + std::to_string(meta_hall_count_) + " Halls but the header (line " +
                  std::to_string(line) + ") has " + std::to_string(meta_.hall_count) + " hall columns");
  }
  meta_.has_accel_base = col_base != 0;
  meta_.has_temperature = col_temp != 0;
  meta_.has_reference = col_ref != 0;
  meta_.has_truth = n_true == 3;
  return error_count_ == errors_before;
}

bool RawLogReader::parse_row(const char* text, std::size_t len) {
  const std::int64_t line = line_no_;
  const char* const end = text + len;
  const std::size_t ncols = columns_.size();

  std::size_t cells = 1;
  for (const char* p = text; (p = static_cast<const char*>(std::memchr(p, ',', static_cast<std::size_t>(end - p))));
       ++p)
    ++cells;
  if (cells != ncols) {
    const std::string what =
        "row has " + std::to_string(cells) + " cells, the header has " + std::to_string(ncols);
    if (cells < ncols) {
      add_error(line, static_cast<int>(len) + 1, names_[cells], what);
    } else {
      const char* p = text;
      for (std::size_t k = 0; k < ncols; ++k)
        p = static_cast<const char*>(std::memchr(p, ',', static_cast<std::size_t>(end - p))) + 1;
      add_error(line, col_of(text, p), "", what);
    }
    return false;
  }

  core::RawSample& s = row_.sample;
  s.hall_v.fill(0.0);
  s.hall_valid_mask = 0;
  s.accel_mps2 = 0.0;
  s.accel_valid = false;
  s.accel_base_mps2 = 0.0;
  s.accel_base_valid = false;
  s.temperature_c = 0.0;
  s.temperature_valid = false;
  double truth[3] = {0.0, 0.0, 0.0};
  int truth_filled = 0;
  const char* first_empty_truth = nullptr;
  std::size_t first_empty_truth_col = 0;
  bool has_ref = false;
  double ref = 0.0;
  std::int64_t t_ns = 0;

  const char* b = text;
  for (std::size_t k = 0; k < ncols; ++k) {
    const char* e = static_cast<const char*>(std::memchr(b, ',', static_cast<std::size_t>(end - b)));
    if (e == nullptr) e = end;
    const Column c = columns_[k];
    if (c.role != Role::ignored) {
      const char* vb = b;
      const char* ve = e;
      trim(vb, ve);
      if (c.role == Role::t) {
        if (vb == ve) {
          add_error(line, col_of(text, vb), names_[k], "t_s may not be empty");
          return false;
        }
        const Num r = parse_time_ns(vb, ve, t_ns);
        if (r != Num::ok) {
          add_error(line, col_of(text, vb), names_[k], num_message(r, vb, ve));
          return false;
        }
        if (rows_ > 0 && t_ns <= last_t_ns_) {
          add_error(line, col_of(text, vb), names_[k],
                    "must be strictly increasing (at 1 ns resolution): " + format_t_ns(t_ns) +
                        " after " + format_t_ns(last_t_ns_) + " on line " + std::to_string(last_t_line_));
          return false;
        }
      } else if (vb == ve) {
        if (c.role == Role::true_pos || c.role == Role::true_vel || c.role == Role::true_acc) {
          if (first_empty_truth == nullptr) {
            first_empty_truth = vb;
            first_empty_truth_col = k;
          }
        }
      } else {
        double x = 0.0;
        const Num r = parse_double(vb, ve, x);
        if (r != Num::ok) {
          add_error(line, col_of(text, vb), names_[k], num_message(r, vb, ve));
          return false;
        }
        // A reading and the flag that says the row has it.
        const auto put = [x](double& value, bool& present) {
          value = x;
          present = true;
        };
        switch (c.role) {
          case Role::hall:
            s.hall_v[static_cast<std::size_t>(c.hall)] = x;
            s.hall_valid_mask |= 1u << c.hall;
            break;
          case Role::accel: put(s.accel_mps2, s.accel_valid); break;
          case Role::accel_base: put(s.accel_base_mps2, s.accel_base_valid); break;
          case Role::temperature: put(s.temperature_c, s.temperature_valid); break;
          case Role::ref: put(ref, has_ref); break;
          case Role::true_pos: truth[0] = x, ++truth_filled; break;
          case Role::true_vel: truth[1] = x, ++truth_filled; break;
          case Role::true_acc: truth[2] = x, ++truth_filled; break;
          default: break;
        }
      }
    }
    b = e + 1;
  }
  if (truth_filled != 0 && truth_filled != 3) {
    add_error(line, col_of(text, first_empty_truth), names_[first_empty_truth_col],
              "truth cells come as a set: fill all three or none");
    return false;
  }
  s.t_ns = t_ns;
  s.seq = rows_;
  s.hall_count = meta_.hall_count;
  row_.has_truth = truth_filled == 3;
  row_.truth = {truth[0], truth[1], truth[2]};
  row_.has_reference = has_ref;
  row_.reference_position_m = ref;
  last_t_ns_ = t_ns;
  last_t_line_ = line;
  return true;
}

RawLogReader::Next RawLogReader::next(RawLogRow& row) {
  for (;;) {
    if (done_) return Next::end;
    const std::size_t errors_before = error_count_;
    const Line l = next_line();
    if (l == Line::eof) {
      done_ = true;
      close_fd();
      return error_count_ != errors_before ? Next::error : Next::end;  // a read error
    }
    if (l == Line::too_long) {
      add_error(line_no_, static_cast<int>(kMaxLineBytes) + 1, "",
                "line longer than " + std::to_string(kMaxLineBytes) + " bytes");
      return Next::error;
    }
    if (line_len_ == 0 || line_[0] == '#') continue;
    const char* b = line_;
    const char* e = line_ + line_len_;
    trim(b, e);
    if (b == e) continue;
    if (!parse_row(line_, line_len_)) return Next::error;
    row = row_;
    ++rows_;
    return Next::row;
  }
}

// ---------------------------------------------------------------------------
// Writer

namespace {

bool write_all(int fd, const char* p, std::size_t n, std::string& error) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      error = std::strerror(errno);
      return false;
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

bool append_fixed(std::string& out, double x, int decimals) {
  char buf[400];  // the largest double in fixed notation needs 309 digits + sign + point + decimals
  const std::to_chars_result r = std::to_chars(buf, buf + sizeof buf, x, std::chars_format::fixed, decimals);
  if (r.ec != std::errc()) return false;
  out.append(buf, r.ptr);
  return true;
}

std::string dir_of(const std::string& path) {
  const std::size_t slash = path.rfind('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

}  // namespace

RawLogWriter::~RawLogWriter() {
  if (fd_ >= 0) {
    std::string ignored;
    if (!io_failed_ && !buf_.empty()) write_all(fd_, buf_.data(), buf_.size(), ignored);
    ::close(fd_);
  }
}

void RawLogWriter::discard() {
  if (fd_ < 0) return;
  ::close(fd_);
  fd_ = -1;
  buf_.clear();
  if (!direct_) ::unlink(partial_path().c_str());
}

bool RawLogWriter::fail(std::string message) {
  error_ = std::move(message);
  return false;
}

bool RawLogWriter::open(const std::string& path, const Columns& cols,
                        const std::vector<std::pair<std::string, std::string>>& metadata, std::string& error) {
  error.clear();
  if (fd_ >= 0) {
    error = error_ = "raw log writer: already open (" + path_ + ")";
    return false;
  }
  error_.clear();
  rows_ = 0;
  io_failed_ = false;
  direct_ = false;
  have_last_t_ = false;
  if (path.empty()) return fail(error = "raw log writer: empty path");
  if (cols.hall_count < 1 || cols.hall_count > core::kMaxHalls) {
    error = error_ = "raw log writer: hall_count " + std::to_string(cols.hall_count) + " must be 1.." +
                     std::to_string(core::kMaxHalls);
    return false;
  }
  std::string text = std::string("# ") + kVersionPrefix + " " + kVersion + "\n";
  bool has_hall_count = false;
  for (const auto& [key, value] : metadata) {
    if (key.empty() || !std::all_of(key.begin(), key.end(), is_key_char)) {
      error = error_ = "raw log writer: metadata key '" + key + "' must match [A-Za-z0-9_.-]+";
      return false;
    }
    if (value.find_first_of("\r\n") != std::string::npos) {
      error = error_ = "raw log writer: metadata value of '" + key + "' holds a line break";
      return false;
    }
    if (key == "hall_count") {
      if (value != std::to_string(cols.hall_count)) {
        error = error_ = "raw log writer: metadata hall_count=" + value + " but " +
                         std::to_string(cols.hall_count) + " hall columns";
        return false;
      }
      has_hall_count = true;
    }
    text += "# " + key + "=" + value + "\n";
  }
  if (!has_hall_count) text += "# hall_count=" + std::to_string(cols.hall_count) + "\n";
  text += "t_s";
  for (int i = 0; i < cols.hall_count; ++i) text += ",hall_" + std::to_string(i) + "_v";
  text += ",accel_mps2";
  if (cols.accel_base) text += ",accel_base_mps2";
  if (cols.temperature) text += ",temperature_c";
  if (cols.reference) text += ",ref_position_m";
  if (cols.truth) text += ",true_position_m,true_velocity_mps,true_acceleration_mps2";
  text += "\n";
  if (text.size() > kMaxLineBytes) {
    error = error_ = "raw log writer: metadata too long";
    return false;
  }

  struct stat st {};
  const bool exists = ::stat(path.c_str(), &st) == 0;
  if (exists && S_ISDIR(st.st_mode)) {
    error = error_ = "raw log writer: cannot write " + path + ": it is a directory";
    return false;
  }
  const bool direct = exists && !S_ISREG(st.st_mode);
  const std::string partial = path + ".partial";
  const std::string target = direct ? path : partial;
  const int fd = ::open(target.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) {
    error = error_ = "raw log writer: cannot create " + target + ": " + std::strerror(errno);
    return false;
  }
  fd_ = fd;
  direct_ = direct;
  path_ = path;
  cols_ = cols;
  buf_.clear();
  buf_.reserve(kWriteFlushBytes + 8192);
  buf_ += text;
  return true;
}

bool RawLogWriter::flush() {
  if (io_failed_) return false;
  if (buf_.empty()) return true;
  std::string why;
  if (!write_all(fd_, buf_.data(), buf_.size(), why)) {
    io_failed_ = true;  // part of the buffer may be on disk: retrying would duplicate it
    buf_.clear();
    return fail("raw log writer: write to " + (direct_ ? path_ : partial_path()) + ": " + why);
  }
  buf_.clear();
  return true;
}

bool RawLogWriter::write(const core::RawSample& s, const core::Truth* truth, const double* reference_position_m) {
  if (fd_ < 0) return fail("raw log writer: not open");
  if (io_failed_) return false;  // error_ still says why
  if (s.hall_count < 0 || s.hall_count > cols_.hall_count)
    return fail("raw log writer: sample has " + std::to_string(s.hall_count) + " Halls, the log " +
                std::to_string(cols_.hall_count));
  if (have_last_t_ && s.t_ns <= last_t_ns_)
    return fail("raw log writer: t_ns " + std::to_string(s.t_ns) + " does not increase (last " +
                std::to_string(last_t_ns_) + ")");
  if (s.t_ns > kMaxAbsTimeS * 1000000000LL || s.t_ns < -kMaxAbsTimeS * 1000000000LL)
    return fail("raw log writer: t_ns " + std::to_string(s.t_ns) + " out of range");
  if (!cols_.truth) truth = nullptr;
  if (!cols_.reference) reference_position_m = nullptr;

  auto hall_on = [&](int i) { return i < s.hall_count && (s.hall_valid_mask >> i & 1u) != 0; };
  bool finite = true;
  for (int i = 0; i < cols_.hall_count; ++i)
    if (hall_on(i)) finite = finite && std::isfinite(s.hall_v[static_cast<std::size_t>(i)]);
  if (s.accel_valid) finite = finite && std::isfinite(s.accel_mps2);
  if (cols_.accel_base && s.accel_base_valid) finite = finite && std::isfinite(s.accel_base_mps2);
  if (cols_.temperature && s.temperature_valid) finite = finite && std::isfinite(s.temperature_c);
  if (reference_position_m != nullptr) finite = finite && std::isfinite(*reference_position_m);
  if (truth != nullptr)
    finite = finite && std::isfinite(truth->position_m) && std::isfinite(truth->velocity_mps) &&
             std::isfinite(truth->acceleration_mps2);
  if (!finite) return fail("raw log writer: sample " + std::to_string(s.seq) + " holds a value that is not finite");

  const std::size_t mark = buf_.size();
  char t_text[32];
  buf_.append(t_text, put_t_ns(t_text, s.t_ns));
  bool ok = true;
  for (int i = 0; i < cols_.hall_count; ++i) {
    buf_ += ',';
    if (hall_on(i)) ok = ok && append_fixed(buf_, s.hall_v[static_cast<std::size_t>(i)], 6);
  }
  buf_ += ',';
  if (s.accel_valid) ok = ok && append_fixed(buf_, s.accel_mps2, 6);
  if (cols_.accel_base) {
    buf_ += ',';
    if (s.accel_base_valid) ok = ok && append_fixed(buf_, s.accel_base_mps2, 6);
  }
  if (cols_.temperature) {
    buf_ += ',';
    if (s.temperature_valid) ok = ok && append_fixed(buf_, s.temperature_c, 6);
  }
  if (cols_.reference) {
    buf_ += ',';
    if (reference_position_m != nullptr) ok = ok && append_fixed(buf_, *reference_position_m, 9);
  }
  if (cols_.truth) {
    buf_ += ',';
    if (truth != nullptr) ok = ok && append_fixed(buf_, truth->position_m, 9);
    buf_ += ',';
    if (truth != nullptr) ok = ok && append_fixed(buf_, truth->velocity_mps, 9);
    buf_ += ',';
    if (truth != nullptr) ok = ok && append_fixed(buf_, truth->acceleration_mps2, 6);
  }
  buf_ += '\n';
  if (!ok || buf_.size() - mark > kMaxLineBytes + 1) {
    buf_.resize(mark);
    return fail("raw log writer: sample " + std::to_string(s.seq) + " cannot be formatted");
  }
  have_last_t_ = true;
  last_t_ns_ = s.t_ns;
  ++rows_;
  if (buf_.size() >= kWriteFlushBytes) return flush();
  return true;
}

bool RawLogWriter::close(std::string& error) {
  error.clear();
  if (fd_ < 0) {
    error = error_ = "raw log writer: not open";
    return false;
  }
  const std::string partial = direct_ ? path_ : partial_path();
  bool ok = flush();
  // A FIFO or a terminal cannot be synced (EINVAL); only a file's data needs to be.
  if (ok && ::fsync(fd_) != 0 && !(direct_ && (errno == EINVAL || errno == EROFS)))
    ok = fail("raw log writer: fsync " + partial + ": " + std::strerror(errno));
  if (::close(fd_) != 0 && ok) ok = fail("raw log writer: close " + partial + ": " + std::strerror(errno));
  fd_ = -1;
  buf_.clear();
  if (!ok) {
    error = error_;
    return false;
  }
  if (direct_) return true;
  if (::rename(partial.c_str(), path_.c_str()) != 0) {
    error = error_ = "raw log writer: rename " + partial + " -> " + path_ + ": " + std::strerror(errno);
    return false;
  }
  const std::string dir = dir_of(path_);
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd < 0 || ::fsync(dfd) != 0) {
    error = error_ = "raw log writer: fsync directory " + dir + ": " + std::strerror(errno);
    if (dfd >= 0) ::close(dfd);
    return false;
  }
  ::close(dfd);
  return true;
}

}  // namespace ve::replay
