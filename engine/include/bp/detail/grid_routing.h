// bp::detail::GridRouting: where each change of a query goes, on one thread. An object covering
// at most max_cells_per_object cells lives in each of them: a move within the same cells is an
// update in each, a move across cells is an insert into the new cells, an update in the kept
// ones and an erase from the old ones; a change of size may move it into or out of the large
// set (GridLargeSet), and a small object's change is tested against the large objects over it.
// The cells are not touched here: each cell operation is appended to a query-wide array and
// counted in the cell's work entry (cell_work_), then grouped by cell (GroupUpdates) before the
// cells are applied (GridCore::QueryCells). Only cells with buffered operations are applied, so
// the work per query is O(u + e) plus the cells' own.
//
// Until a large object is inserted or moved in the query (its rescan reads the cells' tables),
// an insert's local handle in a cell is allocated when the cell is applied (on its pool
// thread), not here (defer_locals_, see EnterCell).
//
// Thread safety: none (a parallel routing, GridParallelRouting, runs these on the caller's
// thread for the updates its runs leave).
// Invariants (checked by GridCore::Validate):
//  1. Between queries no work is left: touched_ and the routed arrays are empty, and every
//     cell's work entry is zero; cell_work_ has one entry per cell index.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "bp/detail/assert.h"
#include "bp/detail/grid_large.h"
#include "bp/detail/huge_alloc.h"
#include "bp/detail/prefetch.h"

namespace bp::detail {

template <class Cell>
class GridRouting : public GridLargeSet<Cell> {
  using Base = GridLargeSet<Cell>;

 protected:
  using Base::kAxes;
  using Base::kDim;
  using Base::kNone;
  using Base::kUnpaired;
  using typename Base::BoxType;
  using typename Base::CellCoord;
  using typename Base::CellRef;
  using typename Base::Coord;
  using typename Base::GridCell;
  using typename Base::Large;
  using typename Base::Object;
  using typename Base::Options;
  using typename Base::Space;
  using typename Base::State;
  // The records and the cell table.
  using Base::AllocLocal;
  using Base::AllocRefs;
  using Base::cell_of_;
  using Base::CellAt;
  using Base::CellCount;
  using Base::CellOf;
  using Base::cells_;
  using Base::ClaimLocal;
  using Base::FirstCellKey;
  using Base::FreeRefs;
  using Base::objects_;
  using Base::options_;
  using Base::PairsWithNothing;
  using Base::Prefetch;
  using Base::RangeOf;
  using Base::refs_;
  using Base::Reserve;
  using Base::unpaired_;
  // The large set and the witness counts.
  using Base::EraseLarge;
  using Base::InsertLarge;
  using Base::large_;
  using Base::large_count_;
  using Base::MoveLarge;
  using Base::TestLargeInBins;
  using Base::Witness;

  explicit GridRouting(const Options& options) : Base(options) {}

  // This query's updates of cell slots, as routed, then grouped by cell (GroupUpdates).
  struct Routed {
    uint32_t cell;
    HandleBox<kDim, Coord> update;  // the cell's local handle and the new box
  };

  // Per-cell tables larger than about half a typical L2 are far from the cache: beyond
  // kWorkInCache work entries (CellWork), routing prefetches them, and beyond kWorkInCacheBytes
  // grouping prefetches any per-cell table (see WorkFarFromCache; in bytes, so that a table of
  // small entries, as the shards' 8-byte ones, counts by its size).
  static constexpr size_t kWorkInCache = 8192, kWorkInCacheBytes = size_t{224} << 10;

