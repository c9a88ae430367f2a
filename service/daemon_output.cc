// broadphased's frames and what goes out (daemon.h): a frame run on the engine, its events in
// parts, the frame log, snapshots on request, status reports and the periodic summary.
#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstddef>
#include <cstring>
#include <random>

#include "daemon.h"
#include <spdlog/spdlog.h>
#include <unistd.h>

#include "bp/transport/clock.h"
#include "bp/util/percentile.h"

namespace bp::service {
namespace {

using Clock = std::chrono::steady_clock;
using util::Percentile;

}  // namespace

void Daemon::RunFrame(uint32_t source_producer, uint64_t source_frame, uint64_t source_sent_ns,
                      bool restate) {
  const auto start = Clock::now();
  const int64_t start_wall_ns = frame_log_ ? static_cast<int64_t>(transport::WallClockNs()) : 0;
  host_->Query(&uncollide_, &collide_);
  interests_->OnFrame(&uncollide_, &collide_);  // the regions' pairs out, each interest's events
  const auto queried = Clock::now();
  const uint64_t frame = frames_.load() + 1;
  const size_t pairs = (uncollide_.size() + collide_.size()) / 2;
  ForEachEventPart(frame, uncollide_, collide_, [&] {
    event_msg_.set_sequence(++event_seq_);
    event_msg_.set_source_producer(source_producer);
    event_msg_.set_source_frame(source_frame);
    event_msg_.set_source_sent_time_ns(source_sent_ns);
    event_msg_.set_restate(restate);
    event_msg_.set_resyncing(!resync_.empty());
    event_msg_.set_objects(host_->Objects());
    event_msg_.set_overlaps(WorldOverlaps());
    WriteEventPart();
  });
  // The key of later snapshots: the producer frame their set is as of. After a restate, an
  // expiry, a tick or a stop the set is as of no frame a producer closed, until the next one.
  if (restate || source_producer == 0) {
    last_source_producer_ = 0;
    last_source_frame_ = 0;
  } else if (source_producer != 0) {
    last_source_producer_ = source_producer;
    last_source_frame_ = source_frame;
  }
  PublishInterestEvents(frame, source_producer, source_frame, source_sent_ns, restate);
  frames_.store(frame);
  frame_dirty_ = false;
  ++interval_frames_;
  interval_events_ += pairs;
  if (summaries_ || frame_log_) {
    using Ms = std::chrono::duration<double, std::milli>;
    const double ingest = Ms(ingest_work_).count(), query = Ms(queried - start).count(),
                 publish = Ms(Clock::now() - queried).count();
    // Kept for the summary's percentiles only, and cleared by it (no summary, no growth).
    if (summaries_) {
      ingest_ms_.push_back(ingest);
      query_ms_.push_back(query);
      publish_ms_.push_back(publish);
      frame_ms_.push_back(ingest + query + publish);
    }
    if (frame_log_) {
      LogFrame(frame, start_wall_ns, source_producer, source_frame, source_sent_ns, ingest, query,
               publish);
    }
  }
  ingest_work_ = std::chrono::nanoseconds(0);
  frame_batches_ = 0;
}

void Daemon::LogFrame(uint64_t frame, int64_t wall_ns, uint32_t source_producer,
                      uint64_t source_frame, uint64_t source_sent_ns, double ingest, double query,
                      double publish) {
  const Stats st = host_->GetStats();
  const GridStats grid = st.grid.value_or(GridStats{});  // zeros for an engine that is no grid
  std::FILE* f = frame_log_.get();
  const int written = std::fprintf(
      f,
      "%" PRIu64 ",%" PRId64 ",%" PRIu32 ",%" PRIu64 ",%" PRIu64 ",%" PRIu64
      ",%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%zu,%zu,%zu,%zu,%zu,%zu,%zu,%zu\n",
      frame, wall_ns, source_producer, source_frame, source_sent_ns, frame_batches_, ingest, query,
      publish, st.prepare_ms, st.core_ms, grid.route_ms, grid.cells_ms, grid.fold_ms, st.events_ms,
      st.inserts, st.updates, st.erases, st.collides, st.uncollides, st.objects, st.overlaps,
      grid.cells_queried);
  // Buffered; flushed about once a second (and when the daemon stops), so that a reader follows
  // the file without a write per frame.
  const auto now = Clock::now();
  const bool flush = now - frame_log_flushed_ >= std::chrono::seconds(1);
  if (written < 0 || (flush && std::fflush(f) != 0)) {
    spdlog::error("logging.frame_log: cannot write ({}); no more frames are logged",
                  std::strerror(errno));
    frame_log_.reset();
    return;
  }
  if (flush) frame_log_flushed_ = now;
}

void Daemon::ForEachEventPart(uint64_t frame, const std::vector<uint64_t>& uncollide,
                              const std::vector<uint64_t>& collide,
                              const std::function<void()>& finish) {
  const size_t n_unc = uncollide.size() / 2;
  const size_t pairs = n_unc + collide.size() / 2;
  const size_t per_part = static_cast<size_t>(config_.limits.max_pairs_per_event_batch);
  const size_t parts = std::max<size_t>(1, (pairs + per_part - 1) / per_part);
  for (size_t part = 0, next = 0; part < parts; ++part) {
    event_msg_.Clear();
    event_msg_.set_version(wire::SCHEMA_VERSION_1);
    event_msg_.set_frame(frame);
    event_msg_.set_part(static_cast<uint32_t>(part));
    event_msg_.set_last_part(part + 1 == parts);
    // The part's pairs [next, end) over the concatenation: a run of uncollides, then a run of
    // collides, copied whole.
    const size_t end = std::min(pairs, next + per_part);
    if (next < n_unc) {
      event_msg_.mutable_uncollide()->Add(
          uncollide.begin() + static_cast<std::ptrdiff_t>(2 * next),
          uncollide.begin() + static_cast<std::ptrdiff_t>(2 * std::min(end, n_unc)));
    }
    if (end > n_unc) {
      const size_t from = std::max(next, n_unc) - n_unc;
      event_msg_.mutable_collide()->Add(
          collide.begin() + static_cast<std::ptrdiff_t>(2 * from),
          collide.begin() + static_cast<std::ptrdiff_t>(2 * (end - n_unc)));
    }
    next = end;
    finish();
  }
}

void Daemon::ForEachSnapshotPart(const std::function<void()>& finish) {
  const size_t pairs = snapshot_pairs_.size();
  const size_t per_part = static_cast<size_t>(config_.limits.max_pairs_per_event_batch);
  const size_t parts = std::max<size_t>(1, (pairs + per_part - 1) / per_part);
  for (size_t part = 0, next = 0; part < parts; ++part) {
    event_msg_.Clear();
    event_msg_.set_version(wire::SCHEMA_VERSION_1);
    event_msg_.set_frame(frames_.load());
    event_msg_.set_part(static_cast<uint32_t>(part));
    event_msg_.set_last_part(part + 1 == parts);
    event_msg_.set_snapshot(true);
    for (const size_t end = std::min(pairs, next + per_part); next < end; ++next) {
      event_msg_.add_snapshot_pairs(snapshot_pairs_[next].first);
      event_msg_.add_snapshot_pairs(snapshot_pairs_[next].second);
    }
    finish();
  }
}

void Daemon::WriteEventPart() {
  event_msg_.set_epoch(epoch_);
  event_msg_.set_published_time_ns(transport::WallClockNs());
  buffer_.clear();
  Status s = event_msg_.SerializeToString(&buffer_)
                 ? events_.Write(event_msg_.sequence(), buffer_)
                 : Status(StatusCode::kResourceExhausted,
                          "the part does not serialise (over 2 GiB?); lower "
                          "limits.max_pairs_per_event_batch");
  if (!s.ok()) {
    ++event_write_failures_;
    spdlog::error("frame {} {}part {}: not delivered ({}); subscribers see a gap at sequence {}",
                  event_msg_.frame(), event_msg_.snapshot() ? "snapshot " : "", event_msg_.part(),
                  s.ToString(), event_msg_.sequence());
  }
}

std::chrono::steady_clock::time_point Daemon::ServeRequests() {
  // One take per loop turn (bounded); requests beyond it wait for the next turn.
  size_t valid = 0;
  {
    size_t taken = 0;
    Status s = requests_.Take(
        kTakeBatch,
        [&](const dds::Received& r) {
          if (!request_.ParseFromArray(r.payload.data(), static_cast<int>(r.payload.size())) ||
              request_.version() != wire::SCHEMA_VERSION_1) {
            spdlog::warn("ignored a snapshot request that does not parse as version 1 ({} bytes)",
                         r.payload.size());
            return;
          }
          spdlog::debug("snapshot requested by {:016x} ({}), interest {:016x}",
                        request_.requester(), request_.reason(), request_.interest());
          if (request_.interest() != 0) {
            // An interest's snapshot, on its stream only (an unknown interest has none).
            const auto stream = streams_.find(request_.interest());
            if (stream != streams_.end()) stream->second.snapshot_due = true;
            return;
          }
          ++valid;
        },
        &taken);
    if (!s.ok()) spdlog::error("reading snapshot requests: {}", s.ToString());
  }
  if (valid > 0) snapshot_due_ = true;
  // One snapshot serves every request so far, at most one per limits.snapshot_interval_ms (per
  // stream); a stopping daemon publishes none.
  if (stop_.load()) return Clock::time_point::max();
  const auto interval = std::chrono::milliseconds(config_.limits.snapshot_interval_ms);
  const auto now = Clock::now();
  const auto next = ServeInterestSnapshots();
  if (!snapshot_due_) return next;
  if (last_snapshot_ != Clock::time_point{} && now < last_snapshot_ + interval) {
    return std::min(next, last_snapshot_ + interval);
  }
  PublishSnapshot();
  snapshot_due_ = false;
  last_snapshot_ = now;
  return next;
}

void Daemon::PublishSnapshot() {
  host_->Snapshot(&snapshot_pairs_);
  // The regions' pairs (a region key is below 2^48, so they come first) are not the world's.
  snapshot_pairs_.erase(snapshot_pairs_.begin(),
                        std::find_if(snapshot_pairs_.begin(), snapshot_pairs_.end(),
                                     [](const auto& p) { return p.first >= kLocalIdLimit; }));
  snapshots_published_.fetch_add(1);  // before its parts: a reader that saw them sees the count
  size_t parts = 0;
  ForEachSnapshotPart([&] {
    event_msg_.set_sequence(++event_seq_);
    event_msg_.set_source_producer(last_source_producer_);
    event_msg_.set_source_frame(last_source_frame_);
    event_msg_.set_resyncing(!resync_.empty());
    event_msg_.set_objects(host_->Objects());
    event_msg_.set_overlaps(WorldOverlaps());
    WriteEventPart();
    ++parts;
  });
  const size_t pairs = snapshot_pairs_.size();
  spdlog::info("snapshot of frame {}: {} pairs in {} part(s)", frames_.load(), pairs, parts);
}

void Daemon::PublishStatus(wire::Health health, bool with_interval) {
  status_msg_.Clear();
  status_msg_.set_version(wire::SCHEMA_VERSION_1);
  status_msg_.set_health(health);
  status_msg_.set_daemon(daemon_name_);
  status_msg_.set_engine(host_->Name());
  status_msg_.set_dim(static_cast<uint32_t>(host_->Dimension()));
  status_msg_.set_coordinate(std::string(CoordinateTypeName(config_.engine.coordinate)));
  status_msg_.set_time_ns(transport::WallClockNs());
  status_msg_.set_frame(frames_.load());
  status_msg_.set_objects(host_->Objects());
  status_msg_.set_overlaps(WorldOverlaps());
  if (with_interval) *status_msg_.mutable_interval() = last_interval_;
  for (auto& r : pending_rejections_) *status_msg_.add_rejections() = r;
  status_msg_.set_rejections_not_listed(pending_not_listed_);
  status_msg_.set_rejected_total(rejected_total_.load());
  status_msg_.set_event_write_failures(event_write_failures_);
  status_msg_.set_producers(static_cast<uint32_t>(claims_.size()));
  status_msg_.set_epoch(epoch_);
  status_msg_.set_producers_expired(producers_expired_.load());
  for (uint32_t p : expired_now_) status_msg_.add_expired_producers(p);
  for (const auto& [p, resync] : resync_) {
    wire::ResyncRequest* request = status_msg_.add_resync();
    request->set_producer(p);
    const auto seen = last_batch_seq_.find(p);
    request->set_seen_batch_seq(seen == last_batch_seq_.end() ? 0 : seen->second);
    request->set_raised(resync.raised);
  }
  for (const auto& r : pending_refusals_) *status_msg_.add_interest_refusals() = r;
  for (uint64_t id : dropped_now_) status_msg_.add_dropped_interests(id);
  status_msg_.set_interests(static_cast<uint32_t>(interests_->size()));
  status_msg_.set_max_batch_items(config_.limits.max_batch_items);
  status_msg_.set_max_batch_bytes(config_.limits.max_batch_bytes);
  if (!shard_.name().empty()) *status_msg_.mutable_shard() = shard_;
  buffer_.clear();
  if (!status_msg_.SerializeToString(&buffer_)) {
    spdlog::warn("status report does not serialise");
    return;
  }
  if (Status s = status_.Write(++status_seq_, buffer_); !s.ok()) {
    spdlog::warn("status report not delivered: {}", s.ToString());
  }
}

void Daemon::Summary() {
  const auto now = Clock::now();
  const double seconds = std::chrono::duration<double>(now - interval_start_).count();
  wire::IntervalStats& st = last_interval_;
  st.Clear();
  st.set_seconds(seconds);
  st.set_frames(interval_frames_);
  st.set_batches(interval_batches_);
  st.set_updates(interval_updates_);
  st.set_events(interval_events_);
  st.set_rejected(interval_rejected_);
  st.set_frame_ms_p50(Percentile(frame_ms_, 0.50));
  st.set_frame_ms_p99(Percentile(frame_ms_, 0.99));
  st.set_frame_ms_max(frame_ms_.empty() ? 0.0
                                        : *std::max_element(frame_ms_.begin(), frame_ms_.end()));
  st.set_ingest_ms_p50(Percentile(ingest_ms_, 0.50));
  st.set_ingest_ms_p99(Percentile(ingest_ms_, 0.99));
  st.set_query_ms_p50(Percentile(query_ms_, 0.50));
  st.set_query_ms_p99(Percentile(query_ms_, 0.99));
  st.set_publish_ms_p50(Percentile(publish_ms_, 0.50));
  st.set_publish_ms_p99(Percentile(publish_ms_, 0.99));
  const double per_s = seconds > 0 ? 1.0 / seconds : 0.0;
  spdlog::info(
      "objects {} | {:.1f} frames/s | {:.0f} updates/s | {:.0f} events/s | frame p50 "
      "{:.3f} ms p99 {:.3f} ms (p50 ingest {:.3f}, query {:.3f}, publish {:.3f} ms) | rejected {}",
      host_->Objects(), static_cast<double>(interval_frames_) * per_s,
      static_cast<double>(interval_updates_) * per_s, static_cast<double>(interval_events_) * per_s,
      st.frame_ms_p50(), st.frame_ms_p99(), st.ingest_ms_p50(), st.query_ms_p50(),
      st.publish_ms_p50(), interval_rejected_);
  PublishStatus(wire::SERVING, true);
  interval_start_ = now;
  for (auto* v : {&frame_ms_, &ingest_ms_, &query_ms_, &publish_ms_}) v->clear();
  interval_frames_ = interval_batches_ = interval_updates_ = interval_events_ = interval_rejected_ =
      0;
}

}  // namespace bp::service
