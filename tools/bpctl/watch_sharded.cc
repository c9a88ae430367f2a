// bpctl watch on a sharded world (shards.map in the config): the shards' streams merged into
// one by the client library's MergedView, printed like a single daemon's.
#include <algorithm>
#include <string>
#include <vector>

#include "common.h"

#include "bp/client/sharded.h"
#include "bp/util/percentile.h"

namespace bp::bpctl {

int WatchSharded(const Common& common, const WatchOptions& options,
                 const transport::ShardMap& map) {
  wire::Interest interest;
  std::string error;
  if (!BuildInterest(options, &interest, &error)) {
    std::fprintf(stderr, "bpctl watch: %s\n", error.c_str());
    return 2;
  }
  if (!options.latency_log.empty() || options.json) {
    std::fprintf(stderr,
                 "bpctl watch: on a sharded world (shards.map), --latency-log and --json are not "
                 "available\n");
    return 2;
  }
  auto connection = Connect(common);
  if (!connection) return 1;
  // With an interest: declared on every shard, its streams merged, dropped on the way out.
  std::unique_ptr<client::ShardedInterestClient> interests;
  if (interest.id() != 0) {
    Status s = client::ShardedInterestClient::Create(*connection, map, &interests);
    if (s.ok()) {
      s = WaitInterruptibly(
          common.wait_s, [&](std::chrono::milliseconds t) { return interests->WaitForDaemons(t); });
    }
    if (s.ok()) s = interests->Declare(interest);
    if (!s.ok()) {
      std::fprintf(stderr, "bpctl watch: cannot declare the interest: %s\n", s.ToString().c_str());
      return s.code() == StatusCode::kInvalidArgument ? 2 : 1;
    }
  }
  struct DropOnExit {
    client::ShardedInterestClient* client;
    uint64_t id;
    ~DropOnExit() {
      if (client != nullptr) (void)client->Drop(id);
    }
  } drop_on_exit{interests.get(), interest.id()};
  std::unique_ptr<client::ShardedSubscriber> sub;
  if (Status s =
          client::ShardedSubscriber::Create(*connection, map, options.depth, &sub, interest.id());
      !s.ok()) {
    std::fprintf(stderr, "bpctl watch: %s\n", s.ToString().c_str());
    return 1;
  }
  if (Status s = WaitInterruptibly(
          common.wait_s, [&](std::chrono::milliseconds t) { return sub->WaitForDaemons(t); });
      !s.ok()) {
    std::fprintf(stderr, "bpctl watch: the shards of %s: %s\n", common.config.shards.map.c_str(),
                 s.ToString().c_str());
    return 1;
  }
  std::fprintf(stderr, "bpctl watch: %zu shards of %s merged into one stream\n", map.size(),
               common.config.shards.map.c_str());
  const auto start = std::chrono::steady_clock::now();
  auto window_start = start;
  uint64_t frames = 0, window_frames = 0, window_events = 0, total_frames = 0, total_events = 0,
           folded = 0;
  std::vector<double> latency_ms, all_latency_ms;
  std::vector<client::MergedFrame> merged;
  while (!StopRequested()) {
    if (options.seconds > 0 && SecondsSince(start) >= options.seconds) break;
    if (options.frames > 0 && frames >= options.frames) break;
    if (interests) {
      if (Status s = interests->Maintain(); !s.ok()) {
        std::fprintf(stderr, "bpctl watch: %s\n", s.ToString().c_str());
        return 1;
      }
    }
    merged.clear();
    if (Status s = sub->Poll(std::chrono::milliseconds(100), &merged); !s.ok()) {
      std::fprintf(stderr, "bpctl watch: %s\n", s.ToString().c_str());
      return 1;
    }
    const uint64_t now_ns = transport::WallClockNs();
    const bool counted = SecondsSince(start) >= options.warmup_s;
    for (const client::MergedFrame& f : merged) {
      ++frames;
      if (f.snapshot) continue;  // the set on (re)joining, not events
      if (f.skipped > 0) folded += f.skipped;
      if (!options.stats) {
        for (size_t i = 0; i + 1 < f.uncollide.size(); i += 2) {
          std::printf("%llu uncollide %s %s\n", static_cast<unsigned long long>(f.frame),
                      KeyName(f.uncollide[i]).c_str(), KeyName(f.uncollide[i + 1]).c_str());
        }
        for (size_t i = 0; i + 1 < f.collide.size(); i += 2) {
          std::printf("%llu collide %s %s\n", static_cast<unsigned long long>(f.frame),
                      KeyName(f.collide[i]).c_str(), KeyName(f.collide[i + 1]).c_str());
        }
      }
      const uint64_t events = (f.uncollide.size() + f.collide.size()) / 2;
      ++window_frames;
      window_events += events;
      double latency = -1;
      if (f.sent_time_ns != 0 && now_ns >= f.sent_time_ns) {
        latency = static_cast<double>(now_ns - f.sent_time_ns) / 1e6;
        latency_ms.push_back(latency);
      }
      if (counted) {
        ++total_frames;
        total_events += events;
        if (latency >= 0) all_latency_ms.push_back(latency);
      }
    }
    std::fflush(stdout);
    if (options.stats && SecondsSince(window_start) >= 1.0) {
      const double span = SecondsSince(window_start);
      std::string waiting;
      for (size_t s : sub->view().waiting_for()) waiting += " " + map.name(s);
      std::printf(
          "%.1f frames/s, %.0f events/s, %zu pairs, update->event p50 %.2f ms p99 %.2f ms, "
          "frame %llu%s%s\n",
          static_cast<double>(window_frames) / span, static_cast<double>(window_events) / span,
          sub->view().size(), util::Percentile(latency_ms, 0.5), util::Percentile(latency_ms, 0.99),
          static_cast<unsigned long long>(sub->view().frame()),
          waiting.empty() ? "" : ", waiting for", waiting.c_str());
      std::fflush(stdout);
      latency_ms.clear();
      window_frames = window_events = 0;
      window_start = std::chrono::steady_clock::now();
    }
  }
  if (options.stats) {
    std::vector<double> sorted = all_latency_ms;
    std::printf(
        "total after %.0f s warm-up: %llu merged frames, %llu events, update->event p50 %.2f "
        "ms p99 %.2f ms\n",
        options.warmup_s, static_cast<unsigned long long>(total_frames),
        static_cast<unsigned long long>(total_events), util::Percentile(sorted, 0.5),
        util::Percentile(sorted, 0.99));
  }
  uint64_t resyncs = 0, restarts = 0;
  for (size_t s = 0; s < map.size(); ++s) {
    resyncs += sub->view().resyncs(s);
    restarts += sub->view().restarts(s);
  }
  std::fprintf(stderr,
               "bpctl watch: merged %llu frames (%llu folded while a shard resynced), %llu "
               "snapshot requests, %llu shard resyncs (%llu restarts), %llu contradictions\n",
               static_cast<unsigned long long>(frames), static_cast<unsigned long long>(folded),
               static_cast<unsigned long long>(sub->snapshot_requests()),
               static_cast<unsigned long long>(resyncs), static_cast<unsigned long long>(restarts),
               static_cast<unsigned long long>(sub->view().contradictions()));
  return options.exact && sub->view().contradictions() > 0 ? 1 : 0;
}

}  // namespace bp::bpctl
