// bp::service::Daemon: broadphased's loop. Updates in (DDS), engine, events out (DDS).
//
// One thread runs Run(): it waits on the updates reader, validates and applies each batch
// through the EngineHost, closes a frame on an end_of_frame batch (or on a fixed tick), queries
// the engine and publishes the frame's EventBatch parts, and publishes Status reports (health and
// interval statistics periodically, rejections as they happen). RequestStop() makes Run() take
// what has already arrived, finish the frame (query and publish if anything changed since the
// last frame), wait briefly for subscribers' acknowledgements, report STOPPING and return.
//
// Thread safety: Run() on one thread; RequestStop() and the counters from any thread.
// Snapshot requests (requests topic) are served between frames: the complete overlap set as of
// the last frame, as snapshot parts on the events topic, in the same sequence as the events.
//
// Producers: a producer id belongs to the DDS writer that first used it. When that writer stops
// being alive (its process died or hung: its liveliness lease expired; or it left) for
// producers.lease_s, the producer's objects are erased and a frame publishes the uncollides. A
// new writer may take the id over once the old one is not alive or gone; it starts afresh (the
// old incarnation's objects are erased first).
//
// Invariants: EventBatch.sequence increases by one per part written (events and snapshots),
// also when a write failed, so subscribers see every loss as a gap; every part carries the
// run's random epoch; a batch's valid items are applied even when others
// are rejected; no input makes Run() fail (only DDS failures do).
//
// Interests (interests.h): clients declare them on the interests topic; each interest's events
// go out on a writer of its own in the interest's partition, with its own sequence, epoch and
// snapshots; the whole-world stream is unchanged (regions never show in it). An interest whose
// declaring writer has not been alive for producers.lease_s is dropped. Spot queries on the
// same topic are answered between frames on the replies topic, in the client's partition.
//
// The code is one file per concern: daemon.cc (creation, the loop, intake), daemon_producers.cc
// (producers over time), daemon_output.cc (frames, events, snapshots, status),
// daemon_interests.cc (interests, their streams, spot queries). Why one class of
// about thirty members: every concern runs on the one thread of Run() and reads the others'
// state (a frame reads the producers' resyncs, the status the intake's counters); the members
// are grouped by concern below.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "broadphase.pb.h"
#include "config.h"
#include "engine_host.h"
#include "interests.h"
#include "keep_awake.h"

#include "bp/status.h"
#include "bp/transport/connection.h"
#include "bp/transport/dds.h"

namespace bp::service {

class Daemon {
 public:
  /// Builds the engine and joins DDS as config says.
  static Status Create(const Config& config, std::unique_ptr<Daemon>* out);
  ~Daemon();
  /// Makes this daemon announce itself as a shard of a sharded world in every status report
  /// (its DDS partition, the shard's, comes from config). Call before Run().
  void SetShard(const wire::ShardInfo& shard) { shard_ = shard; }
  /// Serves until RequestStop(); ok on a clean stop.
  Status Run();
  /// Asks Run() to finish the frame and return (thread-safe; not async-signal-safe).
  void RequestStop();

  /// Frames closed so far.
  uint64_t frames() const { return frames_.load(); }
  /// Items rejected so far.
  uint64_t rejected() const { return rejected_total_.load(); }
  /// Producers whose objects were erased because their lease ran out.
  uint64_t producers_expired() const { return producers_expired_.load(); }
  /// Snapshots published so far.
  uint64_t snapshots() const { return snapshots_published_.load(); }
  /// CPUs kept awake while Run serves (frames.keep_cpus_awake_ms; 0 when off or refused).
  unsigned cpus_kept_awake() const { return cpus_kept_awake_.load(); }
  /// This run's epoch (EventBatch.epoch).
  uint64_t epoch() const { return epoch_; }
  /// Update batches received so far (malformed ones included).
  uint64_t batches() const { return batches_total_.load(); }
  /// True once Run() is serving (its readers and writers exist and SERVING was published).
  bool serving() const { return serving_.load(); }
  /// Interests in force.
  uint64_t interests() const { return interests_count_.load(); }
  /// Interest requests refused so far.
  uint64_t interest_refusals() const { return interest_refusals_total_.load(); }

