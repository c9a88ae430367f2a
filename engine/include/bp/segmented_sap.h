// bp::SegmentedSap: one sweep-and-prune instance over segmented interval lists (Tracy, Buss and
// Woods, IEEE VR 2009, section 3.2.2) with event output (section 3.3).
//
// Per axis the sorted extrema live in chunks of `chunk_capacity` slots (a power of two, paper:
// about 32), linked in list order (prev/next chunk ids) and indexed by `order`, an array of
// chunk ids in list order that is binary searched to place new extrema (rebuilt lazily from the
// links after a merge). An extremum's position is one integer: chunk id << shift | slot.
// Insert and erase touch at most one chunk's worth of extrema per extremum; overlaps of an
// inserted or erased object are found through its chunks and the checkpoint set of the chunk to
// the left. Moved objects are re-sorted either locally (each moved extremum bubbles to its
// place, swaps trigger overlap tests) or, when many moved, by one global insertion sort per axis.
// A query with many inserts and erases takes the paper's proposed improvement (end of 4.1): the
// records are presorted and integrated chunk by chunk, so each extremum already in a chunk moves
// at most once per query however many land there (erase: one compaction per touched chunk;
// insert: one merge per target chunk, which spreads over new chunks when it overflows).
//
// Checkpoints (axis 0 only): CP(c) holds the objects whose min lies in chunk c or to its left and
// whose max lies to its right. During a local sort an object's min is moved before its max, so
// min and max may cross for a moment (fast movers); the paper's R set absorbs that: per chunk, an
// object is in CP(c) when its signed crossing count [min <= c] - [max <= c] is +1 and in R(c)
// when it is -1. Between objects every R(c) is empty again.
//
// Thread safety: none (see bp/broadphase.h).
// Invariants (checked by Validate):
//  1. Every axis list is sorted by (value, min before max at equal value).
//  2. pos[ref] addresses the extremum ref; every linked chunk holds 1..capacity extrema; the
//     links are consistent; `order` (when valid) lists the linked chunks in list order; every
//     chunk id is either linked or free (free: empty, no checkpoints).
//  2b. Any two adjacent chunks hold more than capacity / 2 extrema together, so positions
//     (chunk id << shift | slot) stay below 8 * objects + 2 * capacity: 32 bits suffice.
//  3. CP(c) equals the recomputation above and every R(c) is empty.
//  4. The tracker's overlap set equals the overlapping pairs of the live boxes.
//
// Why one file of about a thousand lines: the chunked lists, the checkpoint sets and the R sets
// are one structure, which every operation (insert, erase, move, presorted batch, bulk load)
// updates under one invariant, in one class; its validator is apart
// (detail/segmented_sap_validate.h).
#pragma once

#include <algorithm>
#include <bit>
#include <cstdint>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/flat_set.h"
#include "bp/detail/front_end.h"
#include "bp/detail/pair_tracker.h"
#include "bp/detail/sweep.h"

namespace bp {

/// Tuning of SegmentedSap.
struct SegmentedSapOptions {
  /// Extremum slots per chunk; a power of two in [4, 4096]. The paper finds ~32 best.
  uint32_t chunk_capacity = 32;
  /// A query re-sorts globally when the moved objects exceed this fraction of the live ones,
  /// and per moved object otherwise: the crossover (`bpbench --threshold-sweep`) lies between 5%
  /// and 10% moved for 3k..30k objects on one SAP instance.
  double global_sort_fraction = 0.07;
  /// A query whose inserts number at least max(bulk_load_min, live objects before it) rebuilds
  /// the lists by sorting and sweeping (O(n log n + pairs)) instead of inserting one object at a
  /// time (O(objects overlapping on axis 0) each): start-up, restart and refills. 0 disables it.
  uint32_t bulk_load_min = 64;
  /// A query whose inserts plus erases (objects, not extrema) number at least this many
  /// integrates them chunk by chunk from presorted records (each extremum of a touched chunk
  /// moves once per query) instead of one extremum at a time; 0 disables it (the paper's
  /// per-event path). It pays once events share chunks, i.e. from about as many events as
  /// chunks per axis (in instructions, a 300-object cell breaks even at about 32 events).
  uint32_t presorted_min = 32;
};

namespace detail {

template <int K, Coordinate T>
class SegmentedSapCore {
 public:
  static constexpr int kDim = K;
  static constexpr size_t kAxes = static_cast<size_t>(K);
  using Coord = T;
  static constexpr const char* kName = "segmented_sap";
  static constexpr const char* kGridName = "grid_segmented_sap";  // as the cell of bp::Grid
  // Positions are chunk << shift | slot in 32 bits. Merging keeps adjacent chunks above half a
  // chunk together, so chunks <= 4 * extrema / capacity + 1 and positions < 8 * handles + cap:
  // 2^28 handles keep every position (and every ref, handle << 1 | is_max) in range.
  static constexpr size_t kMaxHandles = size_t{1} << 28;
  using Options = SegmentedSapOptions;

  explicit SegmentedSapCore(const Options& options = Options()) : options_(options) {
    uint32_t cap = std::bit_ceil(std::clamp<uint32_t>(options.chunk_capacity, 4, 4096));
    cap_ = cap;
    shift_ = static_cast<uint32_t>(std::countr_zero(cap));
    options_.chunk_capacity = cap;
  }

