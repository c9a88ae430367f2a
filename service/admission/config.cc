#include "config.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <system_error>
#include <thread>
#include <utility>

#include "yaml_reader.h"
#include <sched.h>
#include <yaml-cpp/yaml.h>

namespace bp::service {
namespace {

using detail::Field;
using detail::NumberRange;
using detail::YamlReader;

constexpr std::array<std::string_view, 7> kSections{"engine",  "dds",       "frames", "limits",
                                                    "logging", "producers", "shards"};
constexpr std::array<std::string_view, 6> kEngineKeys{"algorithm", "dimension", "coordinate",
                                                      "cell_size", "threads",   "margin"};
constexpr std::array<std::string_view, 7> kDdsKeys{
    "domain",           "cyclone_config", "partition",   "topics",
    "write_timeout_ms", "event_history",  "update_queue"};
constexpr std::array<std::string_view, 6> kTopicKeys{"updates",  "events",    "status",
                                                     "requests", "interests", "replies"};
constexpr std::array<std::string_view, 3> kFramesKeys{"boundary", "tick_ms", "keep_cpus_awake_ms"};
constexpr std::array<std::string_view, 9> kLimitsKeys{
    "max_batch_bytes",         "max_batch_items",      "max_objects",   "max_pairs_per_event_batch",
    "max_rejections_reported", "snapshot_interval_ms", "max_interests", "max_interest_regions",
    "max_interest_keys"};
constexpr std::array<std::string_view, 4> kLoggingKeys{"level", "summary_interval_s", "file",
                                                       "frame_log"};
constexpr std::array<std::string_view, 1> kProducersKeys{"lease_s"};
constexpr std::array<std::string_view, 2> kShardsKeys{"map", "self"};

// Indexed by the enums' values.
constexpr std::array<std::string_view, 3> kCoordinateNames{"float", "double", "int32"};
constexpr std::array<std::string_view, 2> kBoundaryNames{"end_of_frame", "tick"};

constexpr uint32_t kMaxDomain = 232;
constexpr int kMaxThreads = 256;
constexpr int kMaxWriteTimeoutMs = 60000;
constexpr int kMaxQueueDepth = 100000;
constexpr double kMaxTickMs = 60000;
constexpr int kMaxKeepAwakeMs = 60000;
constexpr double kMaxSummaryIntervalS = 86400;
constexpr double kMaxLeaseS = 86400;
constexpr uint64_t kMinBatchBytes = 64;
// protobuf parses and serialises at most 2 GiB - 1 bytes per message.
constexpr uint64_t kMaxBatchBytes = (uint64_t{1} << 31) - 1;
// 2^26 pairs of two fixed64 keys: 1 GiB per event part, well under protobuf's 2 GiB.
constexpr uint64_t kMaxPairsPerEventBatch = uint64_t{1} << 26;
constexpr uint64_t kMaxInterests = 100000;
constexpr uint64_t kMaxInterestRegions = 65536;
constexpr uint64_t kMaxInterestKeys = uint64_t{1} << 24;
constexpr uint64_t kU64Max = std::numeric_limits<uint64_t>::max();
// A configuration file is a few kilobytes; refuse to slurp a device or a huge file by mistake.
constexpr size_t kMaxConfigFileBytes = 1u << 20;

// Engines that partition space into cells.
bool IsGridAlgorithm(std::string_view algorithm) { return algorithm.starts_with("grid_"); }
// Engines whose Query runs on more than one thread: the grids apply their cells in parallel.
bool IsMultiThreaded(std::string_view algorithm) { return IsGridAlgorithm(algorithm); }

void ReadEngine(YamlReader& r, const Field& section, EngineConfig* e) {
  r.ReadMapping(section, kEngineKeys, [&](std::string_view name, const Field& v) {
    size_t index = 0;
    if (name == "algorithm") {
      if (r.ReadChoice(v, kAlgorithms, "algorithm", &index)) e->algorithm = kAlgorithms[index];
    } else if (name == "dimension") {
      r.ReadInt(v, 2, 3, &e->dimension);
    } else if (name == "coordinate") {
      if (r.ReadChoice(v, kCoordinateNames, "coordinate type", &index)) {
        e->coordinate = static_cast<CoordinateType>(index);
      }
    } else if (name == "cell_size") {
      if (v.node.IsScalar() && v.node.Scalar() == "auto") {
        e->cell_size.reset();
      } else {
        double size = 0;
        NumberRange positive{.min = 0, .min_inclusive = false};
        if (r.ReadNumber(v, positive, &size, "'auto'")) e->cell_size = size;
      }
    } else if (name == "threads") {
      if (v.node.IsScalar() && v.node.Scalar() == "auto") {
        e->threads = 0;
      } else {
        r.ReadInt(v, 1, kMaxThreads, &e->threads, "'auto'");
      }
    } else if (name == "margin") {
      r.ReadNumber(v, NumberRange{.min = 0}, &e->margin);
    }
  });
}

// DDS topic names: letters, digits, '_' and '/' (a subset of what DDS allows, safe everywhere).
void ReadTopicName(YamlReader& r, const Field& v, std::string* out) {
  std::string name;
  if (!r.ReadString(v, &name)) return;
  if (name.empty()) {
    r.Error(v, "a topic name must not be empty");
    return;
  }
  for (char c : name) {
    bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
              c == '_' || c == '/';
    if (!ok) {
      r.Error(v, "topic name " + YamlReader::Quote(name) +
                     " has a character outside [A-Za-z0-9_/]: " +
                     YamlReader::Quote(std::string_view(&c, 1)));
      return;
    }
  }
  *out = std::move(name);
}

void ReadDds(YamlReader& r, const Field& section, DdsConfig* d) {
  r.ReadMapping(section, kDdsKeys, [&](std::string_view name, const Field& v) {
    if (name == "domain") {
      r.ReadInt(v, uint32_t{0}, kMaxDomain, &d->domain);
    } else if (name == "cyclone_config") {
      r.ReadString(v, &d->cyclone_config);
    } else if (name == "partition") {
      r.ReadString(v, &d->partition);
    } else if (name == "topics") {
      r.ReadMapping(v, kTopicKeys, [&](std::string_view topic, const Field& t) {
        if (topic == "updates") ReadTopicName(r, t, &d->topics.updates);
        if (topic == "events") ReadTopicName(r, t, &d->topics.events);
        if (topic == "status") ReadTopicName(r, t, &d->topics.status);
        if (topic == "requests") ReadTopicName(r, t, &d->topics.requests);
        if (topic == "interests") ReadTopicName(r, t, &d->topics.interests);
        if (topic == "replies") ReadTopicName(r, t, &d->topics.replies);
      });
    } else if (name == "write_timeout_ms") {
      r.ReadInt(v, 1, kMaxWriteTimeoutMs, &d->write_timeout_ms);
    } else if (name == "event_history") {
      r.ReadInt(v, 1, kMaxQueueDepth, &d->event_history);
    } else if (name == "update_queue") {
      r.ReadInt(v, 1, kMaxQueueDepth, &d->update_queue);
    }
  });
}

void ReadFrames(YamlReader& r, const Field& section, FramesConfig* f) {
  r.ReadMapping(section, kFramesKeys, [&](std::string_view name, const Field& v) {
    if (name == "boundary") {
      size_t index = 0;
      if (r.ReadChoice(v, kBoundaryNames, "frame boundary", &index)) {
        f->boundary = static_cast<FrameBoundary>(index);
      }
    } else if (name == "tick_ms") {
      r.ReadNumber(v, NumberRange{.min = 0, .min_inclusive = false, .max = kMaxTickMs},
                   &f->tick_ms);
    } else if (name == "keep_cpus_awake_ms") {
      r.ReadInt(v, 0, kMaxKeepAwakeMs, &f->keep_cpus_awake_ms);
    }
  });
}

void ReadLimits(YamlReader& r, const Field& section, LimitsConfig* l) {
  r.ReadMapping(section, kLimitsKeys, [&](std::string_view name, const Field& v) {
    if (name == "max_batch_bytes") {
      r.ReadUint64(v, kMinBatchBytes, kMaxBatchBytes, &l->max_batch_bytes);
    } else if (name == "max_batch_items") {
      r.ReadUint64(v, 1, kU64Max, &l->max_batch_items);
    } else if (name == "max_objects") {
      r.ReadUint64(v, 1, kU64Max, &l->max_objects);
    } else if (name == "max_pairs_per_event_batch") {
      r.ReadUint64(v, 1, kMaxPairsPerEventBatch, &l->max_pairs_per_event_batch);
    } else if (name == "max_rejections_reported") {
      r.ReadUint64(v, 0, kU64Max, &l->max_rejections_reported);
    } else if (name == "snapshot_interval_ms") {
      r.ReadInt(v, 0, kMaxWriteTimeoutMs, &l->snapshot_interval_ms);
    } else if (name == "max_interests") {
      r.ReadUint64(v, 0, kMaxInterests, &l->max_interests);
    } else if (name == "max_interest_regions") {
      r.ReadUint64(v, 1, kMaxInterestRegions, &l->max_interest_regions);
    } else if (name == "max_interest_keys") {
      r.ReadUint64(v, 1, kMaxInterestKeys, &l->max_interest_keys);
    }
  });
}

void ReadLogging(YamlReader& r, const Field& section, LoggingConfig* l) {
  r.ReadMapping(section, kLoggingKeys, [&](std::string_view name, const Field& v) {
    if (name == "level") {
      size_t index = 0;
      if (r.ReadChoice(v, kLogLevels, "log level", &index)) l->level = kLogLevels[index];
    } else if (name == "summary_interval_s") {
      r.ReadNumber(v, NumberRange{.min = 0, .max = kMaxSummaryIntervalS}, &l->summary_interval_s);
    } else if (name == "file") {
      r.ReadString(v, &l->file);
    } else if (name == "frame_log") {
      r.ReadString(v, &l->frame_log);
    }
  });
}

void ReadProducers(YamlReader& r, const Field& section, ProducersConfig* p) {
  r.ReadMapping(section, kProducersKeys, [&](std::string_view name, const Field& v) {
    if (name == "lease_s") r.ReadNumber(v, NumberRange{.min = 0, .max = kMaxLeaseS}, &p->lease_s);
  });
}

void ReadShards(YamlReader& r, const Field& section, ShardsConfig* s) {
  r.ReadMapping(section, kShardsKeys, [&](std::string_view name, const Field& v) {
    if (name == "map") r.ReadString(v, &s->map);
    if (name == "self") r.ReadString(v, &s->self);
  });
}

// Checks that involve more than one key, on the values as read (defaults where absent).
void CheckCrossKeys(YamlReader& r, Config* c) {
  const EngineConfig& e = c->engine;
  auto margin_mark = r.MarkOf("engine.margin");
  // An algorithm that failed to read leaves the default in place; do not judge other keys by it,
  // except where every algorithm agrees.
  if (!r.HasError("engine.algorithm")) {
    std::string quoted = YamlReader::Quote(e.algorithm);
    auto cell_mark = r.MarkOf("engine.cell_size");
    if (e.cell_size && cell_mark && !IsGridAlgorithm(e.algorithm)) {
      r.Warning(*cell_mark, "engine.cell_size",
                "ignored by engine " + quoted + " (grid engines only)");
    }
    auto threads_mark = r.MarkOf("engine.threads");
    if (e.threads > 1 && threads_mark && !IsMultiThreaded(e.algorithm)) {
      r.Warning(*threads_mark, "engine.threads",
                "engine " + quoted + " is single-threaded; threads = " + std::to_string(e.threads) +
                    " has no effect");
    }
  }
  // Every engine keeps fattened boxes through the shared front end; an integer engine needs an
  // integral margin.
  if (margin_mark && e.coordinate == CoordinateType::kFloat && !r.HasError("engine.coordinate") &&
      e.margin > static_cast<double>(std::numeric_limits<float>::max())) {
    r.Error(*margin_mark, "engine.margin",
            "float coordinates need a margin within the float range; got " +
                YamlReader::FormatNumber(e.margin));
  }
  if (margin_mark && e.coordinate == CoordinateType::kInt32 && !r.HasError("engine.coordinate") &&
      (std::trunc(e.margin) != e.margin || e.margin > 2147483647.0)) {
    r.Error(*margin_mark, "engine.margin",
            "int32 coordinates need an integral margin below 2^31; got " +
                YamlReader::FormatNumber(e.margin));
  }
  // A shard routes boxes as they are: a fattened box could overlap a block its box does not.
  if (!c->shards.map.empty() && e.margin != 0 && margin_mark) {
    r.Error(*margin_mark, "engine.margin",
            "a shard (shards.map is set) needs margin 0: producers route the boxes as sent");
  }
  if (auto boundary_mark = r.MarkOf("frames.boundary");
      boundary_mark && !c->shards.map.empty() && c->frames.boundary == FrameBoundary::kTick) {
    r.Error(*boundary_mark, "frames.boundary",
            "a shard (shards.map is set) closes frames on end_of_frame: the merge aligns shards "
            "by the producer's frame numbers");
  }
  if (auto self_mark = r.MarkOf("shards.self");
      self_mark && c->shards.map.empty() && !c->shards.self.empty()) {
    r.Error(*self_mark, "shards.self", "needs shards.map (the shard map it names a shard of)");
  }
  // The shipped file spells out every default, tick_ms included; only a changed value means the
  // author expected ticks.
  auto tick_mark = r.MarkOf("frames.tick_ms");
  if (c->frames.boundary == FrameBoundary::kEndOfFrame && tick_mark &&
      c->frames.tick_ms != FramesConfig().tick_ms && !r.HasError("frames.boundary")) {
    r.Warning(*tick_mark, "frames.tick_ms",
              "ignored while frames.boundary is end_of_frame (used only with tick)");
  }
  const std::array<std::pair<std::string, const std::string*>, 6> topics{{
      {"dds.topics.updates", &c->dds.topics.updates},
      {"dds.topics.events", &c->dds.topics.events},
      {"dds.topics.status", &c->dds.topics.status},
      {"dds.topics.requests", &c->dds.topics.requests},
      {"dds.topics.interests", &c->dds.topics.interests},
      {"dds.topics.replies", &c->dds.topics.replies},
  }};
  for (size_t j = 1; j < topics.size(); ++j) {
    for (size_t i = 0; i < j; ++i) {
      if (*topics[i].second != *topics[j].second) continue;
      // Point at the one that was written (the later one when both were).
      bool j_written = r.MarkOf(topics[j].first).has_value();
      const auto& [path, other] = j_written ? topics[j] : topics[i];
      const std::string& other_path = j_written ? topics[i].first : topics[j].first;
      r.Error(r.MarkOf(path).value_or(YAML::Mark::null_mark()), path,
              "topic name " + YamlReader::Quote(*other) + " is also used by " + other_path +
                  "; the topics must differ");
      break;
    }
  }
}

// Relative paths in a file's configuration mean "next to that file".
void ResolveAgainst(const std::filesystem::path& dir, std::string* path) {
  if (path->empty() || dir.empty()) return;
  std::filesystem::path p(*path);
  if (p.is_relative()) *path = (dir / p).string();
}

std::string FormatNumber(double value) {
  std::string text = YamlReader::FormatNumber(value);
  // "5" would read back the same, but "5.0" tells a reader the key is not an integer.
  if (text.find_first_of(".eEni") == std::string::npos) text += ".0";
  return text;
}

// A string as a YAML scalar: plain when that is unambiguous, else double-quoted and escaped.
std::string YamlString(std::string_view text) {
  bool plain = !text.empty() && text != "null" && text != "Null" && text != "NULL";
  for (size_t i = 0; plain && i < text.size(); ++i) {
    char c = text[i];
    bool letter = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' || c == '/';
    bool other = (c >= '0' && c <= '9') || c == '.' || c == '-';
    plain = letter || (i > 0 && other);
  }
  if (plain) return std::string(text);
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out = "\"";
  for (char c : text) {
    auto byte = static_cast<unsigned char>(c);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (byte < 0x20u || byte == 0x7Fu) {
      out += "\\x";
      out += kHex[byte >> 4];
      out += kHex[byte & 0xFu];
    } else {
      out += c;
    }
  }
  out += '"';
  return out;
}

}  // namespace

int EngineThreads(const EngineConfig& engine) {
  if (engine.threads > 0) return engine.threads;
  int cpus = 0;
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) cpus = CPU_COUNT(&set);
  if (cpus <= 0) cpus = static_cast<int>(std::thread::hardware_concurrency());
  return std::clamp(cpus, 1, kMaxThreads);
}

