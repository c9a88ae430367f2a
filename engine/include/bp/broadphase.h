// bp::Broadphase: the one interface every broadphase of the library implements.
//
// Insert, Update and Erase are buffered and validated at call time against the state the
// object will have at the next Query (the last query plus the calls buffered since). Query applies
// everything buffered and reports, through the sink, exactly the pairs whose overlap status
// changed since the previous Query: Collide(a, b) for pairs that overlap now and did not then,
// Uncollide(a, b) for the reverse. Erasing an object uncollides all its pairs. Erasing and
// re-inserting one key before a Query is an update: only real status changes are reported.
//
// Event order is canonical, the same for every engine and every thread count: all uncollides,
// then all collides; each pair reported as (smaller key, larger key); pairs in increasing
// (first, second) order.
//
// Thread safety: an engine is not thread-safe; callers serialise all calls on one instance.
// Invariants (checked by Validate()):
//  1. Between queries, the engine's overlap set equals the brute-force overlap set of its boxes.
//  2. A refused call (non-ok Status) changes nothing.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>

#include "bp/box.h"
#include "bp/object_options.h"
#include "bp/status.h"

namespace bp {

/// Receives the events of one Query.
template <class Key>
class EventSink {
 public:
  virtual ~EventSink() = default;
  /// a and b overlap now and did not at the previous query (a < b).
  virtual void Collide(const Key& a, const Key& b) = 0;
  /// a and b overlapped at the previous query and do not now, or one was erased (a < b).
  virtual void Uncollide(const Key& a, const Key& b) = 0;
};

/// The grid engines' own counters (bp/grid.h), in Stats::grid.
struct GridStats {
  size_t cells = 0;          ///< cells in use
  size_t cells_queried = 0;  ///< cells the last query applied operations to
  size_t large_objects = 0;  ///< objects kept out of the cells for their size
  size_t cell_slots = 0;     ///< slots the cells hold, live or free (dense cells only)
  double cell_size = 0;      ///< the cell edge
  size_t worker_cells = 0;   ///< cells of the last query applied by the pool's other threads
  size_t pool_routed = 0;    ///< updates of the last query routed on the pool
  // Within Stats::core_ms, in milliseconds.
  double route_ms = 0;  ///< objects routed to their cells (and large ones)
  double cells_ms = 0;  ///< work grouped by cell, cells applied (on the pool)
  double fold_ms = 0;   ///< the cells' changes folded into witness counts
};

/// The segmented interval lists' own counters (bp/segmented_sap.h, and the grid over them), in
/// Stats::segmented_sap.
struct SegmentedSapStats {
  size_t chunks = 0;  ///< chunks over all axes (over all cells, for the grid)
};

/// Counters describing the engine and its last Query: those every engine has, and each engine
/// family's own in an optional member that only that family sets.
struct Stats {
  size_t objects = 0;        ///< live objects after the last query
  size_t overlaps = 0;       ///< overlapping pairs after the last query
  size_t inserts = 0;        ///< inserts applied by the last query
  size_t updates = 0;        ///< updates applied by the last query
  size_t erases = 0;         ///< erases applied by the last query
  size_t collides = 0;       ///< collide events of the last query
  size_t uncollides = 0;     ///< uncollide events of the last query
  size_t swaps = 0;          ///< extremum swaps of the last query
  size_t overlap_tests = 0;  ///< full box tests of the last query
  bool global_sort = false;  ///< the last query sorted globally (not per moved object)
  bool rebuilt = false;      ///< the last query rebuilt its structures from scratch (bulk load)
  size_t threads = 1;        ///< threads that may work on a query (a grid's pool; else 1)
  double margin = 0;         ///< the fattened boxes' margin (0: exact boxes)
  size_t fat_skips = 0;      ///< updates of the last query absorbed by a fat box
  // Wall time of the last query by phase, in milliseconds. The client's calls before the query
  // (Insert, Update, Erase) are not in any of them.
  double prepare_ms = 0;  ///< front end: new objects' options set, retired staged calls dropped
  double core_ms = 0;     ///< the core: its structures updated and its changed pairs found
  double events_ms = 0;   ///< front end: changed pairs drained, keyed, sorted and delivered
  std::optional<GridStats> grid;                   ///< the grid engines' counters
  std::optional<SegmentedSapStats> segmented_sap;  ///< segmented lists' (SegmentedSap, its grid)
};

/// One item of Broadphase::UpdateMany: a key and its new box.
template <int K, Coordinate T, class Key = uint64_t>
struct KeyedBox {
  Key key{};
  Box<K, T> box;
};

/// The interface of every broadphase: K axes, coordinates T, client keys Key.
template <int K, Coordinate T, class Key = uint64_t>
class Broadphase {
 public:
  using BoxType = Box<K, T>;
  using Item = KeyedBox<K, T, Key>;
  /// Told the index of each item UpdateMany or EraseMany refused, and why.
  using RefusedFn = std::function<void(size_t index, const Status& status)>;
  virtual ~Broadphase() = default;

