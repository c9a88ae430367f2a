// bp::service::Config: the configuration of the daemon `broadphased`, read from YAML
// (`broadphased --config config/broadphased.yaml`; the shipped file lists every key with its
// default). ParseConfig validates the whole document and reports every problem at once, one line
// each with its position and dotted key; it never throws (yaml-cpp's exceptions are caught).
//
// Thread safety: the functions are reentrant (no shared state); a Config is a plain value.
// Invariants of a Config returned by ParseConfig or LoadConfigFile:
//  1. Every member is within the range written beside it; engine.algorithm is in kAlgorithms;
//     logging.level is in kLogLevels; topic names are non-empty, of [A-Za-z0-9_/] only, and differ.
//  2. engine.margin is integral (and below 2^31) when engine.coordinate is int32.
//  3. `warnings` lists accepted but ineffective settings, one line each, in the errors' format.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "bp/status.h"

namespace bp::service {

/// When the daemon closes a frame (queries the engine and publishes its events).
enum class FrameBoundary {
  kEndOfFrame,  ///< when an update batch marked end-of-frame arrives
  kTick,        ///< every frames.tick_ms milliseconds
};

/// The coordinate type of the engine's boxes.
enum class CoordinateType { kFloat, kDouble, kInt32 };

/// Engine algorithm names the daemon can build: bp::kEngineAlgorithms (bp/engines.h, checked
/// in engine_host.cc), spelled here so that the config does not include the engines.
inline constexpr std::array<std::string_view, 7> kAlgorithms{
    "brute_force",        "segmented_sap",  "batch_sap", "dynamic_octree",
    "grid_segmented_sap", "grid_batch_sap", "grid_dense"};

/// Valid values of logging.level, most verbose first.
inline constexpr std::array<std::string_view, 7> kLogLevels{"trace", "debug",    "info", "warn",
                                                            "error", "critical", "off"};

/// The `engine` section: which broadphase the daemon runs.
struct EngineConfig {
  std::string algorithm = "grid_dense";                ///< one of kAlgorithms
  int dimension = 3;                                   ///< 2 or 3
  CoordinateType coordinate = CoordinateType::kFloat;  ///< yaml: float | double | int32
  std::optional<double> cell_size;  ///< yaml: "auto" (nullopt, default) or a positive finite number
  int threads = 0;                  ///< yaml: "auto" (0, default: EngineThreads) or 1..256
  double margin = 0.0;  ///< >= 0, finite; > 0 fattens boxes (events are then approximate)

  /// Member-wise equality.
  bool operator==(const EngineConfig&) const = default;
};

/// The DDS topic names (`dds.topics`).
struct TopicsConfig {
  std::string updates = "bp_updates";      ///< update batches in
  std::string events = "bp_events";        ///< event batches out
  std::string status = "bp_status";        ///< daemon status out
  std::string requests = "bp_requests";    ///< snapshot requests in
  std::string interests = "bp_interests";  ///< interest declarations and spot queries in
  std::string replies = "bp_replies";      ///< spot-query answers out

  /// Member-wise equality.
  bool operator==(const TopicsConfig&) const = default;
};

/// The `dds` section: Cyclone DDS domain, configuration and QoS sizes.
struct DdsConfig {
  uint32_t domain = 0;  ///< 0..232 (Cyclone's valid domain ids)
  /// Path to Cyclone XML; relative paths are resolved against the YAML file's directory by
  /// LoadConfigFile; "" = Cyclone's own default (CYCLONEDDS_URI).
  std::string cyclone_config = "cyclonedds-loopback.xml";
  std::string partition;       ///< "" = default partition
  TopicsConfig topics;         ///< non-empty, DDS topic-name characters only [A-Za-z0-9_/]
  int write_timeout_ms = 100;  ///< 1..60000: max blocking time of dds_write
  int event_history = 64;      ///< 1..100000: KEEP_LAST depth of the events writer
  int update_queue = 32;       ///< 1..100000: resource limit (max samples) of the updates reader

  /// Member-wise equality.
  bool operator==(const DdsConfig&) const = default;
};

/// The `frames` section: when frames close.
struct FramesConfig {
  FrameBoundary boundary = FrameBoundary::kEndOfFrame;  ///< yaml: end_of_frame | tick
  double tick_ms = 16.667;  ///< > 0, <= 60000; used when boundary is tick
  /// 0 .. 60000 ms; 0 = off. Otherwise, after each update batch the daemon keeps every CPU it may
  /// run on from idling for this long, with spinning threads of the lowest class (SCHED_IDLE,
  /// service/keep_awake.h): lower latency on virtual machines whose idle CPUs wake slowly, for
  /// CPUs that read 100% busy while frames flow.
  int keep_cpus_awake_ms = 0;

