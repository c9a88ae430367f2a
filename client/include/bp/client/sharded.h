// A world served by several daemons (shards, bp/transport/shard_map.h), seen by a producer and
// by a subscriber as if it were one daemon.
//
// ShardedPublisher routes each box to every shard whose part it touches: an insert goes to each
// of them, an update to the shards it still touches, as an insert where it arrives (with the
// attributes of its insert) and an erase where it left, all in the same frame; an erase to every
// shard that holds the object. Every shard gets the batch that closes a frame, so every shard
// closes each of the producer's frames, keyed by its frame number. Each shard is served by an
// UpdatePublisher of its own that restates (restate_on_restart is always on: a restarted shard
// gets back exactly the objects routed to it). An item the daemons would refuse for what it is
// (a coordinate not finite, out of the daemons' range or not integral for int32 daemons, lo > hi,
// an unknown or duplicate id, an id >= 2^48) goes unchanged to one shard, whose daemon reports
// it, and is not placed. A refusal that depends on the daemon (CAPACITY: limits.max_objects
// counts per shard, border copies included) is reported by each shard that refuses.
//
// MergedView merges the shards' event streams into one: the overlap set of the world is the
// union of the shards' sets, each pair counted once per shard that holds it (the witness count
// of docs/DESIGN.md, "Shards"), and a merged frame F applies every shard's frame F at once, so a
// pair handed from one shard to another within a frame produces no event. Each shard's stream
// is followed like OverlapView follows a daemon's (snapshots, gaps, epochs); a shard that lost
// its sync holds the merged stream back until its snapshot arrives, and frames that can no
// longer be told apart are merged into one (MergedFrame.frame jumps).
//
// ShardedSubscriber keeps a MergedView fed from every shard and asks each shard for snapshots.
//
// Rules for a sharded world: the producer that closes frames numbers them increasingly (the
// merge aligns shards by UpdateBatch.frame); other producers do not close frames; every producer
// restates (a shard waiting for a producer's restate holds the merged stream back); frames end on
// end_of_frame and engine.margin is 0 on every shard; every process loads the same shard map
// (checked against each daemon's status, ShardInfo.map_digest).
//
// Thread safety: one thread at a time per object.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "broadphase.pb.h"

#include "bp/client/connection.h"
#include "bp/client/interests.h"
#include "bp/client/overlap_view.h"
#include "bp/client/subscriber.h"
#include "bp/client/update_publisher.h"
#include "bp/status.h"
#include "bp/transport/shard_map.h"

namespace bp::client {

using transport::ShardMap;

/// Waits until every shard's daemon has reported on its status topic and checks that it serves
/// this map (the shard of the partition it is in, the same digest). The error names the shard.
/// With coordinate, also returns the daemons' coordinate type (DaemonStatus.coordinate).
Status CheckShards(Connection& connection, const ShardMap& map, std::chrono::milliseconds timeout,
                   std::string* coordinate = nullptr);

class ShardedPublisher : public BatchPublisher {
 public:
  ~ShardedPublisher() override;
  /// A publisher for producer id on every shard of map (connection must outlive it).
  static Status Create(Connection& connection, const ShardMap& map, uint32_t producer,
                       const PublisherOptions& options, std::unique_ptr<ShardedPublisher>* out);
  /// Checks the shards' maps (CheckShards), then waits for every shard's daemon.
  Status WaitForDaemon(std::chrono::milliseconds timeout) override;
  /// Routes batch to the shards and publishes it. The batch is taken whole or not at all:
  /// DeadlineExceeded means no shard received it (retry it). Once one shard took it, the other
  /// shards' parts that a full queue refused are kept and sent first by the next Publish,
  /// Maintain or Flush (pending()). A batch whose arrays are malformed (coordinates not K per
  /// id, both precisions, attribute arrays of the wrong length, attributes on updates, dim not
  /// the map's) is refused whole with InvalidArgument naming the array; so is a frame-closing
  /// batch whose frame number does not increase.
  Status Publish(wire::UpdateBatch* batch) override;
  Status Maintain() override;
  /// Sends what is pending, then waits for every shard's acknowledgements.
  Status Flush(std::chrono::milliseconds timeout) override;

  size_t shards() const { return shards_.size(); }
  UpdatePublisher& shard(size_t s) { return *shards_[s]; }
  /// Shard parts still to send (0 in the normal case).
  size_t pending() const;
  /// Objects placed, and those held by more than one shard (on a border).
  size_t objects() const { return placed_.size(); }
  size_t border_objects() const;
  /// Objects that left a shard for another so far.
  uint64_t handovers() const { return handovers_; }

