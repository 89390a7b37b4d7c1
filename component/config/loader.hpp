// Machine and motor files -> MachineConfig, with every problem reported as
// FILE:LINE:COL: FIELD: MESSAGE.
//
// The second half of this header is the small schema layer the loaders are
// written in. It is public only so that calibration_file.cpp can share it; it
// deliberately exposes no yaml-cpp type, so users of the loader don't compile
// against yaml-cpp headers.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <initializer_list>
#include <memory>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "config/machine_config.hpp"
#include "core/input_error.hpp"

namespace ve::config {

/// A problem in a machine or motor file; `field` is the dotted path in the file, e.g.
/// "axes[0].output.direction".
using ConfigError = core::InputError;
/// All errors, one per line.
using core::to_string;

struct LoadResult {
  MachineConfig config;              ///< filled as far as the files allowed; use only when ok()
  std::vector<ConfigError> errors;   ///< every problem found, in file and position order
  bool ok() const { return errors.empty(); }
};

struct LoadOptions {
  /// false: a `calibration:` file that does not exist yet is accepted (its path
  /// is still resolved and stored), for the command that is about to create it.
  /// A file that exists but cannot be read is an error either way.
  bool calibration_must_exist = true;
};

/// Loads a machine file from disk. Motor, calibration, profiles and replay
/// paths in it are relative to the machine file's directory.
LoadResult load_machine_file(const std::string& path, const LoadOptions& options = {});

/// The shipped config/machines/sim.yaml compiled into the binary; its motor is
/// resolved inside the embedded files too, so no file on disk is needed.
LoadResult load_embedded_default(const LoadOptions& options = {});

/// Source name given to the embedded default machine file.
inline constexpr const char* kEmbeddedPrefix = "<embedded>/";
inline constexpr const char* kEmbeddedMachine = "config/machines/sim.yaml";

// ---------------------------------------------------------------------------
// Schema layer: walks one parsed YAML document, remembers which keys a schema
// asked for, converts scalars strictly and records errors instead of throwing,
// so a schema is a short list of `get` calls and every problem is reported.
namespace schema {

/// 1-based position in a file; line 0 = unknown.
struct Pos {
  int line = 0;
  int column = 0;
};

/// Returns "" when the value is acceptable, else what is wrong with it
/// ("must be > 0"); the reader adds file, position and field.
template <class T>
using Check = std::function<std::string(const T&)>;

/// Shortest text that reads back as the same double (for files the program writes).
std::string format_number(double x);
/// Compact text for messages, like %.6g ("1e+12", "0.0015", "-3"); never hundreds of digits.
std::string compact_number(double x);
/// Text of a value being compared with limits: compact, but with enough digits that it
/// does not print equal to a limit it differs from (1.0000001 against a limit of 1).
std::string compact_against(double x, double lo, double hi);
/// "X out of range [LO, HI] UNIT" (UNIT may be empty): the message of every range check.
std::string out_of_range(double x, double lo, double hi, std::string_view unit = {});

/// A closed range with its unit ("m", "V", "Hz", "" for a plain number).
template <class T>
Check<T> in_range(T lo, T hi, std::string unit = {}) {
  return [lo, hi, unit](const T& x) {
    return (x >= lo && x <= hi) ? std::string()
                                : out_of_range(static_cast<double>(x), static_cast<double>(lo),
                                               static_cast<double>(hi), unit);
  };
}
Check<double> greater_than(double lo);
Check<double> at_least(double lo);

class Document;
class Map;

/// One value in a document (a scalar, sequence, mapping or null) and its path.
/// A Value that was not in the file is "absent": conversions on it do nothing.
class Value {
 public:
  bool present() const;
  bool is_null() const;
  bool is_map() const;
  bool is_sequence() const;
  Pos pos() const;
  const std::string& path() const;
  Document& document() const;
  /// What the value is, for messages: "a mapping", "'abc'", "nothing (null)"...
  std::string describe() const;