 private:
  // Samples a take reads at most (updates and requests).
  static constexpr size_t kTakeBatch = 64;

  Daemon() = default;
  void ProcessPayload(std::span<const uint8_t> payload, const dds_sample_info_t& info);
  bool ClaimProducer(uint32_t producer, dds_instance_handle_t writer);
  // The producer id the writer holds, or 0 if it holds none or several.
  uint32_t WriterProducer(dds_instance_handle_t writer) const;
  // Takes the writers' liveliness changes; erases the objects of producers whose writer has been
  // gone for producers.lease_s. Returns when the next one is due (time_point::max() if none).
  std::chrono::steady_clock::time_point CheckProducers();
  // Erases producer's objects and forgets the producer. lease: its lease ran out (counted, a
  // frame runs at once, the status report lists it); else a take-over by a new writer.
  void ExpireProducer(uint32_t producer, const std::string& why, bool lease);
  // The claim of a writer that Cyclone dropped (a stall longer than the participant lease) and
  // has just discovered again under a new handle moves to that handle; its producers are asked
  // to restate (batches around the stall may be lost, and a resting producer shows no gap).
  void FollowRediscoveredWriter(dds_instance_handle_t writer);
  // Asks producers to restate (DaemonStatus.resync, listed in every report until a whole
  // restate run arrives); a request is raised (and a report published) at most once a second.
  void RequestResync(const std::vector<uint32_t>& producers, const char* why);
  // Raises again the requests no restate answered in time (1, 2, 4 ... 30 s); returns when the
  // next is due (time_point::max() if none).
  std::chrono::steady_clock::time_point CheckResyncs();
  // Keeps track of a producer's batch_seq and restate runs, before its batch is applied.
  // Returns false if batches were lost (a gap, a restate run missing a batch or cut short).
  bool TrackSequence(uint32_t producer);
  // After a restate batch was applied: collects its ids; the last batch of a whole run erases
  // the producer's objects it did not name and answers the request.
  void ContinueRestate(uint32_t producer);
  // Takes and processes up to max_rounds rounds of batches; with until_stop, also returns as
  // soon as a stop is requested.
  void Drain(size_t max_rounds, bool until_stop);
  // Queries and publishes a frame; restate: a restate run's last batch closed it.
  void RunFrame(uint32_t source_producer, uint64_t source_frame, uint64_t source_sent_ns,
                bool restate = false);
  // Takes the snapshot requests that arrived; publishes one snapshot if any asked for it and
  // the last one is limits.snapshot_interval_ms old. Returns when a deferred one is due
  // (time_point::max() if none).
  std::chrono::steady_clock::time_point ServeRequests();
  void PublishSnapshot();
  // Fills event_msg_ with each part of a frame's pairs (uncollides, then collides; at most
  // limits.max_pairs_per_event_batch pairs per part) and calls finish() to complete and write it.
  void ForEachEventPart(uint64_t frame, const std::vector<uint64_t>& uncollide,
                        const std::vector<uint64_t>& collide, const std::function<void()>& finish);
  // The same for snapshot_pairs_, as snapshot parts of the last frame.
  void ForEachSnapshotPart(const std::function<void()>& finish);
  // Writes event_msg_ (sequence already set); a failure is counted and logged.
  void WriteEventPart();
  // Takes the interest requests that arrived (declare, drop, spot query) and serves them.
  void ServeInterests();
  void ServeInterestRequest(std::span<const uint8_t> payload, dds_instance_handle_t writer);
  void AnswerSpotQuery(uint64_t client, dds_instance_handle_t writer, const wire::SpotQuery& query);
  void RefuseInterest(uint64_t client, uint64_t interest, std::string why);
  // Drops the interests (and reply writers) of writers not alive for producers.lease_s; returns
  // when the next one is due (time_point::max() if none).
  std::chrono::steady_clock::time_point CheckInterestOwners();
  // After a frame: each interest's events on its stream.
  void PublishInterestEvents(uint64_t frame, uint32_t source_producer, uint64_t source_frame,
                             uint64_t source_sent_ns, bool restate);
  // The interest's set on its stream (snapshot parts).
  void PublishInterestSnapshot(uint64_t id);
  // Publishes the interest snapshots asked for whose interval has passed and whose interest's
  // last change has been applied by a frame; returns when a deferred one is due
  // (time_point::max() if none waits for time).
  std::chrono::steady_clock::time_point ServeInterestSnapshots();
  struct Stream;
  // Numbers event_msg_ in the interest's stream and writes it; a failure is counted and logged.
  void WriteStreamPart(uint64_t id, Stream& stream);
  // Takes a dropped interest's stream out of streams_; reaper_ deletes its writer.
  void RetireStream(uint64_t id);
  // The whole world's overlapping pairs (the engine's, without the regions').
  uint64_t WorldOverlaps() const;
  void ReportRejection(uint32_t producer, const wire::UpdateBatch* batch, Reject&& reject);
  void FlushRejections();
  void PublishStatus(wire::Health health, bool with_interval);
  void Summary();
  // Appends the frame's line to logging.frame_log (times in ms, from the frame's stages).
  void LogFrame(uint64_t frame, int64_t wall_ns, uint32_t source_producer, uint64_t source_frame,
                uint64_t source_sent_ns, double ingest, double query, double publish);