std::string_view CoordinateTypeName(CoordinateType type) {
  auto index = static_cast<size_t>(type);
  return index < kCoordinateNames.size() ? kCoordinateNames[index] : "unknown";
}

std::string_view FrameBoundaryName(FrameBoundary boundary) {
  auto index = static_cast<size_t>(boundary);
  return index < kBoundaryNames.size() ? kBoundaryNames[index] : "unknown";
}

Status ParseConfig(std::string_view yaml_text, std::string_view source, Config* out) {
  if (out == nullptr) return Status(StatusCode::kInvalidArgument, "ParseConfig: out is null");
  YamlReader r(source);
  Config config;
  try {
    std::vector<YAML::Node> documents = YAML::LoadAll(std::string(yaml_text));
    if (documents.size() > 1) {
      r.Error(documents[1].Mark(), "",
              "only one YAML document is allowed, found " + std::to_string(documents.size()));
    }
    if (!documents.empty()) {
      Field root{"", documents[0], documents[0].Mark()};
      r.ReadMapping(root, kSections, [&](std::string_view name, const Field& section) {
        if (name == "engine") ReadEngine(r, section, &config.engine);
        if (name == "dds") ReadDds(r, section, &config.dds);
        if (name == "frames") ReadFrames(r, section, &config.frames);
        if (name == "limits") ReadLimits(r, section, &config.limits);
        if (name == "logging") ReadLogging(r, section, &config.logging);
        if (name == "producers") ReadProducers(r, section, &config.producers);
        if (name == "shards") ReadShards(r, section, &config.shards);
      });
      CheckCrossKeys(r, &config);
    }
  } catch (const YAML::Exception& e) {
    r.Error(e.mark, "YAML syntax error", e.msg);
  } catch (const std::exception& e) {
    r.Error(YAML::Mark::null_mark(), "(document)", std::string("cannot be read: ") + e.what());
  }
  if (r.failed()) {
    std::string message;
    for (const std::string& line : r.errors()) {
      if (!message.empty()) message += '\n';
      message += line;
    }
    return Status(StatusCode::kInvalidArgument, std::move(message));
  }
  config.source = std::string(source);
  config.warnings = r.warnings();
  *out = std::move(config);
  return Status::Ok();
}

