// bp::client::UpdatePublisher: publishes a producer's UpdateBatch messages to the daemon.
//
// It stamps each batch with the schema version, the producer id, a batch sequence number
// (1, 2, ...) and the send time, serialises it into a reused buffer and writes it. When the
// daemon falls behind, Publish blocks for at most the write timeout, then returns
// DeadlineExceeded and the batch was not sent: the caller decides to retry or to stop.
//
// Thread safety: one thread at a time per publisher.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "broadphase.pb.h"

#include "bp/client/connection.h"
#include "bp/status.h"

namespace bp::client {

/// Current CLOCK_REALTIME in nanoseconds (the clock of every *_time_ns field).
uint64_t WallClockNs();

class UpdatePublisher {
 public:
  /// A publisher for producer id (1..65535) on connection (which must outlive it).
  static Status Create(Connection& connection, uint32_t producer,
                       std::chrono::milliseconds write_timeout,
                       std::unique_ptr<UpdatePublisher>* out);
  /// Waits until the daemon's update reader has matched, so that no batch is lost to discovery.
  Status WaitForDaemon(std::chrono::milliseconds timeout) const;
  /// Waits until n readers (the daemon, recorders...) have matched.
  Status WaitForReaders(uint32_t n, std::chrono::milliseconds timeout) const {
    return writer_.WaitForReaders(n, timeout);
  }
  /// Stamps (version, producer, batch_seq, sent_time_ns) and publishes batch.
  Status Publish(wire::UpdateBatch* batch);
  /// Publishes payload bytes as they are (replay of recordings; malformed-input tests).
  Status PublishRaw(std::string_view payload);
  /// Waits until every matched reader acknowledged what was published.
  Status Flush(std::chrono::milliseconds timeout) const { return writer_.WaitForAcks(timeout); }
  uint32_t producer() const { return producer_; }
  /// Batches published so far.
  uint64_t published() const { return seq_; }

 private:
  UpdatePublisher() = default;
  dds::Writer writer_;
  uint32_t producer_ = 0;
  uint64_t seq_ = 0;
  std::string buffer_;
};

}  // namespace bp::client
