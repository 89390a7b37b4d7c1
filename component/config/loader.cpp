#include "config/loader.hpp"

#include <fcntl.h>
#include <sched.h>
#include <sys/stat.h>
#include <unistd.h>
#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <sstream>

#include "config/atomic_file.hpp"
#include "config/embedded.hpp"
#include "core/sample.hpp"
#include "config/can_layout_file.hpp"

namespace ve::config {

namespace schema {

// ---------------------------------------------------------------------------
// Scalar conversion
namespace {

Pos to_pos(const YAML::Mark& m) {
  if (m.is_null() || m.line < 0 || m.column < 0) return {};
  return {m.line + 1, m.column + 1};
}

/// Quoted scalars are strings even when they look like numbers: `"5"` is not 5.
bool is_quoted(const YAML::Node& n) { return n.Tag() == "!" || n.Tag() == "tag:yaml.org,2002:str"; }

/// A scalar as a message shows it: at most 40 characters, so a 400-digit number or a
/// pasted table does not flood the terminal.
std::string shown(const std::string& s) {
  constexpr std::size_t kMax = 40;
  if (s.size() <= kMax) return s;
  return s.substr(0, kMax) + "... (" + std::to_string(s.size()) + " characters)";
}

std::string describe_node(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Null:
      return "nothing (null)";
    case YAML::NodeType::Scalar:
      return is_quoted(n) ? "the string \"" + shown(n.Scalar()) + "\"" : "'" + shown(n.Scalar()) + "'";
    case YAML::NodeType::Sequence:
      return "a sequence";
    case YAML::NodeType::Map:
      return "a mapping";
    default:
      return "an undefined value";
  }
}

enum class Parsed { ok, bad, out_of_range };

/// YAML-1.2-core-style decimal number; no inf/nan, no hex, no underscores.
Parsed parse_double(std::string_view s, double& out) {
  if (!s.empty() && s.front() == '+') {
    s.remove_prefix(1);
    if (!s.empty() && s.front() == '-') return Parsed::bad;
  }
  if (s.empty()) return Parsed::bad;
  const char c = s.front() == '-' ? (s.size() > 1 ? s[1] : '\0') : s.front();
  if (!(std::isdigit(static_cast<unsigned char>(c)) || c == '.')) return Parsed::bad;  // rejects inf, nan
  double v = 0.0;
  const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
  if (r.ec == std::errc::result_out_of_range) return Parsed::out_of_range;
  if (r.ec != std::errc() || r.ptr != s.data() + s.size()) return Parsed::bad;
  if (!std::isfinite(v)) return Parsed::out_of_range;
  out = v;
  return Parsed::ok;
}

template <class T>
Parsed parse_integer(std::string_view s, T& out) {
  if (!s.empty() && s.front() == '+') {
    s.remove_prefix(1);
    if (!s.empty() && s.front() == '-') return Parsed::bad;
  }
  if (s.empty()) return Parsed::bad;
  T v{};
  const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
  if (r.ec == std::errc::result_out_of_range) return Parsed::out_of_range;
  if (r.ec != std::errc() || r.ptr != s.data() + s.size()) {
    // "-1" for an unsigned type fails here too; call it out of range, not garbage.
    if (std::is_unsigned_v<T> && s.front() == '-') {
      std::int64_t tmp;
      if (parse_integer(s, tmp) == Parsed::ok) return Parsed::out_of_range;
    }
    return Parsed::bad;
  }
  out = v;
  return Parsed::ok;
}

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> prev(b.size() + 1), cur(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) prev[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    cur[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const bool same = std::tolower(static_cast<unsigned char>(a[i - 1])) ==
                        std::tolower(static_cast<unsigned char>(b[j - 1]));
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (same ? 0 : 1)});
    }
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

/// The known key a typo most likely meant, or "" if none is close.
std::string closest_key(std::string_view key, const std::vector<std::string>& known) {
  std::string best;
  std::size_t best_d = std::numeric_limits<std::size_t>::max();
  for (const auto& k : known) {
    // Units are part of every name; a key without its unit suffix is a near miss.
    if (k.size() > key.size() && k.compare(0, key.size(), key) == 0 && k[key.size()] == '_' &&
        k.find('_', key.size() + 1) == std::string::npos)
      return k;
    const std::size_t d = edit_distance(key, k);
    if (d < best_d) {
      best_d = d;
      best = k;
    }
  }
  const std::size_t limit = std::max<std::size_t>(2, best.size() / 3);
  if (best.empty() || best_d > limit || best_d >= key.size() || best_d >= best.size()) return {};
  return best;
}

}  // namespace

std::string format_number(double x) {
  // Shortest text that reads back as the same double; plain decimals for the
  // magnitudes config files use (100000, not 1e+05), exponents for the rest.
  char buf[400];
  const double a = std::abs(x);
  const bool fixed = a == 0.0 || (a >= 1e-5 && a < 1e15);
  const auto r = std::to_chars(buf, buf + sizeof buf, x, fixed ? std::chars_format::fixed : std::chars_format::general);
  return std::string(buf, r.ptr);
}

std::string compact_number(double x) {
  if (std::isnan(x)) return "nan";
  if (std::isinf(x)) return x > 0 ? "inf" : "-inf";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6g", x);
  return buf;
}

std::string compact_against(double x, double lo, double hi) {
  std::string s = compact_number(x);
  for (int digits = 7; digits <= 17 && ((x != lo && s == compact_number(lo)) || (x != hi && s == compact_number(hi)));
       ++digits) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.*g", digits, x);
    s = buf;
  }
  return s;
}

std::string out_of_range(double x, double lo, double hi, std::string_view unit) {
  std::string s = compact_against(x, lo, hi) + " out of range [" + compact_number(lo) + ", " + compact_number(hi) + "]";
  if (!unit.empty()) {
    s += ' ';
    s += unit;
  }
  return s;
}

Check<double> greater_than(double lo) {
  return [lo](const double& x) {
    return x > lo ? std::string()
                  : compact_against(x, lo, lo) + " out of range (" + compact_number(lo) + ", inf): must be > " +
                        compact_number(lo);
  };
}

Check<double> at_least(double lo) {
  return [lo](const double& x) {
    return x >= lo ? std::string()
                   : compact_against(x, lo, lo) + " out of range [" + compact_number(lo) + ", inf): must be >= " +
                         compact_number(lo);
  };
}

// ---------------------------------------------------------------------------
// Document

struct Document::Impl {
  YAML::Node root;
  bool parsed = false;
};

Document::Document(std::string file, std::vector<ConfigError>& errors)
    : file_(std::move(file)), errors_(errors), impl_(std::make_unique<Impl>()) {}
Document::~Document() = default;

