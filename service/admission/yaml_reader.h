// bp::service::detail::YamlReader: a small typed reader over a parsed yaml-cpp node tree, used by
// the daemon's configuration (service/admission/config.cc). It checks node kinds, unknown and
// duplicate keys, integer and number syntax and ranges, and choices from a fixed list, and
// records every problem as one line "<source>:<line>:<column>: <dotted.key>: <reason>" instead
// of stopping at the first.
// It only reads nodes that yaml-cpp already built; parsing (and catching yaml-cpp's exceptions) is
// the caller's job.
//
// Thread safety: none; one reader per parse, used by one thread.
// Invariants:
//  1. Every recorded line holds exactly one problem and no newline: echoed values are escaped and
//     shortened. Line and column are 1-based (yaml-cpp's Mark + 1); a node without a mark is
//     reported as "<source>: <dotted.key>: <reason>".
//  2. A Read* call writes its output only when the value is valid (kind, syntax and range);
//     otherwise it records one error and leaves the output as it was (the default).
//  3. MarkOf(path) is set for every known key that occurred in the document, HasError(path) for
//     every key with a recorded error.
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <set>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <unordered_map>
#include <vector>

#include <yaml-cpp/yaml.h>

namespace bp::service::detail {

/// One value in the document: its dotted key, the node, and where to point in messages.
struct Field {
  std::string path;  ///< dotted key, e.g. "dds.topics.events"; "" for the document itself
  YAML::Node node;   ///< the value
  YAML::Mark mark;   ///< the value's position, or the key's when the value is empty
};

/// Valid range of a floating-point key: min (inclusive or not) to max (inclusive).
struct NumberRange {
  double min = -std::numeric_limits<double>::infinity();  ///< lower bound
  bool min_inclusive = true;                              ///< false: value must be > min
  double max = std::numeric_limits<double>::infinity();   ///< upper bound, inclusive
};

/// Reads typed values out of a yaml-cpp tree, collecting errors and warnings.
class YamlReader {
 public:
  /// `source` names the document in every message (a path or a caller-chosen name).
  explicit YamlReader(std::string_view source) : source_(source) {}

  /// Visits each key of the mapping `field`: calls `visit(name, value)` for a key listed in
  /// `known` (in document order); records an error for an unknown key (with a suggestion within
  /// edit distance 2, else the valid keys), a duplicate key, or a key that is not a scalar. An
  /// empty value (`engine:` with nothing under it) is an empty mapping. Returns false when
  /// `field` is not a mapping (one error recorded).
  bool ReadMapping(const Field& field, std::span<const std::string_view> known,
                   const std::function<void(std::string_view name, const Field& value)>& visit);

  /// Any scalar (plain or quoted) as text.
  bool ReadString(const Field& field, std::string* out);
  /// A plain decimal integer in [min, max] (no quotes, fraction, exponent or unit suffix).
  /// `alternatives` (e.g. "'auto'") is named in the message when the value is not an integer.
  bool ReadInt64(const Field& field, int64_t min, int64_t max, int64_t* out,
                 std::string_view alternatives = {});
  /// A plain decimal integer in [min, max], unsigned.
  bool ReadUint64(const Field& field, uint64_t min, uint64_t max, uint64_t* out,
                  std::string_view alternatives = {});
  /// ReadInt64 for a narrower integer type T (min and max must fit in T).
  template <class T>
  bool ReadInt(const Field& field, T min, T max, T* out, std::string_view alternatives = {}) {
    if constexpr (std::is_unsigned_v<T>) {
      uint64_t v = 0;
      if (!ReadUint64(field, min, max, &v, alternatives)) return false;
      *out = static_cast<T>(v);
    } else {
      int64_t v = 0;
      if (!ReadInt64(field, min, max, &v, alternatives)) return false;
      *out = static_cast<T>(v);
    }
    return true;
  }
  /// A plain finite number in `range`. `alternatives` (e.g. "'auto'") is named in the message
  /// when the value is not a number at all.
  bool ReadNumber(const Field& field, const NumberRange& range, double* out,
                  std::string_view alternatives = {});
  /// One of `names` (a scalar); `noun` names what it is in the message ("log level").
  bool ReadChoice(const Field& field, std::span<const std::string_view> names,
                  std::string_view noun, size_t* out_index);

  /// Records an error at `mark` for `path`.
  void Error(const YAML::Mark& mark, std::string_view path, std::string_view reason);
  /// Records an error for `field`.
  void Error(const Field& field, std::string_view reason) { Error(field.mark, field.path, reason); }
  /// Records a warning at `mark` for `path` (same format as errors).
  void Warning(const YAML::Mark& mark, std::string_view path, std::string_view reason);

  /// Where the value of `path` is, if it occurred in the document.
  std::optional<YAML::Mark> MarkOf(const std::string& path) const;
  /// True when an error was recorded for `path`.
  bool HasError(const std::string& path) const { return error_paths_.count(path) != 0; }

  /// The errors, one line each, in document order (then in the order found).
  std::vector<std::string> errors() const { return Sorted(errors_); }
  /// The warnings, one line each, in document order (then in the order found).
  std::vector<std::string> warnings() const { return Sorted(warnings_); }
  /// True when an error was recorded.
  bool failed() const { return !errors_.empty(); }

  /// `text` quoted for a message: 'text', control bytes escaped, cut at 60 bytes.
  static std::string Quote(std::string_view text);
  /// Optimal-string-alignment distance (edits: insert, delete, substitute, swap adjacent).
  static size_t EditDistance(std::string_view a, std::string_view b);
  /// The shortest decimal text that reads back as `value`.
  static std::string FormatNumber(double value);

 private:
  struct Entry {
    YAML::Mark mark;
    std::string text;
  };
  static std::vector<std::string> Sorted(std::vector<Entry> entries);
  std::string Line(const YAML::Mark& mark, std::string_view path, std::string_view reason) const;
  // The scalar text of a value that must be a number, or an error naming `expected`.
  std::optional<std::string> NumericScalar(const Field& field, std::string_view expected);
  // Splits an integer scalar into sign and magnitude; records an error when it is not one.
  bool ParseInteger(const Field& field, std::string_view range_text, bool* negative,
                    uint64_t* magnitude, std::string_view alternatives);

  std::string source_;
  std::vector<Entry> errors_;
  std::vector<Entry> warnings_;
  std::unordered_map<std::string, YAML::Mark> marks_;
  std::set<std::string> error_paths_;
};

/// A description of a node for messages: "a mapping", "a sequence", "no value", "the scalar 'x'".
std::string DescribeNode(const YAML::Node& node);

}  // namespace bp::service::detail