  void Apply(std::span<const uint32_t> erases, std::span<const HandleBox<K, T>> updates,
             std::span<const HandleBox<K, T>> inserts) {
    swaps_ = 0;
    tests_ = 0;
    const bool presorted =
        options_.presorted_min != 0 && erases.size() + inserts.size() >= options_.presorted_min;
    if (presorted) {
      EraseBatch(erases);
    } else {
      for (uint32_t h : erases) EraseObject(h);
    }
    rebuilt_ = options_.bulk_load_min != 0 && inserts.size() >= options_.bulk_load_min &&
               inserts.size() >= live_;
    if (presorted && (!erases.empty() || (!rebuilt_ && !inserts.empty()))) ++presorted_queries_;
    if (rebuilt_) {
      global_ = true;
      Rebuild(updates, inserts);
      return;
    }
    global_ = !updates.empty() && static_cast<double>(updates.size()) >
                                      options_.global_sort_fraction * static_cast<double>(live_);
    if (global_) {
      GlobalUpdate(updates);
    } else {
      for (const auto& [h, box] : updates) LocalUpdate(h, box);
    }
    if (presorted) {
      InsertBatch(inserts);
    } else {
      for (const auto& [h, box] : inserts) InsertObject(h, box);
    }
  }

  PairTracker& tracker() { return tracker_; }
  const PairTracker& tracker() const { return tracker_; }
  size_t live() const { return live_; }
  /// The box of live handle h as of the last Apply (the spot query's, see Broadphase).
  const Box<K, T>& box(uint32_t h) const { return boxes_[h]; }

  void FillStats(Stats* out) const {
    out->swaps = swaps_;
    out->overlap_tests = tests_;
    out->global_sort = global_;
    out->rebuilt = rebuilt_;
    SegmentedSapStats& detail = out->segmented_sap.emplace();
    for (const Axis& ax : axes_) detail.chunks += ax.chunk_count;
  }

  Status Validate() const;

  /// Options in force (chunk capacity rounded to a power of two).
  const Options& options() const { return options_; }
  /// White-box tests corrupt internals through this peer to prove Validate() notices.
  friend struct SegmentedSapTestPeer;

  /// Times an R set absorbed a checkpoint removal (a fast mover's min crossed its max), ever.
  size_t r_set_entries() const { return r_set_entries_; }
  /// Queries that integrated their inserts or erases chunk by chunk (presorted_min), ever.
  size_t presorted_queries() const { return presorted_queries_; }

 private:
  // One extremum: its value and ref = handle << 1 | is_max.
  struct Ext {
    T value;
    uint32_t ref;
  };
  static constexpr uint32_t kNone = ~uint32_t{0};
  struct Chunk {
    uint32_t count = 0;     // extrema held, 1..cap_ while linked
    uint32_t prev = kNone;  // neighbours in list order
    uint32_t next = kNone;
  };
  static_assert(sizeof(Chunk) == 12, "Chunk: count, prev, next");
  static_assert(sizeof(Ext) == (sizeof(T) > 4 ? 2 * sizeof(T) : 8), "Ext: value and ref");
  struct Axis {
    std::vector<Ext> items;       // chunk c owns items[c << shift_, (c << shift_) + cap_)
    std::vector<Chunk> chunks;    // by chunk id
    uint32_t head = kNone;        // first chunk
    size_t chunk_count = 0;       // linked chunks
    std::vector<uint32_t> order;  // chunk ids in list order, for binary search
    bool order_valid = true;      // false after a merge or removal until the next rebuild
    std::vector<uint32_t> free_chunks;
    std::vector<uint32_t> pos;  // pos[ref]: position of extremum ref
  };

  // (value, min before max): the list order. Touching boxes overlap because a min sorts before a
  // max of equal value.
  static bool Less(const Ext& a, const Ext& b) {
    return a.value < b.value || (a.value == b.value && (a.ref & 1u) < (b.ref & 1u));
  }
  // The list order with ties broken by handle: a layout that does not depend on the sort
  // algorithm. Rotating the ref puts is_max above the handle: (value, is_max, handle).
  static bool SortsBefore(const Ext& x, const Ext& y) {
    return x.value < y.value || (x.value == y.value && std::rotr(x.ref, 1) < std::rotr(y.ref, 1));
  }
  // Comparators as function objects, so that std::sort and std::merge inline them.
  static constexpr auto kLess = [](const Ext& x, const Ext& y) { return Less(x, y); };
  static constexpr auto kSortsBefore = [](const Ext& x, const Ext& y) { return SortsBefore(x, y); };
  static bool IsMax(uint32_t ref) { return (ref & 1u) != 0; }
  static uint32_t HandleOf(uint32_t ref) { return ref >> 1; }

  uint32_t ChunkOf(uint32_t p) const { return p >> shift_; }
  uint32_t SlotOf(uint32_t p) const { return p & (cap_ - 1); }
  uint32_t Base(uint32_t c) const { return c << shift_; }

  bool PrevPos(const Axis& ax, uint32_t p, uint32_t* out_q) const {
    if (SlotOf(p) > 0) {
      *out_q = p - 1;
      return true;
    }
    uint32_t c = ax.chunks[ChunkOf(p)].prev;
    if (c == kNone) return false;
    *out_q = Base(c) + ax.chunks[c].count - 1;
    return true;
  }
  bool NextPos(const Axis& ax, uint32_t p, uint32_t* out_q) const {
    uint32_t c = ChunkOf(p);
    if (SlotOf(p) + 1 < ax.chunks[c].count) {
      *out_q = p + 1;
      return true;
    }
    uint32_t next = ax.chunks[c].next;
    if (next == kNone) return false;
    *out_q = Base(next);
    return true;
  }

  // ---- checkpoints (axis 0) ----
  void CpAdd(uint32_t c, uint32_t h) {
    auto& r = rsets_[c];
    if (!r.empty()) {
      auto it = std::find(r.begin(), r.end(), h);
      if (it != r.end()) {
        *it = r.back();
        r.pop_back();
        return;
      }
    }
    bool inserted = checkpoints_[c].Insert(h);
    BP_ASSERT(inserted);
    (void)inserted;
  }
  void CpRemove(uint32_t c, uint32_t h) {
    if (!checkpoints_[c].Erase(h)) {
      rsets_[c].push_back(h);
      ++r_set_entries_;
    }
  }