namespace {

/// Records where a document's first event is (the parser's own position).
struct FirstMark final : YAML::EventHandler {
  YAML::Mark mark;
  bool any = false;
  void at(const YAML::Mark& m) {
    if (!any) mark = m;
    any = true;
  }
  void OnDocumentStart(const YAML::Mark& m) override { at(m); }
  void OnDocumentEnd() override {}
  void OnNull(const YAML::Mark& m, YAML::anchor_t) override { at(m); }
  void OnAlias(const YAML::Mark& m, YAML::anchor_t) override { at(m); }
  void OnScalar(const YAML::Mark& m, const std::string&, YAML::anchor_t, const std::string&) override { at(m); }
  void OnSequenceStart(const YAML::Mark& m, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override {
    at(m);
  }
  void OnSequenceEnd() override {}
  void OnMapStart(const YAML::Mark& m, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override {
    at(m);
  }
  void OnMapEnd() override {}
};

/// A line starting with a document marker: only then can a file hold two documents.
bool has_document_marker(const std::string& text) {
  for (std::size_t i = 0; i < text.size(); i = text.find('\n', i) + 1) {
    if (text.compare(i, 3, "---") == 0 || text.compare(i, 3, "...") == 0) return true;
    if (text.find('\n', i) == std::string::npos) break;
  }
  return false;
}

}  // namespace

bool second_yaml_document(const std::string& text, int& line, int& column) {
  if (!has_document_marker(text)) return false;
  // yaml-cpp's own LoadAll() loops forever on some malformed input (a lone ','): its
  // parser hands out the same empty document again without advancing. Two documents
  // at most are asked for, and a second one counts only when the parser moved on.
  std::istringstream in(text);
  YAML::Parser parser(in);
  FirstMark first, second;
  try {
    if (!parser.HandleNextDocument(first)) return false;
    if (!parser.HandleNextDocument(second) || !second.any) return false;
  } catch (const YAML::Exception& e) {
    // The first document was read before (Document::parse): the error is in the second.
    const Pos p = to_pos(e.mark);
    line = p.line ? p.line : 1;
    column = p.line ? p.column : 1;
    return true;
  }
  if (second.mark.pos <= first.mark.pos) return false;
  line = second.mark.line + 1;
  column = second.mark.column + 1;
  return true;
}

bool Document::parse(const std::string& text) {
  try {
    impl_->root = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    error(to_pos(e.mark), "", "malformed YAML: " + e.msg);
    return false;
  } catch (const YAML::Exception& e) {
    error(to_pos(e.mark), "", "malformed YAML: " + e.msg);
    return false;
  }
  int line = 0, column = 0;
  if (second_yaml_document(text, line, column)) {
    error({line, column}, "",
          "a second YAML document (after '---'): a file holds one document; remove the '---' line or split the "
          "file");
    return false;
  }
  impl_->parsed = true;
  return true;
}

void Document::error(Pos pos, std::string field, std::string message) {
  ConfigError e;
  e.file = file_;
  e.line = pos.line;
  e.column = pos.column;
  e.field = std::move(field);
  e.message = std::move(message);
  errors_.push_back(std::move(e));
}

// ---------------------------------------------------------------------------
// Value

struct Value::Impl {
  Document* doc = nullptr;
  YAML::Node node;
  bool present = false;
  std::string path;
  Pos pos;
};

void Value::ImplDeleter::operator()(Impl* impl) const { delete impl; }

bool Value::present() const { return impl_ && impl_->present; }
bool Value::is_null() const { return present() && impl_->node.IsNull(); }
bool Value::is_map() const { return present() && impl_->node.IsMap(); }
bool Value::is_sequence() const { return present() && impl_->node.IsSequence(); }
Pos Value::pos() const { return impl_ ? impl_->pos : Pos{}; }
const std::string& Value::path() const {
  static const std::string empty;
  return impl_ ? impl_->path : empty;
}
Document& Value::document() const { return *impl_->doc; }
std::string Value::describe() const { return present() ? describe_node(impl_->node) : "nothing (absent)"; }

void Value::error(const std::string& message) const {
  if (impl_ && impl_->doc) impl_->doc->error(impl_->pos, impl_->path, message);
}

namespace {

/// Shared integer conversion: the node is known to be present.
template <class T>
bool convert_integer(const Value& v, const YAML::Node& n, T& out, const Check<T>& check) {
  if (!n.IsScalar() || is_quoted(n)) {
    v.error("expected an integer, got " + describe_node(n));
    return false;
  }
  T x{};
  switch (parse_integer(n.Scalar(), x)) {
    case Parsed::ok:
      break;
    case Parsed::out_of_range:
      v.error(shown(n.Scalar()) + " out of range [" + std::to_string(std::numeric_limits<T>::min()) + ", " +
              std::to_string(std::numeric_limits<T>::max()) + "]");
      return false;
    case Parsed::bad: {
      double d;
      v.error(parse_double(n.Scalar(), d) == Parsed::ok ? "expected an integer, got " + shown(n.Scalar())
                                                        : "expected an integer, got " + describe_node(n));
      return false;
    }
  }
  if (check) {
    const std::string why = check(x);
    if (!why.empty()) {
      v.error(why);
      return false;
    }
  }
  out = x;
  return true;
}

/// Converts a number node; errors go to `doc` at `path`. Shared by scalars and tables.
bool convert_double(Document& doc, const YAML::Node& n, const std::string& path, Pos pos, double& out,
                    const Check<double>& check) {
  if (!n.IsScalar() || is_quoted(n)) {
    doc.error(pos, path, "expected a number, got " + describe_node(n));
    return false;
  }
  double x = 0.0;
  switch (parse_double(n.Scalar(), x)) {
    case Parsed::ok:
      break;
    case Parsed::out_of_range:
      doc.error(pos, path, "number out of range: " + shown(n.Scalar()) + " is beyond +-1.8e308");
      return false;
    case Parsed::bad:
      doc.error(pos, path, "expected a number, got " + describe_node(n));
      return false;
  }
  if (check) {
    const std::string why = check(x);
    if (!why.empty()) {
      doc.error(pos, path, why);
      return false;
    }
  }
  out = x;
  return true;
}

}  // namespace

bool Value::as(std::string& out, const Check<std::string>& check) const {
  if (!present()) return false;
  const YAML::Node& n = impl_->node;
  if (!n.IsScalar()) {
    error("expected a string, got " + describe_node(n));
    return false;
  }
  if (check) {
    const std::string why = check(n.Scalar());
    if (!why.empty()) {
      error(why);
      return false;
    }
  }
  out = n.Scalar();
  return true;
}

bool Value::as(bool& out) const {
  if (!present()) return false;
  const YAML::Node& n = impl_->node;
  if (n.IsScalar() && !is_quoted(n)) {
    const std::string& s = n.Scalar();
    // YAML 1.2 core booleans only: `yes`/`on` would be strings to other YAML 1.2 tools.
    if (s == "true" || s == "True" || s == "TRUE") {
      out = true;
      return true;
    }
    if (s == "false" || s == "False" || s == "FALSE") {
      out = false;
      return true;
    }
  }
  error("expected true or false, got " + describe_node(n));
  return false;
}

bool Value::as(int& out, const Check<int>& check) const {
  if (!present()) return false;
  return convert_integer(*this, impl_->node, out, check);
}

bool Value::as(std::int64_t& out, const Check<std::int64_t>& check) const {
  if (!present()) return false;
  return convert_integer(*this, impl_->node, out, check);
}

bool Value::as(std::uint32_t& out, const Check<std::uint32_t>& check) const {
  if (!present()) return false;
  return convert_integer(*this, impl_->node, out, check);
}

bool Value::as(std::uint64_t& out) const {
  if (!present()) return false;
  return convert_integer(*this, impl_->node, out, Check<std::uint64_t>{});
}

bool Value::as(double& out, const Check<double>& check) const {
  if (!present()) return false;
  return convert_double(*impl_->doc, impl_->node, impl_->path, impl_->pos, out, check);
}

bool Value::as(std::vector<double>& out, const Check<double>& check) const {
  if (!present()) return false;
  const YAML::Node& n = impl_->node;
  if (!n.IsSequence()) {
    error("expected a sequence of numbers, got " + describe_node(n));
    return false;
  }
  // A damaged table could otherwise produce one error per element.
  constexpr int kMaxErrors = 5;
  int errors = 0;
  std::vector<double> values;
  values.reserve(n.size());
  std::size_t i = 0;
  for (auto it = n.begin(); it != n.end(); ++it, ++i) {
    const YAML::Node e = *it;  // a copy: the iterator's value is a temporary
    double x = 0.0;
    if (e.IsScalar() && !is_quoted(e) && parse_double(e.Scalar(), x) == Parsed::ok && !check) {
      values.push_back(x);  // fast path: no strings built for good elements
      continue;
    }
    if (errors >= kMaxErrors) {
      ++errors;
      continue;
    }
    const Pos p = e.IsNull() ? impl_->pos : to_pos(e.Mark());
    if (convert_double(*impl_->doc, e, impl_->path + "[" + std::to_string(i) + "]", p, x, check))
      values.push_back(x);
    else
      ++errors;
  }
  if (errors > kMaxErrors)
    error(std::to_string(errors - kMaxErrors) + " more bad elements not listed");
  if (errors > 0) return false;
  out = std::move(values);
  return true;
}

std::size_t Value::size() const { return is_sequence() ? impl_->node.size() : 0; }

Value Value::at(std::size_t i) const {
  const YAML::Node e = impl_->node[i];
  const Pos p = e.IsNull() ? impl_->pos : to_pos(e.Mark());
  Value v;
  v.impl_.reset(new Impl{impl_->doc, e, true, impl_->path + "[" + std::to_string(i) + "]", p.line ? p : impl_->pos});
  return v;
}

// ---------------------------------------------------------------------------
// KeyRecorder

namespace {
thread_local KeyRecorder* t_key_recorder = nullptr;
KeyRecorder* active_key_recorder() { return t_key_recorder; }

/// "axes[0].faults[12].kind" -> "axes[].faults[].kind".
std::string without_indices(const std::string& path) {
  std::string out;
  out.reserve(path.size());
  for (std::size_t i = 0; i < path.size(); ++i) {
    out += path[i];
    if (path[i] != '[') continue;
    std::size_t j = i + 1;
    while (j < path.size() && std::isdigit(static_cast<unsigned char>(path[j]))) ++j;
    if (j > i + 1 && j < path.size() && path[j] == ']') i = j - 1;
  }
  return out;
}
}  // namespace

KeyRecorder::KeyRecorder() : previous_(t_key_recorder) { t_key_recorder = this; }
KeyRecorder::~KeyRecorder() { t_key_recorder = previous_; }

void KeyRecorder::add(std::vector<Key>& to, const std::string& file, const std::string& path) {
  Key k{file, without_indices(path)};
  for (const auto& e : to)
    if (e.file == k.file && e.path == k.path) return;
  to.push_back(std::move(k));
}

// ---------------------------------------------------------------------------
// Map

struct Map::Impl {
  struct Entry {
    std::string key;
    YAML::Node value;
    Pos key_pos;
    Pos value_pos;
    bool used = false;
  };
  Document* doc = nullptr;
  std::string path;
  Pos pos;
  bool valid = true;
  bool finished = false;
  std::vector<Entry> entries;
  std::vector<std::string> known;
  std::vector<std::string> rejected;  // for KeyRecorder only

