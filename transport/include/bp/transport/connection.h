// bp::transport::Connection: one DDS participant joined to a broadphase deployment (domain,
// partition, topic names) and the QoS every party uses on each topic.
//
// QoS (docs/PROTOCOL.md explains the choice):
//  - updates: reliable, KEEP_ALL, the daemon's reader bounded to `update_queue` samples. A
//    producer faster than the daemon blocks in dds_write (back-pressure) for at most
//    `write_timeout`, then gets DeadlineExceeded: updates are never dropped silently. Writers
//    offer AUTOMATIC liveliness with a lease (1 s by default), so the daemon learns that a
//    producer died and, after `producers.lease_s`, erases its objects.
//  - events: reliable, KEEP_LAST `event_history` at the daemon, KEEP_LAST `depth` at each
//    subscriber. A slow subscriber loses the oldest batches (it sees a gap in `sequence`)
//    instead of growing memory or stalling the daemon.
//  - status: reliable, TRANSIENT_LOCAL, KEEP_LAST 16: a late joiner gets the latest reports.
//  - requests: reliable, KEEP_LAST (a few at the subscriber, 64 at the daemon): snapshot
//    requests; one is enough, so losing older ones costs nothing.
//  - interests: reliable, KEEP_ALL with AUTOMATIC liveliness (as updates): declarations are
//    never dropped, and the daemon drops the interests of a client whose writer died.
//  - replies: reliable, KEEP_LAST 64: spot-query answers, in the asking client's partition.
//  An interest's events travel on the events topic in the interest's partition
//  (InterestPartition), a client's replies in its own (ClientPartition): DDS matches a reader
//  and a writer only when they share a partition, so other subscribers receive none of the
//  bytes.
//
// Thread safety: a Connection may be shared by publishers and subscribers on several threads.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>

#include "bp/status.h"
#include "bp/transport/dds.h"

namespace bp::transport {

/// Topic names of one deployment.
struct TopicNames {
  std::string updates = "bp_updates";
  std::string events = "bp_events";
  std::string status = "bp_status";
  std::string requests = "bp_requests";
  std::string interests = "bp_interests";
  std::string replies = "bp_replies";
};

/// A random nonzero 64-bit id (a client's, an interest's, a stream's epoch).
uint64_t RandomId();

/// The partition of interest `interest`'s events: "<partition>.interest.<16 hex digits>"
/// ("interest.<hex>" in the default partition).
std::string InterestPartition(const std::string& partition, uint64_t interest);
/// The partition of client `client`'s replies: "<partition>.client.<16 hex digits>".
std::string ClientPartition(const std::string& partition, uint64_t client);

/// Where a deployment lives.
struct ConnectionOptions {
  uint32_t domain = 0;      ///< DDS domain id
  std::string cyclone_xml;  ///< Cyclone configuration text; "" = Cyclone's default
  std::string partition;    ///< "" = the default partition
  TopicNames topics;
};

/// Reads a whole text file (a Cyclone XML configuration, say). NotFound names the path.
Status ReadTextFile(const std::string& path, std::string* out);

/// The QoS of each topic (see the header comment).
namespace qos {
/// Updates topic, writer side (producers). AUTOMATIC liveliness with liveliness_lease: the
/// daemon notices a producer whose process died about this long after it died.
void UpdatesWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout,
                   std::chrono::milliseconds liveliness_lease = std::chrono::milliseconds(1000));
/// Updates topic, reader side (the daemon), bounded to queue samples.
void UpdatesReader(dds_qos_t* qos, int32_t queue);
/// Events topic, writer side (the daemon).
void EventsWriter(dds_qos_t* qos, int32_t history, std::chrono::milliseconds write_timeout);
/// Events topic, reader side (subscribers), keeping the newest depth batches.
void EventsReader(dds_qos_t* qos, int32_t depth);
/// Status topic, writer side (the daemon).
void StatusWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout);
/// Status topic, reader side.
void StatusReader(dds_qos_t* qos, int32_t depth);
/// Requests topic, writer side (subscribers asking for a snapshot).
void RequestsWriter(dds_qos_t* qos);
/// Requests topic, reader side (the daemon).
void RequestsReader(dds_qos_t* qos);
/// Interests topic, writer side (clients), with AUTOMATIC liveliness of liveliness_lease.
void InterestsWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout,
                     std::chrono::milliseconds liveliness_lease = std::chrono::milliseconds(1000));
/// Interests topic, reader side (the daemon).
void InterestsReader(dds_qos_t* qos);
/// Replies topic, writer side (the daemon).
void RepliesWriter(dds_qos_t* qos, std::chrono::milliseconds write_timeout);
/// Replies topic, reader side (a client).
void RepliesReader(dds_qos_t* qos);
}  // namespace qos

/// The topics of a deployment.
enum class TopicId { kUpdates, kEvents, kStatus, kRequests, kInterests, kReplies };
inline constexpr size_t kTopicCount = 6;

/// A participant of a deployment; its topics are created on first use. (With DDS Security, a
/// participant may only create the topics its permissions cover, so each role creates only the
/// ones it reads or writes.)
class Connection {
 public:
  /// Joins the deployment described by options.
  static Status Open(const ConnectionOptions& options, std::unique_ptr<Connection>* out);
  /// A connection sharing this one's participant and topics, whose writers and readers are in
  /// partition instead (a shard's, ShardPartition). It keeps the participant alive.
  std::unique_ptr<Connection> Scoped(const std::string& partition) const;
  dds::Participant& participant() { return shared_->participant; }
  const dds::Participant& participant() const { return shared_->participant; }
  /// The topic's handle, created on first use; the error names the topic (e.g. "Not Allowed By
  /// Security" when the permissions do not cover it).
  Status GetTopic(TopicId id, dds_entity_t* out);
  /// A writer of topic id with qos, in the connection's partition or, if partition is given, in
  /// that one.
  Status CreateWriter(TopicId id, const dds::Qos& qos, dds::Writer* out,
                      const std::string* partition = nullptr);
  /// A reader of topic id with qos (recording its writers' liveliness if given), in the
  /// connection's partition or the one given.
  Status CreateReader(TopicId id, const dds::Qos& qos, dds::Reader* out,
                      dds::WriterLiveliness* liveliness = nullptr,
                      const std::string* partition = nullptr);
  const ConnectionOptions& options() const { return options_; }

 private:
  Connection() = default;
  // What the scoped connections of one participant share.
  struct Shared {
    std::unique_ptr<dds::Participant> owned;
    dds::Participant& participant;
    std::mutex mutex;                                // guards topics
    std::array<dds_entity_t, kTopicCount> topics{};  // 0 until created
  };
  ConnectionOptions options_;
  bool scoped_ = false;  // writers and readers go to options_.partition explicitly
  std::shared_ptr<Shared> shared_;
};

}  // namespace bp::transport