  // Extremum x moved right from pl to pr and y left from pr to pl (adjacent positions) on
  // axis a: updates the checkpoints and the candidate set. Positions are the caller's.
  void Crossed(size_t a, Ext x, Ext y, uint32_t pl, uint32_t pr) {
    ++swaps_;
    uint32_t hx = HandleOf(x.ref);
    uint32_t hy = HandleOf(y.ref);
    if (a == 0) {
      uint32_t cl = ChunkOf(pl);
      if (cl != ChunkOf(pr)) {
        // x leaves chunk cl rightward, y enters it from the right.
        if (IsMax(x.ref)) {
          CpAdd(cl, hx);
        } else {
          CpRemove(cl, hx);
        }
        if (IsMax(y.ref)) {
          CpRemove(cl, hy);
        } else {
          CpAdd(cl, hy);
        }
      }
    }
    if (hx == hy) return;
    if (IsMax(x.ref) && !IsMax(y.ref)) {
      // y's min moved before x's max: they may overlap now.
      ++tests_;
      if (Overlaps(boxes_[hx], boxes_[hy])) tracker_.Add(hx, hy);  // Add applies the filter
    } else if (!IsMax(x.ref) && IsMax(y.ref)) {
      // y's max moved before x's min: separated on this axis.
      tracker_.Remove(hx, hy);
    }
  }

  // Insertion sort step: moves the extremum at p left past every greater neighbour. The moving
  // extremum stays in a register and each passed one shifts once ("hole" insertion); returns
  // whether it moved.
  bool SortLeft(size_t a, uint32_t p) {
    Axis& ax = axes_[a];
    const Ext e = ax.items[p];
    uint32_t q = 0;
    uint32_t start = p;
    while (PrevPos(ax, p, &q) && Less(e, ax.items[q])) {
      const Ext y = ax.items[q];
      ax.items[p] = y;
      ax.pos[y.ref] = p;
      Crossed(a, y, e, q, p);
      p = q;
    }
    if (p == start) return false;
    ax.items[p] = e;
    ax.pos[e.ref] = p;
    return true;
  }

  // Moves the extremum at p to its place after its value changed.
  void SortExtremum(size_t a, uint32_t p) {
    if (SortLeft(a, p)) return;
    Axis& ax = axes_[a];
    const Ext e = ax.items[p];
    uint32_t q = 0;
    uint32_t start = p;
    while (NextPos(ax, p, &q) && Less(ax.items[q], e)) {
      const Ext y = ax.items[q];
      ax.items[p] = y;
      ax.pos[y.ref] = p;
      Crossed(a, e, y, p, q);
      p = q;
    }
    if (p == start) return;
    ax.items[p] = e;
    ax.pos[e.ref] = p;
  }

  void LocalUpdate(uint32_t h, const Box<K, T>& box) {
    boxes_[h] = box;
    for (size_t a = 0; a < kAxes; ++a) {
      Axis& ax = axes_[a];
      uint32_t p = ax.pos[2 * h];
      ax.items[p].value = box.lo[a];
      SortExtremum(a, p);
      p = ax.pos[2 * h + 1];
      ax.items[p].value = box.hi[a];
      SortExtremum(a, p);
    }
  }

  void GlobalUpdate(std::span<const HandleBox<K, T>> updates) {
    for (const auto& [h, box] : updates) {
      boxes_[h] = box;
      for (size_t a = 0; a < kAxes; ++a) {
        Axis& ax = axes_[a];
        ax.items[ax.pos[2 * h]].value = box.lo[a];
        ax.items[ax.pos[2 * h + 1]].value = box.hi[a];
      }
    }
    for (size_t a = 0; a < kAxes; ++a) {
      Axis& ax = axes_[a];
      // Insertion sort in list order: each inverted pair swaps exactly once.
      for (uint32_t c = ax.head; c != kNone; c = ax.chunks[c].next) {
        uint32_t base = Base(c);
        uint32_t n = ax.chunks[c].count;
        for (uint32_t i = 0; i < n; ++i) SortLeft(a, base + i);
      }
    }
  }

  // ---- chunks ----
  uint32_t NewChunk(size_t a) {
    Axis& ax = axes_[a];
    uint32_t c = 0;
    if (!ax.free_chunks.empty()) {
      c = ax.free_chunks.back();
      ax.free_chunks.pop_back();
    } else {
      c = static_cast<uint32_t>(ax.chunks.size());
      ax.chunks.emplace_back();
      ax.items.resize(static_cast<size_t>(c + 1) << shift_);
      if (a == 0) {
        checkpoints_.emplace_back();
        rsets_.emplace_back();
      }
    }
    ax.chunks[c].count = 0;
    return c;
  }

  // Links chunk d right after chunk c.
  void LinkAfter(Axis& ax, uint32_t c, uint32_t d) {
    uint32_t next = ax.chunks[c].next;
    ax.chunks[d].prev = c;
    ax.chunks[d].next = next;
    ax.chunks[c].next = d;
    if (next != kNone) ax.chunks[next].prev = d;
    ++ax.chunk_count;
  }

  // The binary-search index, rebuilt from the links when a merge invalidated it.
  const std::vector<uint32_t>& Order(Axis& ax) {
    if (!ax.order_valid) {
      ax.order.clear();
      for (uint32_t c = ax.head; c != kNone; c = ax.chunks[c].next) ax.order.push_back(c);
      ax.order_valid = true;
    }
    return ax.order;
  }