  const Entry* find(std::string_view key) const {
    for (const auto& e : entries)
      if (e.key == key) return &e;
    return nullptr;
  }
};


Map Value::as_map() const {
  Map m;
  m.impl_ = std::make_unique<Map::Impl>();
  Map::Impl& mi = *m.impl_;
  mi.doc = impl_ ? impl_->doc : nullptr;
  mi.path = path();
  mi.pos = pos();
  if (!present() || impl_->node.IsNull()) return m;
  const YAML::Node& n = impl_->node;
  if (!n.IsMap()) {
    error("expected a mapping (key: value pairs), got " + describe_node(n));
    mi.valid = false;
    return m;
  }
  for (auto it = n.begin(); it != n.end(); ++it) {
    // yaml-cpp's iterator hands out a temporary pair: copy the nodes (cheap
    // handles), never bind references to it->first / it->second (they dangle).
    const YAML::Node k = it->first;
    const YAML::Node val = it->second;
    const Pos key_pos = to_pos(k.Mark());
    if (!k.IsScalar()) {
      mi.doc->error(key_pos.line ? key_pos : mi.pos, mi.path, "keys must be plain names, got " + describe_node(k));
      continue;
    }
    const std::string& key = k.Scalar();
    if (const Map::Impl::Entry* first = mi.find(key)) {
      mi.doc->error(key_pos, m.field(key),
                    "duplicate key '" + key + "' (first given at line " + std::to_string(first->key_pos.line) + ")");
      continue;
    }
    Map::Impl::Entry e;
    e.key = key;
    e.value = val;
    e.key_pos = key_pos;
    // A null value has no position of its own (yaml-cpp points at the next token).
    const Pos vp = val.IsNull() ? Pos{} : to_pos(val.Mark());
    e.value_pos = vp.line ? vp : key_pos;
    mi.entries.push_back(std::move(e));
  }
  return m;
}

Map::Map() = default;
Map::~Map() {
  if (impl_) finish();
}
Map::Map(Map&&) noexcept = default;
Map& Map::operator=(Map&& other) noexcept {
  if (this != &other) {
    if (impl_) finish();
    impl_ = std::move(other.impl_);
  }
  return *this;
}

Value Map::value(std::string_view key) {
  Value v;
  if (!impl_) return v;
  Impl& mi = *impl_;
  if (std::find(mi.known.begin(), mi.known.end(), key) == mi.known.end()) mi.known.emplace_back(key);
  v.impl_.reset(new Value::Impl());
  v.impl_->doc = mi.doc;
  v.impl_->path = field(key);
  v.impl_->pos = mi.pos;
  for (auto& e : mi.entries) {
    if (e.key != key) continue;
    e.used = true;
    v.impl_->node = e.value;
    v.impl_->present = true;
    v.impl_->pos = e.value_pos;
    break;
  }
  return v;
}

Value Map::required(std::string_view key) {
  Value v = value(key);
  if (!v.present() && impl_ && impl_->valid && impl_->doc)
    impl_->doc->error(impl_->pos, field(key), "missing required key '" + std::string(key) + "'");
  return v;
}

bool Map::has(std::string_view key) const { return impl_ && impl_->find(key) != nullptr; }

Map Map::map(std::string_view key) { return value(key).as_map(); }

void Map::reject(std::string_view key, const std::string& why) {
  if (!impl_) return;
  if (std::find(impl_->rejected.begin(), impl_->rejected.end(), key) == impl_->rejected.end())
    impl_->rejected.emplace_back(key);
  for (auto& e : impl_->entries) {
    if (e.key != key || e.used) continue;
    e.used = true;
    impl_->doc->error(e.key_pos, field(key), "unexpected key '" + e.key + "': " + why);
  }
}

Pos Map::pos() const { return impl_ ? impl_->pos : Pos{}; }
const std::string& Map::path() const {
  static const std::string empty;
  return impl_ ? impl_->path : empty;
}
std::string Map::field(std::string_view key) const {
  const std::string& p = path();
  return p.empty() ? std::string(key) : p + "." + std::string(key);
}
Document& Map::document() const { return *impl_->doc; }
bool Map::valid() const { return impl_ && impl_->valid; }

void Map::finish() {
  if (!impl_ || impl_->finished) return;
  impl_->finished = true;
  if (!impl_->doc) return;
  if (KeyRecorder* rec = active_key_recorder()) {
    for (const auto& k : impl_->known)
      if (std::find(impl_->rejected.begin(), impl_->rejected.end(), k) == impl_->rejected.end())
        KeyRecorder::add(rec->keys_, impl_->doc->file(), field(k));
    for (const auto& k : impl_->rejected) KeyRecorder::add(rec->rejected_, impl_->doc->file(), field(k));
  }
  for (const auto& e : impl_->entries) {
    if (e.used) continue;
    std::string msg = "unknown key '" + e.key + "'";
    const std::string near = closest_key(e.key, impl_->known);
    if (!near.empty()) {
      msg += "; did you mean '" + near + "'?";
    } else if (!impl_->known.empty()) {
      std::vector<std::string> sorted = impl_->known;
      std::sort(sorted.begin(), sorted.end());
      msg += " (valid keys here: ";
      for (std::size_t i = 0; i < sorted.size(); ++i) msg += (i ? ", " : "") + sorted[i];
      msg += ")";
    } else {
      msg += " (no keys are valid here)";
    }
    impl_->doc->error(e.key_pos, field(e.key), msg);
  }
}

void Map::discard() {
  if (impl_) impl_->finished = true;
}

Map Document::root() {
  Value v;
  v.impl_.reset(new Value::Impl());
  v.impl_->doc = this;
  v.impl_->present = impl_->parsed;
  v.impl_->node = impl_->root;
  const Pos p = impl_->root.IsNull() ? Pos{} : to_pos(impl_->root.Mark());
  v.impl_->pos = p.line ? p : Pos{1, 1};
  Map m = v.as_map();
  if (!impl_->parsed) m.impl_->valid = false;
  return m;
}

// ---------------------------------------------------------------------------

namespace {

std::string size_text(std::size_t bytes) {
  if (bytes >= (1u << 20) && bytes % (1u << 20) == 0) return std::to_string(bytes >> 20) + " MiB";
  return std::to_string(bytes) + " bytes";
}

}  // namespace

int regular_file_readable(const std::string& path, std::string& error) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    const int e = errno;
    error = std::strerror(e);
    return e;
  }
  if (S_ISDIR(st.st_mode)) {
    error = std::strerror(EISDIR);
    return EISDIR;
  }
  if (!S_ISREG(st.st_mode)) {
    error = std::string("not a regular file (") + file_kind(st.st_mode) + ")";
    return EINVAL;
  }
  if (::access(path.c_str(), R_OK) != 0) {
    const int e = errno;
    error = std::strerror(e);
    return e;
  }
  return 0;
}

bool read_text_file(const std::string& path, std::string& text, std::string& error, std::size_t max_bytes) {
  // O_NONBLOCK: opening a FIFO without a writer would otherwise wait forever.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) {
    error = std::strerror(errno);
    return false;
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    error = std::strerror(errno);
    ::close(fd);
    return false;
  }
  if (S_ISDIR(st.st_mode)) {
    ::close(fd);
    error = std::strerror(EISDIR);
    return false;
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    error = std::string("not a regular file (") + file_kind(st.st_mode) + ")";
    return false;
  }
  if (st.st_size > 0 && static_cast<std::uint64_t>(st.st_size) > max_bytes) {
    ::close(fd);
    error = "too large: " + std::to_string(st.st_size) + " bytes, at most " + size_text(max_bytes) +
            " are read from a file of this kind";
    return false;
  }
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags >= 0) ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  std::string out;
  if (st.st_size > 0) out.reserve(static_cast<std::size_t>(st.st_size));
  char buf[65536];
  for (;;) {
    const ssize_t n = ::read(fd, buf, sizeof buf);
    if (n == 0) break;
    if (n < 0) {
      if (errno == EINTR) continue;
      error = std::strerror(errno);
      ::close(fd);
      return false;
    }
    out.append(buf, static_cast<std::size_t>(n));
    if (out.size() > max_bytes) {  // a file that grows while it is read
      ::close(fd);
      error = "too large: more than " + size_text(max_bytes) + " (the file grew while it was read)";
      return false;
    }
  }
  ::close(fd);
  text = std::move(out);
  return true;
}

void sort_errors(std::vector<ConfigError>& errors) {
  std::vector<std::string> files;
  for (const auto& e : errors)
    if (std::find(files.begin(), files.end(), e.file) == files.end()) files.push_back(e.file);
  auto rank = [&files](const std::string& f) { return std::find(files.begin(), files.end(), f) - files.begin(); };
  std::stable_sort(errors.begin(), errors.end(), [&rank](const ConfigError& a, const ConfigError& b) {
    const auto ra = rank(a.file), rb = rank(b.file);
    if (ra != rb) return ra < rb;
    if (a.line != b.line) return a.line < b.line;
    return a.column < b.column;
  });
}

}  // namespace schema

// ---------------------------------------------------------------------------
// Machine and motor schemas