 private:
  struct Placed {
    ShardMap::Mask shards = 0;
    bool has_attributes = false;
    bool is_static = false;
    uint64_t category = 1, mask = ~uint64_t{0};
  };
  ShardedPublisher() = default;
  Status SendPending();

  enum class Coordinate { kFloat, kDouble, kInt32 };
  const ShardMap* map_ = nullptr;
  Coordinate coordinate_ = Coordinate::kFloat;  // the daemons' (WaitForDaemon learns it)
  bool mid_frame_ = false;                      // the last batch did not close a frame
  std::vector<std::unique_ptr<Connection>> connections_;
  std::vector<std::unique_ptr<UpdatePublisher>> shards_;
  Connection* connection_ = nullptr;
  std::unordered_map<uint64_t, Placed> placed_;
  std::vector<wire::UpdateBatch> parts_;  // per shard, the part being built or pending
  std::vector<bool> pending_;             // per shard: parts_[s] still to send
  uint64_t last_closed_frame_ = 0;
  bool closed_any_ = false;
  uint64_t handovers_ = 0;
};

/// One merged frame: the world's events between two producer frames.
struct MergedFrame {
  /// The producer frame (UpdateBatch.frame) the world's set is now at.
  uint64_t frame = 0;
  /// The view's first merged frame: collide holds the whole set and uncollide is empty (like a
  /// snapshot).
  bool snapshot = false;
  /// Pairs (a0, b0, a1, b1, ...), a < b, sorted.
  std::vector<uint64_t> uncollide, collide;
  /// frame - previous frame - 1: frames folded into this one (a shard missed them, or resynced
  /// from a snapshot of a later frame), or numbers the producer skipped.
  uint64_t skipped = 0;
  /// The producer's send time of the frame (UpdateBatch.sent_time_ns; the latest over the
  /// shards' frame-closing batches), 0 if unknown: for update->event latency.
  uint64_t sent_time_ns = 0;
};

class MergedView {
 public:
  explicit MergedView(size_t shards);
  /// Applies one part received from shard s. Returns true when shard s has just lost its sync
  /// (or has never had it and this is its first part): the moment to ask it for a snapshot.
  bool Apply(size_t shard, const wire::EventBatch& part);
  /// The next merged frame, if every shard has delivered it (false otherwise).
  bool Next(MergedFrame* out);

  /// The set equals the world's as of frame() (between Next calls).
  bool synced() const { return emitted_; }
  uint64_t frame() const { return frame_; }
  bool wants_snapshot(size_t s) const { return !shards_[s].synced; }
  /// The shards the next merged frame waits for (empty when one is ready or none is due).
  std::vector<size_t> waiting_for() const;
  size_t size() const { return counts_.size(); }
  bool Contains(uint64_t a, uint64_t b) const { return counts_.count(Key(a, b)) != 0; }
  std::vector<std::pair<uint64_t, uint64_t>> SortedPairs() const;

  /// Per shard: times it lost its sync, and why the last time.
  uint64_t resyncs(size_t s) const { return shards_[s].resyncs; }
  uint64_t restarts(size_t s) const { return shards_[s].restarts; }
  uint64_t contradictions() const { return contradictions_; }
  const std::string& last_loss(size_t s) const { return shards_[s].last_loss; }

 private:
  using Pair = std::pair<uint64_t, uint64_t>;
  using PairSet = std::unordered_set<Pair, PairHash>;
  static Pair Key(uint64_t a, uint64_t b) { return a < b ? Pair{a, b} : Pair{b, a}; }
  // A state change of one shard: a frame's events, or (reset) its whole set.
  struct Entry {
    uint64_t key = 0;
    uint64_t sent_ns = 0;
    bool reset = false;
    // The shard's frames before this one are unknown (it missed batches and was restated): the
    // merge cannot produce frames before key from it, as after a reset.
    bool fold = false;
    std::vector<uint64_t> uncollide, collide;  // events (reset: collide holds the set)
  };
  struct Shard {
    bool started = false, synced = false;
    uint64_t epoch = 0, last_seq = 0;
    std::vector<uint64_t> retired;  // epochs of daemons replaced since (late parts are ignored)
    uint64_t newest = 0;            // the newest frame delivered (queued or merged)
    // Snapshot being collected.
    bool building = false;
    uint64_t building_frame = 0;
    std::vector<uint64_t> building_pairs;
    // Since the last keyed frame: a snapshot without a key (has_base, base) and the events of
    // frames closed by no producer's frame end (expiries, restates), counted into the next one.
    bool has_base = false;
    std::vector<uint64_t> base;
    std::vector<uint64_t> acc_uncollide, acc_collide;  // the current frame's parts
    std::unordered_map<Pair, bool, PairHash> net;      // earlier frames' net change: true = in
    bool resyncing = false;  // a frame flagged EventBatch.resyncing since the last keyed one
    std::deque<Entry> queue;
    PairSet held;  // the pairs this shard contributes to counts_
    uint64_t resyncs = 0, restarts = 0;
    std::string last_loss;
  };
  void Lose(Shard& s, std::string why);
  void Push(Shard& s, uint64_t key, uint64_t sent_ns, bool reset, std::vector<uint64_t> uncollide,
            std::vector<uint64_t> collide);
  // Counts the current frame's events into the shard's net change of the frames so far.
  static void FoldFrame(Shard& s);
  // The frame the next merged frame can be (false: some shard has not delivered it).
  bool NextKey(uint64_t* key) const;
  void ApplyEntry(size_t s, const Entry& e, std::unordered_map<Pair, bool, PairHash>* touched);