  void MoveItems(Axis& ax, uint32_t from, uint32_t to, uint32_t n) {
    for (uint32_t i = 0; i < n; ++i) {
      ax.items[to + i] = ax.items[from + i];
      ax.pos[ax.items[to + i].ref] = to + i;
    }
  }

  // Splits the full chunk c, at index `index` of a valid `order`: its upper half moves to a new
  // chunk placed right after it.
  void Split(size_t a, uint32_t c, size_t index) {
    uint32_t d = NewChunk(a);
    Axis& ax = axes_[a];
    uint32_t keep = ax.chunks[c].count / 2;
    uint32_t moved = ax.chunks[c].count - keep;
    MoveItems(ax, Base(c) + keep, Base(d), moved);
    ax.chunks[c].count = keep;
    ax.chunks[d].count = moved;
    LinkAfter(ax, c, d);
    ax.order.insert(ax.order.begin() + static_cast<std::ptrdiff_t>(index) + 1, d);
    if (a == 0) {
      BP_ASSERT(rsets_[c].empty());
      // d inherits c's trailing edge; c's new edge is d's minus what d's extrema open or close.
      checkpoints_[d] = checkpoints_[c];
      FlatSet<uint32_t>& cp = checkpoints_[c];
      for (uint32_t i = moved; i-- > 0;) {
        uint32_t ref = ax.items[Base(d) + i].ref;
        if (IsMax(ref)) {
          cp.Insert(HandleOf(ref));
        } else {
          cp.Erase(HandleOf(ref));  // absent only for the half-inserted object
        }
      }
    }
  }

  void RemoveChunk(size_t a, uint32_t c) {
    Axis& ax = axes_[a];
    Chunk& ch = ax.chunks[c];
    if (ch.prev != kNone) {
      ax.chunks[ch.prev].next = ch.next;
    } else {
      ax.head = ch.next;
    }
    if (ch.next != kNone) ax.chunks[ch.next].prev = ch.prev;
    ch = Chunk{};
    --ax.chunk_count;
    ax.order_valid = false;
    ax.free_chunks.push_back(c);
    if (a == 0) {
      checkpoints_[c].Clear();
      rsets_[c].clear();
    }
  }

  // After an erase from chunk c: merges c with its right neighbour, then with its left one,
  // whenever the two fit in half a chunk, until neither does. This keeps invariant 2b (every two
  // adjacent chunks hold more than half a chunk), which bounds the chunk count by
  // 4 * extrema / capacity + 2. A merge never breaks the invariant for another pair (the merged
  // chunk holds at least what either part held), so after one erase at most one merge per side
  // happens; after a batch erase, calling this on every changed chunk restores it everywhere.
  void MaybeMerge(size_t a, uint32_t c) {
    Axis& ax = axes_[a];
    uint32_t limit = cap_ / 2;
    for (;;) {
      uint32_t next = ax.chunks[c].next;
      if (next != kNone && ax.chunks[c].count + ax.chunks[next].count <= limit) {
        Merge(a, c, next);
        continue;
      }
      uint32_t prev = ax.chunks[c].prev;
      if (prev != kNone && ax.chunks[prev].count + ax.chunks[c].count <= limit) {
        Merge(a, prev, c);
        c = prev;
        continue;
      }
      return;
    }
  }

  // Appends chunk right's extrema to its left neighbour left and drops right; the merged chunk
  // keeps right's checkpoints (its trailing edge).
  void Merge(size_t a, uint32_t left, uint32_t right) {
    Axis& ax = axes_[a];
    MoveItems(ax, Base(right), Base(left) + ax.chunks[left].count, ax.chunks[right].count);
    ax.chunks[left].count += ax.chunks[right].count;
    if (a == 0) {
      BP_ASSERT(rsets_[left].empty() && rsets_[right].empty());
      std::swap(checkpoints_[left], checkpoints_[right]);
    }
    RemoveChunk(a, right);
  }

  void InsertExtremum(size_t a, Ext e) {
    Axis& ax = axes_[a];
    if (ax.head == kNone) {
      uint32_t c = NewChunk(a);
      ax.head = c;
      ax.chunk_count = 1;
      ax.order.assign(1, c);
      ax.order_valid = true;
      ax.chunks[c].count = 1;
      ax.items[Base(c)] = e;
      ax.pos[e.ref] = Base(c);
      return;
    }
    // The first chunk whose last extremum sorts after e, else the last chunk.
    const std::vector<uint32_t>& order = Order(ax);
    auto it = std::partition_point(order.begin(), order.end(), [&](uint32_t c) {
      return !Less(e, ax.items[Base(c) + ax.chunks[c].count - 1]);
    });
    if (it == order.end()) --it;
    uint32_t c = *it;
    if (ax.chunks[c].count == cap_) {
      Split(a, c, static_cast<size_t>(it - order.begin()));
      uint32_t d = ax.chunks[c].next;
      if (!Less(e, ax.items[Base(c) + ax.chunks[c].count - 1])) c = d;
    }
    uint32_t base = Base(c);
    uint32_t i = ax.chunks[c].count++;
    while (i > 0 && Less(e, ax.items[base + i - 1])) {
      ax.items[base + i] = ax.items[base + i - 1];
      ax.pos[ax.items[base + i].ref] = base + i;
      --i;
      ++swaps_;
    }
    ax.items[base + i] = e;
    ax.pos[e.ref] = base + i;
  }

