// bp::detail::GridParallelRouting: a query's routing on the worker pool, when the grid has one
// worth waking for its updates and no large object exists (RouteOnPool says how). The updates
// are cut into one run per thread, each routed into a shard of its own by part of the cells;
// the shards' counts are merged per part, and their updates scattered by cell per part, beside
// the serial pass (GridRouting) that the runs leave: migrations, then the inserts. The events
// do not depend on it: a cell's updates are its shards', in run order, as the serial routing
// would have them.
//
// Thread safety: the runs write only the updated objects' boxes and their shards (the updates
// name distinct objects); the merge and the scatter write only their part's cells' entries.
// Invariants (checked by GridCore::Validate):
//  1. Between queries the shards hold no work (empty lists, zero counts) and no cell has shard
//     updates (shard_work_ counts zero).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <utility>
#include <vector>

#include "bp/detail/assert.h"
#include "bp/detail/grid_routing.h"
#include "bp/detail/huge_alloc.h"
#include "bp/detail/prefetch.h"

namespace bp::detail {

template <class Cell>
class GridParallelRouting : public GridRouting<Cell> {
  using Base = GridRouting<Cell>;

 protected:
  using Base::cell_work_;
  using Base::CellCount;
  using Base::cells_;
  using Base::EraseObjects;
  using Base::InsertObjects;
  using Base::kDim;
  using Base::kNone;
  using Base::large_count_;
  using Base::objects_;
  using Base::options_;
  using Base::pool_;
  using Base::pool_routed_;
  using Base::PoolFor;
  using Base::Prefetch;
  using Base::PushRouted;
  using Base::RangeOf;
  using Base::refs_;
  using Base::routed_;
  using Base::ScatterRouted;
  using Base::StaysInCells;
  using Base::touched_;
  using Base::UpdateObject;
  using Base::WorkFarFromCache;
  using typename Base::BoxType;
  using typename Base::CellCoord;
  using typename Base::CellRef;
  using typename Base::CellWork;
  using typename Base::Coord;
  using typename Base::Object;
  using typename Base::Options;
  using typename Base::Routed;
  using typename Base::Space;
  using typename Base::State;

  explicit GridParallelRouting(const Options& options) : Base(options) {}

  // A parallel routing's parts of the cells per thread (see RouteOnPool): more than one, so that
  // the thread done first with the serial pass or a part can take another part.
  static constexpr size_t kPartsPerThread = 2;
  // What an erase costs, in routed updates (RouteOnPool's first run), as measured on S1-1M.
  static constexpr size_t kEraseWeight = 2;

  // One run of a parallel routing: its updates that stay in their cells and those of migrating
  // objects in the cells they keep, and the cells it touched, each by part of the cells
  // (PartOf), their counts by cell index (zero outside touched), and the updates left for the
  // serial pass (indices into the query's updates, kKeptRouted marking migrations).
  // Two lines apart: the threads push to their shards' vectors at once, and shards' headers
  // sharing a line would bounce it between the threads.
  struct alignas(128) Shard {
    std::vector<HugeVector<Routed>> routed;      // by part
    std::vector<std::vector<uint32_t>> touched;  // by part
    std::vector<uint32_t> counts, deferred;
  };

  // After a pool loop ran Apply's beside task: it is not run again in this query.
  void BesideRan() {
    beside_ran_ = true;
    beside_ = nullptr;
  }