Status LoadConfigFile(const std::string& path, Config* out) {
  if (out == nullptr) return Status(StatusCode::kInvalidArgument, "LoadConfigFile: out is null");
  auto io_error = [&](int error, std::string_view what) {
    return Status(error == ENOENT ? StatusCode::kNotFound : StatusCode::kInvalidArgument,
                  "config file '" + path + "': " + std::string(what) +
                      std::generic_category().message(error));
  };
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"),
                                                       &std::fclose);
  if (!file) return io_error(errno, "cannot open: ");
  std::string text;
  char buffer[16384];
  while (text.size() <= kMaxConfigFileBytes) {
    size_t n = std::fread(buffer, 1, sizeof(buffer), file.get());
    if (n < sizeof(buffer) && std::ferror(file.get())) return io_error(errno, "cannot read: ");
    text.append(buffer, n);
    if (n < sizeof(buffer)) break;
  }
  if (text.size() > kMaxConfigFileBytes) {
    return Status(StatusCode::kInvalidArgument, "config file '" + path + "': larger than " +
                                                    std::to_string(kMaxConfigFileBytes) +
                                                    " bytes; not a configuration file?");
  }
  Config config;
  Status status = ParseConfig(text, path, &config);
  if (!status.ok()) return status;
  std::filesystem::path dir = std::filesystem::path(path).parent_path();
  ResolveAgainst(dir, &config.dds.cyclone_config);
  ResolveAgainst(dir, &config.logging.file);
  ResolveAgainst(dir, &config.logging.frame_log);
  ResolveAgainst(dir, &config.shards.map);
  *out = std::move(config);
  return Status::Ok();
}