  /// Strict conversions: false (and an error recorded) on a wrong type,
  /// unparsable number or failed check; `out` is left unchanged then.
  bool as(std::string& out, const Check<std::string>& check = {}) const;
  bool as(bool& out) const;
  bool as(int& out, const Check<int>& check = {}) const;
  bool as(std::int64_t& out, const Check<std::int64_t>& check = {}) const;
  bool as(std::uint32_t& out, const Check<std::uint32_t>& check = {}) const;
  bool as(std::uint64_t& out) const;
  bool as(double& out, const Check<double>& check = {}) const;
  /// A sequence of numbers. Does not build a Value per element, so tables of
  /// tens of thousands of numbers convert quickly.
  bool as(std::vector<double>& out, const Check<double>& check = {}) const;

  /// A mapping (null counts as an empty one); on a wrong type an error is
  /// recorded and the returned Map reads as empty.
  Map as_map() const;
  std::size_t size() const;  ///< elements of a sequence, else 0
  Value at(std::size_t i) const;

  /// Records an error at this value (or at the owner's position when absent).
  void error(const std::string& message) const;

 private:
  friend class Document;
  friend class Map;
  struct Impl;
  /// Deletes an Impl where it is complete (loader.cpp), so that a Value, move-only,
  /// needs no special member functions of its own.
  struct ImplDeleter {
    void operator()(Impl* impl) const;
  };
  std::unique_ptr<Impl, ImplDeleter> impl_;
};

/// A mapping being read. Keys read through it are "known"; when the Map is
/// finished (explicitly or on destruction) every other key is reported as
/// unknown, with the closest known key suggested.
class Map {
 public:
  Map();
  ~Map();
  Map(Map&&) noexcept;
  Map& operator=(Map&&) noexcept;

  /// Declares `key` valid and returns its value (absent if not in the file).
  Value value(std::string_view key);
  /// Like value(), but records "missing required key" at this map when absent.
  Value required(std::string_view key);

  bool has(std::string_view key) const;

  template <class T, class C = Check<T>>
  bool get(std::string_view key, T& out, const C& check = {}) {
    Value v = value(key);
    if (!v.present()) return false;
    return as_checked(v, out, check);
  }
  template <class T, class C = Check<T>>
  bool require(std::string_view key, T& out, const C& check = {}) {
    Value v = required(key);
    if (!v.present()) return false;
    return as_checked(v, out, check);
  }
  /// A string chosen from `names`; the error lists the allowed names.
  template <class E>
  bool get_enum(std::string_view key, E& out, std::initializer_list<std::pair<const char*, E>> names) {
    Value v = value(key);
    if (!v.present()) return false;
    std::string s;
    if (!v.as(s)) return false;
    std::string allowed;
    for (const auto& [name, e] : names) {
      if (s == name) {
        out = e;
        return true;
      }
      allowed += allowed.empty() ? "" : " | ";
      allowed += name;
    }
    v.error("'" + s + "' is not one of " + allowed);
    return false;
  }
  /// Nested mapping; absent or null reads as an empty one.
  Map map(std::string_view key);
  /// A key that is valid in this mapping only in another variant: if present,
  /// it is reported with `why` instead of as an unknown key.
  void reject(std::string_view key, const std::string& why);

  Pos pos() const;
  const std::string& path() const;
  /// Path of a key in this mapping, e.g. "axes[0].output" + "direction".
  std::string field(std::string_view key) const;
  Document& document() const;
  bool valid() const;  ///< false when the node was not a mapping (already reported)

  /// Reports unknown keys now; further reads through this Map are not allowed.
  void finish();
  /// Stops without reporting unknown keys: for a file found to be of another
  /// kind or version, whose other keys mean nothing to this schema.
  void discard();

