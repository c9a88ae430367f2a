// bp::client::UpdatePublisher: publishes a producer's UpdateBatch messages to the daemon.
//
// It stamps each batch with the schema version, the producer id, a batch sequence number
// (1, 2, ...) and the send time, serialises it into a reused buffer and writes it. When the
// daemon falls behind, Publish blocks for at most the write timeout, then returns
// DeadlineExceeded and the batch was not sent: the caller decides to retry or to stop.
//
// Liveliness: the writer offers AUTOMATIC liveliness with `liveliness_lease`. If the producer's
// process dies (or hangs), the daemon notices after about that long, and erases the producer's
// objects after its `producers.lease_s` (with uncollide events for their pairs).
//
// Restating after a daemon restart (`restate_on_restart`): the publisher keeps a copy of every
// object it has published (the last box and the insert's attributes, as sent) and follows the
// daemon's status reports. When a daemon with a new epoch appears (a restarted daemon starts
// empty), the next Publish or Maintain first sends every kept object as a restate insert
// (UpdateBatch.restate, in batches of `restate_batch_items`, the last closing a frame), then the
// caller's batch. It restates too when the daemon reports that it erased this producer's objects
// (DaemonStatus.expired_producers: the process hung longer than producers.lease_s) or that it
// may have missed some of its batches (DaemonStatus.resync: a batch_seq gap, or DDS
// dropped and rediscovered the producer after a stall longer than the participant lease). A
// restate states the whole set: the daemon erases this producer's objects it does not name
// (objects published with PublishRaw too). Restate batches fit within the limits the daemon's
// reports announce (and restate_batch_items).
// Updates that reach the new daemon before the producer learned of it are refused (UNKNOWN_ID,
// in the daemon's status) and the restate that follows carries their boxes: nothing is lost.
//
// Thread safety: one thread at a time per publisher.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "broadphase.pb.h"

#include "bp/client/connection.h"
#include "bp/status.h"
#include "bp/transport/clock.h"

namespace bp::client {

/// Current CLOCK_REALTIME in nanoseconds (the clock of every *_time_ns field).
using transport::WallClockNs;

struct PublisherOptions {
  /// Longest a Publish blocks on a daemon that falls behind (then DeadlineExceeded).
  std::chrono::milliseconds write_timeout{5000};
  /// The writer's AUTOMATIC liveliness lease: how soon the daemon notices a dead producer.
  std::chrono::milliseconds liveliness_lease{1000};
  /// Keep the published objects and restate them to a restarted daemon (see above).
  bool restate_on_restart = false;
  /// Most objects per restate batch (fewer if the daemon's limits require it).
  uint32_t restate_batch_items = 65536;
};

class KeptObjects;

/// What a producer needs of a publisher: UpdatePublisher (one daemon) and ShardedPublisher
/// (bp/client/sharded.h: a world served by several daemons) both are one.
class BatchPublisher {
 public:
  virtual ~BatchPublisher() = default;
  /// Waits until the daemon (every daemon) can receive batches.
  virtual Status WaitForDaemon(std::chrono::milliseconds timeout) = 0;
  /// Stamps and publishes batch.
  virtual Status Publish(wire::UpdateBatch* batch) = 0;
  /// Restates when a daemon asks for it or restarted (a producer that rests calls it).
  virtual Status Maintain() = 0;
  /// Waits until every matched reader acknowledged what was published.
  virtual Status Flush(std::chrono::milliseconds timeout) = 0;
};

class UpdatePublisher : public BatchPublisher {
 public:
  ~UpdatePublisher() override;
  /// A publisher for producer id (1..65535) on connection (which must outlive it).
  static Status Create(Connection& connection, uint32_t producer, const PublisherOptions& options,
                       std::unique_ptr<UpdatePublisher>* out);
  /// Create with the default options and this write timeout.
  static Status Create(Connection& connection, uint32_t producer,
                       std::chrono::milliseconds write_timeout,
                       std::unique_ptr<UpdatePublisher>* out);
  /// Waits until the daemon's update reader has matched, so that no batch is lost to discovery
  /// (with restate_on_restart, also until the daemon's epoch is known).
  Status WaitForDaemon(std::chrono::milliseconds timeout) override;
  /// Waits until n readers (the daemon, recorders...) have matched.
  Status WaitForReaders(uint32_t n, std::chrono::milliseconds timeout) const {
    return writer_.WaitForReaders(n, timeout);
  }
  /// Stamps (version, producer, batch_seq, sent_time_ns) and publishes batch (after a restate,
  /// if one is due).
  Status Publish(wire::UpdateBatch* batch) override;
  /// With restate_on_restart: reads the daemon's status reports and restates the kept objects if
  /// the daemon restarted. Publish calls it; a producer that may rest for long calls it too.
  Status Maintain() override;
  /// Publishes payload bytes as they are (replay of recordings; malformed-input tests). They do
  /// not reach the kept objects.
  Status PublishRaw(std::string_view payload);
  /// Waits until every matched reader acknowledged what was published.
  Status Flush(std::chrono::milliseconds timeout) override { return writer_.WaitForAcks(timeout); }
  uint32_t producer() const { return producer_; }
  /// Batches published so far (restate batches included).
  uint64_t published() const { return seq_; }
  /// Objects kept for restating (0 without restate_on_restart).
  size_t kept_objects() const;
  /// Restates sent so far.
  uint64_t restates() const { return restates_; }
  /// The epoch of the daemon last seen (0: none yet, or restate_on_restart is off).
  uint64_t daemon_epoch() const { return epoch_; }

 private:
  UpdatePublisher();
  Status Stamp(wire::UpdateBatch* batch);
  void Keep(const wire::UpdateBatch& batch);
  Status Restate();
  void ReadLimits();  // from status_msg_

  PublisherOptions options_;
  dds::Writer writer_;
  dds::Reader status_;  // only with restate_on_restart
  uint32_t producer_ = 0;
  uint64_t seq_ = 0;
  std::string buffer_;
  // Restating.
  std::unique_ptr<KeptObjects> kept_;  // always allocated; empty without restate_on_restart
  uint32_t dim_ = 0;
  uint64_t frame_ = 0;
  uint64_t epoch_ = 0;
  std::vector<uint64_t> retired_epochs_;
  uint64_t status_seq_ = 0;     // the newest report read from the current daemon
  uint64_t answered_upto_ = 0;  // status_seq_ when the last restate began
  uint64_t daemon_max_items_ = 0, daemon_max_bytes_ = 0;
  bool restate_due_ = false;
  bool published_before_epoch_ = false;
  uint64_t restates_ = 0;
  wire::DaemonStatus status_msg_;
  wire::UpdateBatch restate_batch_;
};

}  // namespace bp::client