std::string ConfigToYaml(const Config& c) {
  std::string y;
  auto line = [&y](std::string_view indent, std::string_view key, std::string_view value) {
    y.append(indent).append(key).append(": ").append(value).append("\n");
  };
  const std::string_view k1 = "  ";
  const std::string_view k2 = "    ";
  y += "engine:\n";
  line(k1, "algorithm", YamlString(c.engine.algorithm));
  line(k1, "dimension", std::to_string(c.engine.dimension));
  line(k1, "coordinate", CoordinateTypeName(c.engine.coordinate));
  line(k1, "cell_size", c.engine.cell_size ? FormatNumber(*c.engine.cell_size) : "auto");
  line(k1, "threads", c.engine.threads == 0 ? "auto" : std::to_string(c.engine.threads));
  line(k1, "margin", FormatNumber(c.engine.margin));
  y += "dds:\n";
  line(k1, "domain", std::to_string(c.dds.domain));
  line(k1, "cyclone_config", YamlString(c.dds.cyclone_config));
  line(k1, "partition", YamlString(c.dds.partition));
  y += "  topics:\n";
  line(k2, "updates", YamlString(c.dds.topics.updates));
  line(k2, "events", YamlString(c.dds.topics.events));
  line(k2, "status", YamlString(c.dds.topics.status));
  line(k2, "requests", YamlString(c.dds.topics.requests));
  line(k2, "interests", YamlString(c.dds.topics.interests));
  line(k2, "replies", YamlString(c.dds.topics.replies));
  line(k1, "write_timeout_ms", std::to_string(c.dds.write_timeout_ms));
  line(k1, "event_history", std::to_string(c.dds.event_history));
  line(k1, "update_queue", std::to_string(c.dds.update_queue));
  y += "frames:\n";
  line(k1, "boundary", FrameBoundaryName(c.frames.boundary));
  line(k1, "tick_ms", FormatNumber(c.frames.tick_ms));
  line(k1, "keep_cpus_awake_ms", std::to_string(c.frames.keep_cpus_awake_ms));
  y += "limits:\n";
  line(k1, "max_batch_bytes", std::to_string(c.limits.max_batch_bytes));
  line(k1, "max_batch_items", std::to_string(c.limits.max_batch_items));
  line(k1, "max_objects", std::to_string(c.limits.max_objects));
  line(k1, "max_pairs_per_event_batch", std::to_string(c.limits.max_pairs_per_event_batch));
  line(k1, "max_rejections_reported", std::to_string(c.limits.max_rejections_reported));
  line(k1, "snapshot_interval_ms", std::to_string(c.limits.snapshot_interval_ms));
  line(k1, "max_interests", std::to_string(c.limits.max_interests));
  line(k1, "max_interest_regions", std::to_string(c.limits.max_interest_regions));
  line(k1, "max_interest_keys", std::to_string(c.limits.max_interest_keys));
  y += "logging:\n";
  line(k1, "level", YamlString(c.logging.level));
  line(k1, "summary_interval_s", FormatNumber(c.logging.summary_interval_s));
  line(k1, "file", YamlString(c.logging.file));
  line(k1, "frame_log", YamlString(c.logging.frame_log));
  y += "producers:\n";
  line(k1, "lease_s", FormatNumber(c.producers.lease_s));
  y += "shards:\n";
  line(k1, "map", YamlString(c.shards.map));
  line(k1, "self", YamlString(c.shards.self));
  return y;
}

}  // namespace bp::service

