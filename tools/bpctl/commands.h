// bpctl's commands, as functions so that tests run them in-process. Each returns a process exit
// status (0 ok, 1 failure, 2 bad arguments) and prints its own errors.
//
// Thread safety: one command per thread; StopRequested() is set by SIGINT/SIGTERM (bpctl main)
// or by RequestStop() (tests).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "broadphase.pb.h"
#include "config.h"

#include "bp/workload.h"

namespace bp::bpctl {

/// True once a stop was asked for (Ctrl-C, or RequestStop()).
bool StopRequested();
/// Asks every running command to finish (thread-safe).
void RequestStop();
/// Clears the stop flag (tests run several commands in one process).
void ResetStop();

/// Options shared by every command: the deployment, read from the daemon's YAML.
struct Common {
  service::Config config;  ///< domain, partition, topics, Cyclone XML, engine, limits
  double wait_s = 10.0;    ///< how long to wait for the daemon to appear
};

struct SceneOptions {
  workload::SceneParams params;
  double rate_hz = 60.0;  ///< frames per second; 0 = as fast as possible
  uint64_t frames = 0;    ///< frames after the initial one; 0 = until stopped
  uint32_t producer = 1;
  uint64_t max_items = 100'000;  ///< items per batch (a frame larger than this is split)
  uint32_t readers = 1;  ///< readers to wait for before the first frame (daemon + recorders)
  bool restate = true;   ///< keep the objects and restate them to a restarted daemon
  bool quiet = false;
};
int Scene(const Common& common, const SceneOptions& options);

struct WatchOptions {
  bool stats = false;   ///< print rates and latency each second instead of events
  uint64_t frames = 0;  ///< stop after this many frames (0 = until stopped)
  double seconds = 0;   ///< stop after this long (0 = until stopped)
  int32_t depth = 256;  ///< subscriber history
  double warmup_s = 0;  ///< leave the first seconds out of the final totals
  bool json = false;    ///< with stats: JSON lines (per second, and the totals at the end)
  /// Keep the overlap set from a snapshot and the events (OverlapView) and check it against
  /// the daemon's overlap count after every frame; exit 1 on any difference.
  bool exact = false;
  /// With a path: one CSV line per frame (frame, the scene's stamp, the daemon's publication of
  /// the last part, arrival here; nanoseconds of CLOCK_REALTIME), for latency analysis.
  std::string latency_log;
  /// An interest (any of the following set): only its events, on a stream of its own.
  std::vector<std::string> regions;  ///< each "x0,y0[,z0],x1,y1[,z1]"
  double leave_margin = 0;           ///< regions: leave only this far beyond the region
  bool pairs_inside = false;         ///< regions: also the object pairs inside them
  std::vector<std::string> keys;     ///< each "producer:id"
  std::vector<uint32_t> producers;
  uint64_t category_mask = 0;  ///< pairs with an object of these category bits
};
int Watch(const Common& common, const WatchOptions& options);

struct QueryOptions {
  std::string box;         ///< "x0,y0[,z0],x1,y1[,z1]"
  double timeout_s = 5.0;  ///< for the answer (after the daemon was found)
};
/// bpctl query: the objects whose boxes overlap a box now, one per line.
int Query(const Common& common, const QueryOptions& options);

/// Parses "x0,y0[,z0],x1,y1[,z1]" (2K finite numbers) into lo and hi; false with *error.
bool ParseBox(const std::string& text, std::vector<double>* lo, std::vector<double>* hi,
              std::string* error);
/// The interest of a watch's options; false with *error (a bad argument). Empty interest (id 0)
/// if none is asked for.
bool BuildInterest(const WatchOptions& options, wire::Interest* out, std::string* error);

struct StatusOptions {
  bool follow = false;
  double timeout_s = 5.0;
};
int ShowStatus(const Common& common, const StatusOptions& options);

struct RecordOptions {
  std::string file;
  double seconds = 0;    ///< stop after this long (0 = until stopped)
  uint64_t batches = 0;  ///< stop after this many batches (0 = until stopped)
  std::string note;
};
int Record(const Common& common, const RecordOptions& options);

struct ReplayOptions {
  std::string file;
  double speed = 1.0;  ///< 2 = twice the recorded pace
  bool fast = false;   ///< as fast as possible (back-pressure still applies)
  bool raw = false;    ///< publish payloads byte for byte (no restamped send time)
  bool progress = true;
};
int Replay(const Common& common, const ReplayOptions& options);

struct CheckOptions {
  std::string file;
  std::string engine;  ///< "" = the config's engine.algorithm
  bool quiet = false;
};
/// The result of a check, for tests.
struct CheckResult {
  uint64_t batches = 0;
  uint64_t frames = 0;
  uint64_t events = 0;
  uint64_t rejected = 0;
  bool identical = true;
  /// Every frame's events in order: (frame, uncollide?, a, b).
  std::vector<std::pair<uint64_t, std::pair<uint64_t, uint64_t>>> collides;
  std::vector<std::pair<uint64_t, std::pair<uint64_t, uint64_t>>> uncollides;
};
int Check(const Common& common, const CheckOptions& options, CheckResult* out = nullptr);

}  // namespace bp::bpctl