  void RemoveExtremum(size_t a, uint32_t ref) {
    Axis& ax = axes_[a];
    uint32_t p = ax.pos[ref];
    uint32_t c = ChunkOf(p);
    uint32_t n = ax.chunks[c].count;
    for (uint32_t i = SlotOf(p); i + 1 < n; ++i) {
      ax.items[Base(c) + i] = ax.items[Base(c) + i + 1];
      ax.pos[ax.items[Base(c) + i].ref] = Base(c) + i;
      ++swaps_;
    }
    if (--ax.chunks[c].count == 0) {
      RemoveChunk(a, c);
    } else {
      MaybeMerge(a, c);
    }
  }

  // Calls f(b) once for every live object b != h whose axis-0 interval may overlap h's: the
  // checkpoints of the chunk left of h's min, and every min from the start of h's min chunk up
  // to h's max.
  template <class F>
  void ForEachAxis0Candidate(uint32_t h, F&& f) const {
    const Axis& ax = axes_[0];
    uint32_t pmax = ax.pos[2 * h + 1];
    uint32_t c = ChunkOf(ax.pos[2 * h]);
    if (ax.chunks[c].prev != kNone) checkpoints_[ax.chunks[c].prev].ForEach(f);
    for (;; c = ax.chunks[c].next) {
      uint32_t base = Base(c);
      for (uint32_t i = 0; i < ax.chunks[c].count; ++i) {
        if (base + i == pmax) return;
        uint32_t ref = ax.items[base + i].ref;
        if (!IsMax(ref) && HandleOf(ref) != h) f(HandleOf(ref));
      }
    }
  }

  // Calls f(c) for the axis-0 chunks from h's min chunk (inclusive) to its max chunk (exclusive).
  template <class F>
  void ForEachSpannedChunk(uint32_t h, F&& f) const {
    const Axis& ax = axes_[0];
    uint32_t cmax = ChunkOf(ax.pos[2 * h + 1]);
    for (uint32_t c = ChunkOf(ax.pos[2 * h]); c != cmax; c = ax.chunks[c].next) f(c);
  }

  void Reserve(uint32_t h) {
    if (h < boxes_.size()) return;
    boxes_.resize(h + 1);
    live_flag_.resize(h + 1, 0);
    for (Axis& ax : axes_) ax.pos.resize(2 * (static_cast<size_t>(h) + 1));
  }

  // Bulk load: applies the updates and inserts to the boxes, rebuilds every axis from sorted
  // extrema (chunks three quarters full, checkpoints by one sweep), recomputes the overlap set
  // by sweeping axis 0, and reconciles the tracker with it, so events stay the exact difference.
  void Rebuild(std::span<const HandleBox<K, T>> updates, std::span<const HandleBox<K, T>> inserts) {
    for (const auto& [h, box] : updates) boxes_[h] = box;
    for (const auto& [h, box] : inserts) MakeLive(h, box);
    std::vector<uint32_t> live;
    live.reserve(live_);
    for (uint32_t h = 0; h < live_flag_.size(); ++h) {
      if (live_flag_[h]) live.push_back(h);
    }
    for (size_t a = 0; a < kAxes; ++a) BuildAxis(a, live);

    // Sweep axis 0: each min meets the objects whose interval is open there.
    FlatSet<uint64_t> now;
    std::vector<uint32_t> active;
    std::vector<uint32_t> slot(live_flag_.size(), 0);
    const Axis& ax = axes_[0];
    for (uint32_t c = ax.head; c != kNone; c = ax.chunks[c].next) {
      for (uint32_t i = 0; i < ax.chunks[c].count; ++i) {
        uint32_t ref = ax.items[Base(c) + i].ref;
        uint32_t h = HandleOf(ref);
        if (IsMax(ref)) {
          uint32_t last = active.back();
          active[slot[h]] = last;
          slot[last] = slot[h];
          active.pop_back();
          continue;
        }
        for (uint32_t b : active) {
          ++tests_;
          if (Overlaps(boxes_[h], boxes_[b]) && tracker_.Accepts(h, b))
            now.Insert(HandlePair(h, b));
        }
        slot[h] = static_cast<uint32_t>(active.size());
        active.push_back(h);
      }
    }
    std::vector<uint64_t> gone;
    tracker_.ForEachOverlap([&](uint32_t a, uint32_t b) {
      if (!now.Contains(HandlePair(a, b))) gone.push_back(HandlePair(a, b));
    });
    for (uint64_t p : gone) tracker_.Remove(PairFirst(p), PairSecond(p));
    now.ForEach([&](uint64_t p) { tracker_.Add(PairFirst(p), PairSecond(p)); });
  }

  // Replaces axis a's lists by the sorted extrema of the live handles.
  void BuildAxis(size_t a, const std::vector<uint32_t>& live) {
    Axis& ax = axes_[a];
    for (uint32_t c = ax.head; c != kNone;) {
      uint32_t next = ax.chunks[c].next;
      ax.chunks[c] = Chunk{};
      ax.free_chunks.push_back(c);
      if (a == 0) {
        checkpoints_[c].Clear();
        rsets_[c].clear();
      }
      c = next;
    }
    ax.head = kNone;
    ax.chunk_count = 0;
    ax.order.clear();
    ax.order_valid = true;
    std::vector<Ext> ext;
    ext.reserve(2 * live.size());
    for (uint32_t h : live) {
      ext.push_back(Ext{boxes_[h].lo[a], 2 * h});
      ext.push_back(Ext{boxes_[h].hi[a], 2 * h + 1});
    }
    std::sort(ext.begin(), ext.end(), kSortsBefore);
    uint32_t fill = std::max<uint32_t>(1, cap_ * 3 / 4);
    FlatSet<uint32_t> open;
    uint32_t prev = kNone;
    for (size_t i = 0; i < ext.size(); i += fill) {
      uint32_t c = NewChunk(a);
      if (prev == kNone) {
        ax.head = c;
        ax.chunk_count = 1;
      } else {
        LinkAfter(ax, prev, c);
      }
      ax.order.push_back(c);
      uint32_t n = static_cast<uint32_t>(std::min<size_t>(fill, ext.size() - i));
      for (uint32_t j = 0; j < n; ++j) {
        const Ext& e = ext[i + j];
        ax.items[Base(c) + j] = e;
        ax.pos[e.ref] = Base(c) + j;
        if (a == 0) {
          if (IsMax(e.ref)) {
            open.Erase(HandleOf(e.ref));
          } else {
            open.Insert(HandleOf(e.ref));
          }
        }
      }
      ax.chunks[c].count = n;
      if (a == 0) checkpoints_[c] = open;
      prev = c;
    }
  }