namespace bp::service {

std::string FindDefaultConfig() {
  namespace fs = std::filesystem;
  if (const char* env = std::getenv("BP_CONFIG"); env != nullptr && *env != '\0') return env;
  std::error_code ignored;  // a missing candidate is not an error
  if (fs::is_regular_file("config/broadphased.yaml", ignored)) return "config/broadphased.yaml";
  std::error_code ec;
  fs::path dir = fs::read_symlink("/proc/self/exe", ec).parent_path();
  if (ec) return "";
  for (int up = 0; up < 5 && !dir.empty(); ++up) {
    for (const char* candidate :
         {"config/broadphased.yaml", "share/broadphase/config/broadphased.yaml"}) {
      if (fs::is_regular_file(dir / candidate, ignored)) return (dir / candidate).string();
    }
    if (dir == dir.parent_path()) break;
    dir = dir.parent_path();
  }
  return "";
}

Status LoadConfigOrDefault(const std::string& path, Config* out) {
  const std::string chosen = path.empty() ? FindDefaultConfig() : path;
  if (!chosen.empty()) return LoadConfigFile(chosen, out);
  Status s = ParseConfig("", "<built-in defaults>", out);
  if (!s.ok()) return s;
  out->dds.cyclone_config.clear();
  out->warnings.push_back(
      "no configuration file found (--config, $BP_CONFIG, config/broadphased.yaml): built-in "
      "defaults with Cyclone's default network configuration");
  return Status::Ok();
}

}  // namespace bp::service