namespace {

namespace fs = std::filesystem;
using schema::Check;
using schema::format_number;
using schema::Map;
using schema::Value;

/// Where the files a machine file refers to come from: the disk, or the
/// embedded copies (so the default configuration works with no files installed).
class Files {
 public:
  virtual ~Files() = default;
  /// `rel` as written in `from`, turned into a path this source can open.
  virtual std::string resolve(const std::string& from, const std::string& rel) const = 0;
  virtual bool read(const std::string& path, std::string& text, std::string& error) const = 0;
  /// 0 when the file can be read, else an errno value; `error` says why.
  virtual int readable(const std::string& path, std::string& error) const = 0;
  /// The name errors use for the file.
  virtual std::string display(const std::string& path) const = 0;
  /// The path stored in the config for other components to open.
  virtual std::string stored(const std::string& path) const = 0;
};

class DiskFiles final : public Files {
 public:
  std::string resolve(const std::string& from, const std::string& rel) const override {
    const fs::path r(rel);
    if (r.is_absolute()) return rel;
    const fs::path joined = fs::path(from).parent_path() / r;
    const fs::path normal = joined.lexically_normal();
    // "dir/../x" names something else when dir is a symlink; shorten the path
    // for error messages only when both spellings reach the same file.
    std::error_code ec;
    if (normal == joined || fs::equivalent(joined, normal, ec)) return normal.string();
    // Neither exists: the path only appears in an error message, so make it readable.
    if (!fs::exists(joined, ec) && !fs::exists(normal, ec)) return normal.string();
    return joined.string();
  }
  bool read(const std::string& path, std::string& text, std::string& error) const override {
    return schema::read_text_file(path, text, error);
  }
  int readable(const std::string& path, std::string& error) const override {
    return schema::regular_file_readable(path, error);
  }
  std::string display(const std::string& path) const override { return path; }
  std::string stored(const std::string& path) const override { return path; }
};

class EmbeddedFiles final : public Files {
 public:
  std::string resolve(const std::string& from, const std::string& rel) const override {
    return (fs::path(from).parent_path() / fs::path(rel)).lexically_normal().generic_string();
  }
  bool read(const std::string& path, std::string& text, std::string& error) const override {
    const auto& files = embedded_files();
    const auto it = files.find(path);
    if (it == files.end()) {
      error = "not among the embedded files";
      return false;
    }
    text = it->second;
    return true;
  }
  int readable(const std::string& path, std::string& error) const override {
    std::string text;
    return read(path, text, error) ? 0 : ENOENT;
  }
  std::string display(const std::string& path) const override { return kEmbeddedPrefix + path; }
  std::string stored(const std::string&) const override { return {}; }
};


Check<std::string> non_empty() {
  return [](const std::string& s) { return s.empty() ? std::string("must not be empty") : std::string(); };
}

std::string range_text(double lo, double hi) {
  return "[" + schema::compact_number(lo) + ", " + schema::compact_number(hi) + "]";
}

// ---- motor file -------------------------------------------------------------

/// Reads an optional number; true when it is absent or valid (so cross-checks
/// may use the field), false when an error was reported for it.
template <class T>
bool optional(Map& m, std::string_view key, T& out, const Check<T>& check = {}) {
  const Value v = m.value(key);
  return !v.present() || v.as(out, check);
}

/// A closed physical range with its unit; every limit is listed, with its reason, in
/// docs/configuration-limits.md.
Check<double> range(double lo, double hi, const char* unit) { return schema::in_range(lo, hi, std::string(unit)); }

/// Most magnet periods over the travel: the nominal table holds 256 points per period
/// for each sensor, so this bounds it to 2.6 million points (20 MB per sensor).
constexpr double kMaxMagnetPeriods = 10000.0;

/// Largest |output.preset_counts|: 2^53 would still be exact in a double; 1e15 leaves
/// room for the travel times counts_per_m (at most 1e14) without overflowing 64 bits.
constexpr std::int64_t kMaxPresetCounts = 1000000000000000;

/// The motor file's `filter:` numbers (core::FilterConfig): each read as a double in a
/// closed range; the few keys of other types are read beside the table.
struct FilterNumber {
  const char* key;
  double core::FilterConfig::*field;
  double lo, hi;
  const char* unit;
};
const FilterNumber kFilterNumbers[] = {
    // --- the Kalman filter on [x, v, a] ---
    {"jerk_std_mps3", &core::FilterConfig::jerk_std_mps3, 1e-6, 1e6, "m/s^3"},
    {"snap_std_mps4", &core::FilterConfig::snap_std_mps4, 0.0, 1e9, "m/s^4"},
    {"vibration_random_walk_mps2_per_sqrt_s", &core::FilterConfig::vibration_random_walk_mps2_per_sqrt_s,
      0.0, 100.0, "m/s^2/sqrt(s)"},
    {"hall_position_floor_m", &core::FilterConfig::hall_position_floor_m, 0.0, 1e-3, "m"},
    {"hall_systematic_std_m", &core::FilterConfig::hall_systematic_std_m, 0.0, 1e-3, "m"},
    {"gate_sigma", &core::FilterConfig::gate_sigma, 1.0, 1000.0, "sigma"},
    {"initial_position_std_m", &core::FilterConfig::initial_position_std_m, 1e-9, 1.0, "m"},
    {"initial_velocity_std_mps", &core::FilterConfig::initial_velocity_std_mps, 1e-6, 100.0, "m/s"},
    {"initial_acceleration_std_mps2", &core::FilterConfig::initial_acceleration_std_mps2, 1e-6, 1e4, "m/s^2"},
    {"accel_bias_std_mps2", &core::FilterConfig::accel_bias_std_mps2, 0.0, 100.0, "m/s^2"},
    {"accel_bias_random_walk_mps2_per_sqrt_s", &core::FilterConfig::accel_bias_random_walk_mps2_per_sqrt_s,
      0.0, 100.0, "m/s^2/sqrt(s)"},
    {"accel_scale_std", &core::FilterConfig::accel_scale_std, 0.0, 0.5, ""},
    {"accel_scale_random_walk_per_sqrt_s", &core::FilterConfig::accel_scale_random_walk_per_sqrt_s,
      0.0, 1.0, "1/sqrt(s)"},
    {"accel_spike_mps2", &core::FilterConfig::accel_spike_mps2, 1e-3, 1e5, "m/s^2"},
    // --- sensor health ---
    {"sensor_readmit_s", &core::FilterConfig::sensor_readmit_s, 0.001, 60.0, "s"},
    {"sensor_readmit_sigma", &core::FilterConfig::sensor_readmit_sigma, 1.0, 100.0, "sigma"},
    {"valid_position_accuracy_m", &core::FilterConfig::valid_position_accuracy_m, 1e-9, 1.0, "m"},
    {"valid_velocity_accuracy_mps", &core::FilterConfig::valid_velocity_accuracy_mps, 1e-6, 100.0, "m/s"},
    {"valid_confidence_sigma", &core::FilterConfig::valid_confidence_sigma, 0.5, 10.0, "sigma"},
    // --- Hall adaptation to slow change (temperature, ageing; hall_adaptation.hpp) ---
    {"hall_gain_random_walk_per_sqrt_s", &core::FilterConfig::hall_gain_random_walk_per_sqrt_s, 0.0, 1.0, "1/sqrt(s)"},
    {"hall_offset_random_walk_v_per_sqrt_s", &core::FilterConfig::hall_offset_random_walk_v_per_sqrt_s,
      0.0, 1.0, "V/sqrt(s)"},
    {"hall_gain_initial_std", &core::FilterConfig::hall_gain_initial_std, 0.0, 0.5, ""},
    {"hall_offset_initial_std_v", &core::FilterConfig::hall_offset_initial_std_v, 0.0, 1.0, "V"},
    {"hall_drift_cusum", &core::FilterConfig::hall_drift_cusum, 0.0, 1e6, ""},
    {"hall_gain_limit", &core::FilterConfig::hall_gain_limit, 0.001, 0.5, ""},
    {"hall_offset_limit_v", &core::FilterConfig::hall_offset_limit_v, 0.001, 1.0, "V"},
    {"hall_common_gain_initial_std", &core::FilterConfig::hall_common_gain_initial_std, 1e-6, 0.5, ""},
    {"hall_common_gain_random_walk_per_sqrt_s", &core::FilterConfig::hall_common_gain_random_walk_per_sqrt_s,
      0.0, 1.0, "1/sqrt(s)"},
    {"magnet_remanence_tc_per_k", &core::FilterConfig::magnet_remanence_tc_per_k, -0.01, 0.01, "1/K"},
    {"hall_gain_tc_per_k", &core::FilterConfig::hall_gain_tc_per_k, -0.01, 0.01, "1/K"},
    {"hall_gain_tc_std_per_k", &core::FilterConfig::hall_gain_tc_std_per_k, 0.0, 0.01, "1/K"},
    {"hall_offset_tc_std_v_per_k", &core::FilterConfig::hall_offset_tc_std_v_per_k, 0.0, 0.01, "V/K"},
    {"temperature_coefficient_rel_std", &core::FilterConfig::temperature_coefficient_rel_std, 0.0, 1.0, ""},
    {"hall_unread_temperature_rise_k", &core::FilterConfig::hall_unread_temperature_rise_k, 0.0, 100.0, "K"},
    {"hall_adaptation_model_std_v", &core::FilterConfig::hall_adaptation_model_std_v, 0.0, 0.1, "V"},
    {"hall_common_gain_model_std", &core::FilterConfig::hall_common_gain_model_std, 0.0, 0.1, ""},
    // --- steady motion ---
    {"steady_jerk_std_mps3", &core::FilterConfig::steady_jerk_std_mps3, 0.0, 1e6, "m/s^3"},
    {"steady_position_walk_m_per_sqrt_s", &core::FilterConfig::steady_position_walk_m_per_sqrt_s,
      0.0, 1.0, "m/sqrt(s)"},
    {"steady_hall_position_floor_m", &core::FilterConfig::steady_hall_position_floor_m, 0.0, 1e-3, "m"},
    {"steady_jerk_limit_mps3", &core::FilterConfig::steady_jerk_limit_mps3, 1e-6, 1e6, "m/s^3"},
    {"steady_hold_s", &core::FilterConfig::steady_hold_s, 1e-4, 60.0, "s"},
    {"steady_exit_cusum", &core::FilterConfig::steady_exit_cusum, 1e-3, 1e6, ""},
    // --- accelerometer bias steps ---
    {"accel_bias_step_cusum", &core::FilterConfig::accel_bias_step_cusum, 0.0, 1e6, ""},
    {"accel_bias_step_std_mps2", &core::FilterConfig::accel_bias_step_std_mps2, 1e-6, 100.0, "m/s^2"},
};

void read_motor(Map m, core::MotorConfig& motor) {
  m.require("motor", motor.name, non_empty());
  const bool pitch_ok = optional<double>(m, "magnet_pitch_m", motor.magnet_pitch_m, range(1e-3, 1.0, "m"));
  const bool travel_ok = optional<double>(m, "travel_m", motor.travel_m, range(1e-3, 100.0, "m"));
  if (pitch_ok && travel_ok && motor.travel_m / motor.magnet_pitch_m > kMaxMagnetPeriods)
    m.value(m.has("travel_m") ? "travel_m" : "magnet_pitch_m")
        .error("travel_m / magnet_pitch_m = " + schema::compact_number(motor.travel_m / motor.magnet_pitch_m) +
               " magnet periods out of range [0, " + schema::compact_number(kMaxMagnetPeriods) +
               "] (the Hall table holds 256 points per period)");
  m.get("sample_rate_hz", motor.sample_rate_hz, range(100.0, 100000.0, "Hz"));

  Map hall = m.map("hall");
  core::HallConfig& h = motor.hall;
  const bool count_ok = optional(hall, "count", h.count, schema::in_range(1, core::kMaxHalls, "sensors"));
  const Value offsets = hall.value("offsets_m");
  std::vector<double> off;
  if (offsets.as(off, range(-1.0, 1.0, "m"))) {
    if (count_ok && static_cast<int>(off.size()) != h.count)
      offsets.error("has " + std::to_string(off.size()) + " entries but count is " + std::to_string(h.count));
    else
      h.offsets_m = std::move(off);
  }
  const bool spacing_ok = optional<double>(hall, "spacing_m", h.spacing_m, range(1e-5, 1.0, "m"));
  if (spacing_ok && count_ok && hall.has("spacing_m") && h.spacing_m * (h.count - 1) > 1.0)
    hall.value("spacing_m")
        .error("the sensors span " + schema::compact_number(h.spacing_m * (h.count - 1)) +
               " m: out of range [0, 1] m for sensors on one carriage");
  const bool offset_ok = optional<double>(hall, "offset_v", h.offset_v, range(-50.0, 50.0, "V"));
  hall.get("amplitude_v", h.amplitude_v, range(1e-3, 100.0, "V"));
  hall.get("noise_v", h.noise_v, range(0.0, 1.0, "V"));
  const bool margin_ok = optional<double>(hall, "saturation_margin_v", h.saturation_margin_v, range(0.0, 10.0, "V"));

  Map adc = m.map("adc");
  adc.get("bits", motor.adc.bits, schema::in_range(8, 24, "bits"));
  const bool min_ok = optional<double>(adc, "min_v", motor.adc.min_v, range(-50.0, 50.0, "V"));
  const bool max_ok = optional<double>(adc, "max_v", motor.adc.max_v, range(-50.0, 50.0, "V"));
  if (min_ok && max_ok) {
    if (!(motor.adc.max_v > motor.adc.min_v)) {
      adc.value(adc.has("max_v") ? "max_v" : "min_v")
          .error("max_v (" + schema::compact_number(motor.adc.max_v) + ") must be greater than min_v (" +
                 schema::compact_number(motor.adc.min_v) + ")");
    } else {
      if (offset_ok && (h.offset_v < motor.adc.min_v || h.offset_v > motor.adc.max_v))
        hall.value("offset_v").error("offset_v (" + schema::compact_number(h.offset_v) +
                                     ") must lie inside the ADC range " + range_text(motor.adc.min_v, motor.adc.max_v) +
                                     " V");
      // Every reading would be within the margin of a rail: nothing would carry a position.
      if (margin_ok && !(2.0 * h.saturation_margin_v < motor.adc.max_v - motor.adc.min_v))
        hall.value("saturation_margin_v")
            .error(schema::out_of_range(h.saturation_margin_v, 0.0, 0.5 * (motor.adc.max_v - motor.adc.min_v), "V") +
                   ": must be less than half the ADC range, else every reading counts as clipped");
    }
  }
  {
    Map acc = m.map("accelerometer");
    acc.get("noise_mps2", motor.accelerometer.noise_mps2, range(0.0, 100.0, "m/s^2"));
    acc.get("range_mps2", motor.accelerometer.range_mps2, range(1.0, 10000.0, "m/s^2"));
  }
  {
    Map f = m.map("filter");
    core::FilterConfig& c = motor.filter;
    for (const FilterNumber& n : kFilterNumbers) f.get(n.key, c.*n.field, range(n.lo, n.hi, n.unit));
    f.get("hall_rejections_before_reset", c.hall_rejections_before_reset, schema::in_range(1, 1000, "fixes"));
    f.get("use_frame_accelerometer", c.use_frame_accelerometer);
    f.get("hall_adaptation", c.hall_adaptation);
  }
}

// ---- machine file -------------------------------------------------------------

struct MotorEntry {
  bool ok = false;
  core::MotorConfig motor;
};

class MachineLoader {
 public:
  MachineLoader(const Files& files, std::string path, const LoadOptions& options, std::vector<ConfigError>& errors)
      : files_(files), path_(std::move(path)), options_(options), errors_(errors) {}

