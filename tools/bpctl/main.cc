// bpctl: the broadphase command line. `bpctl --help`; every command takes the daemon's YAML
// (--config) to know the deployment: domain, partition, topics, Cyclone XML, engine, limits.
// Exit status: 0 ok, 1 failure (no daemon, I/O, a difference found by check), 2 bad arguments.
#include <cstdio>
#include <filesystem>

#include "commands.h"
#include <CLI/CLI.hpp>
#include <signal.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "bp/workload_scenarios.h"

namespace {

void OnSignal(int) { bp::bpctl::RequestStop(); }

}  // namespace

int main(int argc, char** argv) {
  // Log lines (Cyclone DDS's warnings among them) go to stderr: stdout carries a command's
  // output (watch's events, check's report), which other programs read line by line.
  spdlog::set_default_logger(spdlog::stderr_color_mt("bpctl"));
  CLI::App app{
      "bpctl: publish scenes, watch events, record, replay and check update streams of "
      "broadphased"};
  app.require_subcommand(1);
  std::string config_path;
  double wait_s = 10.0;
  app.add_option(
      "-c,--config", config_path,
      "the daemon's YAML (default: $BP_CONFIG, else config/broadphased.yaml here or next to "
      "the binary)");
  app.add_option("--wait", wait_s, "seconds to wait for the daemon")->check(CLI::PositiveNumber);

  bp::bpctl::SceneOptions scene;
  std::string scenario;
  auto* scene_cmd = app.add_subcommand("scene", "publish the WORKLOADS.md scene at a rate");
  scene_cmd->add_option("--scenario", scenario,
                        "a named row: S1-10k, S2a, ... (sets n/moving/churn/dim)");
  scene_cmd->add_option("-n,--objects", scene.params.n, "live objects")->check(CLI::PositiveNumber);
  scene_cmd->add_option("--moving", scene.params.moving, "moving objects per frame");
  scene_cmd->add_option("--churn", scene.params.churn, "removals (= insertions) per frame");
  scene_cmd->add_option("--seed", scene.params.seed, "random seed");
  scene_cmd->add_option("--dim", scene.params.dim, "2 or 3")->check(CLI::Range(2, 3));
  scene_cmd->add_option("--rate", scene.rate_hz, "frames per second (0 = as fast as possible)")
      ->check(CLI::NonNegativeNumber);
  scene_cmd->add_option("--frames", scene.frames, "frames after the first (0 = until Ctrl-C)");
  scene_cmd->add_option("--producer", scene.producer, "producer id")->check(CLI::Range(1, 65535));
  scene_cmd
      ->add_option("--readers", scene.readers,
                   "update readers to wait for (2 = the daemon and a recorder)")
      ->check(CLI::PositiveNumber);
  scene_cmd->add_flag("!--no-restate", scene.restate,
                      "do not keep the objects to restate them to a restarted daemon");
  scene_cmd->add_flag("-q,--quiet", scene.quiet, "no progress lines");

  bp::bpctl::WatchOptions watch;
  auto* watch_cmd = app.add_subcommand("watch", "print events, or rates and latency (--stats)");
  watch_cmd->add_flag("--stats", watch.stats, "one line per second: rates, update->event latency");
  watch_cmd->add_option("--frames", watch.frames, "stop after this many frames");
  watch_cmd->add_option("--seconds", watch.seconds, "stop after this many seconds");
  watch_cmd->add_option("--warmup", watch.warmup_s, "seconds left out of the final totals");
  watch_cmd->add_flag("--json", watch.json, "with --stats: JSON lines");
  watch_cmd->add_option("--latency-log", watch.latency_log,
                        "write one CSV line per frame: frame, sent, published and arrival times "
                        "(ns)");
  watch_cmd->add_flag("--exact", watch.exact,
                      "keep the overlap set (snapshot + events) and check it against the "
                      "daemon's count after every frame; exit 1 on a difference");
  watch_cmd->add_option("--region", watch.regions,
                        "an interest: objects entering and leaving this box, "
                        "x0,y0,z0,x1,y1,z1 (repeat for several regions)");
  watch_cmd->add_option("--leave-margin", watch.leave_margin,
                        "with --region: an object leaves only this far beyond the region");
  watch_cmd->add_flag("--pairs-inside", watch.pairs_inside,
                      "with --region: also the events of object pairs inside the regions");
  watch_cmd->add_option("--key", watch.keys,
                        "an interest: events of pairs involving this object, producer:id "
                        "(repeatable)");
  watch_cmd
      ->add_option("--producer", watch.producers,
                   "an interest: events of pairs involving this producer's objects "
                   "(repeatable)")
      ->check(CLI::Range(1, 65535));
  watch_cmd->add_option("--category", watch.category_mask,
                        "an interest: events of pairs with an object of these category bits "
                        "(a mask, e.g. 4 or 0x4)");

  bp::bpctl::QueryOptions query;
  auto* query_cmd =
      app.add_subcommand("query", "list the objects whose boxes overlap a box now (spot query)");
  query_cmd->add_option("--box", query.box, "x0,y0,z0,x1,y1,z1 (or x0,y0,x1,y1 in 2-D)")
      ->required();
  query_cmd->add_option("--timeout", query.timeout_s, "seconds to wait for the answer")
      ->check(CLI::PositiveNumber);

  bp::bpctl::StatusOptions status;
  auto* status_cmd = app.add_subcommand("status", "show the daemon's health and statistics");
  status_cmd->add_flag("-f,--follow", status.follow, "keep printing reports");
  status_cmd->add_option("--timeout", status.timeout_s, "seconds to wait for a report");

  bp::bpctl::RecordOptions record;
  auto* record_cmd = app.add_subcommand("record", "write the update stream to a file");
  record_cmd->add_option("file", record.file, "recording to create")->required();
  record_cmd->add_option("--seconds", record.seconds, "stop after this many seconds");
  record_cmd->add_option("--batches", record.batches, "stop after this many batches");
  record_cmd->add_option("--note", record.note, "a note stored in the header");

  bp::bpctl::ReplayOptions replay;
  auto* replay_cmd = app.add_subcommand("replay", "republish a recording");
  replay_cmd->add_option("file", replay.file, "recording")->required()->check(CLI::ExistingFile);
  replay_cmd->add_option("--speed", replay.speed, "pace factor (2 = twice as fast)")
      ->check(CLI::PositiveNumber);
  replay_cmd->add_flag("--fast", replay.fast, "as fast as the daemon takes it");
  replay_cmd->add_flag("--raw", replay.raw,
                       "payloads byte for byte (default: send times restamped for latency)");
  replay_cmd->add_flag(
      "--no-progress", [&](int64_t) { replay.progress = false; }, "no progress bar");

  bp::bpctl::CheckOptions check;
  auto* check_cmd = app.add_subcommand(
      "check", "replay a recording through an embedded engine and the brute-force oracle");
  check_cmd->add_option("file", check.file, "recording")->required()->check(CLI::ExistingFile);
  check_cmd->add_option("--engine", check.engine, "algorithm (default: the config's)");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }

  bp::bpctl::Common common;
  bp::Status loaded = bp::service::LoadConfigOrDefault(config_path, &common.config);
  if (!loaded.ok()) {
    std::fprintf(stderr, "bpctl: configuration refused:\n%s\n", loaded.message().c_str());
    return 2;
  }
  for (const auto& w : common.config.warnings)
    std::fprintf(stderr, "bpctl: warning: %s\n", w.c_str());
  common.wait_s = wait_s;
  struct sigaction action {};
  action.sa_handler = OnSignal;
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);

  if (*scene_cmd) {
    if (!scenario.empty()) {
      const auto* row = bp::workload::FindGolden(scenario);
      if (!row) {
        std::fprintf(stderr, "bpctl scene: unknown scenario '%s'\n", scenario.c_str());
        return 2;
      }
      const uint64_t seed = scene.params.seed;
      scene.params = row->Params();
      scene.params.seed = seed;
    }
    if (!scene_cmd->count("--dim") && scenario.empty()) {
      scene.params.dim = common.config.engine.dimension;
    }
    return bp::bpctl::Scene(common, scene);
  }
  if (*watch_cmd) return bp::bpctl::Watch(common, watch);
  if (*status_cmd) return bp::bpctl::ShowStatus(common, status);
  if (*query_cmd) return bp::bpctl::Query(common, query);
  if (*record_cmd) return bp::bpctl::Record(common, record);
  if (*replay_cmd) return bp::bpctl::Replay(common, replay);
  if (*check_cmd) return bp::bpctl::Check(common, check);
  return 2;
}
