// bp::detail::GridCore: the grid's core (see bp/grid.h for its contract), composed of its parts:
//   detail/grid_objects.h          records, reference pool, tracker, counters (GridObjects)
//   detail/grid_cells.h            coordinates -> cells, recycling, local handles (GridCellTable)
//   detail/grid_witness.h          witness counts and their fold (GridWitness)
//   detail/grid_large.h            the large-object set (GridLargeSet)
//   detail/grid_routing.h          serial routing of a query's changes (GridRouting)
//   detail/grid_parallel_routing.h routing on the worker pool (GridParallelRouting)
//   detail/grid_sizing.h           the cell size, regridding (GridSizing)
// and runs a query's phases (Apply): route the changes (serially or on the pool), apply every
// touched cell's buffered operations (QueryCells: in parallel, cells share nothing), fold the
// cells' changes into the witness counts (FoldCells), recycle the cells that emptied, and size
// again if the live count has moved far (MaybeResize).
//
// With `threads` > 1 the touched cells are applied by a worker pool; their changes are then
// folded by shard of the pair sets, one shard per thread. The events do not depend on the thread
// count: neither the counts nor the sets depend on the order of the fold (see FoldCells).
//
// Thread safety: none for callers (see bp/broadphase.h); the pool's threads apply one cell each,
// route runs of updates (the first after the erases), or scatter parts of the cells (and run
// Apply's beside task) beside the serial routing (RouteOnPool); without a parallel routing,
// Apply's beside task runs among the cells' applies.
// Invariants: those of its parts, all checked by Validate (detail/grid_validate.h), and
//  1. The tracker's overlap set equals the overlapping pairs of the live boxes.
#pragma once

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/flat_map.h"
#include "bp/detail/grid_sizing.h"
#include "bp/detail/prefetch.h"
#include "bp/detail/worker_pool.h"

namespace bp::detail {

template <class Cell>
class GridCore : private GridSizing<Cell> {
  using Base = GridSizing<Cell>;

 public:
  static constexpr int kDim = Cell::kDim;
  using Coord = typename Cell::Coord;
  using BoxType = Box<kDim, Coord>;
  static constexpr const char* kName = Cell::kGridName;
  static constexpr size_t kMaxHandles = size_t{1} << 28;
  using Options = GridOptions<typename Cell::Options>;

  explicit GridCore(const Options& options = Options()) : Base(options) {
    options_.max_cells_per_object = std::max<uint32_t>(options_.max_cells_per_object, 1);
    if (!(options_.objects_per_cell >= 1)) options_.objects_per_cell = 1;
    if (options_.cell_size > 0 && std::isfinite(options_.cell_size))
      SetCellSize(options_.cell_size);
    options_.threads = std::max(options_.threads, 1u);
    if (options_.threads > 1) {
      pool_ = std::make_unique<WorkerPool>(options_.threads);
      // One shard of the pair sets per thread (rounded up to a power of two): see FoldCells.
      tracker_.SetShards(static_cast<unsigned>(std::bit_width(options_.threads - 1)));
    }
    extra_.resize(tracker_.shards());
  }

  void Apply(std::span<const uint32_t> erases, std::span<const HandleBox<kDim, Coord>> updates,
             std::span<const HandleBox<kDim, Coord>> inserts) {
    swaps_ = tests_ = cells_queried_ = pool_routed_ = worker_cells_ = 0;
    global_ = rebuilt_ = false;
    PlaceFirst(inserts);
    defer_locals_ = true;  // until a large object changes (GridLargeSet::InsertLarge, MoveLarge)
    phase_ = Stopwatch();
    route_ms_ = cells_ms_ = fold_ms_ = 0;
    if (!RouteOnPool(erases, updates, inserts)) {
      EraseObjects(erases);
      RouteUpdates(updates);
      InsertObjects(inserts);
    }
    RescanChanged();
    route_ms_ += phase_.Lap();
    QueryCells();
    live_ = live_ + inserts.size() - erases.size();
    MaybeResize();
  }

  /// Apply that runs beside() once on the pool, as one more task beside the serial part of a
  /// parallel routing (RouteOnPool) or else among the cells' applies, when the grid has a pool
  /// (then returns true), else not at all (false: the caller runs it).
  /// beside must touch nothing of the grid's; the front end commits its erased keys with it.
  static constexpr bool kAppliesBeside = true;
  bool Apply(std::span<const uint32_t> erases, std::span<const HandleBox<kDim, Coord>> updates,
             std::span<const HandleBox<kDim, Coord>> inserts, const std::function<void()>& beside) {
    beside_ = &beside;
    beside_ran_ = false;
    struct Clear {  // never left dangling, even if Apply throws (std::bad_alloc)
      const std::function<void()>** beside;
      ~Clear() { *beside = nullptr; }
    } clear{&beside_};
    Apply(erases, updates, inserts);
    return beside_ran_;
  }