 private:
  friend class Value;
  friend class Document;
  template <class T, class C>
  static bool as_checked(const Value& v, T& out, const C& check) {
    if constexpr (std::is_same_v<T, bool> || std::is_same_v<T, std::uint64_t>) {
      return v.as(out);
    } else {
      return v.as(out, Check<T>(check));
    }
  }
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Records, on the calling thread while it exists, every key a Map declared valid: the
/// list the unknown-key check compares a file's keys against, so the keys recorded are
/// exactly the keys the loaders accept. Each key is recorded once, with the file it was
/// read for and its path, sequence indices written as "[]"
/// ("axes[].driver.imperfections.frame_vibration_hz"). A key a Map rejected (valid
/// only in another variant, e.g. `log` under a sim driver) is not recorded for that Map.
/// Keys are recorded when their Map is finished; a discarded Map records nothing.
/// Recording does not change what is loaded or reported.
class KeyRecorder {
 public:
  struct Key {
    std::string file;  ///< Document::file() of the document the key was read for
    std::string path;
  };
  KeyRecorder();
  ~KeyRecorder();
  KeyRecorder(const KeyRecorder&) = delete;
  KeyRecorder& operator=(const KeyRecorder&) = delete;

  /// Keys recorded so far, in order of first recording.
  const std::vector<Key>& keys() const { return keys_; }
  /// Keys a Map rejected as valid only in another variant, in the same form: each
  /// should be among keys() once a file of that other variant has been read.
  const std::vector<Key>& rejected() const { return rejected_; }

 private:
  friend class Map;
  static void add(std::vector<Key>& to, const std::string& file, const std::string& path);
  KeyRecorder* previous_ = nullptr;
  std::vector<Key> keys_;
  std::vector<Key> rejected_;
};

/// One file being read. Errors go to the caller's list and name `file`.
class Document {
 public:
  Document(std::string file, std::vector<ConfigError>& errors);
  ~Document();
  Document(const Document&) = delete;
  Document& operator=(const Document&) = delete;

  /// Parses YAML text; a syntax error is recorded (with its position) and false returned.
  bool parse(const std::string& text);
  /// The document's root mapping (an empty document reads as an empty mapping).
  Map root();

  void error(Pos pos, std::string field, std::string message);
  const std::string& file() const { return file_; }

 private:
  friend class Value;
  friend class Map;
  struct Impl;
  std::string file_;
  std::vector<ConfigError>& errors_;
  std::unique_ptr<Impl> impl_;
};

/// True when `text` holds a second YAML document after the first (a `---` or `...`
/// line followed by more); `line`/`column` (1-based) say where it starts. Never loops
/// on malformed input, unlike yaml-cpp's LoadAll().
bool second_yaml_document(const std::string& text, int& line, int& column);

/// Largest machine, motor, CAN layout or kept-position file read [bytes]: far above any
/// real one (a few kB), small enough that a wrong path cannot exhaust the memory.
inline constexpr std::size_t kMaxConfigFileBytes = 4u << 20;
/// Largest calibration file read [bytes]: about 6 million table values (32 sensors x
/// 200000 points), a 9 m travel at a 12 mm pitch with every sensor of a big node.
inline constexpr std::size_t kMaxCalibrationFileBytes = 64u << 20;

/// Reads a whole regular file of at most `max_bytes`; on failure returns false and
/// sets `error` to why (strerror, "not a regular file (a FIFO)", "larger than ...").
/// Never blocks on a FIFO and never reads an endless device such as /dev/zero.
bool read_text_file(const std::string& path, std::string& text, std::string& error,
                    std::size_t max_bytes = kMaxConfigFileBytes);
/// 0 when `path` is a readable regular file, else an errno value (EISDIR, EINVAL for
/// another kind of file, ...); `error` says why.
int regular_file_readable(const std::string& path, std::string& error);

/// Orders errors by file (in order of first appearance) and then position.
void sort_errors(std::vector<ConfigError>& errors);

}  // namespace schema
}  // namespace ve::config