  std::vector<Shard> shards_;
  std::unordered_map<Pair, uint32_t, PairHash> counts_;  // pair -> shards holding it (>= 1)
  bool emitted_ = false;  // a merged frame since the last loss of sync
  uint64_t frame_ = 0;
  uint64_t contradictions_ = 0;
};

/// Declares an interest on every shard (an InterestClient per shard): the shards' interest
/// streams then merge like their whole-world streams (ShardedSubscriber with the interest's id).
/// Each criterion of an interest is decided from the boxes of the pair or of the region and the
/// object, which a shard holding them has whole; a leave margin is not (a region's members carry
/// over from frame to frame, and an object that leaves a shard leaves its memory there), so
/// Declare refuses one. A declaration reaches the shards at slightly different frames: the merged
/// stream is the old declaration's, then the new one's, with frames between that mix them.
class ShardedInterestClient {
 public:
  static Status Create(Connection& connection, const ShardMap& map,
                       std::unique_ptr<ShardedInterestClient>* out);
  /// Waits until every shard's daemon reads interests.
  Status WaitForDaemons(std::chrono::milliseconds timeout);
  /// Declares (or changes) interest on every shard; InvalidArgument for a leave margin.
  Status Declare(const wire::Interest& interest);
  Status Drop(uint64_t id);
  /// Reads every shard's status: declares again to a restarted shard; a refusal of one of this
  /// client's interests by a shard is returned as InvalidArgument naming the shard.
  Status Maintain();

 private:
  ShardedInterestClient() = default;
  const ShardMap* map_ = nullptr;
  std::vector<std::unique_ptr<Connection>> connections_;
  std::vector<std::unique_ptr<InterestClient>> clients_;
  std::vector<std::unique_ptr<StatusSubscriber>> status_;
  std::vector<wire::DaemonStatus> reports_;
};

/// Follows every shard's events topic and keeps a MergedView, asking shards for snapshots.
class ShardedSubscriber {
 public:
  /// depth: each shard's KEEP_LAST history (as Subscriber). With interest: that interest's
  /// streams (declared with ShardedInterestClient), merged.
  static Status Create(Connection& connection, const ShardMap& map, int32_t depth,
                       std::unique_ptr<ShardedSubscriber>* out, uint64_t interest = 0);
  /// Checks the shards' maps, then waits until every shard's writer and request reader matched.
  Status WaitForDaemons(std::chrono::milliseconds timeout);
  /// Reads what the shards sent within timeout and appends the merged frames now complete.
  Status Poll(std::chrono::milliseconds timeout, std::vector<MergedFrame>* out);
  const MergedView& view() const { return view_; }
  size_t shards() const { return subscribers_.size(); }
  uint64_t snapshot_requests() const { return requests_; }

 private:
  explicit ShardedSubscriber(size_t shards) : view_(shards) {}
  void Feed(size_t s, const wire::EventBatch& part);
  const ShardMap* map_ = nullptr;
  uint64_t interest_ = 0;
  Connection* connection_ = nullptr;
  std::vector<std::unique_ptr<Connection>> connections_;
  std::vector<std::unique_ptr<EventSubscriber>> subscribers_;
  std::vector<std::unique_ptr<SnapshotRequester>> requesters_;
  std::vector<std::chrono::steady_clock::time_point> asked_;
  std::vector<std::chrono::steady_clock::time_point> waited_since_;  // {}: not waited on
  MergedView view_;
  uint64_t requests_ = 0;
  std::vector<wire::EventBatch> parts_;
};

}  // namespace bp::client