  /// Calls f(h) once for every live object whose box overlaps box (Broadphase's spot query):
  /// the objects of the cells the box covers, each in the first cell its range shares with the
  /// box's, the large objects, and those that pair with nothing (a scan of the records, when
  /// there are any). Touches nothing.
  template <class F>
  void ForEachOverlapping(const BoxType& box, F&& f) const {
    if (!cells_.empty()) {
      CellCoord lo, hi;
      RangeOf(box, &lo, &hi);
      ForEachExistingCell(lo, hi, [&](uint32_t idx) {
        const GridCell& cell = *cells_[idx];
        for (uint32_t g : cell.global) {
          if (g == kNone) continue;
          const Object& o = objects_[g];
          if (!Overlaps(o.box, box)) continue;
          bool first = true;
          for (size_t a = 0; a < kAxes; ++a)
            first = first && cell.coord[a] == std::max(lo[a], o.lo[a]);
          if (first) f(g);
        }
      });
    }
    for (const Large& l : large_) {
      if (l.handle != kNone && Overlaps(objects_[l.handle].box, box)) f(l.handle);
    }
    if (unpaired_ == 0) return;
    for (uint32_t h = 0; h < objects_.size(); ++h) {
      const Object& o = objects_[h];
      if (o.state == State::kLive && o.large == kUnpaired && Overlaps(o.box, box)) f(h);
    }
  }

  PairTracker& tracker() { return tracker_; }
  const PairTracker& tracker() const { return tracker_; }
  size_t live() const { return live_; }
  using Base::LookupPoolFor;
  using Base::PoolFor;

  void FillStats(Stats* out) const {
    out->swaps = swaps_;
    out->overlap_tests = tests_;
    out->global_sort = global_;
    out->rebuilt = rebuilt_;
    out->threads = pool_ != nullptr ? pool_->threads() : 1;
    GridStats& grid = out->grid.emplace();
    grid.cells = cell_of_.size();
    grid.cells_queried = cells_queried_;
    grid.large_objects = large_count_;
    grid.cell_size = cell_size_;
    grid.worker_cells = worker_cells_;
    grid.pool_routed = pool_routed_;
    grid.route_ms = route_ms_;
    grid.cells_ms = cells_ms_;
    grid.fold_ms = fold_ms_;
    for (const auto& c : cells_) {
      if (!c->in_use) continue;
      Stats s;
      c->core.FillStats(&s);
      if (s.segmented_sap) {
        if (!out->segmented_sap) out->segmented_sap.emplace();
        out->segmented_sap->chunks += s.segmented_sap->chunks;
      }
      if constexpr (requires { c->core.slots(); }) grid.cell_slots += c->core.slots();
    }
  }

  Status Validate() const;

  const Options& options() const { return options_; }
  /// White-box tests corrupt internals through this peer to prove Validate() notices.
  friend struct GridTestPeer;

 private:
  template <class>
  friend class GridCellTable;
  template <class>
  friend class GridWitness;
  template <class>
  friend class GridLargeSet;
  template <class>
  friend class GridRouting;
  template <class>
  friend class GridParallelRouting;
  template <class>
  friend class GridSizing;

