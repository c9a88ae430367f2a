// Pieces shared by bpctl's commands: connecting to the deployment of a daemon config.
#pragma once

#include <chrono>
#include <cstdio>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "commands.h"

#include "bp/transport/connection.h"
#include "bp/transport/shard_map.h"

namespace bp::bpctl {

/// Opens a connection to the deployment the config describes; prints the error on failure.
std::unique_ptr<transport::Connection> Connect(const Common& common);

/// The world's shard map when the config names one (shards.map; the daemons' own file): every
/// command then works on all the shards. Empty when not sharded; prints the error and returns
/// false when the map cannot be read or does not match engine.dimension.
bool LoadShardMap(const Common& common, const char* command,
                  std::optional<transport::ShardMap>* map);

/// bpctl watch on a sharded world: the shards' streams merged (watch_sharded.cc).
int WatchSharded(const Common& common, const WatchOptions& options, const transport::ShardMap& map);

/// Seconds since an instant, as double.
inline double SecondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

/// Calls wait(100 ms) until it succeeds, the total timeout passes or a stop is requested (so
/// that Ctrl-C is not held up by discovery). The last status.
Status WaitInterruptibly(double timeout_s,
                         const std::function<Status(std::chrono::milliseconds)>& wait);

/// "producer:id" of a global key.
std::string KeyName(uint64_t key);

}  // namespace bp::bpctl