  void load(MachineConfig& cfg) {
    cfg.source = files_.display(path_);
    std::string text, why;
    if (!files_.read(path_, text, why)) {
      errors_.push_back({cfg.source, 0, 0, "", "cannot read machine file: " + why});
      return;
    }
    schema::Document doc(cfg.source, errors_);
    if (!doc.parse(text)) return;
    Map root = doc.root();
    read_machine(root, cfg);
  }

 private:
  /// Resolves a path written in the machine file and checks that it can be
  /// read (or, with may_be_missing, that it is absent or readable).
  bool referenced_file(const Value& v, std::string& resolved, bool may_be_missing = false) {
    std::string rel;
    if (!v.as(rel, non_empty())) return false;
    resolved = files_.resolve(path_, rel);
    std::string why;
    const int e = files_.readable(resolved, why);
    if (e == ENOENT && may_be_missing) return true;
    if (e != 0) {
      v.error("cannot read '" + rel + "'" + (resolved != rel ? " (" + files_.display(resolved) + ")" : "") +
              ": " + why);
      return false;
    }
    return true;
  }

  const MotorEntry& motor(const Value& v) {
    std::string rel;
    static const MotorEntry kFailed;
    if (!v.as(rel, non_empty())) return kFailed;
    const std::string resolved = files_.resolve(path_, rel);
    auto [it, fresh] = motors_.try_emplace(resolved);
    if (!fresh) return it->second;
    std::string text, why;
    if (!files_.read(resolved, text, why)) {
      v.error("cannot read motor file '" + rel + "'" +
              (resolved != rel ? " (" + files_.display(resolved) + ")" : "") + ": " + why);
      return it->second;
    }
    const std::size_t before = errors_.size();
    schema::Document doc(files_.display(resolved), errors_);
    if (doc.parse(text)) read_motor(doc.root(), it->second.motor);
    it->second.ok = errors_.size() == before;
    return it->second;
  }

  void read_machine(Map& root, MachineConfig& cfg) {
    root.get("machine", cfg.name, non_empty());
    {
      Map dds = root.map("dds");
      dds.get("domain", cfg.dds.domain, schema::in_range(0, 232, "(DDS domain id)"));
      dds.get("deadline_ms", cfg.dds.deadline_ms, [](const double& x) {
        if (!(x >= 1.0 && x <= 60000.0)) return schema::out_of_range(x, 1.0, 60000.0, "ms");
        if (x != std::floor(x))
          return "must be a whole number of milliseconds (Fast DDS 2.9 rounds deadlines to ms), got " +
                 schema::compact_number(x);
        return std::string();
      });
      deadline_ms_ = cfg.dds.deadline_ms;
      dds.get_enum("state_writer", cfg.dds.state_writer,
                   {{"per_group", DdsConfig::StateWriters::per_group}, {"per_axis", DdsConfig::StateWriters::per_axis}});
      const Value profiles = dds.value("profiles_file");
      if (profiles.present()) referenced_file(profiles, cfg.dds.profiles_file);
      const Value stats = dds.value("statistics");
      if (stats.present()) {
        static const char* kTopics[] = {
            "HISTORY_LATENCY_TOPIC",   "NETWORK_LATENCY_TOPIC", "PUBLICATION_THROUGHPUT_TOPIC",
            "SUBSCRIPTION_THROUGHPUT_TOPIC", "RTPS_SENT_TOPIC", "RTPS_LOST_TOPIC",
            "RESENT_DATAS_TOPIC",      "HEARTBEAT_COUNT_TOPIC", "ACKNACK_COUNT_TOPIC",
            "NACKFRAG_COUNT_TOPIC",    "GAP_COUNT_TOPIC",       "DATA_COUNT_TOPIC",
            "PDP_PACKETS_TOPIC",       "EDP_PACKETS_TOPIC",     "DISCOVERY_TOPIC",
            "SAMPLE_DATAS_TOPIC",      "PHYSICAL_DATA_TOPIC"};
        if (!stats.is_sequence()) {
          stats.error("expected a list of Fast DDS statistics topic names, e.g. [HISTORY_LATENCY_TOPIC]");
        } else {
          for (std::size_t i = 0; i < stats.size(); ++i) {
            const Value item = stats.at(i);
            std::string name;
            if (!item.as(name)) continue;
            bool known = false;
            for (const char* t : kTopics) known = known || name == t;
            if (known) {
              cfg.dds.statistics.push_back(name);
            } else {
              std::string all;
              for (const char* t : kTopics) all += (all.empty() ? "" : " | ") + std::string(t);
              item.error("'" + name + "' is not a Fast DDS statistics topic: " + all);
            }
          }
        }
      }
    }
    read_axes(root, cfg);
    read_realtime(root.map("realtime"), cfg);  // after the axes: it may name them
  }

  void read_axes(Map& root, MachineConfig& cfg) {
    const Value axes = root.required("axes");
    if (!axes.present()) return;
    if (!axes.is_sequence() || axes.size() == 0) {
      axes.error(axes.is_sequence() ? std::string("must list at least one axis")
                                    : "expected a sequence of axes, got " + axes.describe());
      return;
    }
    cfg.axes.resize(axes.size());
    for (std::size_t i = 0; i < axes.size(); ++i) {
      const Value item = axes.at(i);
      cfg.axes[i].id = static_cast<std::uint32_t>(i + 1);
      Map a = item.as_map();
      if (!a.valid()) continue;
      read_axis(a, cfg.axes[i]);
      check_unique(a, cfg, i);
      check_unique_node(a, cfg, i);
    }
  }