  /// Buffers the insertion of key with box and options, fixed until its erase. AlreadyExists if
  /// key is live; InvalidArgument if the box is invalid.
  virtual Status Insert(const Key& key, const BoxType& box, const ObjectOptions& options) = 0;
  /// Insert with the default options (every pair accepted).
  Status Insert(const Key& key, const BoxType& box) { return Insert(key, box, ObjectOptions{}); }
  /// Insert(items[i].key, items[i].box, options[i]) for every item, in order; an empty options
  /// means the defaults for all. A refused item changes nothing and is passed to refused (when
  /// set) with its index and the Status Insert would return; the other items are kept. Returns
  /// the number refused. options of another size than items refuses every item
  /// (InvalidArgument). Engines may override it to overlap the look-ups of many items, as
  /// UpdateMany does.
  virtual size_t InsertMany(std::span<const Item> items,
                            std::span<const ObjectOptions> options = {},
                            const RefusedFn& refused = nullptr) {
    if (!options.empty() && options.size() != items.size()) {
      const Status s(StatusCode::kInvalidArgument, "insert: " + std::to_string(options.size()) +
                                                       " options for " +
                                                       std::to_string(items.size()) + " items");
      if (refused) {
        for (size_t i = 0; i < items.size(); ++i) refused(i, s);
      }
      return items.size();
    }
    return CallEach(items.size(), refused, [&](size_t i) {
      return Insert(items[i].key, items[i].box, options.empty() ? ObjectOptions{} : options[i]);
    });
  }
  /// Buffers a new box for key. NotFound if key is not live; InvalidArgument if the box is invalid.
  virtual Status Update(const Key& key, const BoxType& box) = 0;
  /// Update(item.key, item.box) for every item, in order (a later item on a key wins). A refused
  /// item changes nothing and is passed to refused (when set) with its index and the Status
  /// Update would return; the other items are kept. Returns the number refused. Engines may
  /// override it to overlap the memory look-ups of many items: the front end of this library's
  /// engines looks up the keys and slots of the items ahead while it updates the current one,
  /// which a loop of Update calls cannot do. The daemon and bpbench pass their updates here.
  virtual size_t UpdateMany(std::span<const Item> items, const RefusedFn& refused = nullptr) {
    return CallEach(items.size(), refused,
                    [&](size_t i) { return Update(items[i].key, items[i].box); });
  }
  /// Buffers the erasure of key. NotFound if key is not live.
  virtual Status Erase(const Key& key) = 0;
  /// Erase(keys[i]) for every key, in order (a key named twice is refused the second time). A
  /// refused key is passed to refused (when set) with its index and the Status Erase would
  /// return; the others are erased. Returns the number refused. Engines may override it to
  /// overlap the look-ups of many keys, as UpdateMany does.
  virtual size_t EraseMany(std::span<const Key> keys, const RefusedFn& refused = nullptr) {
    return CallEach(keys.size(), refused, [&](size_t i) { return Erase(keys[i]); });
  }
  /// Applies all buffered calls and reports the overlap changes to sink in canonical order.
  virtual void Query(EventSink<Key>& sink) = 0;
  /// Calls f(a, b) with a < b for every overlapping pair as of the last query (any order).
  virtual void ForEachOverlap(const std::function<void(const Key&, const Key&)>& f) const = 0;
  /// Calls f(key) for every object live as of the last query whose box overlaps box (closed
  /// intervals on every axis, as pairs are tested; objects of any options, those that pair with
  /// nothing included), in any order: the spot query "what is in this box now". An engine with a
  /// margin tests its fattened boxes. O(objects) in general; the grid engines visit only the
  /// cells the box covers and their large objects.
  virtual void ForEachOverlapping(const BoxType& box,
                                  const std::function<void(const Key&)>& f) const = 0;
  /// Calls f(key) for every present key: live at the last query and not erased since, or
  /// inserted since (any order). O(objects); meant for rare whole-set work, such as erasing
  /// every object of a client that went away.
  virtual void ForEachObject(const std::function<void(const Key&)>& f) const = 0;
  /// Live objects as of the last query.
  virtual size_t Size() const = 0;
  /// Counters of the engine and of its last query.
  virtual Stats GetStats() const = 0;
  /// Checks every invariant of the internal structures (O(n log n) or worse); Internal on failure.
  virtual Status Validate() const = 0;
  /// A short name of the algorithm, e.g. "segmented_sap".
  virtual std::string Name() const = 0;

 protected:
  /// call(i) for i in [0, n), in order; each refused i is passed to refused (when set) with its
  /// Status. Returns the number refused (the loop of InsertMany, UpdateMany and EraseMany).
  template <class Call>
  static size_t CallEach(size_t n, const RefusedFn& refused, Call&& call) {
    size_t count = 0;
    for (size_t i = 0; i < n; ++i) {
      const Status s = call(i);
      if (s.ok()) continue;
      ++count;
      if (refused) refused(i, s);
    }
    return count;
  }
};

}  // namespace bp
