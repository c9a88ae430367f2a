// broadphased: the proximity daemon. `broadphased --config config/broadphased.yaml`.
// Exit status: 0 after a clean stop (SIGINT/SIGTERM; a second one a second or more later exits
// at once with 1),
// 1 on a runtime failure, 2 on a bad command line or configuration.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <thread>

#include "config.h"
#include "daemon.h"
#include <CLI/CLI.hpp>
#include <pthread.h>
#include <signal.h>
#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "bp/transport/shard_map.h"

namespace {

int SetUpLogging(const bp::service::LoggingConfig& logging) {
  try {
    std::vector<spdlog::sink_ptr> sinks;
    sinks.push_back(std::make_shared<spdlog::sinks::stderr_color_sink_mt>());
    if (!logging.file.empty()) {
      sinks.push_back(std::make_shared<spdlog::sinks::basic_file_sink_mt>(logging.file));
    }
    auto logger = std::make_shared<spdlog::logger>("broadphased", sinks.begin(), sinks.end());
    logger->set_level(spdlog::level::from_str(logging.level));
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e [%^%l%$] %v");
    logger->flush_on(spdlog::level::info);
    spdlog::set_default_logger(logger);
  } catch (const spdlog::spdlog_ex& e) {
    std::fprintf(stderr, "broadphased: cannot set up logging: %s\n", e.what());
    return 2;
  }
  return 0;
}

// A shard of a sharded world: loads the map, finds this daemon's shard (shards.self, or --shard)
// and moves the daemon into the shard's partition. Returns the problem, or "" when all is well.
std::string SetUpShard(const std::string& cli_shard, bp::service::Config* config,
                       bp::wire::ShardInfo* info) {
  if (!cli_shard.empty()) config->shards.self = cli_shard;
  if (config->shards.map.empty()) {
    return cli_shard.empty() ? "" : "--shard needs a shard map (shards.map in the configuration)";
  }
  bp::transport::ShardMap map;
  if (bp::Status s = bp::transport::ShardMap::Load(config->shards.map, &map); !s.ok()) {
    return s.message();
  }
  if (map.dimension() != config->engine.dimension) {
    return "shard map " + config->shards.map + " is " + std::to_string(map.dimension()) +
           "-D but engine.dimension is " + std::to_string(config->engine.dimension);
  }
  const int self = map.Find(config->shards.self);
  if (self < 0) {
    std::string names;
    for (size_t s = 0; s < map.size(); ++s) names += (s ? ", " : "") + map.name(s);
    return "shards.self '" + config->shards.self + "' is not a shard of " + config->shards.map +
           " (its shards: " + names + "; set shards.self or --shard)";
  }
  info->set_name(config->shards.self);
  info->set_index(static_cast<uint32_t>(self));
  info->set_count(static_cast<uint32_t>(map.size()));
  info->set_map_digest(map.digest());
  info->set_map(map.canonical());
  info->set_blocks_owned(map.BlocksOwned(static_cast<size_t>(self)));
  config->dds.partition = bp::transport::ShardPartition(config->dds.partition, config->shards.self);
  return "";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "broadphased: the broadphase proximity daemon (updates in over DDS, collide and "
      "uncollide events out)"};
  std::string config_path;
  bool print_config = false;
  bool check_config = false;
  app.add_option("-c,--config", config_path,
                 "YAML configuration (default: $BP_CONFIG, else config/broadphased.yaml here or "
                 "next to the binary)")
      ->check(CLI::ExistingFile);
  std::string shard;
  app.add_option("--shard", shard,
                 "the shard this daemon serves, a name in the shard map (overrides shards.self)");
  app.add_flag("--print-config", print_config, "print the effective configuration and exit");
  app.add_flag("--check-config", check_config, "validate the configuration and exit");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }

  bp::service::Config config;
  bp::Status loaded = bp::service::LoadConfigOrDefault(config_path, &config);
  if (!loaded.ok()) {
    std::fprintf(stderr, "broadphased: configuration refused:\n%s\n", loaded.message().c_str());
    return 2;
  }
  bp::wire::ShardInfo shard_info;
  const std::string partition = config.dds.partition;
  if (std::string problem = SetUpShard(shard, &config, &shard_info); !problem.empty()) {
    std::fprintf(stderr, "broadphased: configuration refused:\n%s\n", problem.c_str());
    return 2;
  }
  if (print_config) {
    bp::service::Config printed = config;
    printed.dds.partition = partition;  // as configured; the shard's is derived from it
    std::cout << bp::service::ConfigToYaml(printed);
    return 0;
  }
  if (check_config) {
    for (const auto& w : config.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
    std::printf("%s: ok\n", config.source.c_str());
    return 0;
  }
  if (int rc = SetUpLogging(config.logging); rc != 0) return rc;
  spdlog::info("configuration from {}", config.source);
  for (const auto& w : config.warnings) spdlog::warn("config: {}", w);

  // Block the stop signals in every thread (Cyclone's included, which start below) and take
  // them on one thread with sigtimedwait: the daemon's stop path is then ordinary code.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  std::unique_ptr<bp::service::Daemon> daemon;
  if (bp::Status s = bp::service::Daemon::Create(config, &daemon); !s.ok()) {
    spdlog::critical("cannot start: {}", s.ToString());
    return 1;
  }
  if (!shard_info.name().empty()) {
    spdlog::info("shard '{}' ({} of {}, {} blocks) of map {} (digest {:016x}), partition '{}'",
                 shard_info.name(), shard_info.index() + 1, shard_info.count(),
                 shard_info.blocks_owned(), config.shards.map, shard_info.map_digest(),
                 config.dds.partition);
    daemon->SetShard(shard_info);
  }
  std::atomic<bool> done{false};
  std::thread signal_thread([&] {
    const timespec poll{0, 200'000'000};
    bool stopping = false;
    std::chrono::steady_clock::time_point first{};
    while (!done.load()) {
      const int sig = sigtimedwait(&stop_signals, nullptr, &poll);
      if (sig != SIGINT && sig != SIGTERM) continue;
      const char* name = sig == SIGINT ? "SIGINT" : "SIGTERM";
      if (!stopping) {
        spdlog::info("received {}; finishing the frame (send it again to exit at once)", name);
        stopping = true;
        first = std::chrono::steady_clock::now();
        daemon->RequestStop();
      } else if (done.load() ||
                 std::chrono::steady_clock::now() - first < std::chrono::seconds(1)) {
        // A terminal's Ctrl-C reaches the whole process group, and a supervisor may forward
        // it once more at the same moment: only a deliberate second signal forces the exit.
        spdlog::info("received {} again within a second: still finishing the frame", name);
      } else {
        spdlog::warn("received {} again: exiting without finishing the frame", name);
        spdlog::shutdown();
        std::_Exit(1);
      }
    }
  });
  bp::Status run = daemon->Run();
  done.store(true);
  signal_thread.join();
  daemon.reset();
  spdlog::shutdown();
  if (!run.ok()) {
    std::fprintf(stderr, "broadphased: %s\n", run.ToString().c_str());
    return 1;
  }
  return 0;
}
