#include "yaml_reader.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <system_error>
#include <utility>

namespace bp::service::detail {
namespace {

constexpr size_t kMaxQuoted = 60;

std::string_view PathOrDocument(std::string_view path) {
  return path.empty() ? "(document)" : path;
}

bool IsDigit(char c) { return c >= '0' && c <= '9'; }
bool IsAlpha(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); }

// YAML's spellings of infinity and not-a-number, and the ones from_chars takes.
bool IsNonFiniteSpelling(std::string_view text) {
  if (!text.empty() && (text[0] == '+' || text[0] == '-')) text.remove_prefix(1);
  if (!text.empty() && text[0] == '.') text.remove_prefix(1);
  std::string lower(text);
  std::transform(lower.begin(), lower.end(), lower.begin(), [](char c) {
    return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c;
  });
  return lower == "inf" || lower == "infinity" || lower == "nan";
}

std::string JoinNames(std::span<const std::string_view> names) {
  std::string out;
  for (std::string_view name : names) {
    if (!out.empty()) out += ", ";
    out += name;
  }
  return out;
}

template <class T>
std::string RangeText(T min, T max) {
  if (max == std::numeric_limits<T>::max()) return "must be >= " + std::to_string(min);
  if (max == min + 1) return "must be " + std::to_string(min) + " or " + std::to_string(max);
  return "must be between " + std::to_string(min) + " and " + std::to_string(max);
}

}  // namespace

std::string DescribeNode(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Map:
      return "a mapping";
    case YAML::NodeType::Sequence:
      return "a sequence";
    case YAML::NodeType::Scalar:
      return (node.Tag() == "!" ? "the quoted string " : "the scalar ") +
             YamlReader::Quote(node.Scalar());
    case YAML::NodeType::Null:
      return "no value";
    case YAML::NodeType::Undefined:
      break;
  }
  return "nothing";
}

std::string YamlReader::Quote(std::string_view text) {
  bool cut = text.size() > kMaxQuoted;
  if (cut) {
    size_t end = kMaxQuoted;
    // Do not end inside a UTF-8 sequence: back off over continuation bytes.
    while (end > 0 && (static_cast<unsigned char>(text[end]) & 0xC0u) == 0x80u) --end;
    text = text.substr(0, end);
  }
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out = "'";
  for (char c : text) {
    auto byte = static_cast<unsigned char>(c);
    if (c == '\n') {
      out += "\\n";
    } else if (c == '\t') {
      out += "\\t";
    } else if (c == '\r') {
      out += "\\r";
    } else if (byte < 0x20u || byte == 0x7Fu) {
      out += "\\x";
      out += kHex[byte >> 4];
      out += kHex[byte & 0xFu];
    } else {
      out += c;
    }
  }
  out += cut ? "'..." : "'";
  return out;
}

size_t YamlReader::EditDistance(std::string_view a, std::string_view b) {
  // Rows i-2, i-1 and i of the optimal-string-alignment table.
  std::vector<size_t> prev2(b.size() + 1), prev(b.size() + 1), cur(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) prev[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    cur[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) {
        cur[j] = std::min(cur[j], prev2[j - 2] + 1);
      }
    }
    std::swap(prev2, prev);
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

std::string YamlReader::FormatNumber(double value) {
  char buffer[64];
  auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return std::string(buffer, result.ptr);
}

std::string YamlReader::Line(const YAML::Mark& mark, std::string_view path,
                             std::string_view reason) const {
  std::string out = source_;
  if (!mark.is_null()) {
    out += ':';
    out += std::to_string(mark.line + 1);
    out += ':';
    out += std::to_string(mark.column + 1);
  }
  out += ": ";
  out += PathOrDocument(path);
  out += ": ";
  out += reason;
  // Invariant 1: one line per problem, whatever yaml-cpp put into a message.
  std::replace(out.begin(), out.end(), '\n', ' ');
  return out;
}

void YamlReader::Error(const YAML::Mark& mark, std::string_view path, std::string_view reason) {
  errors_.push_back({mark, Line(mark, path, reason)});
  error_paths_.emplace(path);
}

void YamlReader::Warning(const YAML::Mark& mark, std::string_view path, std::string_view reason) {
  warnings_.push_back({mark, Line(mark, path, reason)});
}

std::vector<std::string> YamlReader::Sorted(std::vector<Entry> entries) {
  // Cross-key checks run last; sorting puts their lines where a reader of the file expects them.
  std::stable_sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) {
    return std::pair(a.mark.line, a.mark.column) < std::pair(b.mark.line, b.mark.column);
  });
  std::vector<std::string> out;
  out.reserve(entries.size());
  for (Entry& entry : entries) out.push_back(std::move(entry.text));
  return out;
}