  // Records a new live object's box (its extrema are placed by the caller).
  void MakeLive(uint32_t h, const Box<K, T>& box) {
    Reserve(h);
    BP_ASSERT(!live_flag_[h]);
    boxes_[h] = box;
    live_flag_[h] = 1;
    ++live_;
  }

  void InsertObject(uint32_t h, const Box<K, T>& box) {
    MakeLive(h, box);
    for (size_t a = 0; a < kAxes; ++a) {
      InsertExtremum(a, Ext{box.lo[a], 2 * h});
      InsertExtremum(a, Ext{box.hi[a], 2 * h + 1});
    }
    ForEachSpannedChunk(h, [&](uint32_t c) { CpAdd(c, h); });
    ForEachAxis0Candidate(h, [&](uint32_t b) {
      ++tests_;
      if (Overlaps(boxes_[h], boxes_[b])) tracker_.Add(h, b);
    });
  }

  // The part of an erase that needs h's extrema still in place: its pairs end and it leaves
  // the checkpoints of the chunks it spans. Flattened (its callees inlined into it) so that both
  // erase paths run the same code: left alone, GCC 12 inlined PairTracker::Remove into the
  // per-event loop but not into the batch one.
  [[gnu::flatten]] void ForgetPairsAndCheckpoints(uint32_t h) {
    BP_ASSERT(h < live_flag_.size() && live_flag_[h] == 1);
    ForEachAxis0Candidate(h, [&](uint32_t b) { tracker_.Remove(h, b); });
    ForEachSpannedChunk(h, [&](uint32_t c) { CpRemove(c, h); });
  }

  void EraseObject(uint32_t h) {
    ForgetPairsAndCheckpoints(h);
    for (size_t a = 0; a < kAxes; ++a) {
      RemoveExtremum(a, 2 * h + 1);
      RemoveExtremum(a, 2 * h);
    }
    live_flag_[h] = 0;
    --live_;
  }

  // ---- presorted inserts and erases (the improvement proposed at the end of section 4.1) ----
  // live_flag_ of an object whose extrema are being placed by InsertBatch: it is in the lists
  // but in no checkpoint set yet.
  static constexpr uint8_t kInserting = 2;

  // Erases the objects chunk by chunk: first, on the intact lists, what EraseObject does before
  // touching them (ForgetPairsAndCheckpoints); then per axis each touched chunk is compacted
  // in one pass and, once every chunk is compacted, merged where invariant 2b asks for it.
  void EraseBatch(std::span<const uint32_t> erases) {
    if (erases.empty()) return;
    for (uint32_t h : erases) ForgetPairsAndCheckpoints(h);
    for (uint32_t h : erases) {
      live_flag_[h] = 0;
      --live_;
    }
    for (size_t a = 0; a < kAxes; ++a) CompactErased(a, erases);
  }

  // Compacts the chunks of axis a that hold extrema of the erased objects (live flag 0 by now):
  // each chunk is marked with its erased count and first erased slot, then compacted from there
  // in one pass, so every surviving extremum moves at most once. No sort of the positions is
  // needed: a dead extremum is recognised by its live flag (and a chunk with one needs no check).
  void CompactErased(size_t a, std::span<const uint32_t> erases) {
    Axis& ax = axes_[a];
    if (first_gone_.size() < ax.chunks.size()) first_gone_.resize(ax.chunks.size(), kNone);
    std::vector<uint32_t>& marked = marked_chunks_;
    marked.clear();
    for (uint32_t h : erases) {
      for (uint32_t p : {ax.pos[2 * h], ax.pos[2 * h + 1]}) {
        // first_gone_[c]: erased extrema in c << 16 | the first one's slot (slots < 4096).
        uint32_t& mark = first_gone_[ChunkOf(p)];
        if (mark == kNone) {
          marked.push_back(ChunkOf(p));
          mark = 1u << 16 | SlotOf(p);
        } else {
          mark = ((mark >> 16) + 1) << 16 | std::min(mark & 0xffffu, SlotOf(p));
        }
      }
    }
    // At most two entries per marked chunk (itself, or its two neighbours when it empties).
    touched_.resize(2 * marked.size());
    size_t touched = 0;
    for (uint32_t c : marked) {
      const uint32_t base = Base(c);
      const uint32_t n = ax.chunks[c].count;
      const uint32_t gone = first_gone_[c] >> 16;
      uint32_t w = first_gone_[c] & 0xffffu;
      first_gone_[c] = kNone;
      for (uint32_t s = w + 1; s < n; ++s) {
        const Ext e = ax.items[base + s];
        if (gone > 1 && live_flag_[HandleOf(e.ref)] == 0) continue;  // one gone: none after it
        ax.items[base + w] = e;
        ax.pos[e.ref] = base + w;
        ++w;
        ++swaps_;
      }
      ax.chunks[c].count = w;
      if (w != 0) {
        touched_[touched++] = c;
        continue;
      }
      // Its neighbours meet now: one of them must be checked for invariant 2b.
      if (ax.chunks[c].prev != kNone) touched_[touched++] = ax.chunks[c].prev;
      if (ax.chunks[c].next != kNone) touched_[touched++] = ax.chunks[c].next;
      RemoveChunk(a, c);
    }
    touched_.resize(touched);
    // Merging moves extrema across chunks, so it waits until every compaction is done. Every
    // pair of adjacent chunks that may hold half a chunk or less now has a member in touched_;
    // removed chunks (count 0: merged away or emptied after being listed) are skipped.
    for (uint32_t c : touched_) {
      if (ax.chunks[c].count != 0) MaybeMerge(a, c);
    }
  }