  // The updates and inserts on the pool, when it has one worth waking for n updates and no
  // large object exists (else false, and nothing is done):
  //  1. The updates are cut into one run per thread, and routed in parallel into per-run
  //     shards (RouteRun), by part of the cells (PartOf): those that stay in their cells
  //     whole, those of migrating objects in the cells they keep. The first run starts with
  //     the erases (EraseObjects), and is shorter by their cost: they touch no updated object
  //     (the front end stages one call per object) and share with the runs only the objects'
  //     table and refs_, in other records (and read refs_ only; their cells' work entries,
  //     touched_, routed_erases_ and the free references are the serial side's, and nothing
  //     grows), so the erases no longer run before the routing.
  //  2. The shards' counts are merged per part, in parallel (MergeCounts); this also brings
  //     the touched cells' work entries into the caches, where the serial pass finds them (so
  //     the merge does not run beside that pass).
  //  3. One task makes the serial pass, in order: the rest of the updates the runs left
  //     (RouteDeferred), then the inserts. Beside it, the other threads run Apply's beside task
  //     (the front end's commit of its erased keys), then scatter the shards' updates by cell
  //     into grouped_shard_, part by part (ScatterShard), which the serial pass never touches.
  //     The pass is longer than the scatter; the beside task fills the other threads' wait.
  // A cell's updates are then its shards', in run order.
  bool RouteOnPool(std::span<const uint32_t> erases,
                   std::span<const HandleBox<kDim, Coord>> updates,
                   std::span<const HandleBox<kDim, Coord>> inserts) {
    const size_t n = updates.size();
    if (large_count_ != 0 || PoolFor(n) == nullptr) return false;
    const size_t runs = pool_->threads();
    // Run 0 starts with the erases and is shorter by their cost (kEraseWeight updates each).
    const size_t weighted = n + erases.size() * kEraseWeight;
    const size_t per_run = (weighted + runs - 1) / runs;
    run_begin_.resize(runs + 1);
    run_begin_[0] = 0;
    run_begin_[1] = std::min(n, per_run - std::min(per_run, erases.size() * kEraseWeight));
    // The runs after it hold per_run each, the last the rest (runs * per_run >= weighted).
    for (size_t r = 2; r < runs; ++r) run_begin_[r] = std::min(n, run_begin_[r - 1] + per_run);
    run_begin_[runs] = n;
    SetParts(runs * kPartsPerThread);
    shards_.resize(runs);
    for (Shard& sh : shards_) {
      sh.counts.resize(cells_.size(), 0);
      sh.routed.resize(parts_);
      sh.touched.resize(parts_);
    }
    pool_->ParallelFor(runs, 1, [&](size_t begin, size_t end, unsigned) {
      for (size_t r = begin; r < end; ++r) {
        if (r == 0) EraseObjects(erases);
        RouteRun(updates, run_begin_[r], run_begin_[r + 1], shards_[r]);
      }
    });
    // The shards' counts into shard_work_, one part per thread, marking the cells touched.
    shard_work_.resize(cells_.size());
    part_touched_.resize(parts_);
    part_base_.resize(parts_ + 1);
    pool_->ParallelFor(parts_, 1, [this](size_t begin, size_t end, unsigned) {
      for (size_t part = begin; part < end; ++part) MergeCounts(part);
    });
    for (const std::vector<uint32_t>& t : part_touched_)
      touched_.insert(touched_.end(), t.begin(), t.end());
    // part_base_[p] holds part p's count of updates (MergeCounts): now where its run starts.
    uint32_t total = 0;
    for (size_t part = 0; part < parts_; ++part) total += std::exchange(part_base_[part], total);
    part_base_[parts_] = total;
    grouped_shard_.resize(total);
    pool_routed_ = n;
    for (const Shard& sh : shards_) pool_routed_ -= sh.deferred.size();
    // Task 0 is the serial pass, 1 Apply's beside task when there is one, the parts' scatters
    // follow.
    const size_t extra = beside_ != nullptr ? 1 : 0;
    pool_->ParallelFor(parts_ + 1 + extra, 1, [&](size_t begin, size_t end, unsigned) {
      for (size_t task = begin; task < end; ++task) {
        if (task == 0) {
          RouteDeferred(updates);
          InsertObjects(inserts);
        } else if (task <= extra) {
          (*beside_)();
        } else {
          ScatterShard(task - 1 - extra);
        }
      }
    });
    if (extra != 0) BesideRan();
    // Every update the serial pass met was a migration whose kept cells its run routed (or an
    // object turned large, which leaves its cells): none was routed serially (see ApplyCell).
    BP_ASSERT(routed_.empty());
    shard_work_.resize(cells_.size());  // cells created by the serial pass: no shard updates
    parts_ = 0;
    return true;
  }

  // The updates the routing runs left, in order (migrations).
  void RouteDeferred(std::span<const HandleBox<kDim, Coord>> updates) {
    for (Shard& sh : shards_) {
      const std::vector<uint32_t>& d = sh.deferred;
      for (size_t k = 0; k < d.size(); ++k) {
        // Prefetched as in the serial loop: these objects lie all over the table.
        if (k + 32 < d.size()) Prefetch(&objects_[updates[d[k + 32] & ~kKeptRouted].handle]);
        if (k + 16 < d.size()) {
          const Object& ahead = objects_[updates[d[k + 16] & ~kKeptRouted].handle];
          if (ahead.nrefs != 0) Prefetch(&refs_[ahead.refs]);
        }
        if (k + 8 < d.size()) {
          // The work entries of its cells: routing its erases from those it leaves writes them.
          const Object& ahead = objects_[updates[d[k + 8] & ~kKeptRouted].handle];
          for (uint32_t j = 0; j < ahead.nrefs; ++j) {
            PrefetchForWrite(&cell_work_[refs_[ahead.refs + j].cell]);
          }
        }
        const HandleBox<kDim, Coord>& u = updates[d[k] & ~kKeptRouted];
        UpdateObject(u.handle, u.box, (d[k] & kKeptRouted) != 0);
      }
      sh.deferred.clear();
    }
  }

