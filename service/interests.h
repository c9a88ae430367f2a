// bp::service::InterestTable: the daemon's interests (wire::Interest) and the events of each,
// computed exactly and incrementally from the whole world's events.
//
// Design. Each region of an interest is an object of the engine (a producer-0 key, category
// kRegionCategory), so the engine finds region-object pairs with no algorithm of its own, in
// the same query as the object pairs. With a leave margin a region is two engine objects: the
// region itself (an object enters on a collide with it) and the region grown by the margin (it
// leaves on an uncollide with that); without one, a single object does both. Membership is
// then exactly "entered the region and has not left the grown region since", with no scan per
// frame. The object pairs of an interest (pairs inside its regions, of listed keys, producers,
// categories) are the whole world's pairs that satisfy its predicate; the table keeps each
// interest's set, finds the interests a world event may concern through watch lists (keys,
// producers, category interests), and re-evaluates the partners of an object whose membership
// or category changed through the current pairs' adjacency (kept while an interest with object
// criteria exists).
// Every change is applied to the interest's set and emitted only if it changes the set, so a
// frame's events are exactly the difference between the set before and after it.
//
// A frame: the daemon hands the engine's events to OnFrame, which removes the region pairs
// (the whole-world stream never shows regions) and leaves each interest's events of the frame
// in its delta. A declaration, change or drop takes effect at the next OnFrame.
//
// Thread safety: none; the daemon's loop is the only caller.
// Invariants: after OnFrame, each interest's set equals {overlapping object pairs satisfying
// its predicate} plus {(region index, object) : object inside that region}; its delta is the
// difference from the set after the previous OnFrame, uncollides and collides sorted.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "broadphase.pb.h"
#include "engine_host.h"

#include "bp/detail/flat_set.h"
#include "bp/status.h"

namespace bp::service {

/// Limits on interests (config `limits`).
struct InterestLimits {
  uint64_t max_interests = 1000;
  uint64_t max_regions = 256;  ///< per interest
  uint64_t max_keys = 100000;  ///< per interest: keys + producers
  /// The engine fattens boxes (engine.margin > 0): a changed region is placed anew instead of
  /// moved, so that its box's fat box stays inside its grown box's.
  bool fat_boxes = false;
};

class InterestTable {
 public:
  /// A flattened list of pairs (a0, b0, a1, b1, ...).
  using Flat = std::vector<uint64_t>;

  /// One interest's events of the last frame.
  struct Delta {
    Flat uncollide;
    Flat collide;
  };

  InterestTable(EngineHost* host, InterestLimits limits,
                std::function<bool(uint32_t)> known_producer);
  ~InterestTable();

  /// Declares or replaces interest.id(), owned by owner (the declaring writer). A refusal
  /// leaves the previous declaration in force; its message names the item and the reason.
  /// With take_over, an interest held by another owner (one that is gone) passes to owner.
  Status Declare(const wire::Interest& interest, uint64_t owner, bool take_over = false);
  /// Drops an interest; NotFound if there is none, AlreadyExists if another owner holds it.
  Status Drop(uint64_t id, uint64_t owner);
  /// Drops every interest of owner (its writer went away); returns their ids.
  std::vector<uint64_t> DropOwner(uint64_t owner);

  /// Takes the region pairs out of the engine's events (sorted, flattened, canonical) and
  /// computes each interest's delta.
  void OnFrame(Flat* uncollide, Flat* collide);

  /// Calls f(id, delta) for each interest whose last frame changed its set.
  void ForEachDelta(const std::function<void(uint64_t, const Delta&)>& f) const;
  /// The interest's current set, sorted (region pairs first); false if there is no such interest.
  bool Snapshot(uint64_t id, std::vector<std::pair<uint64_t, uint64_t>>* out) const;
  /// False from a change of the interest until the next OnFrame: its set is the last frame's
  /// only once the change has been applied (a snapshot waits for it).
  bool SnapshotReady(uint64_t id) const;
  /// The interest's current set size; 0 if there is none.
  uint64_t SetSize(uint64_t id) const;
  /// The owner of an interest (0 if there is none).
  uint64_t Owner(uint64_t id) const;
  /// True if an interest with this id exists.
  bool Contains(uint64_t id) const;
  /// Interests in force.
  size_t size() const { return by_id_.size(); }
  /// Region pairs the engine holds (to take out of the whole world's counts).
  uint64_t region_pairs() const { return region_pairs_; }
  /// Internal unless the watch lists name exactly each interest's
  /// keys, inside objects (with pairs_inside), producers and category criterion. For tests.
  Status CheckWatches() const;

 private:
  struct State;
  using Pair = std::pair<uint64_t, uint64_t>;
  struct PairHash {
    size_t operator()(const Pair& p) const {
      uint64_t h = p.first * 0x9E3779B97F4A7C15ull ^ (p.second + 0x632BE59BD9B4E019ull);
      h ^= h >> 29;
      return static_cast<size_t>(h * 0xBF58476D1CE4E5B9ull);
    }
  };
  using PairSet = std::unordered_set<Pair, PairHash>;
  // What an engine region key stands for.
  struct RegionRef {
    State* state;
    uint32_t region;
    bool enter;  // an object enters on a collide with it
    bool leave;  // an object leaves on an uncollide with it
  };

  Status Validate(const wire::Interest& interest, uint64_t owner, bool take_over) const;
  // Places the interest's regions in the engine (the first n_keep reuse their objects).
  Status PlaceRegions(State& s, const wire::Interest& interest);
  void EraseRegions(State& s, size_t from);
  void Unwatch(State& s);
  void Watch(State& s);
  void AddWatch(uint64_t key, State* s);
  void RemoveWatch(uint64_t key, State* s);
  bool Predicate(const State& s, uint64_t a, uint64_t b) const;
  // Applies the predicate's verdict on the current pair (a, b) to s, emitting if it changes.
  void Reevaluate(State& s, uint64_t a, uint64_t b);
  // The interests a world pair may concern (deduplicated, in candidates_).
  void Candidates(uint64_t a, uint64_t b);
  // An interest with object criteria needs the world's pairs by object (to re-evaluate the
  // partners of an object that entered or left, and to compute a declaration whole).
  static bool NeedsAdjacency(const State& s);
  void BuildAdjacency();
  void Link(uint64_t a, uint64_t b);
  void Unlink(uint64_t a, uint64_t b);
  void Recompute(State& s);

  EngineHost* host_;
  InterestLimits limits_;
  std::function<bool(uint32_t)> known_producer_;
  std::unordered_map<uint64_t, std::unique_ptr<State>> by_id_;
  std::unordered_map<uint64_t, RegionRef> region_refs_;  // engine key -> region
  uint64_t next_region_key_ = 1;                         // below 2^48, never reused
  uint64_t region_pairs_ = 0;
  // Watch lists: the interests a pair with this key (or producer) may concern. A key is listed
  // once per reason (a listed key, inside a region of an interest with pairs_inside).
  std::unordered_map<uint64_t, std::vector<State*>> watch_keys_;
  std::unordered_map<uint32_t, std::vector<State*>> watch_producers_;
  std::vector<State*> category_interests_;
  // The current object pairs, by object, while an interest needs them (NeedsAdjacency).
  bool adjacency_built_ = false;
  std::unordered_map<uint64_t, std::vector<uint64_t>> adjacency_;
  std::vector<State*> candidates_;
  uint64_t stamp_ = 0;
  std::vector<uint64_t> recategorized_;
};

}  // namespace bp::service