  // New objects land anywhere, and churn recycles handles from anywhere: each one's record and
  // the cell-table line of the first cell it enters are prefetched 16 inserts ahead, then that
  // cell's work entry (for writing) and, when local handles are allocated now (see
  // defer_locals_), its record 8 ahead (found through the table, which is not changed). On a
  // parallel routing the work entries were last written by either thread (MergeCounts).
  void InsertObjects(std::span<const HandleBox<kDim, Coord>> inserts) {
    const size_t n = inserts.size();
    for (size_t i = 0; i < n; ++i) {
      if (i + 16 < n) {
        const HandleBox<kDim, Coord>& ahead = inserts[i + 16];
        if (ahead.handle < objects_.size()) Prefetch(&objects_[ahead.handle]);
        if (const void* line = cell_of_.HomeLine(FirstCellKey(ahead.box))) Prefetch(line);
      }
      if (i + 8 < n) {
        // The first cell's work entry, which routing the insert writes (Touch); and its record
        // when the local handle is allocated now.
        const uint32_t* idx = std::as_const(cell_of_).Find(FirstCellKey(inserts[i + 8].box));
        if (idx != nullptr && *idx < cells_.size()) {
          PrefetchForWrite(&cell_work_[*idx]);  // cell_work_ grows with cells_
          if (!defer_locals_) Prefetch(cells_[*idx].get());
        }
      }
      InsertObject(inserts[i].handle, inserts[i].box);
    }
  }
  void InsertObject(uint32_t h, const BoxType& box) {
    Reserve(h);
    Object& o = objects_[h];
    BP_ASSERT(o.state == State::kDead);
    o.state = State::kLive;
    objects_[h].box = box;
    if (PairsWithNothing(h)) {
      o.large = kUnpaired;
      o.nrefs = 0;
      ++unpaired_;
      return;
    }
    CellCoord lo, hi;
    RangeOf(box, &lo, &hi);
    if (CellCount(lo, hi) > options_.max_cells_per_object) {
      InsertLarge(h, lo, hi);
      return;
    }
    EnterCells(h, lo, hi);
    if (large_count_ != 0) TestLargeInBins(h, nullptr, lo, hi);
  }

  // Churn picks its victims anywhere in the table: each erased object's records are prefetched
  // ahead in the order they depend on each other (the object, then its cell references, then
  // the work entries of the cells it leaves, which routing its erases writes; the cells
  // themselves are not touched until they are applied).
  void EraseObjects(std::span<const uint32_t> erases) {
    const size_t n = erases.size();
    for (size_t i = 0; i < n; ++i) {
      if (i + 32 < n) Prefetch(&objects_[erases[i + 32]]);
      if (i + 16 < n) {
        const Object& ahead = objects_[erases[i + 16]];
        if (ahead.nrefs != 0) Prefetch(&refs_[ahead.refs]);
      }
      if (i + 8 < n) {
        // The work entries of its cells, which routing the erases writes (Touch).
        const Object& ahead = objects_[erases[i + 8]];
        for (uint32_t k = 0; k < ahead.nrefs; ++k) {
          PrefetchForWrite(&cell_work_[refs_[ahead.refs + k].cell]);
        }
      }
      EraseObject(erases[i]);
    }
  }

  void EraseObject(uint32_t h) {
    Object& o = objects_[h];
    BP_ASSERT(o.state == State::kLive);
    o.state = State::kDead;
    if (o.large != kNone) {
      if (o.large == kUnpaired) {
        o.large = kNone;
        --unpaired_;
        return;
      }
      EraseLarge(h);
      return;
    }
    // Dead: every pair it had goes.
    if (large_count_ != 0) TestLargeInBins(h, &objects_[h].box, o.lo, o.hi);
    LeaveCells(h);
  }

