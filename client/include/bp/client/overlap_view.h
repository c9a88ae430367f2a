// bp::client::OverlapView: the exact current overlap set, kept from the events topic, for a
// subscriber that joins late, falls behind, or outlives a daemon restart.
//
// Feed it every EventBatch in the order received (Subscriber::Poll or Listen). It starts
// unsynced. It becomes synced at the end of a complete snapshot (snapshot parts 0..last, with
// consecutive sequence numbers), and from then on applies each frame's uncollides and collides.
// It drops back to unsynced, clearing its set, when:
//  - a sequence number is skipped (a gap: its KEEP_LAST history overwrote batches, or a write
//    failed at the daemon);
//  - the epoch changes (the daemon restarted);
//  - an event contradicts the set (an uncollide of an absent pair, a collide of a present one),
//    which a correct daemon never sends.
// While unsynced it ignores events, and wants_snapshot() is true: the application asks for one
// (SnapshotRequester), again after a while if none arrives. Snapshots are published for every
// subscriber, so a synced view skips the ones others asked for.
//
// The same view follows an interest's stream (InterestClient, EventSubscriber created for the
// interest): its set is then the interest's, and its snapshots are requested for the interest.
//
// Exactness: the daemon publishes a snapshot between frames, with the set as of the frame
// before it, in the same sequence as the events. A view that applies the snapshot and then
// every later part without a gap holds exactly the daemon's set after each frame.
//
// Thread safety: none (one thread feeds and reads it).
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <unordered_set>
#include <utility>
#include <vector>

#include "broadphase.pb.h"

#include "bp/client/connection.h"
#include "bp/status.h"

namespace bp::client {

/// A hash of a pair of keys, for the sets of pairs the views keep.
struct PairHash {
  size_t operator()(const std::pair<uint64_t, uint64_t>& p) const {
    uint64_t h = p.first * 0x9E3779B97F4A7C15ull ^ (p.second + 0x632BE59BD9B4E019ull);
    h ^= h >> 29;
    return static_cast<size_t>(h * 0xBF58476D1CE4E5B9ull);
  }
};

class OverlapView {
 public:
  /// Applies one received part. Returns true when the view has just lost its sync (or has
  /// never had it and this is the first part): the moment to request a snapshot.
  bool Apply(const wire::EventBatch& part);

  /// The set matches the daemon's as of frame() (false between the parts of a frame).
  bool synced() const { return synced_ && !mid_frame_; }
  /// True while unsynced (waiting for a snapshot).
  bool wants_snapshot() const { return !synced_; }
  /// The daemon frame the set reflects (valid while synced).
  uint64_t frame() const { return frame_; }
  /// The daemon run the view follows (EventBatch.epoch; 0 before the first part).
  uint64_t epoch() const { return epoch_; }
  /// Overlapping pairs (a < b); empty while unsynced.
  size_t size() const { return pairs_.size(); }
  bool Contains(uint64_t a, uint64_t b) const { return pairs_.count(Key(a, b)) != 0; }
  /// The pairs, sorted.
  std::vector<std::pair<uint64_t, uint64_t>> SortedPairs() const;

  /// Times the view lost its sync (gap, restart, contradiction), and why the last time.
  uint64_t resyncs() const { return resyncs_; }
  uint64_t gaps() const { return gaps_; }
  uint64_t restarts() const { return restarts_; }
  uint64_t contradictions() const { return contradictions_; }
  const std::string& last_loss() const { return last_loss_; }
  /// Complete snapshots applied.
  uint64_t snapshots() const { return snapshots_; }

 private:
  using PairSet = std::unordered_set<std::pair<uint64_t, uint64_t>, PairHash>;
  static std::pair<uint64_t, uint64_t> Key(uint64_t a, uint64_t b) {
    return a < b ? std::pair{a, b} : std::pair{b, a};
  }
  void Lose(std::string why);

  bool synced_ = false;
  bool mid_frame_ = false;  // synced, and some but not all parts of a frame applied
  bool started_ = false;    // a part was seen
  bool building_ = false;   // snapshot parts 0..k of frame building_frame_ collected
  uint64_t building_frame_ = 0;
  uint64_t frame_ = 0;
  uint64_t epoch_ = 0;
  uint64_t last_seq_ = 0;
  PairSet pairs_;
  PairSet pending_;
  uint64_t resyncs_ = 0, gaps_ = 0, restarts_ = 0, contradictions_ = 0, snapshots_ = 0;
  std::string last_loss_;
};

/// Asks the daemon for a snapshot (requests topic).
class SnapshotRequester {
 public:
  static Status Create(Connection& connection, std::unique_ptr<SnapshotRequester>* out);
  /// Waits until the daemon's requests reader has matched.
  Status WaitForDaemon(std::chrono::milliseconds timeout) const {
    return writer_.WaitForReaders(1, timeout);
  }
  /// Sends one request; reason is for the daemon's log ("join", "gap", ...). With interest, asks
  /// for that interest's snapshot (published on its stream only).
  Status Request(const std::string& reason, uint64_t interest = 0);

 private:
  SnapshotRequester() = default;
  dds::Writer writer_;
  uint64_t requester_ = 0;
  uint64_t seq_ = 0;
  wire::SnapshotRequest msg_;
  std::string buffer_;
};

}  // namespace bp::client