std::optional<YAML::Mark> YamlReader::MarkOf(const std::string& path) const {
  auto it = marks_.find(path);
  if (it == marks_.end()) return std::nullopt;
  return it->second;
}

bool YamlReader::ReadMapping(
    const Field& field, std::span<const std::string_view> known,
    const std::function<void(std::string_view name, const Field& value)>& visit) {
  const YAML::Node& node = field.node;
  if (node.IsNull()) return true;
  if (!node.IsMap()) {
    Error(field, "expected a mapping (keys: " + JoinNames(known) + "), got " + DescribeNode(node));
    return false;
  }
  std::unordered_map<std::string, YAML::Mark> seen;
  for (auto it = node.begin(); it != node.end(); ++it) {
    // Copies: the iterator hands out a temporary pair of node handles.
    YAML::Node key = it->first;
    YAML::Node value = it->second;
    if (!key.IsScalar()) {
      Error(key.Mark(), field.path, "a key must be a plain name, got " + DescribeNode(key));
      continue;
    }
    const std::string& name = key.Scalar();
    std::string path = field.path.empty() ? name : field.path + "." + name;
    // yaml-cpp 0.7 keeps both entries of a duplicated key (lookups see one); catch it here.
    auto [first, inserted] = seen.emplace(name, key.Mark());
    if (!inserted) {
      Error(key.Mark(), path,
            "duplicate key " + Quote(path) + " (first at line " +
                std::to_string(first->second.line + 1) + "); each key may appear once");
      continue;
    }
    if (std::find(known.begin(), known.end(), name) == known.end()) {
      std::string reason = "unknown key " + Quote(path);
      std::string_view best;
      size_t best_distance = 3;
      for (std::string_view candidate : known) {
        size_t d = EditDistance(name, candidate);
        if (d < best_distance) {
          best = candidate;
          best_distance = d;
        }
      }
      if (!best.empty()) {
        reason += " (did you mean '" + std::string(best) + "'?)";
      } else {
        reason += " (valid keys: " + JoinNames(known) + ")";
      }
      Error(key.Mark(), path, reason);
      continue;
    }
    Field child{path, value, value.IsNull() ? key.Mark() : value.Mark()};
    marks_[path] = child.mark;
    visit(name, child);
  }
  return true;
}

bool YamlReader::ReadString(const Field& field, std::string* out) {
  if (field.node.IsNull()) {
    Error(field, "expected a string, got no value (write \"\" for an empty string)");
    return false;
  }
  if (!field.node.IsScalar()) {
    Error(field, "expected a string, got " + DescribeNode(field.node));
    return false;
  }
  *out = field.node.Scalar();
  return true;
}

std::optional<std::string> YamlReader::NumericScalar(const Field& field,
                                                     std::string_view expected) {
  const YAML::Node& node = field.node;
  if (!node.IsScalar()) {
    Error(field, "expected " + std::string(expected) + ", got " + DescribeNode(node));
    return std::nullopt;
  }
  // A quoted scalar is a string in YAML; taking it as a number would hide a typing mistake.
  if (node.Tag() == "!") {
    Error(field, "expected " + std::string(expected) + ", got " + DescribeNode(node) +
                     " (remove the quotes)");
    return std::nullopt;
  }
  return node.Scalar();
}

bool YamlReader::ParseInteger(const Field& field, std::string_view range_text, bool* negative,
                              uint64_t* magnitude, std::string_view alternatives) {
  std::string expected = "an integer";
  if (!alternatives.empty()) expected += " or " + std::string(alternatives);
  std::optional<std::string> text = NumericScalar(field, expected);
  if (!text) return false;
  std::string_view digits = *text;
  *negative = false;
  if (!digits.empty() && (digits[0] == '+' || digits[0] == '-')) {
    *negative = digits[0] == '-';
    digits.remove_prefix(1);
  }
  size_t n = 0;
  while (n < digits.size() && IsDigit(digits[n])) ++n;
  if (n == 0 || n != digits.size()) {
    std::string reason = "expected " + expected + ", got " + Quote(*text);
    double as_double = 0;
    auto as_number = std::from_chars(digits.data(), digits.data() + digits.size(), as_double);
    if (as_number.ec == std::errc() && as_number.ptr == digits.data() + digits.size()) {
      reason += " (must be a whole number)";  // 2.0, 1e3
    } else if (n > 0 && IsAlpha(digits[n])) {
      reason += " (unit suffixes are not supported; write the plain number)";
    }
    Error(field, reason);
    return false;
  }
  auto result = std::from_chars(digits.data(), digits.data() + digits.size(), *magnitude);
  if (result.ec != std::errc()) {
    Error(field, std::string(range_text) + ", got " + *text);
    return false;
  }
  return true;
}

