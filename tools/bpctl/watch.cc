// bpctl watch (events or live statistics) and bpctl status (daemon health).
#include <algorithm>
#include <cerrno>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "common.h"

#include "bp/client/interests.h"
#include "bp/client/overlap_view.h"
#include "bp/client/subscriber.h"
#include "bp/client/update_publisher.h"
#include "bp/util/percentile.h"

namespace bp::bpctl {
namespace {

using util::Percentile;

const char* HealthName(wire::Health h) {
  switch (h) {
    case wire::STARTING:
      return "starting";
    case wire::SERVING:
      return "serving";
    case wire::STOPPING:
      return "stopping";
    default:
      return "unknown";
  }
}

}  // namespace

int Watch(const Common& common, const WatchOptions& options) {
  std::optional<transport::ShardMap> map;
  if (!LoadShardMap(common, "watch", &map)) return 2;
  if (map) return WatchSharded(common, options, *map);
  struct CloseFile {
    void operator()(std::FILE* f) const { (void)std::fclose(f); }
  };
  std::unique_ptr<std::FILE, CloseFile> log_file;  // closed on every return
  if (!options.latency_log.empty()) {
    log_file.reset(std::fopen(options.latency_log.c_str(), "w"));
    if (!log_file) {
      std::fprintf(stderr, "bpctl watch: cannot write --latency-log %s: %s\n",
                   options.latency_log.c_str(), std::strerror(errno));
      return 1;
    }
    std::fprintf(log_file.get(), "frame,sent_ns,published_ns,arrived_ns\n");
  }
  wire::Interest interest;
  std::string error;
  if (!BuildInterest(options, &interest, &error)) {
    std::fprintf(stderr, "bpctl watch: %s\n", error.c_str());
    return 2;
  }
  auto connection = Connect(common);
  if (!connection) return 1;
  std::unique_ptr<client::EventSubscriber> sub;
  if (Status s = client::EventSubscriber::Create(*connection, options.depth, &sub, interest.id());
      !s.ok()) {
    std::fprintf(stderr, "bpctl watch: %s\n", s.ToString().c_str());
    return 1;
  }
  // With an interest: declared once the daemon is found, watched for refusals on the status
  // topic (and declared again to a restarted daemon), dropped on the way out.
  std::unique_ptr<client::InterestClient> interests;
  std::unique_ptr<client::StatusSubscriber> status;
  if (interest.id() != 0) {
    Status s = client::InterestClient::Create(*connection, &interests);
    if (s.ok()) s = client::StatusSubscriber::Create(*connection, 64, &status);
    if (s.ok()) {
      s = WaitInterruptibly(
          common.wait_s, [&](std::chrono::milliseconds t) { return interests->WaitForDaemon(t); });
    }
    if (s.ok()) s = interests->Declare(interest);
    if (!s.ok()) {
      std::fprintf(stderr, "bpctl watch: cannot declare the interest: %s\n", s.ToString().c_str());
      return 1;
    }
    std::fprintf(stderr,
                 "bpctl watch: interest %016llx: %d region(s), %d key(s), %d producer(s), "
                 "category mask %llx\n",
                 static_cast<unsigned long long>(interest.id()),
                 interest.region_lo_size() / std::max(1, static_cast<int>(interest.dim())),
                 interest.keys_size(), interest.producers_size(),
                 static_cast<unsigned long long>(interest.category_mask()));
  }
  struct DropOnExit {
    client::InterestClient* client;
    uint64_t id;
    ~DropOnExit() {
      if (client != nullptr) (void)client->Drop(id);
    }
  } drop_on_exit{interests.get(), interest.id()};
  std::vector<wire::DaemonStatus> reports;
  std::vector<wire::InterestRefusal> refusals;
  // (An interest's stream has no writer until the daemon accepts it: the daemon was found
  // through the interests topic, and a refusal comes on the status topic.)
  if (Status s = interests ? Status::Ok()
                           : WaitInterruptibly(common.wait_s,
                                               [&](std::chrono::milliseconds t) {
                                                 return sub->WaitForDaemon(t);
                                               });
      !s.ok()) {
    std::fprintf(stderr, "bpctl watch: no daemon on domain %u partition '%s' (%s)\n",
                 common.config.dds.domain, common.config.dds.partition.c_str(),
                 s.ToString().c_str());
    return 1;
  }
  // --exact: the set from a snapshot and the events, checked after every frame.
  std::unique_ptr<client::SnapshotRequester> requests;
  client::OverlapView view;
  uint64_t exact_checked = 0, exact_mismatches = 0;
  auto asked = std::chrono::steady_clock::time_point{};
  if (options.exact) {
    if (Status s = client::SnapshotRequester::Create(*connection, &requests); !s.ok()) {
      std::fprintf(stderr, "bpctl watch: %s\n", s.ToString().c_str());
      return 1;
    }
    (void)WaitInterruptibly(
        common.wait_s, [&](std::chrono::milliseconds t) { return requests->WaitForDaemon(t); });
  }
  const auto start = std::chrono::steady_clock::now();
  auto window_start = start;
  uint64_t frames = 0, window_frames = 0, window_collides = 0, window_uncollides = 0;
  uint64_t objects = 0, overlaps = 0;
  std::vector<double> latency_ms;
  // Totals after the warm-up: frames, the span they arrived in, every latency.
  std::vector<double> all_latency_ms;
  // The two legs of each latency: the scene's stamp to the daemon's publication stamp of the
  // frame's last part (upload, ingest, query; the stamp precedes the part's encoding), and that
  // stamp to arrival here (encoding, DDS delivery, decoding, this process's scheduling). Both
  // clocks are CLOCK_REALTIME: across machines the legs carry the clocks' offset, their sum
  // does not. Frames without both stamps, or whose stamps go backwards, are left out of the legs.
  // Kept (like the totals) only with --stats, which prints them.
  std::vector<double> all_to_publish_ms, all_delivery_ms;
  uint64_t total_frames = 0, total_events = 0;
  std::chrono::steady_clock::time_point first_frame{}, last_frame{};
  std::vector<wire::EventBatch> batches;
  while (!StopRequested()) {
    if (options.seconds > 0 && SecondsSince(start) >= options.seconds) break;
    if (options.frames > 0 && frames >= options.frames) break;
    if (status) {
      reports.clear();
      refusals.clear();
      Status s = status->Poll(std::chrono::milliseconds(0), &reports);
      for (const auto& r : reports) {
        if (s.ok()) s = interests->OnStatus(r, &refusals);
      }
      if (!s.ok()) {
        std::fprintf(stderr, "bpctl watch: %s\n", s.ToString().c_str());
        return 1;
      }
      for (const auto& r : refusals) {
        if (r.interest() != interest.id()) continue;
        std::fprintf(stderr, "bpctl watch: the daemon refused the interest: %s\n",
                     r.message().c_str());
        return 1;
      }
    }
    batches.clear();
    if (Status s = sub->Poll(std::chrono::milliseconds(100), &batches); !s.ok()) {
      std::fprintf(stderr, "bpctl watch: %s\n", s.ToString().c_str());
      return 1;
    }
    const uint64_t now_ns = transport::WallClockNs();
    if (options.exact) {
      for (const auto& b : batches) {
        if (view.Apply(b)) asked = {};  // lost its sync (or never had it): ask at once
        if (!b.snapshot() && b.last_part() && view.synced()) {
          ++exact_checked;
          if (view.size() != b.overlaps()) {
            ++exact_mismatches;
            std::fprintf(stderr,
                         "bpctl watch: frame %llu: %zu pairs from the snapshot and events, the "
                         "daemon counts %llu\n",
                         static_cast<unsigned long long>(b.frame()), view.size(),
                         static_cast<unsigned long long>(b.overlaps()));
          }
        }
      }
      const auto now = std::chrono::steady_clock::now();
      if (view.wants_snapshot() && now - asked > std::chrono::seconds(1)) {
        (void)requests->Request(view.resyncs() == 0 ? "join" : "resync", interest.id());
        asked = now;
      }
    }
    for (const auto& b : batches) {
      // Snapshots (the whole overlap set, published when some subscriber asks for one) are
      // not events: a line per event and the rates ignore them.
      if (b.snapshot()) continue;
      if (!options.stats) {
        for (int i = 0; i + 1 < b.uncollide_size(); i += 2) {
          std::printf("%llu uncollide %s %s\n", static_cast<unsigned long long>(b.frame()),
                      KeyName(b.uncollide(i)).c_str(), KeyName(b.uncollide(i + 1)).c_str());
        }
        for (int i = 0; i + 1 < b.collide_size(); i += 2) {
          std::printf("%llu collide %s %s\n", static_cast<unsigned long long>(b.frame()),
                      KeyName(b.collide(i)).c_str(), KeyName(b.collide(i + 1)).c_str());
        }
      }
      window_collides += static_cast<uint64_t>(b.collide_size()) / 2;
      window_uncollides += static_cast<uint64_t>(b.uncollide_size()) / 2;
      const bool counted = SecondsSince(start) >= options.warmup_s;
      if (counted) total_events += static_cast<uint64_t>(b.collide_size() + b.uncollide_size()) / 2;
      if (!b.last_part()) continue;
      ++frames;
      ++window_frames;
      objects = b.objects();
      overlaps = b.overlaps();
      double latency = -1;
      if (b.source_sent_time_ns() != 0 && now_ns >= b.source_sent_time_ns()) {
        latency = static_cast<double>(now_ns - b.source_sent_time_ns()) / 1e6;
        if (options.stats) latency_ms.push_back(latency);  // printed and cleared each second
      }
      if (counted) {
        const auto now = std::chrono::steady_clock::now();
        if (total_frames == 0) first_frame = now;
        last_frame = now;
        ++total_frames;
        if (options.stats && latency >= 0) all_latency_ms.push_back(latency);
        const uint64_t published = b.published_time_ns(), sent = b.source_sent_time_ns();
        if (options.stats && sent != 0 && published >= sent && now_ns >= published) {
          all_to_publish_ms.push_back(static_cast<double>(published - sent) / 1e6);
          all_delivery_ms.push_back(static_cast<double>(now_ns - published) / 1e6);
        }
      }
      if (log_file) {
        std::fprintf(log_file.get(), "%llu,%llu,%llu,%llu\n",
                     static_cast<unsigned long long>(b.frame()),
                     static_cast<unsigned long long>(b.source_sent_time_ns()),
                     static_cast<unsigned long long>(b.published_time_ns()),
                     static_cast<unsigned long long>(now_ns));
      }
    }
    if (!options.stats) {
      std::fflush(stdout);
      continue;
    }
    const double window = SecondsSince(window_start);
    if (window < 1.0) continue;
    const double p50 = Percentile(latency_ms, 0.5), p99 = Percentile(latency_ms, 0.99);
    if (options.json) {
      std::printf(
          "{\"objects\": %llu, \"overlaps\": %llu, \"frames_per_s\": %.2f, \"events_per_s\": "
          "%.1f, \"latency_ms_p50\": %.3f, \"latency_ms_p99\": %.3f, \"gaps\": %llu}\n",
          static_cast<unsigned long long>(objects), static_cast<unsigned long long>(overlaps),
          static_cast<double>(window_frames) / window,
          static_cast<double>(window_collides + window_uncollides) / window, p50, p99,
          static_cast<unsigned long long>(sub->gaps()));
    } else {
      std::printf(
          "objects %llu | overlaps %llu | %.1f frames/s | %.0f collides/s | %.0f uncollides/s | "
          "update->event p50 %.2f ms p99 %.2f ms | gaps %llu\n",
          static_cast<unsigned long long>(objects), static_cast<unsigned long long>(overlaps),
          static_cast<double>(window_frames) / window,
          static_cast<double>(window_collides) / window,
          static_cast<double>(window_uncollides) / window, p50, p99,
          static_cast<unsigned long long>(sub->gaps()));
    }
    std::fflush(stdout);
    window_start = std::chrono::steady_clock::now();
    window_frames = window_collides = window_uncollides = 0;
    latency_ms.clear();
  }
  bool log_failed = false;
  if (log_file) {
    const bool lost = std::ferror(log_file.get()) != 0;
    if (std::fclose(log_file.release()) != 0 || lost) {
      std::fprintf(stderr, "bpctl watch: --latency-log %s is incomplete: %s\n",
                   options.latency_log.c_str(), std::strerror(errno));
      log_failed = true;
    }
  }
  if (options.stats) {
    // Sustained rate: frames after the first counted one over the time they took to arrive.
    const double span = std::chrono::duration<double>(last_frame - first_frame).count();
    const double rate =
        total_frames > 1 && span > 0 ? static_cast<double>(total_frames - 1) / span : 0.0;
    std::vector<double> sorted = all_latency_ms;
    const double p50 = Percentile(sorted, 0.5), p99 = Percentile(sorted, 0.99);
    const double max = sorted.empty() ? 0 : *std::max_element(sorted.begin(), sorted.end());
    // A leg's percentile, or null (JSON) / n/a when no frame had both stamps.
    auto leg = [&](std::vector<double>& v, double p) -> std::string {
      if (v.empty()) return options.json ? "null" : "n/a";
      char text[32];
      std::snprintf(text, sizeof(text), options.json ? "%.3f" : "%.2f", Percentile(v, p));
      return text;
    };
    const std::string up50 = leg(all_to_publish_ms, 0.5), up99 = leg(all_to_publish_ms, 0.99);
    const std::string down50 = leg(all_delivery_ms, 0.5), down99 = leg(all_delivery_ms, 0.99);
    if (options.json) {
      std::printf(
          "{\"total\": true, \"frames\": %llu, \"seconds\": %.3f, \"frames_per_s\": "
          "%.2f, \"events\": %llu, \"latency_ms_p50\": %.3f, \"latency_ms_p99\": %.3f, "
          "\"latency_ms_max\": %.3f, \"to_publish_ms_p50\": %s, \"to_publish_ms_p99\": %s, "
          "\"delivery_ms_p50\": %s, \"delivery_ms_p99\": %s, \"gaps\": %llu}\n",
          static_cast<unsigned long long>(total_frames), span, rate,
          static_cast<unsigned long long>(total_events), p50, p99, max, up50.c_str(), up99.c_str(),
          down50.c_str(), down99.c_str(), static_cast<unsigned long long>(sub->gaps()));
    } else {
      std::printf(
          "total after %.0f s warm-up: %llu frames in %.2f s (%.1f frames/s), %llu "
          "events, update->event p50 %.2f ms p99 %.2f ms max %.2f ms (to the daemon's "
          "publication p50 %s p99 %s, delivery p50 %s p99 %s), gaps %llu\n",
          options.warmup_s, static_cast<unsigned long long>(total_frames), span, rate,
          static_cast<unsigned long long>(total_events), p50, p99, max, up50.c_str(), up99.c_str(),
          down50.c_str(), down99.c_str(), static_cast<unsigned long long>(sub->gaps()));
    }
    std::fflush(stdout);
  }
  if (options.exact) {
    std::fprintf(stderr,
                 "bpctl watch: exact: %llu frames checked against the daemon's count, %llu "
                 "differences, %llu snapshots applied, %llu resyncs (%llu gaps, %llu restarts, "
                 "%llu contradictions)\n",
                 static_cast<unsigned long long>(exact_checked),
                 static_cast<unsigned long long>(exact_mismatches),
                 static_cast<unsigned long long>(view.snapshots()),
                 static_cast<unsigned long long>(view.resyncs()),
                 static_cast<unsigned long long>(view.gaps()),
                 static_cast<unsigned long long>(view.restarts()),
                 static_cast<unsigned long long>(view.contradictions()));
    if (exact_checked == 0) {
      std::fprintf(stderr, "bpctl watch: exact: no frame could be checked (no snapshot?)\n");
      return 1;
    }
    if (exact_mismatches > 0 || view.contradictions() > 0) return 1;
  }
  return log_failed ? 1 : 0;
}

namespace {

void PrintReport(const wire::DaemonStatus& r) {
  std::printf(
      "%s: %s, epoch %016llx, engine %s %u-D %s, frame %llu, objects %llu, overlaps %llu, "
      "producers %u (%llu expired), interests %u, rejected %llu, event write failures %llu\n",
      r.daemon().c_str(), HealthName(r.health()), static_cast<unsigned long long>(r.epoch()),
      r.engine().c_str(), r.dim(), r.coordinate().c_str(),
      static_cast<unsigned long long>(r.frame()), static_cast<unsigned long long>(r.objects()),
      static_cast<unsigned long long>(r.overlaps()), r.producers(),
      static_cast<unsigned long long>(r.producers_expired()), r.interests(),
      static_cast<unsigned long long>(r.rejected_total()),
      static_cast<unsigned long long>(r.event_write_failures()));
  if (r.has_shard()) {
    std::printf("  shard '%s' (%u of %u, %llu blocks), map digest %016llx\n",
                r.shard().name().c_str(), r.shard().index() + 1, r.shard().count(),
                static_cast<unsigned long long>(r.shard().blocks_owned()),
                static_cast<unsigned long long>(r.shard().map_digest()));
  }
  if (r.has_interval() && r.interval().seconds() > 0) {
    const auto& i = r.interval();
    std::printf(
        "  last %.1f s: %.1f frames/s, %.0f updates/s, %.0f events/s, frame p50 %.3f ms p99 "
        "%.3f ms max %.3f ms\n",
        i.seconds(), static_cast<double>(i.frames()) / i.seconds(),
        static_cast<double>(i.updates()) / i.seconds(),
        static_cast<double>(i.events()) / i.seconds(), i.frame_ms_p50(), i.frame_ms_p99(),
        i.frame_ms_max());
    std::printf(
        "  frame stages p50/p99: ingest %.3f/%.3f ms, query %.3f/%.3f ms, publish %.3f/%.3f ms\n",
        i.ingest_ms_p50(), i.ingest_ms_p99(), i.query_ms_p50(), i.query_ms_p99(),
        i.publish_ms_p50(), i.publish_ms_p99());
  }
  for (const auto& j : r.rejections()) {
    std::printf("  rejected (producer %u, frame %llu): %s\n", j.producer(),
                static_cast<unsigned long long>(j.frame()), j.message().c_str());
  }
  for (const auto& j : r.interest_refusals()) {
    std::printf("  interest refused (client %016llx): %s\n",
                static_cast<unsigned long long>(j.client()), j.message().c_str());
  }
  if (r.rejections_not_listed() > 0) {
    std::printf("  ... and %llu more rejections\n",
                static_cast<unsigned long long>(r.rejections_not_listed()));
  }
}

}  // namespace

int ShowStatus(const Common& common, const StatusOptions& options) {
  std::optional<transport::ShardMap> map;
  if (!LoadShardMap(common, "status", &map)) return 2;
  auto connection = Connect(common);
  if (!connection) return 1;
  // One daemon, or one status topic per shard (each in its shard's partition).
  std::vector<std::string> names{""};
  std::vector<std::unique_ptr<transport::Connection>> scoped;
  std::vector<std::unique_ptr<client::StatusSubscriber>> subs;
  if (map) {
    names.clear();
    for (size_t i = 0; i < map->size(); ++i) {
      names.push_back(map->name(i));
      scoped.push_back(
          connection->Scoped(transport::ShardPartition(common.config.dds.partition, map->name(i))));
    }
  }
  for (size_t i = 0; i < names.size(); ++i) {
    std::unique_ptr<client::StatusSubscriber> sub;
    if (Status s = client::StatusSubscriber::Create(map ? *scoped[i] : *connection, 64, &sub);
        !s.ok()) {
      std::fprintf(stderr, "bpctl status: %s\n", s.ToString().c_str());
      return 1;
    }
    subs.push_back(std::move(sub));
  }
  const auto start = std::chrono::steady_clock::now();
  std::vector<bool> heard(names.size(), false);
  std::vector<wire::DaemonStatus> reports;
  while (!StopRequested()) {
    const bool all = std::find(heard.begin(), heard.end(), false) == heard.end();
    if (all && !options.follow) break;
    if (!options.follow && SecondsSince(start) >= options.timeout_s) break;
    for (size_t i = 0; i < subs.size(); ++i) {
      reports.clear();
      if (Status s = subs[i]->Poll(std::chrono::milliseconds(100 / subs.size()), &reports);
          !s.ok()) {
        std::fprintf(stderr, "bpctl status: %s\n", s.ToString().c_str());
        return 1;
      }
      // Without --follow only the newest report matters (a late joiner receives the last 16).
      if (!options.follow && heard[i]) continue;
      const size_t first = options.follow || reports.empty() ? 0 : reports.size() - 1;
      for (size_t k = first; k < reports.size(); ++k) {
        heard[i] = true;
        if (map) std::printf("shard %s: ", names[i].c_str());
        PrintReport(reports[k]);
        if (map && reports[k].shard().map_digest() != map->digest()) {
          std::printf("  WARNING: this daemon serves another shard map than %s\n",
                      common.config.shards.map.c_str());
        }
      }
    }
    std::fflush(stdout);
  }
  int rc = 0;
  for (size_t i = 0; i < names.size(); ++i) {
    if (heard[i]) continue;
    rc = 1;
    if (map) {
      std::fprintf(stderr, "bpctl status: no report from shard '%s' (domain %u partition '%s')\n",
                   names[i].c_str(), common.config.dds.domain,
                   transport::ShardPartition(common.config.dds.partition, names[i]).c_str());
    } else {
      std::fprintf(stderr, "bpctl status: no report from a daemon on domain %u partition '%s'\n",
                   common.config.dds.domain, common.config.dds.partition.c_str());
    }
  }
  return rc;
}

}  // namespace bp::bpctl