  Config config_;
  // Before connection_: Cyclone's listener thread may call it until the reader is deleted.
  std::unique_ptr<dds::WriterLiveliness> liveliness_;
  std::unique_ptr<dds::WriterLiveliness> interest_liveliness_;
  std::unique_ptr<EngineHost> host_;
  std::unique_ptr<KeepAwake> keep_awake_;     // frames.keep_cpus_awake_ms > 0, while Run serves
  std::atomic<unsigned> cpus_kept_awake_{0};  // its threads, for other threads to read
  std::unique_ptr<transport::Connection> connection_;
  // After connection_ (destroyed before it): deletes the writers of dropped interests and gone
  // clients off the loop's thread (dds::Reaper says why).
  std::unique_ptr<dds::Reaper> reaper_ = std::make_unique<dds::Reaper>();
  dds::Reader updates_;
  dds::Writer events_;
  dds::Writer status_;
  dds::Reader requests_;
  dds::Reader interest_requests_;
  dds::WaitSet waitset_;
  std::string daemon_name_;

  std::atomic<bool> stop_{false};
  std::atomic<bool> serving_{false};
  std::atomic<uint64_t> frames_{0};
  std::atomic<uint64_t> rejected_total_{0};
  std::atomic<uint64_t> batches_total_{0};
  std::atomic<uint64_t> snapshots_published_{0};
  std::atomic<uint64_t> producers_expired_{0};
  std::atomic<uint64_t> interests_count_{0};
  std::atomic<uint64_t> interest_refusals_total_{0};

  // Frame state.
  bool frame_dirty_ = false;  // a batch was applied since the last frame
  bool summaries_ = false;    // periodic summaries are on (frame times are kept for them)
  std::chrono::nanoseconds ingest_work_{0};  // the open frame's batches: decode, validate, apply
  uint64_t frame_batches_ = 0;               // the open frame's batches
  struct FileCloser {
    void operator()(std::FILE* f) const { std::fclose(f); }
  };
  std::unique_ptr<std::FILE, FileCloser> frame_log_;  // logging.frame_log; null when off or failed
  std::chrono::steady_clock::time_point frame_log_flushed_{};
  uint64_t event_seq_ = 0;
  uint64_t status_seq_ = 0;
  uint64_t event_write_failures_ = 0;
  uint64_t epoch_ = 0;     // random per start, on every event part
  wire::ShardInfo shard_;  // name empty: not a shard
  // The source of the last frame a producer's batch closed: carried by snapshot parts.
  uint32_t last_source_producer_ = 0;
  uint64_t last_source_frame_ = 0;
  std::vector<std::pair<uint64_t, uint64_t>> snapshot_pairs_;
  wire::SnapshotRequest request_;
  bool snapshot_due_ = false;  // a request arrived and its snapshot waits for the interval
  std::chrono::steady_clock::time_point last_snapshot_{};
  std::vector<uint64_t> uncollide_;
  std::vector<uint64_t> collide_;
  wire::UpdateBatch batch_;
  wire::EventBatch event_msg_;
  wire::DaemonStatus status_msg_;
  std::string buffer_;