  // kept_routed: h stays small and migrates, and its updates in the cells it keeps were routed
  // (RouteRun).
  void UpdateObject(uint32_t h, const BoxType& box, bool kept_routed = false) {
    Object& o = objects_[h];
    BP_ASSERT(o.state == State::kLive);
    if (o.large == kUnpaired) {
      o.box = box;
      return;
    }
    const BoxType before = objects_[h].box;
    objects_[h].box = box;
    CellCoord lo, hi;
    // The new range, compared with the old one axis by axis in registers (comparing the arrays
    // would read back the just-stored coordinates whole: a failed store-to-load forward).
    bool same_range = true;
    for (size_t a = 0; a < kAxes; ++a) {
      const auto l = static_cast<typename Space::Scalar>(CellOf(box.lo[a], a));
      const auto u = static_cast<typename Space::Scalar>(CellOf(box.hi[a], a));
      same_range = same_range && l == o.lo[a] && u == o.hi[a];
      lo[a] = l;
      hi[a] = u;
    }
    bool large_now = CellCount(lo, hi) > options_.max_cells_per_object;
    BP_ASSERT(!kept_routed || (o.large == kNone && !large_now));
    if (o.large != kNone) {
      if (large_now) {
        MoveLarge(o.large, lo, hi);
        return;
      }
      EraseLarge(h);  // and back into the cells as a small object
      EnterCells(h, lo, hi);
      if (large_count_ != 0) TestLargeInBins(h, nullptr, lo, hi);
      return;
    }
    if (large_now) {
      // Out of every large partner set (by scan: a large object moved earlier in this query may
      // have left the lists of this object's cells), then out of the cells.
      for (Large& l : large_) {
        if (l.handle != kNone && l.partners.Erase(h)) Witness(h, l.handle, false);
      }
      LeaveCells(h);
      InsertLarge(h, lo, hi);
      return;
    }
    BP_ASSERT(!kept_routed || !same_range);
    const CellCoord then_lo = o.lo, then_hi = o.hi;
    if (same_range) {
      for (uint32_t i = 0; i < o.nrefs; ++i) RouteUpdate(refs_[o.refs + i], box);
    } else {
      Migrate(h, lo, hi, kept_routed);
    }
    if (large_count_ != 0) TestLargeInBins(h, &before, then_lo, then_hi);
  }

  // A small object's new cell range differs: update it in the cells it keeps, insert it into
  // the new ones, erase it from the ones it left.
  // (kept_routed: the updates in the cells it keeps are routed already.)
  void Migrate(uint32_t h, const CellCoord& lo, const CellCoord& hi, bool kept_routed = false) {
    const BoxType& box = objects_[h].box;
    const uint32_t n = static_cast<uint32_t>(CellCount(lo, hi));
    const uint32_t refs = AllocRefs(n);
    Object& o = objects_[h];
    uint32_t i = 0;
    Space::ForEachCoord(lo, hi, [&](const CellCoord& c) {
      CellRef ref;
      if (Space::Contains(o.lo, o.hi, c)) {
        ref = refs_[o.refs + Space::RowMajor(o.lo, o.hi, c)];
        if (!kept_routed) RouteUpdate(ref, box);
      } else {
        ref = EnterCell(CellAt(c), h, refs + i, box);
      }
      refs_[refs + i++] = ref;
    });
    uint32_t j = 0;
    Space::ForEachCoord(o.lo, o.hi, [&](const CellCoord& c) {
      CellRef ref = refs_[o.refs + j++];
      if (Space::Contains(lo, hi, c)) return;
      RouteErase(ref);
    });
    FreeRefs(o.refs, o.nrefs);
    o.lo = lo;
    o.hi = hi;
    o.refs = refs;
    o.nrefs = n;
  }

  void EnterCells(uint32_t h, const CellCoord& lo, const CellCoord& hi) {
    const uint32_t n = static_cast<uint32_t>(CellCount(lo, hi));
    const uint32_t refs = AllocRefs(n);
    uint32_t i = 0;
    Space::ForEachCoord(lo, hi, [&](const CellCoord& c) {
      const CellRef ref = EnterCell(CellAt(c), h, refs + i, objects_[h].box);
      refs_[refs + i++] = ref;
    });
    Object& o = objects_[h];
    o.lo = lo;
    o.hi = hi;
    o.refs = refs;
    o.nrefs = n;
    o.large = kNone;
  }

  // Routes h's insert into cell idx, whose reference will sit at refs_[ref_at]; returns that
  // reference. With defer_locals_ the cell's local handle is left for ApplyCell to allocate
  // (the reference's local is kNone until then): the cell's record and tables are not touched
  // here, on the serial path, but when the cell is applied (on its pool thread), where they are
  // read anyway.
  CellRef EnterCell(uint32_t idx, uint32_t h, uint32_t ref_at, const BoxType& box) {
    if (defer_locals_) {
      RouteInsert(CellRef{idx, h}, box, ref_at);
      return CellRef{idx, kNone};
    }
    const CellRef ref{idx, AllocLocal(*cells_[idx], h)};
    RouteInsert(ref, box, kNone);
    return ref;
  }

