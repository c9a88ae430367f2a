// bpctl scene: publishes the WORKLOADS.md scene at a rate.
#include <algorithm>
#include <thread>

#include "common.h"

#include "bp/client/sharded.h"
#include "bp/client/update_publisher.h"
#include "bp/tools/scene_frame.h"

namespace bp::bpctl {
namespace {

// Publishes ops as one frame in batches of at most max_items items; the last closes the frame.
// Retries a batch the daemon's back-pressure refused; false when stopped or on a hard error.
bool PublishFrame(client::BatchPublisher& pub, const workload::FrameOps& ops, int dim,
                  uint64_t frame, uint64_t max_items, uint64_t* retries) {
  wire::UpdateBatch batch;
  size_t e = 0, u = 0, i = 0;
  do {
    batch.Clear();
    batch.set_dim(static_cast<uint32_t>(dim));
    batch.set_frame(frame);
    uint64_t items = 0;
    for (; e < ops.erases.size() && items < max_items; ++e, ++items) {
      batch.add_erases(ops.erases[e]);
    }
    for (; i < ops.inserts.size() && items < max_items; ++i, ++items) {
      tools::AddSceneBox(batch.mutable_inserts(), ops.inserts[i], dim);
    }
    for (; u < ops.updates.size() && items < max_items; ++u, ++items) {
      tools::AddSceneBox(batch.mutable_updates(), ops.updates[u], dim);
    }
    const bool last = e == ops.erases.size() && i == ops.inserts.size() && u == ops.updates.size();
    batch.set_end_of_frame(last);
    for (;;) {
      Status s = pub.Publish(&batch);
      if (s.ok()) break;
      if (s.code() != StatusCode::kDeadlineExceeded) {
        std::fprintf(stderr, "bpctl scene: %s\n", s.ToString().c_str());
        return false;
      }
      ++*retries;  // the daemon is saturated (or a restate was cut short): retry the batch
      if (StopRequested()) return false;
    }
  } while (e < ops.erases.size() || i < ops.inserts.size() || u < ops.updates.size());
  return true;
}

}  // namespace

int Scene(const Common& common, const SceneOptions& options) {
  if (options.params.dim != common.config.engine.dimension) {
    std::fprintf(stderr, "bpctl scene: the scene is %d-D but the daemon's config says %d-D\n",
                 options.params.dim, common.config.engine.dimension);
    return 2;
  }
  auto connection = Connect(common);
  if (!connection) return 1;
  // Batches the daemon accepts: at most limits.max_batch_items items, and bytes below
  // limits.max_batch_bytes (a box costs at most 8 + 2 * 3 * 8 bytes plus tags; 64 is safe).
  const uint64_t max_items =
      std::max<uint64_t>(1, std::min({options.max_items, common.config.limits.max_batch_items,
                                      common.config.limits.max_batch_bytes / 64}));
  client::PublisherOptions publisher_options;
  publisher_options.write_timeout = std::chrono::milliseconds(common.config.dds.write_timeout_ms);
  publisher_options.restate_on_restart = options.restate;
  publisher_options.restate_batch_items =
      static_cast<uint32_t>(std::min<uint64_t>(max_items, UINT32_MAX));
  std::optional<transport::ShardMap> map;
  if (!LoadShardMap(common, "scene", &map)) return 2;
  // One daemon, or every shard of the world (routed by the client library).
  std::unique_ptr<client::UpdatePublisher> single;
  std::unique_ptr<client::ShardedPublisher> sharded;
  Status created = map ? client::ShardedPublisher::Create(*connection, *map, options.producer,
                                                          publisher_options, &sharded)
                       : client::UpdatePublisher::Create(*connection, options.producer,
                                                         publisher_options, &single);
  if (!created.ok()) {
    std::fprintf(stderr, "bpctl scene: %s\n", created.ToString().c_str());
    return 1;
  }
  client::BatchPublisher* pub =
      map ? static_cast<client::BatchPublisher*>(sharded.get()) : single.get();
  if (Status s = WaitInterruptibly(common.wait_s,
                                   [&](std::chrono::milliseconds t) {
                                     return map ? sharded->WaitForDaemon(t)
                                                : single->WaitForReaders(options.readers, t);
                                   });
      !s.ok()) {
    std::fprintf(stderr, "bpctl scene: no daemon on domain %u partition '%s' (%s)\n",
                 common.config.dds.domain, common.config.dds.partition.c_str(),
                 s.ToString().c_str());
    return 1;
  }
  const auto& p = options.params;
  if (!options.quiet) {
    std::fprintf(stderr,
                 "bpctl scene: n %u, moving %u, churn %u, %d-D, seed %llu, producer %u, %.1f Hz\n",
                 p.n, p.moving, p.churn, p.dim, static_cast<unsigned long long>(p.seed),
                 options.producer, options.rate_hz);
  }
  // The daemon's epoch before the first frame (else the first status report would look like a
  // restart and cost a restate of everything).
  for (int i = 0; options.restate && single && i < 200 && single->daemon_epoch() == 0; ++i) {
    (void)single->Maintain();
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  workload::Scene scene(p);
  workload::FrameOps ops;
  ops.inserts = scene.Initial();
  uint64_t retries = 0;
  const auto start = std::chrono::steady_clock::now();
  auto report_at = start + std::chrono::seconds(1);
  uint64_t reported_frames = 0;
  auto last_report = start;
  const auto period = options.rate_hz > 0
                          ? std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                std::chrono::duration<double>(1.0 / options.rate_hz))
                          : std::chrono::steady_clock::duration::zero();
  auto next = start;
  uint64_t frame = 0;
  uint64_t late = 0;
  bool failed = false;
  for (;;) {
    if (!PublishFrame(*pub, ops, p.dim, frame + 1, max_items, &retries)) {
      if (!StopRequested()) failed = true;
      break;
    }
    ++frame;
    if (options.frames != 0 && frame > options.frames) break;
    if (StopRequested()) break;
    const auto now = std::chrono::steady_clock::now();
    if (!options.quiet && now >= report_at) {
      const double elapsed = std::chrono::duration<double>(now - last_report).count();
      std::fprintf(stderr, "bpctl scene: frame %llu, %.1f frames/s, %llu late, %llu retries\n",
                   static_cast<unsigned long long>(frame),
                   static_cast<double>(frame - reported_frames) / elapsed,
                   static_cast<unsigned long long>(late), static_cast<unsigned long long>(retries));
      reported_frames = frame;
      last_report = now;
      report_at = now + std::chrono::seconds(1);
    }
    // The next frame is generated after the wait, just before it is published, as a simulator
    // steps at its tick. Generated right after publishing, it took a CPU from the daemon while
    // the daemon worked on the frame just sent, where the daemon, the scene and the watcher share
    // few CPUs, and lengthened the update→event tail.
    next += period;
    if (next > std::chrono::steady_clock::now()) {
      std::this_thread::sleep_until(next);
    } else if (period.count() > 0) {
      ++late;  // the frame took longer than the period: publish the next one at once
      next = std::chrono::steady_clock::now();
    }
    scene.NextFrame(&ops);
  }
  (void)pub->Flush(std::chrono::seconds(5));
  auto restates = [&] {
    if (single) return single->restates();
    uint64_t n = 0;
    for (size_t i = 0; i < sharded->shards(); ++i) n += sharded->shard(i).restates();
    return n;
  };
  if (sharded && !options.quiet) {
    std::fprintf(stderr,
                 "bpctl scene: %zu shards, %zu of %zu objects on a border, %llu handovers\n",
                 sharded->shards(), sharded->border_objects(), sharded->objects(),
                 static_cast<unsigned long long>(sharded->handovers()));
  }
  if (!options.quiet) {
    const double seconds = SecondsSince(start);
    std::fprintf(stderr,
                 "bpctl scene: published %llu frames in %.2f s (%.1f frames/s), %llu late, "
                 "%llu restates to a restarted daemon\n",
                 static_cast<unsigned long long>(frame), seconds,
                 static_cast<double>(frame) / std::max(seconds, 1e-9),
                 static_cast<unsigned long long>(late),
                 static_cast<unsigned long long>(restates()));
  }
  return failed ? 1 : 0;
}

}  // namespace bp::bpctl
