// bp::detail::GridWitness: the grid's witness counts. Every cell reports the changes of its own
// overlap set, and the large set its own pairs; the grid counts, per pair, the cells (and the
// large set) that witness it. A pair is in the grid's overlap set iff its count is at least
// one, and the count's transitions between 0 and 1 are the events (the tracker cancels a pair
// that leaves one cell and enters another in the same query). The tracker holds the first
// witness (its overlap set); extra_ holds the count beyond one, for the few pairs several
// cells share.
//
// The cells' changes wait, translated to global handles, in per-thread buffers by shard of the
// tracker (witnessed_, filled by GridCore::ApplyCell), and the large set's in buffers of their
// own (serial_witnessed_, filled by Witness during the routing), and are folded shard by shard,
// in parallel when there are enough (FoldWitnessed), with the lines they probe prefetched. A
// rebuild (GridSizing::Regrid) recounts instead: the tracker already holds the pair set, and only
// extra_ is rebuilt.
//
// Thread safety: none, except that FoldShard for distinct shards runs on distinct threads.
// Invariants (checked by GridCore::Validate):
//  1. For every pair, the cells whose core holds it plus the large set (once) number
//     1 + extra_[pair] when the tracker holds it (extra_ absent means 1), and 0 otherwise.
//  2. extra_ has one map per shard of the tracker, and a pair's count lies in its shard's.
//  3. Between queries no change waits in serial_witnessed_.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "bp/detail/flat_map.h"
#include "bp/detail/flat_set.h"
#include "bp/detail/grid_cells.h"

namespace bp::detail {

template <class Cell>
class GridWitness : public GridCellTable<Cell> {
  using Base = GridCellTable<Cell>;

 protected:
  using Base::pool_;
  using Base::PoolFor;
  using Base::Prefetch;
  using Base::tracker_;
  using typename Base::Options;

  explicit GridWitness(const Options& options) : Base(options) {}

  // A change of a pair's overlap in one cell, in global handles (now: it overlaps there now).
  struct Witnessed {
    uint32_t a, b;
    bool now;
  };

  // Folds every applied cell's changes into the witness counts (GridCore::FoldCells then
  // recycles the cells that emptied). A cell's changes wait in the buffer of the thread that
  // applied it and of each pair's shard of the tracker (GridCore::ApplyCell). With a pool and
  // enough changes, each shard is folded by one thread (FoldShard): a pair's witness count and
  // sets lie in its shard alone. The changes are folded in any order (each thread's buffer whole,
  // one after the other, which is cheaper than merging them in the order of touched_): the events
  // do not depend on it. A cell removes only a pair it held at the last query, which the pair's
  // count includes, so no order takes a count below zero; a pair whose count passes through zero
  // leaves the overlap set and comes back, which the tracker cancels; and the counts and sets end
  // the same. (The layout of the sets' tables may differ, and with it the order of ForEachOverlap:
  // it never promised one.) A rebuild's recount (GridSizing::Regrid) folds serially. A change's
  // fold (three probes of hash tables) counts as kWitnessWeight routed updates or key look-ups,
  // PoolFor's unit: a few thousand changes a frame fold faster on two threads than on one.
  static constexpr size_t kWitnessWeight = 4;
  void FoldWitnessed() {
    size_t changes = 0;
    for (const auto& w : witnessed_) changes += w.size();
    for (const auto& w : serial_witnessed_) changes += w.size();
    const size_t shards = tracker_.shards();
    if (shards > 1 && !recount_ && PoolFor(kWitnessWeight * changes) != nullptr) {
      pool_->ParallelFor(shards, 1, [this](size_t begin, size_t end, unsigned) {
        for (size_t shard = begin; shard < end; ++shard) FoldShard(shard);
      });
    } else {
      for (size_t shard = 0; shard < shards; ++shard) FoldShard(shard);
    }
    for (auto& w : serial_witnessed_) w.clear();
  }