  // Ends deferral for the rest of the query: allocates the local handles of the inserts routed
  // so far. A large object is about to appear, whose scans read the cells' tables.
  void AssignDeferredLocals() {
    for (size_t k = 0; k < routed_inserts_.size(); ++k) {
      uint32_t& ref_at = routed_insert_refs_[k];
      if (ref_at == kNone) continue;
      Routed& r = routed_inserts_[k];
      r.update.handle = ClaimLocal(*cells_[r.cell], r.update.handle, ref_at);
      ref_at = kNone;
    }
    defer_locals_ = false;
  }

  // Ends deferral, if on (see AssignDeferredLocals): a large object is about to appear.
  void EndLocalDeferral() {
    if (defer_locals_) AssignDeferredLocals();
  }

  void LeaveCells(uint32_t h) {
    Object& o = objects_[h];
    for (uint32_t i = 0; i < o.nrefs; ++i) RouteErase(refs_[o.refs + i]);
    FreeRefs(o.refs, o.nrefs);
    o.nrefs = 0;
  }

  // Starts loading the records updates[i + 32] and updates[i + 16] read first (distances long
  // enough for a virtual machine's memory misses; docs/TUNING.md). Each loop
  // spells these prefetches out: GCC 12 finds a helper whose only effect is a prefetch pure (a
  // prefetch touches no memory it models) and deletes the calls to it.
#define BP_GRID_PREFETCH_UPDATE(updates, i, end)                           \
  do {                                                                     \
    if ((i) + 32 < (end)) Prefetch(&objects_[(updates)[(i) + 32].handle]); \
    if ((i) + 16 < (end)) {                                                \
      const Object& ahead = objects_[(updates)[(i) + 16].handle];          \
      if (ahead.nrefs != 0) Prefetch(&refs_[ahead.refs]);                  \
    }                                                                      \
  } while (false)

  // A third stage for the serial loops, when the work table outgrows the L2: the work entry of
  // updates[i + 8]'s first cell, which routing counts in (where the table fits, these loads
  // only cost).
#define BP_GRID_PREFETCH_WORK(updates, i, end)                             \
  do {                                                                     \
    if ((i) + 8 < (end) && cell_work_.size() > kWorkInCache) {             \
      const Object& ahead = objects_[(updates)[(i) + 8].handle];           \
      if (ahead.nrefs != 0) Prefetch(&cell_work_[refs_[ahead.refs].cell]); \
    }                                                                      \
  } while (false)

  // Updates come in handle order, not memory order: the loads of each object's records miss the
  // cache, so they are prefetched a few updates ahead, in the order they depend on each other
  // (object and box, then its cell references). An update that stays in its cells touches no
  // cell here: it is appended to routed_ (see RouteUpdate). With a pool, see RouteOnPool.
  void RouteUpdates(std::span<const HandleBox<kDim, Coord>> updates) {
    if (large_count_ != 0) {
      RouteUpdatesBesideLarge(updates);
      return;
    }
    const size_t n = updates.size();
    routed_.reserve(n);
    for (size_t i = 0; i < n; ++i) {
      BP_GRID_PREFETCH_UPDATE(updates, i, n);
      BP_GRID_PREFETCH_WORK(updates, i, n);
      const auto& [h, box] = updates[i];
      Object& o = objects_[h];
      BP_ASSERT(o.state == State::kLive);
      if (large_count_ == 0 && StaysInCells(o, box)) {
        // Most updates: the box, and one routed update per cell, as UpdateObject would do
        // (in about half its instructions: no new range, cell count or large-object checks).
        o.box = box;
        for (uint32_t k = 0; k < o.nrefs; ++k) RouteUpdate(refs_[o.refs + k], box);
        continue;
      }
      UpdateObject(h, box);
    }
  }