  // What the composer uses of its parts (and Validate, with it).
  using Base::beside_;
  using Base::beside_ran_;
  using Base::BesideRan;
  using Base::bin_begin_;
  using Base::BinRange;
  using Base::bins_stale_;
  using Base::blocks_;
  using Base::cell_of_;
  using Base::cell_size_;
  using Base::cell_work_;
  using Base::CellCount;
  using Base::CellPairs;
  using Base::cells_;
  using Base::cells_ms_;
  using Base::cells_queried_;
  using Base::changed_large_;
  using Base::ClaimLocal;
  using Base::defer_locals_;
  using Base::EraseObject;
  using Base::EraseObjects;
  using Base::extra_;
  using Base::fold_ms_;
  using Base::FoldWitnessed;
  using Base::ForEachBin;
  using Base::ForEachExistingCell;
  using Base::FreeCell;
  using Base::global_;
  using Base::grouped_;
  using Base::grouped_erases_;
  using Base::grouped_insert_refs_;
  using Base::grouped_inserts_;
  using Base::grouped_shard_;
  using Base::GroupUpdates;
  using Base::InsertObjects;
  using Base::kAxes;
  using Base::kBlockSlots;
  using Base::kMasks;
  using Base::kNone;
  using Base::kUnpaired;
  using Base::large_;
  using Base::large_change_count_;
  using Base::large_count_;
  using Base::live_;
  using Base::MaybeResize;
  using Base::objects_;
  using Base::options_;
  using Base::PairsWithNothing;
  using Base::phase_;
  using Base::PlaceFirst;
  using Base::pool_;
  using Base::pool_routed_;
  using Base::Prefetch;
  using Base::RangeOf;
  using Base::rebuilt_;
  using Base::refs_;
  using Base::RescanChanged;
  using Base::route_ms_;
  using Base::routed_;
  using Base::routed_erases_;
  using Base::routed_inserts_;
  using Base::RouteOnPool;
  using Base::RouteUpdates;
  using Base::serial_witnessed_;
  using Base::SetCellSize;
  using Base::shard_work_;
  using Base::shards_;
  using Base::swaps_;
  using Base::tests_;
  using Base::touched_;
  using Base::tracker_;
  using Base::unpaired_;
  using Base::witnessed_;
  using Base::worker_cells_;
  using typename Base::CellCoord;
  using typename Base::CellRef;
  using typename Base::CellWork;
  using typename Base::GridCell;
  using typename Base::Large;
  using typename Base::Object;
  using typename Base::Shard;
  using typename Base::ShardWork;
  using typename Base::Space;
  using typename Base::State;
  using typename Base::Witnessed;

  // Touched cells a pool thread claims at a time (guided, see GuidedRuns): from kMaxCellRun,
  // while many are left, down to kCellRun at the end: each run's first cells find nothing
  // prefetched, so long runs save cold starts, and short ones at the end balance the threads.
  static constexpr size_t kCellRun = 32, kMaxCellRun = 512;
  // How far ahead of the cell being applied its successors' records and arrays are prefetched.
  static constexpr size_t kRecordAhead = 4, kArraysAhead = 2;

  // Validate's parts (detail/grid_validate.h), one per part of the grid, in the order Validate
  // runs them: live lists the live handles; count gathers each pair's witnesses.
  static Status Invalid(const std::string& what) {
    return Status(StatusCode::kInternal, std::string(kName) + ": " + what);
  }
  Status ValidateRecords(std::vector<uint32_t>* live) const;
  Status ValidateNoWorkLeft() const;
  Status ValidateCellTable(FlatMap<uint64_t, uint32_t>* count) const;
  Status ValidateLargeSet(const std::vector<uint32_t>& live,
                          FlatMap<uint64_t, uint32_t>* count) const;
  Status ValidateWitnessCounts(const FlatMap<uint64_t, uint32_t>& count) const;

  // A new cell (GridCellTable::CellAt) gets a work entry if its index is new.
  void CellCreated(uint32_t /*idx*/, bool fresh) {
    if (fresh) cell_work_.emplace_back();
  }