  // Inserts the objects chunk by chunk: their extrema are placed axis by axis (InsertSorted)
  // while they are marked kInserting, so that chunks created on axis 0 get the checkpoints of
  // the objects already present only; then each is added to the checkpoints of the chunks it
  // spans, and then tested against its axis-0 candidates, which include the other new objects.
  void InsertBatch(std::span<const HandleBox<K, T>> inserts) {
    if (inserts.empty()) return;
    for (const HandleBox<K, T>& hb : inserts) {
      MakeLive(hb.handle, hb.box);
      live_flag_[hb.handle] = kInserting;
    }
    for (size_t a = 0; a < kAxes; ++a) InsertSorted(a, inserts);
    for (const HandleBox<K, T>& hb : inserts) {
      const uint32_t h = hb.handle;
      ForEachSpannedChunk(h, [&](uint32_t c) { CpAdd(c, h); });
    }
    // Two new objects that overlap on axis 0 are candidates of each other (the candidates are a
    // superset of the axis-0 overlaps), so such a pair is met twice. Testing it from the lower
    // handle only costs a flag check per candidate: worth it only when new objects make up a
    // good part of the candidates.
    if (inserts.size() * 4 >= live_) {
      TestNewCandidates<true>(inserts);
    } else {
      TestNewCandidates<false>(inserts);
    }
    for (const HandleBox<K, T>& hb : inserts) live_flag_[hb.handle] = 1;
  }

  template <bool kOnce>
  void TestNewCandidates(std::span<const HandleBox<K, T>> inserts) {
    for (const HandleBox<K, T>& hb : inserts) {
      const uint32_t h = hb.handle;
      ForEachAxis0Candidate(h, [&](uint32_t b) {
        if (kOnce && b < h && live_flag_[b] == kInserting) return;
        ++tests_;
        if (Overlaps(hb.box, boxes_[b])) tracker_.Add(h, b);
      });
    }
  }

  // Places the new extrema of axis a: sorted, cut into runs by target chunk (InsertExtremum's
  // rule: the first chunk whose last extremum sorts after it, else the last chunk) while walking
  // the chunks in list order, and each run merged into its chunk in one pass (MergeRun).
  void InsertSorted(size_t a, std::span<const HandleBox<K, T>> inserts) {
    Axis& ax = axes_[a];
    std::vector<Ext>& ext = batch_ext_;
    ext.resize(2 * inserts.size());
    for (size_t i = 0; i < inserts.size(); ++i) {
      ext[2 * i] = Ext{inserts[i].box.lo[a], 2 * inserts[i].handle};
      ext[2 * i + 1] = Ext{inserts[i].box.hi[a], 2 * inserts[i].handle + 1};
    }
    std::sort(ext.begin(), ext.end(), kSortsBefore);
    if (ax.head == kNone) {
      // An empty list: one empty chunk that takes everything (and spreads if it overflows).
      uint32_t c = NewChunk(a);
      ax.head = c;
      ax.chunk_count = 1;
      ax.order.assign(1, c);
      ax.order_valid = true;
    }
    const std::vector<uint32_t>& order = Order(ax);
    new_chunks_.clear();
    size_t r = 0;
    for (size_t i = 0; i < ext.size();) {
      r = TargetRank(ax, r, ext[i]);
      const uint32_t c = order[r];
      size_t j = ext.size();
      if (r + 1 < order.size()) {
        const Ext last = ax.items[Base(c) + ax.chunks[c].count - 1];
        j = i + 1;
        while (j < ext.size() && Less(ext[j], last)) ++j;
      }
      MergeRun(a, c, r, std::span<const Ext>(ext.data() + i, j - i));
      i = j;
      ++r;  // the next run sorts after c's last extremum: its chunk lies further right
    }
    if (new_chunks_.empty()) return;
    // The index gains the new chunks right after the chunk each came from (block copies: the
    // index of a long list is long, the new chunks few).
    new_order_.resize(ax.order.size() + new_chunks_.size());
    auto out = new_order_.begin();
    size_t done = 0;
    for (const auto& [rank, d] : new_chunks_) {
      out = std::copy(ax.order.begin() + static_cast<std::ptrdiff_t>(done),
                      ax.order.begin() + static_cast<std::ptrdiff_t>(rank + 1), out);
      done = rank + 1;
      *out++ = d;
    }
    std::copy(ax.order.begin() + static_cast<std::ptrdiff_t>(done), ax.order.end(), out);
    ax.order.swap(new_order_);
  }

  // The rank (in the valid `order`) of e's target chunk, at `from` or after it: gallops from
  // `from`, then binary searches, so a run costs O(log distance) and not one search of the list.
  size_t TargetRank(const Axis& ax, size_t from, const Ext& e) const {
    const std::vector<uint32_t>& order = ax.order;
    if (from + 1 >= order.size()) return from;
    auto before = [&](uint32_t c) { return !Less(e, ax.items[Base(c) + ax.chunks[c].count - 1]); };
    size_t lo = from;
    size_t hi = from;
    for (size_t step = 1; hi < order.size() && before(order[hi]); step *= 2) {
      lo = hi + 1;
      hi += step;
    }
    hi = std::min(hi, order.size());
    auto it = std::partition_point(order.begin() + static_cast<std::ptrdiff_t>(lo),
                                   order.begin() + static_cast<std::ptrdiff_t>(hi), before);
    return std::min(static_cast<size_t>(it - order.begin()), order.size() - 1);
  }