  // RouteUpdates while large objects exist: as its loop (which stays as short as it is for the
  // scenes without them), with the large objects' candidate tests on the common path too.
  void RouteUpdatesBesideLarge(std::span<const HandleBox<kDim, Coord>> updates) {
    const size_t n = updates.size();
    routed_.reserve(n);
    for (size_t i = 0; i < n; ++i) {
      BP_GRID_PREFETCH_UPDATE(updates, i, n);
      BP_GRID_PREFETCH_WORK(updates, i, n);
      const auto& [h, box] = updates[i];
      Object& o = objects_[h];
      BP_ASSERT(o.state == State::kLive);
      if (StaysInCells(o, box)) {
        const BoxType before = o.box;
        o.box = box;
        for (uint32_t k = 0; k < o.nrefs; ++k) RouteUpdate(refs_[o.refs + k], box);
        TestLargeInBins(h, &before, o.lo, o.hi);
        continue;
      }
      UpdateObject(h, box);
    }
  }

  // True iff small object o's cell range is the same for box (its update touches no cell,
  // handle or reference): one axis bound at a time, stopping at the first that differs.
  bool StaysInCells(const Object& o, const BoxType& box) const {
    bool same_range = o.large == kNone;
    for (size_t a = 0; a < kAxes && same_range; ++a) {
      same_range = CellOf(box.lo[a], a) == o.lo[a] && CellOf(box.hi[a], a) == o.hi[a];
    }
    return same_range;
  }

  void Touch(uint32_t idx) {
    CellWork& work = cell_work_[idx];
    if (!work.touched) {
      work.touched = true;
      touched_.push_back(idx);
    }
  }

  // Buffers the update of a cell's slot: appended to routed_ (sequential writes, where a
  // per-cell buffer cost two cache misses, its header and its end) and counted per cell;
  // QueryCells groups routed_ by cell.
  void RouteUpdate(CellRef ref, const BoxType& box) {
    PushRouted(routed_, ref, box);
    ++cell_work_[ref.cell].updates;
    Touch(ref.cell);
  }
  // Inserts and erases of cell slots are buffered like updates, in query-wide arrays grouped by
  // cell before the cells are applied: per-cell vectors cost a miss on each first push and
  // again on each cell's first read.
  // ref_at: where the object's reference to the cell sits when its local handle is still to be
  // allocated (ref.local is then the global handle), else kNone.
  void RouteInsert(CellRef ref, const BoxType& box, uint32_t ref_at) {
    PushRouted(routed_inserts_, ref, box);
    routed_insert_refs_.push_back(ref_at);
    ++cell_work_[ref.cell].inserts;
    Touch(ref.cell);
  }
  void RouteErase(CellRef ref) {
    routed_erases_.push_back(ref);
    ++cell_work_[ref.cell].erases;
    Touch(ref.cell);
  }
  // Appends {cell, local, box} to v, written in place (see PushBox).
  static void PushRouted(HugeVector<Routed>& v, CellRef ref, const BoxType& box) {
    Routed& r = v.emplace_back();
    r.cell = ref.cell;
    r.update.handle = ref.local;
    r.update.box = box;
  }