  // Routes updates[begin, end) on one pool thread: an update of a small object that stays in its
  // cells (no cell, handle or reference changes) stores the box and goes into the shard's
  // routed list and per-cell counts; a migration's updates in the cells it keeps go there too
  // and the rest of it is left for the serial pass, as is any other update (deferred). Writes
  // only the updated objects' boxes and the shard: the updates name distinct objects.
  void RouteRun(std::span<const HandleBox<kDim, Coord>> updates, size_t begin, size_t end,
                Shard& sh) {
    // The counts were last read and zeroed by whichever thread merged their part (MergeCounts):
    // a line is then a miss to the other core's cache, met at random. All are requested for writing
    // at once first, unless they outnumber the run's updates (then most lines are not touched).
    const char* counts = reinterpret_cast<const char*>(sh.counts.data());
    const size_t counts_bytes = sh.counts.size() * sizeof(uint32_t);
    if (counts_bytes / 64 <= end - begin) {
      for (size_t off = 0; off < counts_bytes; off += 64) PrefetchForWrite(counts + off);
    }
    for (size_t i = begin; i < end; ++i) {
      BP_GRID_PREFETCH_UPDATE(updates, i, end);
      // Not a structured binding: the lambda below captures box (clang 14 cannot).
      const uint32_t h = updates[i].handle;
      const BoxType& box = updates[i].box;
      Object& o = objects_[h];
      BP_ASSERT(o.state == State::kLive);
      const auto route = [&](const CellRef& ref) {
        const size_t part = PartOf(ref.cell);
        PushRouted(sh.routed[part], ref, box);
        if (sh.counts[ref.cell]++ == 0) sh.touched[part].push_back(ref.cell);
      };
      if (StaysInCells(o, box)) {
        o.box = box;
        for (uint32_t k = 0; k < o.nrefs; ++k) route(refs_[o.refs + k]);
        continue;
      }
      // A small object that stays small migrates: its updates in the cells it keeps are routed
      // here (most of a migration's cell operations), and the rest left for the serial pass
      // (RouteDeferred). Any other update is left whole.
      CellCoord lo, hi;
      RangeOf(box, &lo, &hi);
      if (o.large != kNone || CellCount(lo, hi) > options_.max_cells_per_object) {
        sh.deferred.push_back(static_cast<uint32_t>(i));
        continue;
      }
      uint32_t k = 0;
      Space::ForEachCoord(o.lo, o.hi, [&](const CellCoord& c) {
        const CellRef& ref = refs_[o.refs + k++];
        if (Space::Contains(lo, hi, c)) route(ref);
      });
      sh.deferred.push_back(static_cast<uint32_t>(i) | kKeptRouted);
    }
  }
  // Marks a deferred update (an index into the query's updates, below kMaxHandles) whose
  // updates in the cells it keeps were routed by its run.
  static constexpr uint32_t kKeptRouted = uint32_t{1} << 31;

  // Adds the shards' counts of the cells of `part` to their shard_work_ entries, marks the cells
  // touched (those newly touched into part_touched_[part], in shard order, or in cell order when
  // most are touched), counts the part's updates (into part_base_[part]) and zeroes the shards'
  // counts. Writes only the part's cells' entries: the parts merge in parallel.
  void MergeCounts(size_t part) {
    std::vector<uint32_t>& out = part_touched_[part];
    out.clear();
    uint32_t total = 0;
    const auto merge = [&](uint32_t idx, uint32_t count) {
      shard_work_[idx].count += count;
      total += count;
      CellWork& work = cell_work_[idx];
      if (!work.touched) {
        work.touched = true;
        out.push_back(idx);
      }
    };
    const uint32_t first = PartBegin(part), last = PartBegin(part + 1);
    size_t listed = 0;
    for (const Shard& sh : shards_) listed += sh.touched[part].size();
    if (listed * 2 > last - first) {
      // Most of the part's cells are touched: one sweep of the part in cell order, which reads
      // the counts and work entries in memory order (the lists are in routing order, random).
      for (uint32_t idx = first; idx < last; ++idx) {
        uint32_t count = 0;
        for (Shard& sh : shards_) count += std::exchange(sh.counts[idx], 0);
        if (count != 0) merge(idx, count);
      }
    } else {
      for (Shard& sh : shards_) {
        for (uint32_t idx : sh.touched[part]) merge(idx, std::exchange(sh.counts[idx], 0));
      }
    }
    for (Shard& sh : shards_) sh.touched[part].clear();
    part_base_[part] = total;
  }

