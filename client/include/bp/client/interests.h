// bp::client::InterestClient: declares, changes and drops interests (what a subscriber wants to
// receive: regions, keys, producers, categories; wire::Interest), and asks spot queries ("which
// objects overlap this box now?").
//
// An interest's events arrive on a stream of their own: an EventSubscriber created with the
// interest's id, fed into an OverlapView exactly as for the whole world (snapshots are asked for
// with SnapshotRequester::Request(reason, id)). The daemon drops the interests of a client whose
// writer stops being alive (its process died) once producers.lease_s has passed, and a restarted
// daemon holds none: feed the status reports to OnStatus, which declares them again when the
// daemon's epoch changes.
//
// Thread safety: one thread at a time.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "broadphase.pb.h"

#include "bp/client/connection.h"
#include "bp/status.h"

namespace bp::client {

class InterestClient {
 public:
  /// A client with a random id, its writer on the interests topic and its reader of replies.
  static Status Create(Connection& connection, std::unique_ptr<InterestClient>* out);
  /// A random nonzero interest id.
  static uint64_t NewInterestId();
  /// Waits until the daemon's interests reader has matched.
  Status WaitForDaemon(std::chrono::milliseconds timeout) const {
    return writer_.WaitForReaders(1, timeout);
  }
  /// Declares interest (or changes it: same id). The daemon answers a refusal on the status
  /// topic (DaemonStatus.interest_refusals, see OnStatus); the previous declaration then stays.
  Status Declare(const wire::Interest& interest);
  /// Drops an interest of this client.
  Status Drop(uint64_t id);
  /// Feeds a status report: declares every interest again when the daemon's epoch changed (a
  /// restarted daemon), and those of its interests the daemon dropped while this client was cut
  /// off or hung (DaemonStatus.dropped_interests); appends the refusals addressed to this client
  /// to *refusals. A refused declaration is forgotten: the one before it (if any) is what a
  /// restarted daemon is given again.
  Status OnStatus(const wire::DaemonStatus& status,
                  std::vector<wire::InterestRefusal>* refusals = nullptr);
  /// The keys of the objects overlapping [lo, hi] as of the daemon's last frame, sorted, and
  /// that frame. InvalidArgument with the daemon's reason if it refused the box;
  /// DeadlineExceeded if no complete answer came within timeout.
  Status Query(std::span<const double> lo, std::span<const double> hi,
               std::chrono::milliseconds timeout, std::vector<uint64_t>* keys,
               uint64_t* frame = nullptr);
  /// This client's id (InterestRequest.client).
  uint64_t id() const { return client_; }

 private:
  InterestClient() = default;
  Status Send();

  dds::Writer writer_;
  dds::Reader replies_;
  dds::WaitSet waitset_;
  uint64_t client_ = 0;
  uint64_t seq_ = 0;
  uint64_t next_query_ = 0;
  uint64_t epoch_ = 0;
  std::map<uint64_t, wire::Interest> declared_;
  // For each interest: the declaration before its last one (none for a new interest), restored
  // if the daemon refuses the last one.
  std::map<uint64_t, std::optional<wire::Interest>> before_;
  wire::InterestRequest request_;
  std::string buffer_;
};

}  // namespace bp::client