  // Applies every touched cell's buffered operations (in parallel: cells share nothing), then
  // folds each cell's overlap changes into the witness counts (FoldCells: in an order that may
  // depend on the thread count, which the events do not). A cell's changes leave it already
  // translated to global handles, into its thread's buffer, so the fold reads them sequentially
  // instead of touching each cell again.
  void QueryCells() {
    cells_queried_ = touched_.size();
    if (touched_.size() * 4 > cells_.size()) {
      // Most cells are touched: list them in cell order by one walk of the cell array.
      touched_.clear();
      for (uint32_t idx = 0; idx < cells_.size(); ++idx) {
        if (cell_work_[idx].touched) touched_.push_back(idx);
      }
    }
    GroupUpdates();
    thread_out_.resize(pool_ != nullptr ? pool_->threads() : 1);
    for (ThreadOut& to : thread_out_) {
      to.swaps = to.tests = to.cells = 0;
      to.global_sort = false;
      to.emptied.clear();
    }
    if (pool_ != nullptr) {
      witnessed_.resize(size_t{pool_->threads()} * tracker_.shards());
      for (auto& w : witnessed_) w.clear();
      // Index 0 is Apply's beside task when there is one and no parallel routing ran it (see
      // Apply), the cells' follow: the pool's dynamic runs balance it with them.
      const size_t extra = beside_ != nullptr ? 1 : 0;
      GuidedRuns(touched_.size(), pool_->threads(), 1, kCellRun, kMaxCellRun, &cell_runs_);
      pool_->ParallelFor(cell_runs_.size() - 1 + extra, 1,
                         [this, extra](size_t begin, size_t end, unsigned t) {
                           for (size_t task = begin; task < end; ++task) {
                             if (task < extra) {
                               (*beside_)();
                               continue;
                             }
                             const size_t from = cell_runs_[task - extra];
                             const size_t to = cell_runs_[task - extra + 1];
                             for (size_t i = from; i < to; ++i) {
                               PrefetchAhead(i, to);
                               ApplyCell(i, t);
                             }
                             thread_out_[t].cells += to - from;
                           }
                         });
      worker_cells_ = 0;
      for (size_t t = 1; t < thread_out_.size(); ++t) worker_cells_ += thread_out_[t].cells;
      if (extra != 0) BesideRan();  // once: a rebuild (Regrid) queries the cells again
    } else {
      // One thread: the same, on this thread.
      witnessed_.resize(1);
      witnessed_[0].clear();
      for (size_t i = 0; i < touched_.size(); ++i) {
        PrefetchAhead(i, touched_.size());
        ApplyCell(i, 0);
      }
    }
    cells_ms_ += phase_.Lap();
    FoldCells();
    fold_ms_ += phase_.Lap();
    touched_.clear();
  }

  // Starts loading what applying touched_[k] reads, for the cells after touched_[i] (of a run
  // ending at end), in two stages, as each stage reads what the one before loads: every line of
  // the record of the cell 4 ahead, and the arrays of the cell 2 ahead (its local handles' table,
  // its free list's end and, for a cell type that says where its hot arrays are, those). Without
  // the stages, a cell's record and arrays were dependent misses, one after the other.
  void PrefetchAhead(size_t i, size_t end) {
    if (i + kRecordAhead < end) {
      const uint32_t idx = touched_[i + kRecordAhead];
      const char* p = reinterpret_cast<const char*>(cells_[idx].get());
      for (size_t off = 0; off < sizeof(GridCell); off += 64) PrefetchForWrite(p + off);
      PrefetchForWrite(&cell_work_[idx]);
      if (idx < shard_work_.size()) PrefetchForWrite(&shard_work_[idx]);
    }
    if (i + kArraysAhead < end) {
      const GridCell& cell = *cells_[touched_[i + kArraysAhead]];
      if constexpr (requires { cell.core.Prefetch(); }) cell.core.Prefetch();
      if (!cell.global.empty()) Prefetch(cell.global.data());
      if (!cell.free_local.empty()) Prefetch(&cell.free_local.back());
    }
  }

  // Applies touched_[i] on pool thread `thread`: runs the cell's core, appends its changes (as
  // global handle pairs) to the thread's buffer, and frees the local handles it erased (after
  // the core has used them). Touches nothing but the cell, its work entries (cell_work_,
  // shard_work_), thread_out_[thread] and the references to the cell of its objects (ClaimLocal,
  // CompactCell).
  void ApplyCell(size_t i, unsigned thread) {
    const uint32_t idx = touched_[i];
    GridCell& cell = *cells_[idx];
    const CellWork& work = cell_work_[idx];
    const std::span<const uint32_t> erases(grouped_erases_.data() + work.erase_begin, work.erases);
    const std::span inserts(grouped_inserts_.data() + work.insert_begin, work.inserts);
    // Deferred inserts get their local handles now (see EnterCell), in routing order; each
    // writes its object's reference to this cell, which no other cell's thread writes.
    const uint32_t* ref_at = grouped_insert_refs_.data() + work.insert_begin;
    for (size_t k = 0; k < inserts.size(); ++k) {
      if (ref_at[k] != kNone) inserts[k].handle = ClaimLocal(cell, inserts[k].handle, ref_at[k]);
    }
    cell.members = cell.members + work.inserts - work.erases;
    // The cell's updates: routed serially (grouped_), or by a parallel routing's shards
    // (grouped_shard_), which leaves no update to the serial pass (RouteOnPool).
    std::span<const HandleBox<kDim, Coord>> updates(grouped_.data() + work.begin, work.updates);
    if (idx < shard_work_.size() && shard_work_[idx].count != 0) {
      BP_ASSERT(updates.empty());
      const ShardWork sw = std::exchange(shard_work_[idx], ShardWork{});
      updates = std::span<const HandleBox<kDim, Coord>>(grouped_shard_.data() + sw.begin, sw.count);
    }
    cell.core.Apply(erases, updates, inserts);
    Stats s;
    cell.core.FillStats(&s);
    // Each change goes to this thread's buffer of its pair's shard (see FoldCells).
    const size_t shards = tracker_.shards();
    std::vector<Witnessed>* out = witnessed_.data() + size_t{thread} * shards;
    ThreadOut& to = thread_out_[thread];
    to.swaps += s.swaps;
    to.tests += s.overlap_tests;
    to.global_sort = to.global_sort || s.global_sort;
    const auto cell_i = static_cast<uint32_t>(i);
    CellPairs(cell.core).DrainChanges([&](uint32_t a, uint32_t b, bool now) {
      const uint32_t ga = cell.global[a], gb = cell.global[b];
      const size_t shard = shards == 1 ? 0 : tracker_.ShardOf(HandlePair(ga, gb));
      out[shard].push_back(Witnessed{ga, gb, now});
    });
    for (uint32_t local : erases) {
      cell.global[local] = kNone;
      cell.free_local.push_back(local);
    }
    cell_work_[idx] = CellWork{};
    if (cell.members == 0) {
      to.emptied.push_back(cell_i);
      BP_ASSERT(cell.core.live() == 0);
      cell.global.clear();
      cell.free_local.clear();
    } else {
      CompactCell(idx, cell);
    }
  }