  // Starts loading the lines that folding change w (of FoldShard's shard) probes: the overlap
  // and changed sets' homes, and for a removal the witness table's. Spelled out in each loop,
  // as BP_GRID_PREFETCH_UPDATE: GCC 12 deletes these prefetches from a lambda (only loads and
  // prefetches: pure), and the fold then waits on every probe.
#define BP_GRID_PREFETCH_WITNESS(w)                                              \
  do {                                                                           \
    const uint64_t ahead_pair = HandlePair((w)->a, (w)->b);                      \
    if (const void* line = tracker_.OverlapLine(ahead_pair)) Prefetch(line);     \
    if (const void* line = tracker_.ChangedLine(ahead_pair)) Prefetch(line);     \
    if (!(w)->now) {                                                             \
      if (const void* line = extra_[shard].HomeLine(ahead_pair)) Prefetch(line); \
    }                                                                            \
  } while (false)

  // Folds the changes of the pairs in tracker shard `shard`: the threads' buffers of the shard,
  // one after the other (see FoldCells: the order does not matter). The pairs land all over the
  // tracker's sets and the witness table: the lines a change probes are prefetched kFoldAhead
  // changes ahead.
  void FoldShard(size_t shard) {
    static constexpr size_t kFoldAhead = 32;
    const size_t shards = tracker_.shards();
    const auto fold = [&](const std::vector<Witnessed>& buf) {
      for (size_t k = 0; k < buf.size(); ++k) {
        if (k + kFoldAhead < buf.size()) BP_GRID_PREFETCH_WITNESS(&buf[k + kFoldAhead]);
        WitnessIn(shard, buf[k].a, buf[k].b, buf[k].now);
      }
    };
    for (size_t at = shard; at < witnessed_.size(); at += shards) fold(witnessed_[at]);
    if (shard < serial_witnessed_.size()) fold(serial_witnessed_[shard]);
  }
#undef BP_GRID_PREFETCH_WITNESS

  // One more (add) or one fewer (remove) witness of the pair a, b, folded with the cells'
  // changes (FoldWitnessed): the pairs land all over the tracker's sets, and folded one by one
  // as they came each probe was a cache miss.
  void Witness(uint32_t a, uint32_t b, bool add) {
    const size_t shards = tracker_.shards();
    if (serial_witnessed_.size() != shards) serial_witnessed_.resize(shards);
    serial_witnessed_[shards == 1 ? 0 : tracker_.ShardOf(HandlePair(a, b))].push_back(
        Witnessed{a, b, add});
  }
  // Witness of a pair whose shard (PairTracker::ShardOf) the caller knows.
  void WitnessIn(size_t shard, uint32_t a, uint32_t b, bool add) {
    const uint64_t p = HandlePair(a, b);
    FlatMap<uint64_t, uint32_t>& extra = extra_[shard];
    if (recount_) {
      // Rebuilding after a resize: the tracker already holds the pair set; count only.
      BP_ASSERT(add && tracker_.Contains(a, b));
      if (!recount_seen_.Insert(p)) ++extra.FindOrInsert(p, 0);
      return;
    }
    if (add) {
      if (!tracker_.AddIn(shard, a, b)) ++extra.FindOrInsert(p, 0);
      return;
    }
    if (uint32_t* e = extra.Find(p)) {
      if (--*e == 0) extra.Erase(p);
      return;
    }
    bool removed = tracker_.RemoveIn(shard, a, b);
    BP_ASSERT(removed);
    (void)removed;
  }

  // A rebuild's recount (see GridSizing::Regrid): from here to EndRecount, witnesses count the
  // pairs the tracker holds already.
  void BeginRecount() {
    for (auto& extra : extra_) extra.Clear();
    recount_ = true;
  }
  void EndRecount() {
    recount_ = false;
    BP_ASSERT(recount_seen_.size() == tracker_.overlaps());
    recount_seen_.Clear();
  }

  // Per pool thread and shard of the tracker: witnessed_[thread * shards + shard].
  std::vector<std::vector<Witnessed>> witnessed_;
  // The large set's changes (Witness), by shard of the tracker.
  std::vector<std::vector<Witnessed>> serial_witnessed_;
  // Witnesses beyond the first, by shard of the tracker; line-aligned, as the folding threads
  // write their shards' headers.
  struct alignas(64) Extra : FlatMap<uint64_t, uint32_t> {};
  std::vector<Extra> extra_;
  bool recount_ = false;
  FlatSet<uint64_t> recount_seen_;
};

}  // namespace bp::detail