  // ---- realtime section ----
  /// `realtime: {sample_thread_priority, dds_thread_priority, cpu_affinity, lock_memory, required, sample_loop}`.
  /// The CPUs must exist on the machine that loads the file: a machine file
  /// describes the machine it runs on, and `check` there reports a wrong index.
  static void read_realtime(Map rt, MachineConfig& cfg) {
    RealtimeConfig& c = cfg.realtime;
    auto fifo_range = [](const int& p) {
      return (p >= 0 && p <= 99) ? std::string()
                                 : "must be in [0, 99] (SCHED_FIFO 1..99; 0 = normal scheduling), got " + std::to_string(p);
    };
    rt.get("sample_thread_priority", c.sample_thread_priority, Check<int>(fifo_range));
    rt.get("dds_thread_priority", c.dds_thread_priority, Check<int>([&c, &fifo_range](const int& p) {
             if (const std::string range = fifo_range(p); !range.empty()) return range;
             if (p > 0 && p >= c.sample_thread_priority)
               return std::string("must be below realtime.sample_thread_priority (") +
                      std::to_string(c.sample_thread_priority) + ", " +
                      (c.sample_thread_priority > 0 ? "" : "normal scheduling, ") + "got " + std::to_string(p) +
                      "): Fast DDS's threads at or above the sample threads would delay them";
             return std::string();
           }));
    rt.get("lock_memory", c.lock_memory);
    rt.get("required", c.required);
    rt.get_enum("sample_loop", c.sample_loop,
                {{"shared", RealtimeConfig::SampleLoop::shared}, {"per_axis", RealtimeConfig::SampleLoop::per_axis}});
    const Value aff = rt.value("cpu_affinity");
    if (!aff.present() || aff.is_null()) return;
    if (aff.is_sequence()) {
      read_cpu_list(aff, c.cpu_affinity);
      return;
    }
    if (!aff.is_map()) {
      aff.error("expected a list of CPU indices for every sample thread, e.g. [2, 3], or one list per axis, e.g. "
                "{x: [1], y: [2]}; got " + aff.describe());
      return;
    }
    Map per_axis = aff.as_map();  // keys other than the axes' names are reported as unknown
    for (const auto& axis : cfg.axes) {
      if (axis.name.empty()) continue;
      const Value v = per_axis.value(axis.name);
      if (!v.present()) continue;
      std::vector<int> cpus;
      if (!v.is_sequence()) {
        v.error("expected a list of CPU indices, e.g. [1], got " + v.describe());
        continue;
      }
      if (read_cpu_list(v, cpus)) c.axis_cpu_affinity.emplace_back(axis.name, std::move(cpus));
    }
  }

  static bool read_cpu_list(const Value& list, std::vector<int>& out) {
    if (list.size() == 0) {
      list.error("must list at least one CPU (leave cpu_affinity out for no pinning)");
      return false;
    }
    const long configured = sysconf(_SC_NPROCESSORS_CONF);
    const int cpus = configured > 0 ? static_cast<int>(std::min<long>(configured, CPU_SETSIZE)) : CPU_SETSIZE;
    bool ok = true;
    std::vector<int> got;
    for (std::size_t i = 0; i < list.size(); ++i) {
      const Value item = list.at(i);
      int cpu = -1;
      if (!item.as(cpu, Check<int>([](const int& c) {
            return c >= 0 && c < CPU_SETSIZE ? std::string()
                                             : "must be in [0, " + std::to_string(CPU_SETSIZE - 1) + "], got " +
                                                   std::to_string(c);
          }))) {
        ok = false;
        continue;
      }
      if (cpu >= cpus) {
        item.error("CPU " + std::to_string(cpu) + " does not exist on this machine (it has CPUs 0-" +
                   std::to_string(cpus - 1) + ")");
        ok = false;
        continue;
      }
      if (std::find(got.begin(), got.end(), cpu) != got.end()) {
        item.error("CPU " + std::to_string(cpu) + " is listed twice");
        ok = false;
        continue;
      }
      got.push_back(cpu);
    }
    if (ok) out = std::move(got);
    return ok;
  }
  // ---- end realtime section ----

  void check_unique(Map& a, const MachineConfig& cfg, std::size_t i) {
    const AxisConfig& axis = cfg.axes[i];
    for (std::size_t j = 0; j < i; ++j) {
      const std::string other = "axes[" + std::to_string(j) + "]";
      if (!axis.name.empty() && axis.name == cfg.axes[j].name)
        a.value("name").error("duplicate axis name '" + axis.name + "' (also " + other + ")");
      if (axis.id == cfg.axes[j].id)
        a.value("id").error("duplicate id " + std::to_string(axis.id) + " (also " + other +
                            "; ids default to position + 1)");
    }
  }

  static std::string check_axis_name(const std::string& s) {
    if (s.empty() || s.size() > 15) return "must be 1 to 15 characters, got " + std::to_string(s.size());
    for (const char c : s)
      if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-'))
        return "may contain only letters, digits, '_' and '-', got '" + s + "'";
    return {};
  }

  void read_axis(Map& a, AxisConfig& axis) {
    a.require("name", axis.name, Check<std::string>(check_axis_name));
    a.get("id", axis.id);
    const Value motor_ref = a.required("motor");
    const MotorEntry* m = nullptr;
    if (motor_ref.present()) {
      m = &motor(motor_ref);
      axis.motor = m->motor;
      std::string rel;
      if (motor_ref.as(rel)) axis.motor_file = files_.stored(files_.resolve(path_, rel));
    }
    // Position checks need the motor's travel; skip them when the motor file
    // itself is broken (its errors are already reported).
    const double travel = (m && m->ok) ? m->motor.travel_m : -1.0;

    const Value cal = a.value("calibration");
    if (cal.present()) {
      std::string resolved;
      if (referenced_file(cal, resolved, !options_.calibration_must_exist))
        axis.calibration_file = files_.stored(resolved);
    }
    current_motor_ = m;  // socketcan layout cross-check (issue 6)
    read_driver(a.map("driver"), axis.driver, travel);
    read_canopen(a, axis, travel);
    {
      Map out = a.map("output");
      out.get("counts_per_m", axis.output.counts_per_m, range(1.0, 1e12, "counts/m"));
      out.get("direction", axis.output.direction, [](const int& d) {
        return (d == 1 || d == -1) ? std::string() : "must be 1 or -1, got " + std::to_string(d);
      });
      out.get("preset_counts", axis.output.preset_counts,
              schema::in_range<std::int64_t>(-kMaxPresetCounts, kMaxPresetCounts, "counts"));
      // The offered deadline must cover at least two published periods, else it is
      // missed by design.
      const double rate_hz = current_motor_ && current_motor_->ok ? current_motor_->motor.sample_rate_hz : 0.0;
      const double deadline_ms = deadline_ms_;
      out.get("publish_divider", axis.output.publish_divider, Check<int>([rate_hz, deadline_ms](const int& n) {
                if (n < 1 || n > 1000) return schema::out_of_range(n, 1, 1000, "samples");
                if (rate_hz > 0.0 && 2.0 * 1000.0 * n / rate_hz > deadline_ms)
                  return "publishes every " + schema::compact_number(1000.0 * n / rate_hz) + " ms at " +
                         schema::compact_number(rate_hz) + " Hz: the offered deadline (dds.deadline_ms = " +
                         schema::compact_number(deadline_ms) + ") must be at least two published periods";
                return std::string();
              }));
    }
    {
      Map h = a.map("homing");
      h.get_enum("mode", axis.homing.mode,
                 {{"none", HomingConfig::Mode::none},
                  {"startup_position", HomingConfig::Mode::startup_position},
                  {"signature", HomingConfig::Mode::signature}});
      if (h.get("position_m", axis.homing.position_m) || axis.homing.mode == HomingConfig::Mode::startup_position)
        within_travel(h, "position_m", axis.homing.position_m, travel);
      const Value state = h.value("state_file");
      if (axis.homing.mode == HomingConfig::Mode::signature) {
        // The nominal table is the same in every period: nothing to match.
        if (!cal.present())
          h.value("mode").error("signature homing needs a calibration (axes[].calibration): the nominal table has "
                                "no magnet signature to match");
        std::string rel;
        if (state.present() && state.as(rel, non_empty())) axis.homing.state_file = files_.stored(files_.resolve(path_, rel));
      } else if (state.present()) {
        state.error("only used with mode: signature (the kept position is checked against the magnet signature)");
      }
    }
  }