  // Scatters the shards' updates of the cells of `part` into grouped_shard_ (from
  // part_base_[part] on), each cell's run in shard order: see RouteOnPool. Writes only the part's
  // cells' shard_work_ entries and their runs.
  void ScatterShard(size_t part) {
    // In cell order, as the cells are applied when most are touched (QueryCells): their
    // updates are then read in memory order.
    const uint32_t first = PartBegin(part), last = PartBegin(part + 1);
    uint32_t at = part_base_[part];
    for (uint32_t idx = first; idx < last; ++idx) {
      shard_work_[idx].begin = at;  // the write cursor, set back below
      at += shard_work_[idx].count;
    }
    BP_ASSERT(at == part_base_[part + 1]);
    for (Shard& sh : shards_) {
      ScatterRouted(sh.routed[part], grouped_shard_.data(), WorkFarFromCache(shard_work_),
                    [this](uint32_t cell) -> uint32_t& { return shard_work_[cell].begin; });
      sh.routed[part].clear();
    }
    for (uint32_t idx = first; idx < last; ++idx) shard_work_[idx].begin -= shard_work_[idx].count;
  }

  // The parts of the cells, for a parallel routing's merge and grouping: `parts` runs of cell
  // indices of about equal length, cut over the cells that exist now. Only those get shard
  // work: cells created later (by the serial pass) are never routed to, merged or scattered.
  void SetParts(size_t parts) {
    parts_ = parts;
    part_cells_ = cells_.size();
    part_mul_ = ((uint64_t{1} << 32) * parts) / std::max<size_t>(part_cells_, 1);
  }
  // The first cell of part p, of those counted by SetParts (p == parts_: their count).
  uint32_t PartBegin(size_t p) const {
    if (p == 0) return 0;
    if (p >= parts_) return static_cast<uint32_t>(part_cells_);
    const uint64_t at = ((uint64_t{p} << 32) + part_mul_ - 1) / part_mul_;  // PartOf(at) >= p
    return static_cast<uint32_t>(std::min<uint64_t>(at, part_cells_));
  }
  // The part of cell idx, one of the cells counted by SetParts: floor(idx * parts / cells),
  // which never reaches parts_ (the multiplier is rounded down; the min is a guard).
  size_t PartOf(uint32_t idx) const {
    return std::min<size_t>((uint64_t{idx} * part_mul_) >> 32, parts_ - 1);
  }
#undef BP_GRID_PREFETCH_UPDATE  // defined in detail/grid_routing.h
#undef BP_GRID_PREFETCH_WORK    // likewise

  std::vector<Shard> shards_;
  std::vector<size_t> run_begin_;  // RouteOnPool: where each routing run starts, then n
  // A parallel routing's parts of the cells (SetParts; 0 outside a query that routed in
  // parallel) and the cells each part's merge found newly touched.
  size_t parts_ = 0;
  uint64_t part_mul_ = 0;
  size_t part_cells_ = 0;  // the cells SetParts counted
  std::vector<std::vector<uint32_t>> part_touched_;
  // And where each part's run of grouped_shard_ starts (part_base_[parts_]: their count).
  std::vector<uint32_t> part_base_;
  // Per cell index, a parallel routing's shard updates: where they start in grouped_shard_ and
  // how many (count zero outside a query; begin is then meaningless). Apart from cell_work_, which
  // the serial pass writes (and grows, creating cells) while ScatterShard writes this.
  struct ShardWork {
    uint32_t begin = 0, count = 0;
  };
  std::vector<ShardWork> shard_work_;
  // A parallel routing's shard updates grouped by cell (ScatterShard), each part's run in cell
  // order; the serially routed ones go to grouped_ (GroupUpdates).
  HugeVector<HandleBox<kDim, Coord>> grouped_shard_;
  const std::function<void()>* beside_ = nullptr;  // see GridCore::Apply
  bool beside_ran_ = false;
};

}  // namespace bp::detail
