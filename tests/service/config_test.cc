// The daemon's YAML configuration (service/admission/config.h): defaults, the shipped file, one
// test per validation rule asserting line, column, key and reason, several errors at once,
// warnings, relative paths in LoadConfigFile, I/O errors, and the ConfigToYaml round trip. Why
// one file of about 800 lines: one test per rule of the configuration, which is one file itself.
// BP_SOURCE_DIR (the repository root) is defined on the compile line.
#include "config.h"

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <ostream>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include <gtest/gtest.h>
#include <sched.h>
#include <stdlib.h>
#include <unistd.h>

#ifndef BP_SOURCE_DIR
#error "compile with -DBP_SOURCE_DIR=\"<repository root>\""
#endif

namespace bp::service {
namespace {

constexpr char kSource[] = "cfg.yaml";

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

bool Contains(std::string_view haystack, std::string_view needle) {
  return haystack.find(needle) != std::string_view::npos;
}

// The error message of a parse that must fail.
std::string ParseError(std::string_view yaml) {
  Config config;
  Status status = ParseConfig(yaml, kSource, &config);
  EXPECT_FALSE(status.ok()) << yaml;
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument);
  return status.message();
}

// A parse that must succeed.
Config ParseOk(std::string_view yaml) {
  Config config;
  Status status = ParseConfig(yaml, kSource, &config);
  EXPECT_TRUE(status.ok()) << status.ToString() << "\n--- for ---\n" << yaml;
  return config;
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  EXPECT_TRUE(in.good()) << path;
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteFile(const std::filesystem::path& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
  ASSERT_TRUE(out.good()) << path;
}

// The sections (not source and warnings) equal.
void ExpectSameSettings(const Config& a, const Config& b) {
  EXPECT_EQ(a.engine, b.engine);
  EXPECT_EQ(a.dds, b.dds);
  EXPECT_EQ(a.frames, b.frames);
  EXPECT_EQ(a.limits, b.limits);
  EXPECT_EQ(a.logging, b.logging);
  EXPECT_EQ(a.producers, b.producers);
}

// A fresh directory under the system's temporary directory, removed at the end of the test.
class TempDir {
 public:
  TempDir() {
    std::string pattern =
        (std::filesystem::temp_directory_path() / "bp_config_test.XXXXXX").string();
    if (mkdtemp(pattern.data()) != nullptr) path_ = pattern;
  }
  ~TempDir() {
    std::error_code ignored;
    if (!path_.empty()) std::filesystem::remove_all(path_, ignored);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// ---------------------------------------------------------------------------------------------
// Defaults and the shipped files.

TEST(ConfigDefaults, MatchTheDocumentedValues) {
  Config c;
  EXPECT_EQ(c.engine.algorithm, "grid_dense");
  EXPECT_EQ(c.engine.dimension, 3);
  EXPECT_EQ(c.engine.coordinate, CoordinateType::kFloat);
  EXPECT_FALSE(c.engine.cell_size.has_value());
  EXPECT_EQ(c.engine.threads, 0);  // auto
  EXPECT_GE(EngineThreads(c.engine), 1);
  EXPECT_LE(EngineThreads(c.engine), 256);
  EXPECT_EQ(c.engine.margin, 0.0);
  EXPECT_EQ(c.dds.domain, 0u);
  EXPECT_EQ(c.dds.cyclone_config, "cyclonedds-loopback.xml");
  EXPECT_EQ(c.dds.partition, "");
  EXPECT_EQ(c.dds.topics.updates, "bp_updates");
  EXPECT_EQ(c.dds.topics.events, "bp_events");
  EXPECT_EQ(c.dds.topics.status, "bp_status");
  EXPECT_EQ(c.dds.write_timeout_ms, 100);
  EXPECT_EQ(c.dds.event_history, 64);
  EXPECT_EQ(c.dds.update_queue, 32);
  EXPECT_EQ(c.frames.boundary, FrameBoundary::kEndOfFrame);
  EXPECT_EQ(c.frames.tick_ms, 16.667);
  EXPECT_EQ(c.frames.keep_cpus_awake_ms, 0);
  EXPECT_EQ(c.limits.max_batch_bytes, 64ull << 20);
  EXPECT_EQ(c.limits.max_batch_items, 1ull << 20);
  EXPECT_EQ(c.limits.max_objects, 1ull << 26);
  EXPECT_EQ(c.limits.max_pairs_per_event_batch, 1ull << 20);
  EXPECT_EQ(c.limits.max_rejections_reported, 100u);
  EXPECT_EQ(c.logging.level, "info");
  EXPECT_EQ(c.logging.summary_interval_s, 5.0);
  EXPECT_EQ(c.logging.file, "");
  EXPECT_EQ(c.logging.frame_log, "");
}

TEST(ConfigDefaults, EmptyTextAndEmptyDocumentsGiveTheDefaults) {
  for (std::string_view text :
       {"", "\n", "   \n\n", "# only a comment\n", "---\n", "--- ~\n", "~\n",
        "engine:\ndds:\nframes:\nlimits:\nlogging:\n", "engine: {}\ndds: {topics: {}}\n"}) {
    Config c = ParseOk(text);
    ExpectSameSettings(c, Config());
    EXPECT_TRUE(c.warnings.empty()) << text;
    EXPECT_EQ(c.source, kSource);
  }
}

TEST(ConfigShipped, ParsesWithoutErrorOrWarningAndEqualsTheDefaults) {
  std::string text = ReadFile(BP_SOURCE_DIR "/config/broadphased.yaml");
  Config c = ParseOk(text);
  ExpectSameSettings(c, Config());
  EXPECT_TRUE(c.warnings.empty()) << c.warnings.front();
}

TEST(ConfigShipped, SpellsOutEveryKeyInTheOrderOfConfigToYaml) {
  std::string shipped = ReadFile(BP_SOURCE_DIR "/config/broadphased.yaml");
  size_t from = 0;
  for (const std::string& line : Lines(ConfigToYaml(Config()))) {
    std::string key = line.substr(0, line.find(':') + 1);  // indentation included
    size_t at = shipped.find("\n" + key, from);
    ASSERT_NE(at, std::string::npos) << "missing or out of order: '" << key << "'";
    from = at + 1;
  }
}

// docs/OPERATIONS.md's configuration reference: one table row per key, `section.key` in the
// first column and the default in the third, exactly as ConfigToYaml prints it. Every key the
// reader takes is documented once, with its default; nothing else is.
TEST(ConfigDocs, OperationsReferenceListsEveryKeyWithItsDefault) {
  std::vector<std::pair<std::string, std::string>> printed;  // dotted key, value
  std::vector<std::string> path;
  for (const std::string& line : Lines(ConfigToYaml(Config()))) {
    const size_t indent = line.find_first_not_of(' ') / 2;
    const size_t colon = line.find(':');
    path.resize(indent);
    path.push_back(line.substr(indent * 2, colon - indent * 2));
    if (colon + 1 == line.size()) continue;  // a section
    std::string key;
    for (const std::string& part : path) key += (key.empty() ? "" : ".") + part;
    printed.emplace_back(key, line.substr(colon + 2));
  }
  std::vector<std::pair<std::string, std::string>> documented;
  for (const std::string& line : Lines(ReadFile(BP_SOURCE_DIR "/docs/OPERATIONS.md"))) {
    // | `section.key` | type | default | meaning |
    if (line.rfind("| `", 0) != 0) continue;
    std::vector<std::string> cells;
    for (size_t at = 1; at < line.size();) {
      const size_t bar = line.find(" |", at);
      if (bar == std::string::npos) break;
      std::string cell = line.substr(at, bar - at);
      cell.erase(0, cell.find_first_not_of(' '));
      cells.push_back(cell);
      at = bar + 2;
    }
    if (cells.size() != 4) continue;
    const std::string key = cells[0].substr(1, cells[0].find('`', 1) - 1);
    if (key.find('.') == std::string::npos || key.find(' ') != std::string::npos) continue;
    std::string value = cells[2];
    if (value.size() >= 2 && value.front() == '`' && value.back() == '`') {
      value = value.substr(1, value.size() - 2);
    }
    documented.emplace_back(key, value);
  }
  EXPECT_EQ(documented, printed) << "docs/OPERATIONS.md and ConfigToYaml(Config()) disagree";
}

TEST(ConfigShipped, LoadsAndResolvesTheCycloneConfigNextToIt) {
  Config c;
  const std::string path = BP_SOURCE_DIR "/config/broadphased.yaml";
  ASSERT_TRUE(LoadConfigFile(path, &c).ok());
  EXPECT_EQ(c.source, path);
  EXPECT_EQ(c.dds.cyclone_config, BP_SOURCE_DIR "/config/cyclonedds-loopback.xml");
  EXPECT_TRUE(std::filesystem::is_regular_file(c.dds.cyclone_config));
  EXPECT_TRUE(std::filesystem::is_regular_file(BP_SOURCE_DIR "/config/cyclonedds-lan.xml"));
  EXPECT_EQ(c.logging.file, "");  // "" stays "" (stderr only)
  EXPECT_EQ(c.logging.frame_log, "");
}

// ---------------------------------------------------------------------------------------------
// One rule per case: the message is exactly one line and contains the expected text, which
// always starts with "<source>:<line>:<column>: <dotted.key>: ".

struct RuleCase {
  const char* name;
  const char* yaml;
  const char* expected;
};

// Test names and failure messages show the case's name, not its bytes.
void PrintTo(const RuleCase& c, std::ostream* os) { *os << c.name; }

class ConfigRuleTest : public ::testing::TestWithParam<RuleCase> {};

TEST_P(ConfigRuleTest, ReportsLineColumnKeyAndReason) {
  const RuleCase& c = GetParam();
  std::string message = ParseError(c.yaml);
  EXPECT_EQ(Lines(message).size(), 1u) << message;
  EXPECT_TRUE(Contains(message, c.expected))
      << "message:  " << message << "\nexpected: " << c.expected;
}

// clang-format off
const RuleCase kRuleCases[] = {
    // Unknown keys, with a suggestion within edit distance 2, else the valid keys.
    {"UnknownKeySuggested", "engine:\n  dimensions: 3\n",
     "cfg.yaml:2:3: engine.dimensions: unknown key 'engine.dimensions' (did you mean "
     "'dimension'?)"},
    {"UnknownKeyTransposed", "engine:\n  thraeds: 2\n",
     "cfg.yaml:2:3: engine.thraeds: unknown key 'engine.thraeds' (did you mean 'threads'?)"},
    {"UnknownSection", "engin:\n  threads: 1\n",
     "cfg.yaml:1:1: engin: unknown key 'engin' (did you mean 'engine'?)"},
    {"UnknownKeyListsValidKeys", "logging:\n  colour: true\n",
     "cfg.yaml:2:3: logging.colour: unknown key 'logging.colour' (valid keys: level, "
     "summary_interval_s, file, frame_log)"},
    {"UnknownNestedKey", "dds:\n  topics:\n    event: x\n",
     "cfg.yaml:3:5: dds.topics.event: unknown key 'dds.topics.event' (did you mean 'events'?)"},
    {"KeyNotAScalar", "engine:\n  ? [a]\n  : 1\n",
     "cfg.yaml:2:5: engine: a key must be a plain name, got a sequence"},
    // Wrong node kinds.
    {"SequenceForSection", "engine: [1, 2]\n",
     "cfg.yaml:1:9: engine: expected a mapping (keys: algorithm, dimension, coordinate, "
     "cell_size, threads, margin), got a sequence"},
    {"ScalarForSection", "frames: tick\n",
     "cfg.yaml:1:9: frames: expected a mapping (keys: boundary, tick_ms, keep_cpus_awake_ms), got "
     "the scalar 'tick'"},
    {"SequenceForDocument", "- engine\n- dds\n",
     "cfg.yaml:1:1: (document): expected a mapping (keys: engine, dds, frames, limits, logging, "
     "producers, shards), got a sequence"},
    {"ShardNeedsMarginZero", "engine:\n  margin: 0.5\nshards:\n  map: m.yaml\n",
     "cfg.yaml:2:11: engine.margin: a shard (shards.map is set) needs margin 0"},
    {"ShardNeedsEndOfFrame", "frames:\n  boundary: tick\nshards:\n  map: m.yaml\n",
     "cfg.yaml:2:13: frames.boundary: a shard (shards.map is set) closes frames on end_of_frame"},
    {"ShardSelfWithoutMap", "shards:\n  self: a\n",
     "cfg.yaml:2:9: shards.self: needs shards.map (the shard map it names a shard of)"},
    {"SequenceForInteger", "engine:\n  threads: [1]\n",
     "cfg.yaml:2:12: engine.threads: expected an integer or 'auto', got a sequence"},
    {"MappingForString", "engine:\n  algorithm: {a: 1}\n",
     "cfg.yaml:2:14: engine.algorithm: expected a string, got a mapping"},
    {"MappingForTopics", "dds:\n  topics: [bp_a]\n",
     "cfg.yaml:2:11: dds.topics: expected a mapping (keys: updates, events, status, requests, interests, replies), got a "
     "sequence"},
    {"EmptyString", "dds:\n  partition:\n",
     "cfg.yaml:2:3: dds.partition: expected a string, got no value (write \"\" for an empty "
     "string)"},
    {"EmptyInteger", "engine:\n  threads:\n",
     "cfg.yaml:2:3: engine.threads: expected an integer or 'auto', got no value"},
    {"EmptyNumber", "frames:\n  tick_ms: ~\n",
     "cfg.yaml:2:3: frames.tick_ms: expected a number, got no value"},
    // Numbers: syntax.
    {"NonNumericInteger", "engine:\n  threads: four\n",
     "cfg.yaml:2:12: engine.threads: expected an integer or 'auto', got 'four'"},
    {"TrailingGarbage", "engine:\n  threads: 3x\n",
     "cfg.yaml:2:12: engine.threads: expected an integer or 'auto', got '3x'"},
    {"FractionForInteger", "engine:\n  dimension: 2.0\n",
     "cfg.yaml:2:14: engine.dimension: expected an integer, got '2.0' (must be a whole number)"},
    {"ExponentForInteger", "dds:\n  update_queue: 1e3\n",
     "cfg.yaml:2:17: dds.update_queue: expected an integer, got '1e3' (must be a whole number)"},
    {"QuotedInteger", "engine:\n  threads: \"4\"\n",
     "cfg.yaml:2:12: engine.threads: expected an integer or 'auto', got the quoted string '4' (remove the "
     "quotes)"},
    {"QuotedNumber", "frames:\n  tick_ms: '10'\n",
     "cfg.yaml:2:12: frames.tick_ms: expected a number, got the quoted string '10'"},
    {"NonNumericNumber", "engine:\n  margin: abc\n",
     "cfg.yaml:2:11: engine.margin: expected a number, got 'abc'"},
    {"TrailingGarbageNumber", "logging:\n  summary_interval_s: 2.5.1\n",
     "cfg.yaml:2:23: logging.summary_interval_s: expected a number, got '2.5.1'"},
    {"CellSizeNeitherNumberNorAuto", "engine:\n  cell_size: big\n",
     "cfg.yaml:2:14: engine.cell_size: expected a number or 'auto', got 'big'"},
    {"Infinity", "engine:\n  margin: .inf\n",
     "cfg.yaml:2:11: engine.margin: must be a finite number, got '.inf'"},
    {"NotANumber", "frames:\n  tick_ms: .NaN\n",
     "cfg.yaml:2:12: frames.tick_ms: must be a finite number, got '.NaN'"},
    {"HugeNumber", "engine:\n  cell_size: 1e999\n",
     "cfg.yaml:2:14: engine.cell_size: '1e999' is out of range"},
    {"SizeSuffix", "limits:\n  max_batch_bytes: 64MiB\n",
     "cfg.yaml:2:20: limits.max_batch_bytes: expected an integer, got '64MiB' (unit suffixes are "
     "not supported; write the plain number)"},
    {"DurationSuffix", "logging:\n  summary_interval_s: 5s\n",
     "cfg.yaml:2:23: logging.summary_interval_s: expected a number, got '5s' (unit suffixes are "
     "not supported"},
    // Numbers: ranges.
    {"DimensionTooLarge", "engine:\n  dimension: 4\n",
     "cfg.yaml:2:14: engine.dimension: must be 2 or 3, got 4"},
    {"DimensionTooSmall", "engine:\n  dimension: 1\n",
     "cfg.yaml:2:14: engine.dimension: must be 2 or 3, got 1"},
    {"ThreadsZero", "engine:\n  threads: 0\n",
     "cfg.yaml:2:12: engine.threads: must be between 1 and 256, got 0"},
    {"ThreadsTooMany", "engine:\n  threads: 257\n",
     "cfg.yaml:2:12: engine.threads: must be between 1 and 256, got 257"},
    {"ThreadsOverflow", "engine:\n  threads: 99999999999999999999\n",
     "cfg.yaml:2:12: engine.threads: must be between 1 and 256, got 99999999999999999999"},
    {"MarginNegative", "engine:\n  margin: -1\n",
     "cfg.yaml:2:11: engine.margin: must be >= 0, got -1"},
    {"CellSizeZero", "engine:\n  cell_size: 0\n",
     "cfg.yaml:2:14: engine.cell_size: must be > 0, got 0"},
    {"CellSizeNegative", "engine:\n  cell_size: -2.5\n",
     "cfg.yaml:2:14: engine.cell_size: must be > 0, got -2.5"},
    {"DomainTooLarge", "dds:\n  domain: 233\n",
     "cfg.yaml:2:11: dds.domain: must be between 0 and 232, got 233"},
    {"DomainNegative", "dds:\n  domain: -1\n",
     "cfg.yaml:2:11: dds.domain: must be between 0 and 232, got -1"},
    {"WriteTimeoutZero", "dds:\n  write_timeout_ms: 0\n",
     "cfg.yaml:2:21: dds.write_timeout_ms: must be between 1 and 60000, got 0"},
    {"WriteTimeoutTooLong", "dds:\n  write_timeout_ms: 60001\n",
     "cfg.yaml:2:21: dds.write_timeout_ms: must be between 1 and 60000, got 60001"},
    {"EventHistoryZero", "dds:\n  event_history: 0\n",
     "cfg.yaml:2:18: dds.event_history: must be between 1 and 100000, got 0"},
    {"EventHistoryTooDeep", "dds:\n  event_history: 100001\n",
     "cfg.yaml:2:18: dds.event_history: must be between 1 and 100000, got 100001"},
    {"UpdateQueueZero", "dds:\n  update_queue: 0\n",
     "cfg.yaml:2:17: dds.update_queue: must be between 1 and 100000, got 0"},
    {"UpdateQueueTooDeep", "dds:\n  update_queue: 100001\n",
     "cfg.yaml:2:17: dds.update_queue: must be between 1 and 100000, got 100001"},
    {"TickZero", "frames:\n  tick_ms: 0\n",
     "cfg.yaml:2:12: frames.tick_ms: must be > 0 and <= 60000, got 0"},
    {"TickTooLong", "frames:\n  tick_ms: 60000.5\n",
     "cfg.yaml:2:12: frames.tick_ms: must be > 0 and <= 60000, got 60000.5"},
    {"KeepAwakeNegative", "frames:\n  keep_cpus_awake_ms: -1\n",
     "cfg.yaml:2:23: frames.keep_cpus_awake_ms: must be between 0 and 60000, got -1"},
    {"KeepAwakeTooLong", "frames:\n  keep_cpus_awake_ms: 60001\n",
     "cfg.yaml:2:23: frames.keep_cpus_awake_ms: must be between 0 and 60000, got 60001"},
    {"BatchBytesTooSmall", "limits:\n  max_batch_bytes: 63\n",
     "cfg.yaml:2:20: limits.max_batch_bytes: must be between 64 and 2147483647, got 63"},
    {"BatchBytesTooLarge", "limits:\n  max_batch_bytes: 2147483648\n",
     "cfg.yaml:2:20: limits.max_batch_bytes: must be between 64 and 2147483647, got 2147483648"},
    {"BatchItemsZero", "limits:\n  max_batch_items: 0\n",
     "cfg.yaml:2:20: limits.max_batch_items: must be >= 1, got 0"},
    {"ObjectsZero", "limits:\n  max_objects: 0\n",
     "cfg.yaml:2:16: limits.max_objects: must be >= 1, got 0"},
    {"ObjectsOverflow", "limits:\n  max_objects: 18446744073709551616\n",
     "cfg.yaml:2:16: limits.max_objects: must be >= 1, got 18446744073709551616"},
    {"PairsPerBatchZero", "limits:\n  max_pairs_per_event_batch: 0\n",
     "cfg.yaml:2:30: limits.max_pairs_per_event_batch: must be between 1 and 67108864, got 0"},
    {"PairsPerBatchTooLarge", "limits:\n  max_pairs_per_event_batch: 67108865\n",
     "cfg.yaml:2:30: limits.max_pairs_per_event_batch: must be between 1 and 67108864, got "
     "67108865"},
    {"RejectionsNegative", "limits:\n  max_rejections_reported: -1\n",
     "cfg.yaml:2:28: limits.max_rejections_reported: must be >= 0, got -1"},
    {"SummaryNegative", "logging:\n  summary_interval_s: -1\n",
     "cfg.yaml:2:23: logging.summary_interval_s: must be >= 0 and <= 86400, got -1"},
    {"SummaryTooLong", "logging:\n  summary_interval_s: 86401\n",
     "cfg.yaml:2:23: logging.summary_interval_s: must be >= 0 and <= 86400, got 86401"},
    // Names from a fixed list.
    {"UnknownAlgorithm", "engine:\n  algorithm: sap\n",
     "cfg.yaml:2:14: engine.algorithm: unknown algorithm 'sap' (valid: brute_force, "
     "segmented_sap, batch_sap, dynamic_octree, grid_segmented_sap, grid_batch_sap, grid_dense)"},
    {"UnknownCoordinate", "engine:\n  coordinate: int64\n",
     "cfg.yaml:2:15: engine.coordinate: unknown coordinate type 'int64' (valid: float, double, "
     "int32)"},
    {"UnknownBoundary", "frames:\n  boundary: frame\n",
     "cfg.yaml:2:13: frames.boundary: unknown frame boundary 'frame' (valid: end_of_frame, tick)"},
    {"UnknownLogLevel", "logging:\n  level: verbose\n",
     "cfg.yaml:2:10: logging.level: unknown log level 'verbose' (valid: trace, debug, info, warn, "
     "error, critical, off)"},
    // Topic names.
    {"EmptyTopic", "dds:\n  topics:\n    events: \"\"\n",
     "cfg.yaml:3:13: dds.topics.events: a topic name must not be empty"},
    {"TopicCharacters", "dds:\n  topics:\n    events: bp-events\n",
     "cfg.yaml:3:13: dds.topics.events: topic name 'bp-events' has a character outside "
     "[A-Za-z0-9_/]: '-'"},
    {"TopicSameAsDefault", "dds:\n  topics:\n    status: bp_events\n",
     "cfg.yaml:3:13: dds.topics.status: topic name 'bp_events' is also used by dds.topics.events; "
     "the topics must differ"},
    {"TopicsSameBothWritten", "dds:\n  topics:\n    updates: t\n    events: t\n",
     "cfg.yaml:4:13: dds.topics.events: topic name 't' is also used by dds.topics.updates"},
    {"TopicSameAsLaterDefault", "dds:\n  topics:\n    updates: bp_status\n",
     "cfg.yaml:3:14: dds.topics.updates: topic name 'bp_status' is also used by "
     "dds.topics.status"},
    // Duplicate keys (yaml-cpp keeps both silently).
    {"DuplicateKey", "engine:\n  threads: 1\n  threads: 2\n",
     "cfg.yaml:3:3: engine.threads: duplicate key 'engine.threads' (first at line 2)"},
    {"DuplicateKeyInFlowMapping", "engine: {threads: 1, threads: 1}\n",
     "cfg.yaml:1:22: engine.threads: duplicate key 'engine.threads' (first at line 1)"},
    {"DuplicateSection", "engine:\n  threads: 1\nengine:\n  dimension: 2\n",
     "cfg.yaml:3:1: engine: duplicate key 'engine' (first at line 1)"},
    {"DuplicateTopicKey", "dds:\n  topics:\n    events: a\n    events: b\n",
     "cfg.yaml:4:5: dds.topics.events: duplicate key 'dds.topics.events' (first at line 3)"},
    // Cross-key errors.
    {"FractionalMarginWithInt32", "engine:\n  margin: 0.5\n  coordinate: int32\n",
     "cfg.yaml:2:11: engine.margin: int32 coordinates need an integral margin below 2^31; got "
     "0.5"},
    {"MarginBeyondFloat", "engine:\n  margin: 1e300\n",
     "cfg.yaml:2:11: engine.margin: float coordinates need a margin within the float range; got "
     "1e+300"},
    {"HugeMarginWithInt32", "engine:\n  coordinate: int32\n  margin: 3e9\n",
     "cfg.yaml:3:11: engine.margin: int32 coordinates need an integral margin below 2^31; got "
     "3e+09"},
    // YAML itself.
    {"UnclosedFlowSequence", "engine:\n  threads: [1, 2\n",
     "cfg.yaml:3:1: YAML syntax error: end of sequence flow not found"},
    {"TabIndentation", "engine:\n\tthreads: 1\n", "cfg.yaml:2:9: YAML syntax error: "},
    {"BadEscape", "dds:\n  partition: \"\\q\"\n",
     "cfg.yaml:2:17: YAML syntax error: unknown escape character: q"},
    {"TwoDocuments", "engine: {}\n---\ndds: {}\n",
     "cfg.yaml:3:1: (document): only one YAML document is allowed, found 2"},
};
// clang-format on

INSTANTIATE_TEST_SUITE_P(Rules, ConfigRuleTest, ::testing::ValuesIn(kRuleCases),
                         [](const ::testing::TestParamInfo<RuleCase>& param_info) {
                           return std::string(param_info.param.name);
                         });

// ---------------------------------------------------------------------------------------------
// Many errors at once, messages, and values accepted.

TEST(ConfigErrors, EveryProblemIsReportedInDocumentOrder) {
  const char* yaml =
      "engine:\n"                  // 1
      "  dimensions: 3\n"          // 2  unknown key
      "  algorithm: sap\n"         // 3  unknown algorithm
      "  threads: 3x\n"            // 4  trailing garbage
      "  margin: -0.5\n"           // 5  out of range
      "dds:\n"                     // 6
      "  domain: 300\n"            // 7  out of range
      "  topics:\n"                // 8
      "    updates: bp_events\n"   // 9  same as events (cross-key)
      "  partition: [a]\n"         // 10 wrong kind
      "frames:\n"                  // 11
      "  boundary: tik\n"          // 12 unknown name
      "  boundary: tick\n"         // 13 duplicate
      "limits:\n"                  // 14
      "  max_batch_bytes: 1GiB\n"  // 15 suffix
      "logging: verbose\n"         // 16 wrong kind
      "extra: 1\n";                // 17 unknown section
  std::string message = ParseError(yaml);
  std::vector<std::string> lines = Lines(message);
  const char* expected[] = {
      "cfg.yaml:2:3: engine.dimensions: unknown key",
      "cfg.yaml:3:14: engine.algorithm: unknown algorithm 'sap'",
      "cfg.yaml:4:12: engine.threads: expected an integer or 'auto', got '3x'",
      "cfg.yaml:5:11: engine.margin: must be >= 0, got -0.5",
      "cfg.yaml:7:11: dds.domain: must be between 0 and 232, got 300",
      "cfg.yaml:9:14: dds.topics.updates: topic name 'bp_events' is also used by",
      "cfg.yaml:10:14: dds.partition: expected a string, got a sequence",
      "cfg.yaml:12:13: frames.boundary: unknown frame boundary 'tik'",
      "cfg.yaml:13:3: frames.boundary: duplicate key",
      "cfg.yaml:15:20: limits.max_batch_bytes: expected an integer, got '1GiB'",
      "cfg.yaml:16:10: logging: expected a mapping",
      "cfg.yaml:17:1: extra: unknown key 'extra'",
  };
  ASSERT_EQ(lines.size(), std::size(expected)) << message;
  for (size_t i = 0; i < lines.size(); ++i) {
    EXPECT_EQ(lines[i].rfind(expected[i], 0), 0u) << "line " << i << ": " << lines[i];
  }
}

TEST(ConfigErrors, SourceNameStartsEveryLine) {
  Config c;
  Status s = ParseConfig("engine:\n  threads: 0\n  dimension: 5\n", "other.yml", &c);
  ASSERT_FALSE(s.ok());
  for (const std::string& line : Lines(s.message())) {
    EXPECT_EQ(line.rfind("other.yml:", 0), 0u) << line;
  }
}

TEST(ConfigErrors, EchoedValuesAreEscapedAndShortened) {
  std::string message = ParseError("dds:\n  topics:\n    events: \"a\\nb\\u0001\"\n");
  EXPECT_EQ(Lines(message).size(), 1u) << message;
  EXPECT_TRUE(Contains(message, "'a\\nb\\x01'")) << message;

  std::string long_name(200, 'x');
  message = ParseError("engine:\n  algorithm: " + long_name + "\n");
  EXPECT_TRUE(Contains(message, "'" + std::string(60, 'x') + "'...")) << message;
  EXPECT_FALSE(Contains(message, std::string(61, 'x'))) << message;
}

TEST(ConfigErrors, FailureLeavesTheOutputUnchanged) {
  Config c;
  c.source = "before";
  c.engine.threads = 7;
  ASSERT_FALSE(ParseConfig("engine:\n  threads: 300\n", kSource, &c).ok());
  EXPECT_EQ(c.source, "before");
  EXPECT_EQ(c.engine.threads, 7);
  EXPECT_EQ(ParseConfig("", kSource, nullptr).code(), StatusCode::kInvalidArgument);
}

TEST(ConfigValues, ThreadsAreAutoOrACount) {
  Config c = ParseOk("engine:\n  threads: auto\n");
  EXPECT_EQ(c.engine.threads, 0);
  // Auto is the CPUs this process may run on (its affinity mask: `taskset -c 0` gives 1).
  cpu_set_t set;
  CPU_ZERO(&set);
  ASSERT_EQ(sched_getaffinity(0, sizeof(set), &set), 0);
  EXPECT_EQ(EngineThreads(c.engine), std::min(CPU_COUNT(&set), 256));
  EXPECT_TRUE(Contains(ConfigToYaml(c), "\n  threads: auto\n")) << ConfigToYaml(c);
  c = ParseOk("engine:\n  threads: 3\n");
  EXPECT_EQ(c.engine.threads, 3);
  EXPECT_EQ(EngineThreads(c.engine), 3);
  EXPECT_TRUE(Contains(ConfigToYaml(c), "\n  threads: 3\n")) << ConfigToYaml(c);
  // A single-threaded engine warns about a count, not about auto.
  EXPECT_TRUE(ParseOk("engine:\n  algorithm: batch_sap\n  threads: auto\n").warnings.empty());
  EXPECT_EQ(ParseOk("engine:\n  algorithm: batch_sap\n  threads: 2\n").warnings.size(), 1u);
}

TEST(ConfigValues, EveryKeyIsReadIncludingTheBounds) {
  Config c = ParseOk(
      "engine:\n"
      "  algorithm: brute_force\n"
      "  dimension: 2\n"
      "  coordinate: int32\n"
      "  cell_size: auto\n"
      "  threads: +1\n"
      "  margin: -0.0\n"
      "dds:\n"
      "  domain: 232\n"
      "  cyclone_config: /etc/cyclone.xml\n"
      "  partition: \"world 1\"\n"
      "  topics: {updates: in/updates, events: OUT_2, status: s}\n"
      "  write_timeout_ms: 60000\n"
      "  event_history: 100000\n"
      "  update_queue: 1\n"
      "frames:\n"
      "  boundary: tick\n"
      "  tick_ms: 60000\n"
      "  keep_cpus_awake_ms: 60000\n"
      "limits:\n"
      "  max_batch_bytes: 64\n"
      "  max_batch_items: 1\n"
      "  max_objects: 18446744073709551615\n"
      "  max_pairs_per_event_batch: 1\n"
      "  max_rejections_reported: 0\n"
      "logging:\n"
      "  level: 'off'\n"
      "  summary_interval_s: 0\n"
      "  file: log/bp.log\n");
  EXPECT_TRUE(c.warnings.empty());
  EXPECT_EQ(c.engine.algorithm, "brute_force");
  EXPECT_EQ(c.engine.dimension, 2);
  EXPECT_EQ(c.engine.coordinate, CoordinateType::kInt32);
  EXPECT_FALSE(c.engine.cell_size.has_value());
  EXPECT_EQ(c.engine.threads, 1);
  EXPECT_EQ(c.engine.margin, 0.0);
  EXPECT_EQ(c.dds.domain, 232u);
  EXPECT_EQ(c.dds.cyclone_config, "/etc/cyclone.xml");
  EXPECT_EQ(c.dds.partition, "world 1");
  EXPECT_EQ(c.dds.topics, (TopicsConfig{"in/updates", "OUT_2", "s"}));
  EXPECT_EQ(c.dds.write_timeout_ms, 60000);
  EXPECT_EQ(c.dds.event_history, 100000);
  EXPECT_EQ(c.dds.update_queue, 1);
  EXPECT_EQ(c.frames.boundary, FrameBoundary::kTick);
  EXPECT_EQ(c.frames.tick_ms, 60000.0);
  EXPECT_EQ(c.frames.keep_cpus_awake_ms, 60000);
  EXPECT_EQ(c.limits.max_batch_bytes, 64u);
  EXPECT_EQ(c.limits.max_batch_items, 1u);
  EXPECT_EQ(c.limits.max_objects, std::numeric_limits<uint64_t>::max());
  EXPECT_EQ(c.limits.max_pairs_per_event_batch, 1u);
  EXPECT_EQ(c.limits.max_rejections_reported, 0u);
  EXPECT_EQ(c.logging.level, "off");
  EXPECT_EQ(c.logging.summary_interval_s, 0.0);
  EXPECT_EQ(c.logging.file, "log/bp.log");
}

TEST(ConfigValues, NumbersTakeTheUsualSpellings) {
  EXPECT_EQ(ParseOk("frames: {boundary: tick, tick_ms: 1e1}\n").frames.tick_ms, 10.0);
  EXPECT_EQ(ParseOk("frames: {boundary: tick, tick_ms: .5}\n").frames.tick_ms, 0.5);
  EXPECT_EQ(ParseOk("frames: {boundary: tick, tick_ms: +7}\n").frames.tick_ms, 7.0);
  EXPECT_EQ(ParseOk("engine: {cell_size: 2}\n").engine.cell_size, 2.0);
  EXPECT_EQ(ParseOk("engine: {cell_size: 'auto'}\n").engine.cell_size, std::nullopt);
}

// ---------------------------------------------------------------------------------------------
// Warnings: accepted, but noteworthy.

TEST(ConfigValues, MarginIsAcceptedByEveryEngine) {
  for (const char* algorithm : {"grid_segmented_sap", "brute_force", "dynamic_octree"}) {
    Config c = ParseOk(std::string("engine:\n  algorithm: ") + algorithm + "\n  margin: 0.25\n");
    EXPECT_TRUE(c.warnings.empty()) << algorithm;
    EXPECT_EQ(c.engine.margin, 0.25);
  }
  Config c = ParseOk("engine:\n  coordinate: int32\n  margin: 2\n");
  EXPECT_EQ(c.engine.margin, 2.0);
}

TEST(ConfigWarnings, CellSizeForANonGridEngine) {
  Config c = ParseOk("engine:\n  algorithm: segmented_sap\n  cell_size: 0.5\n");
  EXPECT_EQ(c.engine.cell_size, 0.5);
  ASSERT_EQ(c.warnings.size(), 1u);
  EXPECT_EQ(c.warnings[0],
            "cfg.yaml:3:14: engine.cell_size: ignored by engine 'segmented_sap' (grid engines "
            "only)");
  EXPECT_TRUE(ParseOk("engine:\n  cell_size: 0.5\n").warnings.empty());  // the grid's
  EXPECT_TRUE(ParseOk("engine:\n  cell_size: auto\n").warnings.empty());
}

TEST(ConfigWarnings, ThreadsForASingleThreadedEngine) {
  Config c = ParseOk("engine:\n  algorithm: brute_force\n  threads: 4\n");
  EXPECT_EQ(c.engine.threads, 4);
  ASSERT_EQ(c.warnings.size(), 1u);
  EXPECT_EQ(c.warnings[0],
            "cfg.yaml:3:12: engine.threads: engine 'brute_force' is single-threaded; threads = 4 "
            "has no effect");
  EXPECT_TRUE(ParseOk("engine:\n  threads: 2\n").warnings.empty());  // the grids' cells
}

TEST(ConfigWarnings, TickWithoutTickBoundary) {
  Config c = ParseOk("frames:\n  tick_ms: 10\n");
  EXPECT_EQ(c.frames.tick_ms, 10.0);
  ASSERT_EQ(c.warnings.size(), 1u);
  EXPECT_EQ(c.warnings[0],
            "cfg.yaml:2:12: frames.tick_ms: ignored while frames.boundary is end_of_frame (used "
            "only with tick)");
  EXPECT_TRUE(ParseOk("frames:\n  boundary: tick\n  tick_ms: 10\n").warnings.empty());
  // The default value spelled out (as in the shipped file) is no mistake.
  EXPECT_TRUE(ParseOk("frames:\n  tick_ms: 16.667\n").warnings.empty());
}

TEST(ConfigWarnings, AreInDocumentOrder) {
  Config c = ParseOk(
      "frames: {tick_ms: 5}\nengine: {threads: 2, cell_size: 1, algorithm: segmented_sap}\n");
  ASSERT_EQ(c.warnings.size(), 3u);
  EXPECT_EQ(c.warnings[0].rfind("cfg.yaml:1:19: frames.tick_ms", 0), 0u);
  EXPECT_EQ(c.warnings[1].rfind("cfg.yaml:2:19: engine.threads", 0), 0u);
  EXPECT_EQ(c.warnings[2].rfind("cfg.yaml:2:33: engine.cell_size", 0), 0u);
}

// ---------------------------------------------------------------------------------------------
// LoadConfigFile.

TEST(ConfigFile, RelativePathsResolveAgainstTheFilesDirectory) {
  TempDir tmp;
  ASSERT_FALSE(tmp.path().empty());
  std::filesystem::create_directory(tmp.path() / "etc");
  std::filesystem::path file = tmp.path() / "etc" / "bp.yaml";
  WriteFile(file,
            "dds:\n  cyclone_config: dds/lan.xml\nlogging:\n  file: ../log/bp.log\n"
            "  frame_log: frames.csv\n");
  Config c;
  Status s = LoadConfigFile(file.string(), &c);
  ASSERT_TRUE(s.ok()) << s.ToString();
  EXPECT_EQ(c.source, file.string());
  EXPECT_EQ(c.dds.cyclone_config, (tmp.path() / "etc" / "dds/lan.xml").string());
  EXPECT_EQ(c.logging.file, (tmp.path() / "etc" / "../log/bp.log").string());
  EXPECT_EQ(c.logging.frame_log, (tmp.path() / "etc" / "frames.csv").string());

  // The default (relative) cyclone_config resolves too; absolute paths and "" stay.
  WriteFile(file, "logging:\n  file: /var/log/bp.log\n");
  ASSERT_TRUE(LoadConfigFile(file.string(), &c).ok());
  EXPECT_EQ(c.dds.cyclone_config, (tmp.path() / "etc" / "cyclonedds-loopback.xml").string());
  EXPECT_EQ(c.logging.file, "/var/log/bp.log");
  WriteFile(file, "dds:\n  cyclone_config: \"\"\n");
  ASSERT_TRUE(LoadConfigFile(file.string(), &c).ok());
  EXPECT_EQ(c.dds.cyclone_config, "");
  EXPECT_EQ(c.logging.file, "");
}

TEST(ConfigFile, ErrorsNameTheFileWithLineAndColumn) {
  TempDir tmp;
  std::filesystem::path file = tmp.path() / "bad.yaml";
  WriteFile(file, "# comment\nengine:\n  threads: 0\n");
  Config c;
  Status s = LoadConfigFile(file.string(), &c);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(s.message(), file.string() + ":3:12: engine.threads: must be between 1 and 256, got 0");
}

TEST(ConfigFile, MissingFileIsNotFoundAndNamesThePath) {
  TempDir tmp;
  std::string path = (tmp.path() / "absent.yaml").string();
  Config c;
  Status s = LoadConfigFile(path, &c);
  EXPECT_EQ(s.code(), StatusCode::kNotFound);
  EXPECT_TRUE(Contains(s.message(), "'" + path + "'")) << s.message();
  EXPECT_TRUE(Contains(s.message(), "No such file")) << s.message();
}

TEST(ConfigFile, DirectoryAndHugeFileAreInvalidArguments) {
  TempDir tmp;
  Config c;
  Status s = LoadConfigFile(tmp.path().string(), &c);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(s.message(), tmp.path().string())) << s.message();

  std::filesystem::path big = tmp.path() / "big.yaml";
  WriteFile(big, std::string((1u << 20) + 1, '#'));
  s = LoadConfigFile(big.string(), &c);
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(s.message(), "larger than")) << s.message();
}

// ---------------------------------------------------------------------------------------------
// ConfigToYaml and the names.

TEST(ConfigToYamlTest, RoundTripsANonDefaultConfig) {
  Config c;
  c.engine.algorithm = "brute_force";
  c.engine.dimension = 2;
  c.engine.coordinate = CoordinateType::kDouble;
  c.engine.cell_size = 0.1 + 0.2;  // 0.30000000000000004: needs all 17 digits
  c.engine.threads = 3;
  c.dds.domain = 17;
  c.dds.cyclone_config = "/opt/my dds/cyclone: \"lan\".xml";
  c.dds.partition = "world #1 \\ 'quoted' \t tab, ünïcode";
  c.dds.topics = {"a/updates", "B_events", "null", "req_4"};
  c.dds.write_timeout_ms = 250;
  c.dds.event_history = 1000;
  c.dds.update_queue = 4096;
  c.frames.boundary = FrameBoundary::kTick;
  c.frames.tick_ms = 1.0 / 3.0;
  c.limits = {1u << 10, 12345, std::numeric_limits<uint64_t>::max(), 7, 0, 0};
  c.logging.level = "trace";
  c.logging.summary_interval_s = 1e-3;
  c.logging.file = "null";
  c.logging.frame_log = "/tmp/frames: a.csv";
  c.producers.lease_s = 0.25;

  std::string yaml = ConfigToYaml(c);
  Config back = ParseOk(yaml);
  ExpectSameSettings(back, c);
  EXPECT_EQ(back.warnings.size(), 2u) << yaml;  // cell_size and threads, as for any such file

  Config defaults = ParseOk(ConfigToYaml(Config()));
  ExpectSameSettings(defaults, Config());
  EXPECT_TRUE(defaults.warnings.empty());
}

TEST(ConfigToYamlTest, WritesEveryKeyPlainWhereUnambiguous) {
  std::string yaml = ConfigToYaml(Config());
  for (const char* line :
       {"engine:\n", "  algorithm: grid_dense\n", "  cell_size: auto\n", "  margin: 0.0\n",
        "  partition: \"\"\n", "  topics:\n", "    events: bp_events\n", "  tick_ms: 16.667\n",
        "  keep_cpus_awake_ms: 0\n", "  max_batch_bytes: 67108864\n", "  summary_interval_s: 5.0\n",
        "  file: \"\"\n", "producers:\n", "  lease_s: 10.0\n"}) {
    EXPECT_TRUE(Contains(yaml, line)) << line << "---\n" << yaml;
  }
  EXPECT_EQ(Lines(yaml).size(), 45u) << yaml;  // 7 sections + topics + 37 keys
}

TEST(ConfigNames, AreCanonical) {
  EXPECT_EQ(CoordinateTypeName(CoordinateType::kFloat), "float");
  EXPECT_EQ(CoordinateTypeName(CoordinateType::kDouble), "double");
  EXPECT_EQ(CoordinateTypeName(CoordinateType::kInt32), "int32");
  EXPECT_EQ(FrameBoundaryName(FrameBoundary::kEndOfFrame), "end_of_frame");
  EXPECT_EQ(FrameBoundaryName(FrameBoundary::kTick), "tick");
  for (CoordinateType t :
       {CoordinateType::kFloat, CoordinateType::kDouble, CoordinateType::kInt32}) {
    Config c = ParseOk("engine:\n  coordinate: " + std::string(CoordinateTypeName(t)) + "\n");
    EXPECT_EQ(c.engine.coordinate, t);
  }
}

}  // namespace
}  // namespace bp::service