  // Merges the sorted run into chunk c (at index `rank` of `order`): in place, backward, when
  // it fits; else through merged_, spread evenly over c and new chunks linked after it, each
  // with cap / 2 .. 3 / 4 cap extrema (so invariant 2b holds around them). Every extremum that
  // was in c moves at most once.
  void MergeRun(size_t a, uint32_t c, size_t rank, std::span<const Ext> run) {
    Axis& ax = axes_[a];
    const uint32_t m = ax.chunks[c].count;
    const auto g = static_cast<uint32_t>(run.size());
    const uint32_t base = Base(c);
    if (m + g <= cap_) {
      uint32_t i = m;
      uint32_t j = g;
      uint32_t w = m + g;
      while (j > 0) {
        --w;
        if (i > 0 && Less(run[j - 1], ax.items[base + i - 1])) {
          ax.items[base + w] = ax.items[base + --i];
          ++swaps_;
        } else {
          ax.items[base + w] = run[--j];
        }
        ax.pos[ax.items[base + w].ref] = base + w;
      }
      ax.chunks[c].count = m + g;
      return;
    }
    merged_.resize(m + g);
    std::merge(ax.items.begin() + base, ax.items.begin() + base + m, run.begin(), run.end(),
               merged_.begin(), kLess);
    swaps_ += m;
    const uint32_t total = m + g;
    const uint32_t fill = cap_ / 4 * 3;
    const uint32_t parts = std::max<uint32_t>(2, (total + fill - 1) / fill);
    run_chunks_.assign(1, c);
    for (uint32_t k = 1; k < parts; ++k) {
      uint32_t d = NewChunk(a);  // may grow ax.items: nothing above points into it
      LinkAfter(ax, run_chunks_.back(), d);
      run_chunks_.push_back(d);
      new_chunks_.emplace_back(rank, d);
    }
    uint32_t from = 0;
    for (uint32_t k = 0; k < parts; ++k) {
      const uint32_t d = run_chunks_[k];
      const uint32_t n = total / parts + (k < total % parts ? 1 : 0);
      for (uint32_t s = 0; s < n; ++s) {
        ax.items[Base(d) + s] = merged_[from + s];
        ax.pos[merged_[from + s].ref] = Base(d) + s;
      }
      ax.chunks[d].count = n;
      from += n;
    }
    if (a == 0) SpreadCheckpoints();
  }

  // Checkpoints of the chunks in run_chunks_ (a chunk whose extrema were spread over it and the
  // new chunks after it), as Split computes them: the last inherits the chunk's trailing edge,
  // and each other one's edge is its successor's plus the maxima and minus the minima the
  // successor holds. Objects being inserted are left out (InsertBatch adds them later).
  void SpreadCheckpoints() {
    const Axis& ax = axes_[0];
    BP_ASSERT(rsets_[run_chunks_[0]].empty());
    FlatSet<uint32_t> edge;
    std::swap(edge, checkpoints_[run_chunks_[0]]);
    for (size_t k = run_chunks_.size() - 1; k > 0; --k) {
      const uint32_t d = run_chunks_[k];
      checkpoints_[d] = edge;
      for (uint32_t i = ax.chunks[d].count; i-- > 0;) {
        const uint32_t ref = ax.items[Base(d) + i].ref;
        const uint32_t h = HandleOf(ref);
        if (live_flag_[h] == kInserting) continue;
        if (IsMax(ref)) {
          edge.Insert(h);
        } else {
          edge.Erase(h);
        }
      }
    }
    std::swap(edge, checkpoints_[run_chunks_[0]]);
  }

  Options options_;
  uint32_t cap_ = 32;
  uint32_t shift_ = 5;
  Axis axes_[kAxes];
  std::vector<FlatSet<uint32_t>> checkpoints_;  // axis 0, by chunk id
  std::vector<std::vector<uint32_t>> rsets_;    // axis 0, by chunk id; empty between objects
  std::vector<Box<K, T>> boxes_;
  std::vector<uint8_t> live_flag_;
  size_t live_ = 0;
  PairTracker tracker_;
  size_t swaps_ = 0;
  size_t tests_ = 0;
  size_t r_set_entries_ = 0;
  size_t presorted_queries_ = 0;
  // Scratch of the presorted path, kept to reuse their allocations.
  std::vector<Ext> batch_ext_;           // new extrema of one axis, sorted
  std::vector<Ext> merged_;              // one overflowing chunk's merge
  std::vector<uint32_t> marked_chunks_;  // chunks holding erased extrema
  std::vector<uint32_t> first_gone_;     // by chunk id: erased count << 16 | first slot, or kNone
  std::vector<uint32_t> touched_;        // chunks to merge after compaction
  std::vector<uint32_t> run_chunks_;     // a chunk and the chunks it spread to
  std::vector<std::pair<size_t, uint32_t>> new_chunks_;  // (rank of origin, new chunk id)
  std::vector<uint32_t> new_order_;
  bool global_ = false;
  bool rebuilt_ = false;
};

}  // namespace detail

}  // namespace bp

#include "bp/detail/segmented_sap_validate.h"  // NOLINT(build/include_order): defines Validate

namespace bp {

/// Sweep and prune over segmented interval lists, behind the common interface.
template <int K, Coordinate T, class Key = uint64_t>
using SegmentedSap = detail::FrontEnd<detail::SegmentedSapCore<K, T>, Key>;

}  // namespace bp