  // Lets a cell type that can give back free slots (dense cells) do so: each object it moves
  // gets its new local handle in the cell's table and in its own reference to the cell. Runs on
  // the thread applying the cell: it writes only this cell and the CellRef entries that name it
  // (one per object, so no other cell's thread writes them).
  void CompactCell(uint32_t idx, GridCell& cell) {
    if constexpr (requires { cell.core.slots(); }) {
      const uint32_t before = cell.core.slots();
      cell.core.Compact([&](uint32_t from, uint32_t to) {
        const uint32_t h = cell.global[from];
        cell.global[to] = h;
        cell.global[from] = kNone;
        const Object& o = objects_[h];
        CellRef* ref = &refs_[o.refs];
        while (ref->cell != idx) ++ref;
        BP_ASSERT(ref->local == from);
        ref->local = to;
      });
      const uint32_t slots = cell.core.slots();
      if (slots == before) return;  // nothing given back, nothing moved
      if (cell.global.size() > slots) cell.global.resize(slots);
      cell.free_local.clear();
      for (uint32_t l = static_cast<uint32_t>(cell.global.size()); l-- > 0;) {
        if (cell.global[l] == kNone) cell.free_local.push_back(l);
      }
    }
  }
  // Folds every applied cell's changes into the witness counts (GridWitness::FoldWitnessed),
  // then adds up the threads' counters and recycles the cells that emptied, in the order of
  // touched_.
  void FoldCells() {
    FoldWitnessed();
    // The counters, and the cells that emptied, recycled in the order of touched_.
    emptied_.clear();
    for (const ThreadOut& to : thread_out_) {
      swaps_ += to.swaps;
      tests_ += to.tests;
      global_ = global_ || to.global_sort;
      emptied_.insert(emptied_.end(), to.emptied.begin(), to.emptied.end());
    }
    std::sort(emptied_.begin(), emptied_.end());
    for (uint32_t i : emptied_) FreeCell(touched_[i]);
  }

  // What applying a cell leaves for the fold: its changes, as global handle pairs (Witnessed, in
  // witnessed_), and in its thread's ThreadOut its counters (summed) and, if it emptied, its
  // position in touched_.
  // Line-aligned: the threads write theirs at once. (Per thread rather than a record per cell
  // added up serially after, which would be a serial loop over every touched cell.)
  struct alignas(64) ThreadOut {
    size_t swaps = 0, tests = 0, cells = 0;
    bool global_sort = false;
    std::vector<uint32_t> emptied;
  };
  std::vector<ThreadOut> thread_out_;  // per pool thread (one without a pool)
  std::vector<uint32_t> cell_runs_;    // the pool's runs of touched_ (GuidedRuns)
  std::vector<uint32_t> emptied_;      // FoldCells' scratch: the emptied cells' positions
};

}  // namespace bp::detail

#include "bp/detail/grid_validate.h"  // NOLINT(build/include_order): defines Validate