namespace bp::service {
namespace {

// Without --config: $BP_CONFIG, then ./config/broadphased.yaml, then next to the executable.
TEST(ConfigDefault, EnvironmentThenWorkingDirectoryThenNextToTheBinary) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("bp-config-default-" + std::to_string(getpid()));
  fs::create_directories(dir);
  const fs::path mine = dir / "mine.yaml";
  std::ofstream(mine) << "dds:\n  domain: 7\n";
  const fs::path cwd = fs::current_path();
  setenv("BP_CONFIG", mine.c_str(), 1);
  Config config;
  ASSERT_TRUE(LoadConfigOrDefault("", &config).ok());
  EXPECT_EQ(config.dds.domain, 7u);
  EXPECT_EQ(FindDefaultConfig(), mine.string());
  unsetenv("BP_CONFIG");
  fs::current_path(dir);  // no config/ here: the one above the test binary (the source tree's)
  const std::string found = FindDefaultConfig();
  fs::current_path(cwd);
  EXPECT_NE(found.find("config/broadphased.yaml"), std::string::npos) << found;
  EXPECT_TRUE(fs::path(found).is_absolute()) << found;
  // An explicit path wins, and a missing one is an error naming it.
  Status s = LoadConfigOrDefault((dir / "missing.yaml").string(), &config);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("missing.yaml"), std::string::npos);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace bp::service