bool YamlReader::ReadInt64(const Field& field, int64_t min, int64_t max, int64_t* out,
                           std::string_view alternatives) {
  bool negative = false;
  uint64_t magnitude = 0;
  std::string range_text = RangeText(min, max);
  if (!ParseInteger(field, range_text, &negative, &magnitude, alternatives)) return false;
  constexpr uint64_t kMaxPositive = static_cast<uint64_t>(std::numeric_limits<int64_t>::max());
  int64_t value = 0;
  if (!negative && magnitude <= kMaxPositive) {
    value = static_cast<int64_t>(magnitude);
  } else if (negative && magnitude <= kMaxPositive + 1) {
    // -(2^63) is representable: negate in unsigned arithmetic, then convert.
    value = magnitude == kMaxPositive + 1 ? std::numeric_limits<int64_t>::min()
                                          : -static_cast<int64_t>(magnitude);
  } else {
    Error(field, range_text + ", got " + field.node.Scalar());
    return false;
  }
  if (value < min || value > max) {
    Error(field, range_text + ", got " + std::to_string(value));
    return false;
  }
  *out = value;
  return true;
}

bool YamlReader::ReadUint64(const Field& field, uint64_t min, uint64_t max, uint64_t* out,
                            std::string_view alternatives) {
  bool negative = false;
  uint64_t magnitude = 0;
  std::string range_text = RangeText(min, max);
  if (!ParseInteger(field, range_text, &negative, &magnitude, alternatives)) return false;
  if ((negative && magnitude != 0) || magnitude < min || magnitude > max) {
    Error(field, range_text + ", got " + field.node.Scalar());
    return false;
  }
  *out = magnitude;
  return true;
}

bool YamlReader::ReadNumber(const Field& field, const NumberRange& range, double* out,
                            std::string_view alternatives) {
  std::string expected = "a number";
  if (!alternatives.empty()) expected += " or " + std::string(alternatives);
  std::optional<std::string> text = NumericScalar(field, expected);
  if (!text) return false;
  if (IsNonFiniteSpelling(*text)) {
    Error(field, "must be a finite number, got " + Quote(*text));
    return false;
  }
  std::string_view digits = *text;
  if (!digits.empty() && digits[0] == '+') digits.remove_prefix(1);
  double value = 0;
  auto result = std::from_chars(digits.data(), digits.data() + digits.size(), value);
  if (result.ec == std::errc::result_out_of_range) {
    Error(field, Quote(*text) + " is out of range");
    return false;
  }
  if (digits.empty() || result.ec != std::errc() || result.ptr != digits.data() + digits.size()) {
    std::string reason = "expected " + expected + ", got " + Quote(*text);
    if (result.ec == std::errc() && IsAlpha(*result.ptr)) {
      reason += " (unit suffixes are not supported; write the plain number)";
    }
    Error(field, reason);
    return false;
  }
  if (value == 0) value = 0.0;  // -0 reads as 0
  bool above_min = range.min_inclusive ? value >= range.min : value > range.min;
  if (!above_min || value > range.max) {
    std::string reason = "must be ";
    if (!std::isinf(range.min)) {
      reason += (range.min_inclusive ? ">= " : "> ") + FormatNumber(range.min);
      if (!std::isinf(range.max)) reason += " and ";
    }
    if (!std::isinf(range.max)) reason += "<= " + FormatNumber(range.max);
    Error(field, reason + ", got " + *text);
    return false;
  }
  *out = value;
  return true;
}

bool YamlReader::ReadChoice(const Field& field, std::span<const std::string_view> names,
                            std::string_view noun, size_t* out_index) {
  std::string text;
  if (!ReadString(field, &text)) return false;
  for (size_t i = 0; i < names.size(); ++i) {
    if (names[i] == text) {
      *out_index = i;
      return true;
    }
  }
  Error(field,
        "unknown " + std::string(noun) + " " + Quote(text) + " (valid: " + JoinNames(names) + ")");
  return false;
}

}  // namespace bp::service::detail