  /// Member-wise equality.
  bool operator==(const FramesConfig&) const = default;
};

/// The `limits` section: bounds on untrusted input and on output sizes.
struct LimitsConfig {
  /// 64 .. 2^31-1; an update batch payload larger than this is rejected whole.
  uint64_t max_batch_bytes = 64ull << 20;
  uint64_t max_batch_items = 1u << 20;  ///< >= 1; inserts + updates + erases in one batch
  uint64_t max_objects = 1ull << 26;    ///< >= 1; inserts beyond this are rejected
  /// 1 .. 2^26; a frame's events are split into parts of at most this many pairs.
  uint64_t max_pairs_per_event_batch = 1u << 20;
  uint64_t max_rejections_reported = 100;  ///< per batch, individually; the rest are counted
  /// 0 .. 60000 ms: at most one snapshot per this interval; requests in between wait for it
  /// (one snapshot serves them all), so subscribers that keep asking cannot flood the topic.
  int snapshot_interval_ms = 100;
  uint64_t max_interests = 1000;        ///< 0 .. 100000 interests in force (0: none allowed)
  uint64_t max_interest_regions = 256;  ///< 1 .. 65536 regions per interest
  uint64_t max_interest_keys = 100000;  ///< 1 .. 2^24 keys + producers per interest

  /// Member-wise equality.
  bool operator==(const LimitsConfig&) const = default;
};

/// The `logging` section.
struct LoggingConfig {
  std::string level = "info";       ///< trace | debug | info | warn | error | critical | off
  double summary_interval_s = 5.0;  ///< > 0 (or 0 = no periodic summary), <= 86400
  /// "" = stderr only; else also append to this file (resolved like dds.cyclone_config).
  std::string file;
  /// "" = none; else a CSV file (resolved the same way, replaced at start) with one line per
  /// frame: its stages' times, the engine's phases and its counts (docs/OPERATIONS.md lists
  /// the columns).
  std::string frame_log;

  /// Member-wise equality.
  bool operator==(const LoggingConfig&) const = default;
};

/// The `producers` section: what happens to the objects of a producer that goes away.
struct ProducersConfig {
  /// Seconds a producer's DDS writer may be not alive (its process died or hung, or it left)
  /// before the daemon erases its objects, with uncollide events for their pairs; a producer
  /// that comes back in time keeps them. 0 = never erase. >= 0, <= 86400.
  double lease_s = 10.0;

  /// Member-wise equality.
  bool operator==(const ProducersConfig&) const = default;
};

/// The `shards` section: this daemon is one shard of a world served by several daemons.
struct ShardsConfig {
  /// "" = not sharded; else the shard map file (bp/transport/shard_map.h), the same for every
  /// daemon and client of the world, resolved like dds.cyclone_config.
  std::string map;
  /// The shard this daemon serves: a name in the map (broadphased --shard overrides it).
  std::string self;

  /// Member-wise equality.
  bool operator==(const ShardsConfig&) const = default;
};

/// The whole configuration.
struct Config {
  EngineConfig engine;        ///< `engine`
  DdsConfig dds;              ///< `dds`
  FramesConfig frames;        ///< `frames`
  LimitsConfig limits;        ///< `limits`
  LoggingConfig logging;      ///< `logging`
  ProducersConfig producers;  ///< `producers`
  ShardsConfig shards;        ///< `shards`
  /// Where it came from: the file path, or the name given to ParseConfig.
  std::string source;
  /// Accepted but noteworthy, e.g. "<source>:3:14: engine.cell_size: ignored by engine
  /// 'segmented_sap' (grid engines only)".
  std::vector<std::string> warnings;

  /// Member-wise equality (source and warnings included).
  bool operator==(const Config&) const = default;
};

/// Parses YAML text. On failure returns InvalidArgument whose message lists EVERY problem found,
/// one per line, each as "<source>:<line>:<column>: <dotted.key>: <reason>" (line/column 1-based
/// from yaml-cpp's Mark), and leaves *out unchanged. On success *out is the configuration with
/// `source` set and its warnings. Empty text (or an empty document) is the default configuration.
/// Relative paths are kept as written.
Status ParseConfig(std::string_view yaml_text, std::string_view source, Config* out);

/// Reads the file (NotFound / InvalidArgument with the path on I/O errors), parses it, and
/// resolves the relative paths (dds.cyclone_config, logging.file) against the file's directory.
Status LoadConfigFile(const std::string& path, Config* out);

/// The effective configuration as YAML (every key, defaults included), for logging at start-up
/// and `--print-config`. ParseConfig reads it back to an equal configuration.
std::string ConfigToYaml(const Config& config);

/// The configuration to use when none is given on the command line: $BP_CONFIG if set, else
/// config/broadphased.yaml in the working directory, else the one next to the executable (the
/// source tree's config/ above a build directory, or an installation's
/// share/broadphase/config/). "" when there is none.
std::string FindDefaultConfig();

/// Loads path, or when path is "" the default of FindDefaultConfig(), or else the built-in
/// defaults with Cyclone's own default configuration (a warning says so).
Status LoadConfigOrDefault(const std::string& path, Config* out);

/// The engine's query threads: engine.threads, or for "auto" (0) the CPUs this process may run
/// on (its affinity mask, so taskset and cpusets count; a container's CPU quota does not: set a
/// count there), else std::thread::hardware_concurrency, else 1; at most 256.
int EngineThreads(const EngineConfig& engine);
/// Canonical names: "float"/"double"/"int32".
std::string_view CoordinateTypeName(CoordinateType type);
/// Canonical names: "end_of_frame"/"tick".
std::string_view FrameBoundaryName(FrameBoundary boundary);

}  // namespace bp::service