  // The serially routed operations grouped by cell, in the order of touched_: each touched
  // cell's updates, erases and inserts become one contiguous run each in grouped_,
  // grouped_erases_ and grouped_inserts_ (starting at begin, erase_begin, insert_begin), in
  // routing order within it. (A parallel routing's shards are grouped by RouteOnPool.)
  void GroupUpdates() {
    uint32_t offset = 0, erase_offset = 0, insert_offset = 0;
    for (uint32_t idx : touched_) {
      CellWork& work = cell_work_[idx];
      work.begin = offset;
      work.erase_begin = erase_offset;
      work.insert_begin = insert_offset;
      offset += work.updates;
      erase_offset += work.erases;
      insert_offset += work.inserts;
    }
    grouped_.resize(offset);
    grouped_erases_.resize(erase_offset);
    grouped_inserts_.resize(insert_offset);
    grouped_insert_refs_.resize(insert_offset);
    // The begin fields serve as write cursors, and are set back after.
    ScatterRouted(routed_, grouped_.data(), WorkFarFromCache(cell_work_),
                  [this](uint32_t cell) -> uint32_t& { return cell_work_[cell].begin; });
    for (const CellRef& r : routed_erases_) {
      grouped_erases_[cell_work_[r.cell].erase_begin++] = r.local;
    }
    for (size_t k = 0; k < routed_inserts_.size(); ++k) {
      const Routed& r = routed_inserts_[k];
      const uint32_t at = cell_work_[r.cell].insert_begin++;
      grouped_inserts_[at] = r.update;
      grouped_insert_refs_[at] = routed_insert_refs_[k];
    }
    for (uint32_t idx : touched_) {
      CellWork& work = cell_work_[idx];
      work.begin -= work.updates;
      work.erase_begin -= work.erases;
      work.insert_begin -= work.inserts;
    }
    routed_.clear();
    routed_erases_.clear();
    routed_inserts_.clear();
    routed_insert_refs_.clear();
  }

  // True iff a per-cell table outgrows kWorkInCacheBytes.
  template <class Table>
  static bool WorkFarFromCache(const Table& table) {
    return table.size() * sizeof(table[0]) > kWorkInCacheBytes;
  }

  // Writes each of v's updates at its cell's write cursor in dst (cursor(cell), advanced). When
  // the cursors' table is far from the cache (far), cells and cursors lie all over a table
  // larger than the L2: the cursor's line is prefetched 32 updates ahead, then the line the
  // cursor points at 16 ahead, for writing (on a table that fits, the prefetches only cost).
  template <class Cursor>
  static void ScatterRouted(const HugeVector<Routed>& v, HandleBox<kDim, Coord>* dst, bool far,
                            Cursor&& cursor) {
    const size_t n = v.size();
    const Routed* r = v.data();
    if (!far) {
      for (size_t k = 0; k < n; ++k) dst[cursor(r[k].cell)++] = r[k].update;
      return;
    }
    for (size_t k = 0; k < n; ++k) {
      if (k + 32 < n) __builtin_prefetch(&cursor(r[k + 32].cell));
      if (k + 16 < n) PrefetchForWrite(dst + cursor(r[k + 16].cell));
      dst[cursor(r[k].cell)++] = r[k].update;
    }
  }

  HugeVector<Routed> routed_;
  std::vector<uint32_t> touched_;
  HugeVector<HandleBox<kDim, Coord>> grouped_;
  std::vector<CellRef> routed_erases_;        // this query's erases of cell slots, as routed
  HugeVector<Routed> routed_inserts_;         // and its inserts
  std::vector<uint32_t> routed_insert_refs_;  // per routed insert: see RouteInsert's ref_at
  std::vector<uint32_t> grouped_erases_;
  HugeVector<HandleBox<kDim, Coord>> grouped_inserts_;
  std::vector<uint32_t> grouped_insert_refs_;
  // This query allocates cell-local handles of inserts when it applies the cells (EnterCell).
  // Only until a large object is inserted or moved: its rescan reads the cells' tables, so the
  // first such change ends the deferral (AssignDeferredLocals).
  bool defer_locals_ = false;
  // Per cell index, this query's work: touched (in touched_), the updates, erases and inserts
  // routed to it, and where their runs start in grouped_, grouped_erases_ and grouped_inserts_.
  // Kept apart from the cells so that routing reads a few bytes; 32-byte aligned, so that an
  // entry never straddles two lines (at 28 bytes, 6 in 16 entries did, and a prefetch of the
  // entry missed its touched flag).
  struct alignas(32) CellWork {
    uint32_t updates = 0, erases = 0, inserts = 0;
    uint32_t begin = 0, erase_begin = 0, insert_begin = 0;
    bool touched = false;
  };
  HugeVector<CellWork> cell_work_;
};

}  // namespace bp::detail