  // Producers: the writer that claimed each id (its handle, and its GUID, which survives a
  // rediscovery), and the last batch_seq seen.
  struct Claim {
    dds_instance_handle_t writer = 0;
    dds::Guid guid{};
  };
  std::unordered_map<uint32_t, Claim> claims_;
  std::unordered_map<uint32_t, uint64_t> last_batch_seq_;
  // Restate runs under way, by producer: the batch_seq of the run's first batch and the
  // producer-local ids named so far. A broken run (a batch missing or refused) keeps no ids and
  // erases nothing.
  struct RestateRun {
    uint64_t first = 0;
    bool broken = false;
    std::vector<uint64_t> ids;
  };
  std::unordered_map<uint32_t, RestateRun> runs_;
  // Producers asked to restate, until a whole run arrives (sorted for the reports): the report
  // that raised the request last, and when to raise it again if no restate comes.
  struct Resync {
    uint64_t raised = 0;
    std::chrono::steady_clock::time_point last_raise{};
    std::chrono::steady_clock::duration backoff{};
  };
  std::map<uint32_t, Resync> resync_;
  // Writers of the updates topic that are not alive (lost liveliness or left), since when.
  std::unordered_map<dds_instance_handle_t, std::chrono::steady_clock::time_point> down_since_;
  std::vector<dds::WriterLiveliness::Change> liveliness_changes_;
  std::chrono::steady_clock::time_point next_forget_{};
  std::vector<uint32_t> expired_now_;  // listed in the status report being published

  // Interests: the table (after host_, which it uses), one stream per interest, one reply writer
  // per client that asked a spot query, the declaring writers that are not alive.
  std::unique_ptr<InterestTable> interests_;
  struct Stream {
    dds::Writer writer;
    uint64_t seq = 0;
    uint64_t epoch = 0;         // random per stream
    bool snapshot_due = false;  // requested, waiting for limits.snapshot_interval_ms
    bool published = false;     // a part of the current frame was written (shards)
    std::chrono::steady_clock::time_point last_snapshot{};
  };
  std::unordered_map<uint64_t, Stream> streams_;

  struct ReplyWriter {
    dds::Writer writer;
    dds_instance_handle_t owner = 0;
    uint64_t seq = 0;
  };
  std::unordered_map<uint64_t, ReplyWriter> reply_writers_;  // by client id
  std::unordered_map<dds_instance_handle_t, std::chrono::steady_clock::time_point>
      interest_down_since_;
  std::vector<dds::WriterLiveliness::Change> interest_liveliness_changes_;
  bool interests_changed_ = false;  // a declaration or drop waits for a frame
  std::vector<wire::InterestRefusal> pending_refusals_;
  std::vector<uint64_t> dropped_now_;  // interests dropped by the lease, for the next report
  wire::InterestRequest interest_request_;
  wire::SpotAnswer answer_;
  std::vector<uint64_t> spot_keys_;

  // Rejections of the batch being processed.
  std::vector<wire::Rejection> pending_rejections_;
  uint64_t pending_not_listed_ = 0;

  // Interval statistics.
  std::chrono::steady_clock::time_point interval_start_;
  // Per frame of the interval, in ms: the whole daemon work, and its stages (ingest: the
  // frame's batches decoded, validated and applied; query: the engine's query; publish: the
  // event parts encoded and written).
  std::vector<double> frame_ms_, ingest_ms_, query_ms_, publish_ms_;
  uint64_t interval_frames_ = 0;
  uint64_t interval_batches_ = 0;
  uint64_t interval_updates_ = 0;
  uint64_t interval_events_ = 0;
  uint64_t interval_rejected_ = 0;
  wire::IntervalStats last_interval_;
};

}  // namespace bp::service