  // ---- canopen node ----
  /// `canopen:` of an axis (CanopenConfig). Every key is declared whether or not the
  /// block is there (the configuration reference test reads them all).
  void read_canopen(Map& a, AxisConfig& axis, double travel) {
    CanopenConfig& c = axis.canopen;
    c.enabled = a.has("canopen");
    Map m = a.map("canopen");
    const auto interface_name = Check<std::string>([](const std::string& s) {
      return (!s.empty() && s.size() <= 15 && s.find('/') == std::string::npos && s.find(' ') == std::string::npos)
                 ? std::string()
                 : "must be a network interface name of 1 to 15 characters, got '" + s + "'";
    });
    const auto node_id = schema::in_range<int>(1, 127);
    if (c.enabled) {
      m.require("interface", c.interface, interface_name);
      m.require("node_id", c.node_id, node_id);
    } else {
      m.get("interface", c.interface, interface_name);
      m.get("node_id", c.node_id, node_id);
    }
    m.get("bitrate_kbps", c.bitrate_kbps, Check<int>([](const int& b) {
            for (int ok : {10, 20, 50, 125, 250, 500, 800, 1000})
              if (b == ok) return std::string();
            return "must be one of 10, 20, 50, 125, 250, 500, 800, 1000 (kbit/s), got " + std::to_string(b);
          }));
    // The position value (6004h) is 32 bits: the whole travel must fit in it.
    m.get("measuring_step_nm", c.measuring_step_nm, Check<std::uint32_t>([travel](const std::uint32_t& n) {
            if (n < 1 || n > 1000000) return schema::out_of_range(static_cast<double>(n), 1, 1000000, "nm");
            if (travel > 0.0 && travel * 1e9 / n > 2147483647.0)
              return "a travel of " + schema::compact_number(travel) + " m is more than 2^31 - 1 steps of " +
                     std::to_string(n) + " nm (the 32-bit position value)";
            return std::string();
          }));
    m.get("cyclic_timer_ms", c.cyclic_timer_ms, schema::in_range<int>(0, 65535, "ms"));
    m.get("heartbeat_ms", c.heartbeat_ms, schema::in_range<int>(0, 65535, "ms"));
    const bool type_ok = m.get("transmission_type", c.transmission_type, Check<int>([](const int& t) {
            return (t >= 1 && t <= 240) || t == 254 || t == 255
                       ? std::string()
                       : "must be 1..240 (every n-th SYNC), 254 or 255 (cyclic, cyclic_timer_ms), got " + std::to_string(t);
          }));
    const Value mapping = m.value("tpdo_mapping");
    if (mapping.present() && !mapping.is_null()) {
      if (!mapping.is_sequence() || mapping.size() == 0 || mapping.size() > 2) {
        mapping.error("expected a list of one or two of position, speed (e.g. [position, speed]), got " + mapping.describe());
      } else {
        std::vector<std::string> names;
        for (std::size_t i = 0; i < mapping.size(); ++i) {
          const Value item = mapping.at(i);
          std::string name;
          if (!item.as(name)) continue;
          if (name != "position" && name != "speed") {
            item.error("'" + name + "' is not one of position, speed");
            continue;
          }
          if (std::find(names.begin(), names.end(), name) != names.end()) {
            item.error("'" + name + "' is mapped twice");
            continue;
          }
          names.push_back(name);
        }
        c.map_speed = std::find(names.begin(), names.end(), "speed") != names.end();
        c.speed_first = !names.empty() && names.front() == "speed";
        if (std::find(names.begin(), names.end(), "position") == names.end() && !names.empty())
          mapping.error("must map position (6004h); speed may follow it");
      }
    }
    if (c.enabled && type_ok && c.cyclic_timer_ms == 0 && (c.transmission_type == 254 || c.transmission_type == 255))
      m.value("transmission_type")
          .error(std::to_string(c.transmission_type) +
                 " sends TPDO1 every cyclic_timer_ms (6200h): give cyclic_timer_ms a period > 0");
  }

  /// Two CANopen nodes on one interface must have different node ids.
  void check_unique_node(Map& a, const MachineConfig& cfg, std::size_t i) {
    const CanopenConfig& c = cfg.axes[i].canopen;
    if (!c.enabled) return;
    for (std::size_t j = 0; j < i; ++j) {
      const CanopenConfig& o = cfg.axes[j].canopen;
      if (!(o.enabled && o.interface == c.interface && o.node_id == c.node_id)) continue;
      Map again = a.map("canopen");  // read once already: its other keys are not reported twice
      again.value("node_id").error("duplicate node id " + std::to_string(c.node_id) + " on interface '" +
                                                c.interface + "' (also axes[" + std::to_string(j) + "], axis '" +
                                                cfg.axes[j].name + "')");
      again.discard();
    }
  }
  // ---- end canopen node ----

  /// Cross-check against the motor's travel; reports at the value, or at the
  /// enclosing mapping when the value is a default.
  static bool within_travel(Map& m, std::string_view key, double x, double travel) {
    if (travel <= 0.0 || (x >= 0.0 && x <= travel)) return true;
    const Value v = m.value(key);
    v.error(std::string(v.present() ? "" : "(default) ") + schema::out_of_range(x, 0.0, travel, "m") +
            ": outside the motor's travel");
    return false;
  }

  void read_driver(Map d, DriverConfig& drv, double travel) {
    d.get_enum("type", drv.kind,
               {{"sim", DriverConfig::Kind::sim},
                {"replay", DriverConfig::Kind::replay},
                {"socketcan", DriverConfig::Kind::socketcan}});
    // ---- socketcan driver (issue 6) ----
    if (drv.kind == DriverConfig::Kind::socketcan) {
      for (const char* k : {"noise_seed", "profile", "imperfections", "temperature", "faults", "realtime"})
        d.reject(k, "only used with type: sim");
      d.reject("log", "only used with type: replay");
      read_socketcan(d, drv.socketcan);
      return;
    }
    for (const char* k : {"interface", "layout", "timeout_ms"}) d.reject(k, "only used with type: socketcan");
    // ---- end socketcan ----
    if (drv.kind == DriverConfig::Kind::replay) {
      const std::string why = "only used with type: sim";
      for (const char* k : {"noise_seed", "profile", "imperfections", "temperature", "faults"}) d.reject(k, why);
      d.get("realtime", drv.replay_realtime);
      const Value log = d.required("log");
      if (log.present()) referenced_file(log, drv.replay_path);
      if (!drv.replay_path.empty()) drv.replay_path = files_.stored(drv.replay_path);
      return;
    }
    d.reject("log", "only used with type: replay");
    sim::SimConfig& s = drv.sim;
    d.get("realtime", s.realtime);
    d.get("noise_seed", s.noise_seed);
    read_profile(d.map("profile"), s.profile, travel);
    read_faults(d.value("faults"), s, current_motor_ && current_motor_->ok ? current_motor_ : nullptr);
    {
      Map im = d.map("imperfections");
      sim::ImperfectionConfig& c = s.imperfections;
      im.get("track_seed", c.track_seed);
      const double pitch = current_motor_ && current_motor_->ok ? current_motor_->motor.magnet_pitch_m : 1.0;
      im.get("magnet_strength_std", c.magnet_strength_std, range(0.0, 0.5, ""));
      im.get("magnet_placement_std_m", c.magnet_placement_std_m, range(0.0, 0.1 * pitch, "m (pitch / 10)"));
      im.get("field_third_harmonic", c.field_third_harmonic,
             range(-sim::kMaxThirdHarmonic, sim::kMaxThirdHarmonic, ""));
      im.get("sensor_placement_std_m", c.sensor_placement_std_m, range(0.0, 0.25 * pitch, "m (pitch / 4)"));
      im.get("sensor_gain_std", c.sensor_gain_std, range(0.0, 0.5, ""));
      im.get("sensor_offset_std_v", c.sensor_offset_std_v, range(0.0, 1.0, "V"));
      im.get("hall_delay_s", c.hall_delay_s, range(0.0, 0.01, "s"));
      im.get("coil_field_v_per_mps2", c.coil_field_v_per_mps2, range(-0.1, 0.1, "V/(m/s^2)"));
      im.get("accel_bias_mps2", c.accel_bias_mps2, range(-100.0, 100.0, "m/s^2"));
      im.get("accel_scale_error", c.accel_scale_error, range(-0.5, 0.5, ""));
      im.get("accel_bias_random_walk_mps2_per_sqrt_s", c.accel_bias_random_walk_mps2_per_sqrt_s,
             range(0.0, 10.0, "m/s^2/sqrt(s)"));
      im.get("accel_delay_s", c.accel_delay_s, range(0.0, 0.1, "s"));
      im.get("frame_reaction_ratio", c.frame_reaction_ratio, range(-1.0, 1.0, ""));
      im.get("frame_vibration_mps2", c.frame_vibration_mps2, range(0.0, 1000.0, "m/s^2"));
      im.get("frame_vibration_hz", c.frame_vibration_hz, range(0.01, 10000.0, "Hz"));
      im.get("frame_accelerometer", c.frame_accelerometer);
    }
    read_temperature(d.map("temperature"), s.temperature);
  }

  /// The sim driver's `temperature:` block (sim::TemperatureConfig).
  static void read_temperature(Map t, sim::TemperatureConfig& c) {
    using P = sim::TemperatureConfig::Profile;
    t.get_enum("profile", c.profile,
               {{"constant", P::constant}, {"step", P::step}, {"ramp", P::ramp}, {"warmup", P::warmup}});
    const double max_rise = sim::kMaxTemperatureRiseK, max_tc = sim::kMaxTemperatureCoefficientPerK;
    const bool delta_ok = t.get("delta_k", c.delta_k, range(-max_rise, max_rise, "K"));
    const bool offset_ok = t.get("offset_k", c.offset_k, range(-max_rise, max_rise, "K"));
    t.get("start_s", c.start_s, range(0.0, 1e9, "s"));
    const bool duration_ok = t.get("duration_s", c.duration_s, range(0.0, 1e9, "s"));
    t.get("magnet_remanence_per_k", c.magnet_remanence_per_k, range(-max_tc, max_tc, "1/K"));
    t.get("hall_gain_tc_per_k", c.hall_gain_tc_per_k, range(-max_tc, max_tc, "1/K"));
    t.get("hall_gain_tc_std_per_k", c.hall_gain_tc_std_per_k,
          range(0.0, sim::kMaxTemperatureCoefficientStdPerK, "1/K"));
    t.get("hall_offset_tc_std_v_per_k", c.hall_offset_tc_std_v_per_k,
          range(0.0, sim::kMaxHallOffsetDriftStdVPerK, "V/K"));
    t.get("reference_c", c.reference_c, range(-60.0, 200.0, "deg C"));
    t.get("report", c.report);
    t.get("report_noise_k", c.report_noise_k, range(0.0, 100.0, "K"));
    t.get("report_resolution_k", c.report_resolution_k, range(0.0, 10.0, "K"));
    // Cross-checks, reported at the value (or at the block when it is a default).
    if ((delta_ok || offset_ok) && std::abs(c.delta_k) + std::abs(c.offset_k) > max_rise)
      t.value(delta_ok ? "delta_k" : "offset_k")
          .error("the temperature rise reaches " + schema::compact_number(std::abs(c.delta_k) + std::abs(c.offset_k)) +
                 " K: |offset_k| + |delta_k| must be <= " + schema::compact_number(max_rise));
    if ((c.profile == P::ramp || c.profile == P::warmup) && !(c.duration_s > 0.0) && (duration_ok || !t.has("duration_s"))) {
      const Value v = t.value("duration_s");
      v.error(std::string("duration_s") + (v.present() ? " " : " (default) ") + schema::compact_number(c.duration_s) +
              " must be > 0 for profile " + (c.profile == P::ramp ? "ramp (time to reach delta_k)" : "warmup (time constant)"));
    }
  }

