#include "common.h"

#include <atomic>

#include "engine_host.h"

namespace bp::bpctl {
namespace {
std::atomic<bool> stop_requested{false};
}  // namespace

bool StopRequested() { return stop_requested.load(); }
void RequestStop() { stop_requested.store(true); }
void ResetStop() { stop_requested.store(false); }

std::unique_ptr<transport::Connection> Connect(const Common& common) {
  const auto& dds = common.config.dds;
  transport::ConnectionOptions options;
  options.domain = dds.domain;
  options.partition = dds.partition;
  options.topics = {dds.topics.updates,  dds.topics.events,    dds.topics.status,
                    dds.topics.requests, dds.topics.interests, dds.topics.replies};
  if (!dds.cyclone_config.empty()) {
    if (Status s = transport::ReadTextFile(dds.cyclone_config, &options.cyclone_xml); !s.ok()) {
      std::fprintf(stderr, "bpctl: dds.cyclone_config: %s\n", s.ToString().c_str());
      return nullptr;
    }
  }
  std::unique_ptr<transport::Connection> connection;
  if (Status s = transport::Connection::Open(options, &connection); !s.ok()) {
    std::fprintf(stderr, "bpctl: cannot join DDS domain %u: %s\n", dds.domain,
                 s.ToString().c_str());
    return nullptr;
  }
  return connection;
}

bool LoadShardMap(const Common& common, const char* command,
                  std::optional<transport::ShardMap>* map) {
  map->reset();
  if (common.config.shards.map.empty()) return true;
  transport::ShardMap loaded;
  if (Status s = transport::ShardMap::Load(common.config.shards.map, &loaded); !s.ok()) {
    std::fprintf(stderr, "bpctl %s: %s\n", command, s.message().c_str());
    return false;
  }
  if (loaded.dimension() != common.config.engine.dimension) {
    std::fprintf(stderr, "bpctl %s: shard map %s is %d-D but engine.dimension is %d\n", command,
                 common.config.shards.map.c_str(), loaded.dimension(),
                 common.config.engine.dimension);
    return false;
  }
  *map = std::move(loaded);
  return true;
}

Status WaitInterruptibly(double timeout_s,
                         const std::function<Status(std::chrono::milliseconds)>& wait) {
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    Status s = wait(std::chrono::milliseconds(100));
    if (s.ok() || s.code() != StatusCode::kDeadlineExceeded) return s;
    if (StopRequested()) return Status(StatusCode::kDeadlineExceeded, "interrupted");
    if (SecondsSince(start) >= timeout_s) {
      return Status(StatusCode::kDeadlineExceeded,
                    "nothing matched within " + std::to_string(timeout_s) + " s");
    }
  }
}

std::string KeyName(uint64_t key) {
  // On an interest's stream, keys below 2^48 are its regions (by declaration index).
  if (key < service::kLocalIdLimit) return "region:" + std::to_string(key);
  return std::to_string(key >> service::kProducerShift) + ":" +
         std::to_string(key & (service::kLocalIdLimit - 1));
}

}  // namespace bp::bpctl