  // ---- socketcan driver (issue 6) ----
  void read_socketcan(Map& d, SocketCanConfig& c) {
    d.require("interface", c.interface, Check<std::string>([](const std::string& s) {
                return (!s.empty() && s.size() <= 15 && s.find('/') == std::string::npos && s.find(' ') == std::string::npos)
                           ? std::string()
                           : "must be a network interface name of 1 to 15 characters, got '" + s + "'";
              }));
    d.get("timeout_ms", c.timeout_ms, range(0.1, 60000.0, "ms"));
    const Value layout = d.required("layout");
    std::string resolved;
    if (!layout.present() || !referenced_file(layout, resolved)) return;
    c.layout_file = files_.stored(resolved);
    std::string text, why;
    if (!files_.read(resolved, text, why)) {
      layout.error("cannot read layout file " + files_.display(resolved) + ": " + why);
      return;
    }
    const std::size_t before = errors_.size();
    if (!socketcan::load_can_layout_text(files_.display(resolved), text, c.layout, errors_) || errors_.size() != before)
      return;
    if (current_motor_ && current_motor_->ok) {
      const core::MotorConfig& m = current_motor_->motor;
      if (c.layout.hall_count != m.hall.count)
        layout.error("the layout carries " + std::to_string(c.layout.hall_count) + " Hall signals but motor '" + m.name +
                     "' has " + std::to_string(m.hall.count) + " sensors");
      if (std::abs(c.layout.sample_rate_hz - m.sample_rate_hz) > 1e-9 * m.sample_rate_hz)
        layout.error("the layout's sample_rate_hz " + schema::compact_number(c.layout.sample_rate_hz) +
                     " differs from motor '" + m.name + "' (" + schema::compact_number(m.sample_rate_hz) + ")");
    }
  }
  const MotorEntry* current_motor_ = nullptr;  // the axis being read, for cross-checks
  double deadline_ms_ = 0.0;                   // dds.deadline_ms, for the axes' cross-checks
  // ---- end socketcan ----

  /// Injected sensor faults: a list of {kind, sensor, start_s, end_s, magnitude}.
  static void read_faults(const Value& list, sim::SimConfig& s, const MotorEntry* motor) {
    if (!list.present() || list.is_null()) return;
    if (!list.is_sequence()) {
      list.error("expected a list of faults, e.g. [{kind: hall_stuck_high, sensor: 1, start_s: 2.0}]");
      return;
    }
    if (list.size() > static_cast<std::size_t>(sim::kMaxFaults)) {
      list.error("at most " + std::to_string(sim::kMaxFaults) + " faults");
      return;
    }
    using K = sim::FaultConfig::Kind;
    for (std::size_t i = 0; i < list.size(); ++i) {
      Map f = list.at(i).as_map();
      sim::FaultConfig fc;
      f.get_enum("kind", fc.kind,
                 {{"hall_stuck_high", K::hall_stuck_high}, {"hall_stuck_low", K::hall_stuck_low},
                  {"hall_stuck_mid", K::hall_stuck_mid}, {"hall_noisy", K::hall_noisy},
                  {"hall_intermittent", K::hall_intermittent}, {"hall_spikes", K::hall_spikes},
                  {"accel_dead", K::accel_dead}, {"accel_saturated", K::accel_saturated},
                  {"accel_bias", K::accel_bias}, {"accel_missing", K::accel_missing},
                  {"no_samples", K::no_samples}});
      if (!f.has("kind")) f.required("kind");
      const bool hall_kind = fc.kind == K::hall_stuck_high || fc.kind == K::hall_stuck_low ||
                             fc.kind == K::hall_stuck_mid || fc.kind == K::hall_noisy ||
                             fc.kind == K::hall_intermittent || fc.kind == K::hall_spikes;
      // The sensor must exist on this axis' motor (a fault on sensor 7 of a 4-sensor
      // motor would inject nothing and the test it is written for would pass vacuously).
      const int sensors = motor ? motor->motor.hall.count : core::kMaxHalls;
      const Value sensor = f.value("sensor");
      if (sensor.present() && sensor.as(fc.sensor, schema::in_range(0, core::kMaxHalls - 1, "(Hall sensor index)")) &&
          fc.sensor >= sensors)
        sensor.error(schema::out_of_range(fc.sensor, 0, sensors - 1, "(Hall sensor index)") + ": motor '" +
                     motor->motor.name + "' has " + std::to_string(sensors) + " Hall sensors, 0 .. " +
                     std::to_string(sensors - 1));
      if (sensor.present() && f.has("kind") && !hall_kind)
        sensor.error("only used with the hall_* fault kinds (the accelerometer has no index)");
      const bool start_ok = optional<double>(f, "start_s", fc.start_s, range(0.0, 1e9, "s"));
      const bool end_ok = optional<double>(f, "end_s", fc.end_s, range(0.0, 1e300, "s"));
      switch (fc.kind) {
        case K::hall_noisy: f.get("magnitude", fc.magnitude, range(0.0, 100.0, "V (noise, one sigma)")); break;
        case K::hall_intermittent: f.get("magnitude", fc.magnitude, range(0.0, 1.0, "(probability)")); break;
        case K::hall_spikes: f.get("magnitude", fc.magnitude, range(-100.0, 100.0, "V")); break;
        case K::accel_bias: f.get("magnitude", fc.magnitude, range(-1e4, 1e4, "m/s^2")); break;
        case K::no_samples: f.reject("magnitude", "not used with kind no_samples (the node sends nothing)"); break;
        default: f.get("magnitude", fc.magnitude, range(-1e4, 1e4, "")); break;
      }
      if (start_ok && end_ok && fc.end_s <= fc.start_s)
        f.value(f.has("end_s") ? "end_s" : "start_s")
            .error("end_s (" + schema::compact_number(fc.end_s) + ") must be after start_s (" +
                   schema::compact_number(fc.start_s) + ")");
      s.faults[s.fault_count++] = fc;
    }
  }

  static void read_profile(Map p, sim::MotionProfileConfig& c, double travel) {
    using K = sim::MotionProfileConfig::Kind;
    p.get_enum("type", c.kind,
               {{"standstill", K::standstill},
                {"constant_velocity", K::constant_velocity},
                {"constant_acceleration", K::constant_acceleration},
                {"multisine", K::multisine},
                {"shuttle", K::shuttle},
                {"point_to_point", K::point_to_point}});
    const bool start_ok = optional<double>(p, "start_m", c.start_m);
    p.get("velocity_mps", c.velocity_mps, range(-100.0, 100.0, "m/s"));
    p.get("acceleration_mps2", c.acceleration_mps2, range(-1e4, 1e4, "m/s^2"));
    p.get("max_velocity_mps", c.max_velocity_mps, range(1e-6, 100.0, "m/s"));
    p.get("max_acceleration_mps2", c.max_acceleration_mps2, range(1e-6, 1e4, "m/s^2"));
    p.get("max_jerk_mps3", c.max_jerk_mps3, range(1e-3, 1e7, "m/s^3"));
    p.get("dwell_s", c.dwell_s, range(0.0, 3600.0, "s"));
    const bool min_ok = optional<double>(p, "min_m", c.min_m);
    const bool max_ok = optional<double>(p, "max_m", c.max_m);
    // One error per problem: a position already outside the travel is not compared again.
    const bool start_in = start_ok && within_travel(p, "start_m", c.start_m, travel);
    const bool min_in = min_ok && within_travel(p, "min_m", c.min_m, travel);
    const bool max_in = max_ok && within_travel(p, "max_m", c.max_m, travel);
    if (!(min_in && max_in && start_in)) return;
    if (!(c.min_m < c.max_m)) {
      p.value(p.has("max_m") ? "max_m" : "min_m")
          .error("min_m (" + schema::compact_number(c.min_m) + ") must be less than max_m (" +
                 schema::compact_number(c.max_m) + ")");
    } else if (c.start_m < c.min_m || c.start_m > c.max_m) {
      // The simulator keeps every profile inside [min_m, max_m]; a start outside it is a contradiction.
      p.value("start_m").error("start_m " + schema::compact_number(c.start_m) + " is outside [min_m, max_m] = " +
                               range_text(c.min_m, c.max_m));
    }
  }

  const Files& files_;
  std::string path_;
  LoadOptions options_;
  std::vector<ConfigError>& errors_;
  std::map<std::string, MotorEntry> motors_;
};

LoadResult load(const Files& files, const std::string& path, const LoadOptions& options) {
  LoadResult r;
  MachineLoader(files, path, options, r.errors).load(r.config);
  schema::sort_errors(r.errors);
  return r;
}

}  // namespace

LoadResult load_machine_file(const std::string& path, const LoadOptions& options) {
  return load(DiskFiles{}, path, options);
}

LoadResult load_embedded_default(const LoadOptions& options) {
  return load(EmbeddedFiles{}, kEmbeddedMachine, options);
}

}  // namespace ve::config
