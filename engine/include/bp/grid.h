// bp::Grid: the superstructure of Tracy, Buss and Woods (IEEE VR 2009, sections 3.1 and 3.3): a
// uniform grid whose cells are sweep-and-prune instances (either cell core: SegmentedSap or
// BatchSap), with a witness-count table that turns per-cell overlap changes into exactly one
// collide and one uncollide per pair.
//
// Cells are hashed by their integer coordinates (the world is unbounded), created when an object
// first enters them and recycled when their last object leaves. A cell coordinate is
// floor((x - origin) / cell_size) (up to rounding: see CellOf) clamped to [-2^(b-1), 2^(b-1))
// with b = 63 / K bits, so coordinates far from the origin land in the edge cells instead of
// overflowing. The origin is the middle of the first objects' centres (a multiple of the cell
// size), so a world far from zero (1e12 in double) gets cells as small as one at zero. Any
// monotone map from coordinates to cells keeps the grid exact: two boxes that overlap share a
// cell on every axis.
//
// An object covering at most `max_cells_per_object` cells lives in each of them (a cell knows it
// by a local handle); a move within the same cells is an update in each, a move across cells is
// an insert into the new cells, an update in the kept ones and an erase from the old ones.
// Bigger objects are not copied into cells: they form the large set, registered in the lists of
// the existing cells their range covers. A changed small object is tested against the large
// objects listed in its old and new cells; a changed large object is rescanned against the
// objects of the cells it covers and against the other large objects. Each large object keeps
// its witnessed partners (for large pairs, both sides hold each other and count once).
//
// Every cell reports the changes of its own overlap set; the grid counts, per pair, the cells
// (and the large set) that witness it. A pair is in the grid's overlap set iff its count is at
// least one; the count's transitions between 0 and 1 are the events (the tracker cancels a pair
// that leaves one cell and enters another in the same query). Work per query is O(u + e) plus
// the cells' own work: only cells with buffered operations are applied.
//
// With `threads` > 1 the touched cells are applied by a worker pool (cells share nothing); their
// changes are then folded into the witness counts by shard of the pair sets, one shard per
// thread. The events do not depend on the thread count: neither the counts nor the sets depend
// on the order of the fold (see FoldCells).
//
// The cell size is either given or chosen from the objects (about `objects_per_cell` objects per
// cell over the bounds of the box centres); it is chosen again, and every cell rebuilt, when the
// live count has changed fourfold and the best size differs by more than a factor of two.
//
// Thread safety: none for callers (see bp/broadphase.h); the pool's threads apply one cell each,
// route runs of updates (the first after the erases), or scatter parts of the cells (and run
// Apply's beside task) beside the serial routing (RouteOnPool); without a parallel routing,
// Apply's beside task runs among the cells' applies.
// Invariants (checked by Validate, in detail/grid_validate.h):
//  1. A live small object's refs list, in row-major order over its cell range, one (cell, local)
//     per cell; cells_[cell] has that coordinate and global[local] is the object.
//  2. A cell in use is in the hash under its coordinate, holds members > 0 live objects (its
//     core's live count), and lists exactly the large objects whose range covers it.
//  3. A large object's partners are exactly the live objects overlapping it; large partners
//     hold each other.
//  4. For every pair, the cells whose core holds it plus the large set (once) number
//     1 + extra_[pair] when the tracker holds it (extra_ absent means 1), and 0 otherwise;
//     extra_ has one map per shard of the tracker, and a pair's count lies in its shard's.
//  5. The tracker's overlap set equals the overlapping pairs of the live boxes.
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "bp/batch_sap.h"
#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/dense_cell.h"
#include "bp/detail/assert.h"
#include "bp/detail/cell_space.h"
#include "bp/detail/flat_map.h"
#include "bp/detail/flat_set.h"
#include "bp/detail/huge_alloc.h"
#include "bp/detail/keyed_engine.h"
#include "bp/detail/pair_tracker.h"
#include "bp/detail/prefetch.h"
#include "bp/detail/stopwatch.h"
#include "bp/detail/sweep.h"
#include "bp/detail/worker_pool.h"
#include "bp/segmented_sap.h"

namespace bp {

/// The objects per cell the automatic size aims at, by cell type: about 300 for SAP cells (the
/// paper's finding on uniform scenes), 32 for dense cells (measured on S1-200k, S3 and S4:
/// docs/TUNING.md).
template <class CellOptions>
inline constexpr double kDefaultObjectsPerCell = 300;
template <>
inline constexpr double kDefaultObjectsPerCell<DenseCellOptions> = 32;

/// Tuning of the grid; CellOptions are the options of its cell engine.
template <class CellOptions>
struct GridOptions {
  /// Edge of a cell on every axis; 0 chooses it from the objects and adapts it as they grow.
  double cell_size = 0;
  /// The automatic cell size aims at this many objects per cell (kDefaultObjectsPerCell).
  double objects_per_cell = kDefaultObjectsPerCell<CellOptions>;
  /// An object whose box would cover more cells than this is kept in the large set instead.
  uint32_t max_cells_per_object = 16;
  /// Threads that apply the touched cells of a query (the caller's included). Events do not
  /// depend on it: cells are independent, and their changes fold to the same counts and sets
  /// in any order (see GridCore::FoldCells).
  unsigned threads = 1;
  /// With threads > 1, a query with at least this many updates routes them in parallel, and an
  /// UpdateMany or EraseMany of at least this many items looks their keys up in parallel
  /// (below, waking the workers costs more than it saves); 0 never does either.
  size_t parallel_routing_from = 4096;
  /// With threads > 1, a large UpdateMany or EraseMany (as many items as above) looks its keys
  /// up on every thread first (faster calls). The daemon turns it off: its update→event tail
  /// is lower without (docs/TUNING.md).
  bool parallel_lookups = true;
  /// Options of every cell.
  CellOptions cell{};
};

namespace detail {

template <class Cell>
class GridCore {
 public:
  static constexpr int kDim = Cell::kDim;
  static constexpr size_t kAxes = static_cast<size_t>(kDim);
  using Coord = typename Cell::Coord;
  using BoxType = Box<kDim, Coord>;
  static constexpr const char* kName = Cell::kGridName;
  static constexpr size_t kMaxHandles = size_t{1} << 28;
  using Options = GridOptions<typename Cell::Options>;

  explicit GridCore(const Options& options = Options()) : options_(options) {
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
    if (!placed_ && !inserts.empty()) {
      // First objects: choose the origin, and the automatic size, from them.
      Sizing sizing = IdealCellSize(inserts.size(), [&](auto&& f) {
        for (const auto& hb : inserts) f(hb.box);
      });
      SetCellSize(inv_size_ == 0 ? sizing.size : cell_size_, sizing.middle);
      sized_for_ = inserts.size();
      placed_ = true;
    }
    defer_locals_ = large_count_ == 0;
    phase_ = Stopwatch();
    route_ms_ = cells_ms_ = fold_ms_ = 0;
    if (!RouteOnPool(erases, updates, inserts)) {
      EraseObjects(erases);
      RouteUpdates(updates);
      InsertObjects(inserts);
    }
    for (uint32_t l : changed_large_) {
      large_[l].changed = false;
      if (large_[l].handle != kNone) Rescan(l);
    }
    changed_large_.clear();
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

  PairTracker& tracker() { return tracker_; }
  const PairTracker& tracker() const { return tracker_; }
  size_t live() const { return live_; }
  /// The worker pool, when the grid has one and a loop over n light items (look-ups, routing)
  /// is worth waking its workers for (n >= options().parallel_routing_from); else nullptr. The
  /// front end resolves a large batch's keys through it (see KeyedEngine::ForEachResolved).
  WorkerPool* PoolFor(size_t n) const {
    if (pool_ == nullptr || options_.parallel_routing_from == 0) return nullptr;
    return n >= std::max<size_t>(options_.parallel_routing_from, 2) ? pool_.get() : nullptr;
  }
  /// PoolFor for the front end's look-ups of n keys: nullptr unless options().parallel_lookups.
  WorkerPool* LookupPoolFor(size_t n) const {
    return options_.parallel_lookups ? PoolFor(n) : nullptr;
  }

  void FillStats(Stats* out) const {
    out->swaps = swaps_;
    out->overlap_tests = tests_;
    out->global_sort = global_;
    out->rebuilt = rebuilt_;
    out->cells = cell_of_.size();
    out->cells_queried = cells_queried_;
    out->large_objects = large_count_;
    out->cell_size = cell_size_;
    out->threads = pool_ != nullptr ? pool_->threads() : 1;
    out->worker_cells = worker_cells_;
    out->pool_routed = pool_routed_;
    out->route_ms = route_ms_;
    out->cells_ms = cells_ms_;
    out->fold_ms = fold_ms_;
    out->chunks = 0;
    out->cell_slots = 0;
    for (const auto& c : cells_) {
      if (!c->in_use) continue;
      Stats s;
      c->core.FillStats(&s);
      out->chunks += s.chunks;
      if constexpr (requires { c->core.slots(); }) out->cell_slots += c->core.slots();
    }
  }

  Status Validate() const;

  const Options& options() const { return options_; }
  /// White-box tests corrupt internals through this peer to prove Validate() notices.
  friend struct GridTestPeer;

 private:
  static constexpr uint32_t kNone = ~uint32_t{0};
  // Touched cells a pool thread claims at a time (guided, see GuidedRuns): from kMaxCellRun,
  // while many are left, down to kCellRun at the end: each run's first cells find nothing
  // prefetched, so long runs save cold starts, and short ones at the end balance the threads.
  static constexpr size_t kCellRun = 32, kMaxCellRun = 512;
  // A parallel routing's parts of the cells per thread (see RouteOnPool): more than one, so that
  // the thread done first with the serial pass or a part can take another part.
  static constexpr size_t kPartsPerThread = 2;
  // What an erase costs, in routed updates (RouteOnPool's first run), as measured on S1-1M.
  static constexpr size_t kEraseWeight = 2;
  // How far ahead of the cell being applied its successors' records and arrays are prefetched.
  static constexpr size_t kRecordAhead = 4, kArraysAhead = 2;
  // Per-cell tables larger than about half a typical L2 are far from the cache: beyond
  // kWorkInCache work entries (CellWork), routing prefetches them, and beyond kWorkInCacheBytes
  // grouping prefetches any per-cell table (see WorkFarFromCache; in bytes, so that a table of
  // small entries, as the shards' 8-byte ones, counts by its size).
  static constexpr size_t kWorkInCache = 8192, kWorkInCacheBytes = size_t{224} << 10;
  using Space = CellSpace<kDim>;
  using CellCoord = typename Space::Coord;
  static constexpr int64_t kLimit = Space::kLimit;

  struct CellRef {
    uint32_t cell;
    uint32_t local;
  };
  // This query's updates of cell slots, as routed, then grouped by cell (GroupUpdates).
  struct Routed {
    uint32_t cell;
    HandleBox<kDim, Coord> update;  // the cell's local handle and the new box
  };
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
  enum class State : uint8_t { kDead, kLive };
  // One record per global handle, box included; line-aligned when it fits a line (3-D float:
  // 61 bytes), so routing an update reads one line.
  struct ObjectFields {
    BoxType box;
    CellCoord lo{}, hi{};    // cell range
    uint32_t refs = 0;       // first CellRef in refs_ (small objects)
    uint32_t nrefs = 0;      // cells covered (0 for large objects)
    uint32_t large = kNone;  // index in large_ (large objects)
    State state = State::kDead;
  };
  struct alignas(sizeof(ObjectFields) <= 64 ? 64 : alignof(ObjectFields)) Object : ObjectFields {};
  struct GridCell {
    explicit GridCell(const typename Cell::Options& o) : core(o) {}
    Cell core;
    CellCoord coord{};
    uint64_t key = 0;
    std::vector<uint32_t> global;      // local handle -> global handle (kNone: free)
    std::vector<uint32_t> free_local;  // reusable local handles
    std::vector<uint32_t> large;       // large objects whose range covers this cell
    uint32_t members = 0;              // live objects as of the cell's last apply
    bool in_use = false;
  };
  struct Large {
    uint32_t handle = kNone;
    bool changed = false;
    FlatSet<uint32_t> partners;  // live objects overlapping this one (global handles)
  };

  // The cell's pairs as the grid sees them: a SAP core's tracker, or a dense cell itself.
  template <class C>
  static auto& CellPairs(C& core) {
    if constexpr (requires { core.tracker(); }) {
      return core.tracker();
    } else {
      return core;
    }
  }

  static void Prefetch(const void* p) { __builtin_prefetch(p); }

  // After a pool loop ran Apply's beside task: it is not run again in this query.
  void BesideRan() {
    beside_ran_ = true;
    beside_ = nullptr;
  }

  // --- cell coordinates ----------------------------------------------------------------------

  // The size, and an origin near middle on a multiple of the size (so that cell boundaries stay
  // where a user who set the size expects them, wherever they are representable).
  void SetCellSize(double size, const std::array<double, kAxes>& middle = {}) {
    cell_size_ = size;
    inv_size_ = 1.0 / size;
    for (size_t a = 0; a < kAxes; ++a) {
      double o = std::floor(middle[a] * inv_size_) * size;
      origin_[a] = std::isfinite(o) ? o : 0.0;
    }
  }
  // Monotone in x: a rounded subtraction of a constant, a product by a positive constant, a
  // clamp to [-kLimit, kLimit - 1] (NaN to -kLimit), then floor. With two axes or more (kLimit
  // at most 2^30) floor is a rounded addition of kLimit (the sum is then at least 0, where
  // truncation is floor) and a truncation: that rounds a quotient just below an integer up to
  // it (within 2^-32 at 3-D), which keeps the map monotone. No std::floor there: baseline x86-64
  // has no floor instruction, and GCC's emulation (sign, NaN and range fix-ups) in an update's
  // six calls dominated UpdateObject. One axis (kLimit 2^62) keeps
  // std::floor: the sum would drop the quotient's low bits and overflow int64 at the top.
  int64_t CellOf(Coord x, size_t axis) const {
    constexpr double kLow = -static_cast<double>(kLimit), kHigh = static_cast<double>(kLimit - 1);
    double q = (static_cast<double>(x) - origin_[axis]) * inv_size_;
    q = q > kLow ? q : kLow;  // NaN takes kLow
    if constexpr (kLimit <= (int64_t{1} << 31)) {
      q = q < kHigh ? q : kHigh;
      return static_cast<int64_t>(q + static_cast<double>(kLimit)) - kLimit;
    } else {
      if (q >= kHigh) return kLimit - 1;
      return static_cast<int64_t>(std::floor(q));
    }
  }
  void RangeOf(const BoxType& box, CellCoord* out_lo, CellCoord* out_hi) const {
    for (size_t a = 0; a < kAxes; ++a) {
      (*out_lo)[a] = static_cast<typename Space::Scalar>(CellOf(box.lo[a], a));
      (*out_hi)[a] = static_cast<typename Space::Scalar>(CellOf(box.hi[a], a));
    }
  }
  // Cells in a range, saturated just above the large-object threshold.
  uint64_t CellCount(const CellCoord& lo, const CellCoord& hi) const {
    const uint64_t cap = uint64_t{options_.max_cells_per_object} + 1;
    uint64_t n = 1;
    for (size_t a = 0; a < kAxes; ++a) {
      uint64_t w = static_cast<uint64_t>(int64_t{hi[a]} - lo[a]) + 1;
      if (w >= cap || n * w >= cap) return cap;
      n *= w;
    }
    return n;
  }
  // Calls f(cell index) for every existing cell in a range of any size: by coordinates when the
  // range has fewer cells than the grid, else by walking the cells in use.
  template <class F>
  void ForEachExistingCell(const CellCoord& lo, const CellCoord& hi, F&& f) {
    uint64_t n = 1;
    bool small = true;
    for (size_t a = 0; a < kAxes && small; ++a) {
      uint64_t w = static_cast<uint64_t>(int64_t{hi[a]} - lo[a]) + 1;
      small = w <= cell_of_.size() && n * w <= cell_of_.size();
      n *= w;
    }
    if (small) {
      Space::ForEachCoord(lo, hi, [&](const CellCoord& c) {
        if (const uint32_t* idx = cell_of_.Find(Space::Pack(c))) f(*idx);
      });
      return;
    }
    for (uint32_t idx = 0; idx < cells_.size(); ++idx) {
      if (cells_[idx]->in_use && Space::Contains(lo, hi, cells_[idx]->coord)) f(idx);
    }
  }

  // --- automatic cell size --------------------------------------------------------------------

  struct Sizing {
    double size;                       // the ideal cell size
    std::array<double, kAxes> middle;  // the middle of the box centres' bounds
  };

  // About objects_per_cell objects per cell over the bounds of the box centres; never below the
  // median box extent, so typical objects cover a few cells at most.
  template <class ForEachBox>
  Sizing IdealCellSize(size_t n, ForEachBox&& each) {
    std::array<double, kAxes> lo, hi;
    lo.fill(std::numeric_limits<double>::infinity());
    hi.fill(-std::numeric_limits<double>::infinity());
    extents_.clear();
    each([&](const BoxType& b) {
      double ext = 0;
      for (size_t a = 0; a < kAxes; ++a) {
        double l = static_cast<double>(b.lo[a]), h = static_cast<double>(b.hi[a]);
        double c = l * 0.5 + h * 0.5;
        lo[a] = std::min(lo[a], c);
        hi[a] = std::max(hi[a], c);
        ext = std::max(ext, h - l);
      }
      extents_.push_back(ext);
    });
    double median = 0;
    if (!extents_.empty()) {
      auto mid = extents_.begin() + static_cast<std::ptrdiff_t>(extents_.size() / 2);
      std::nth_element(extents_.begin(), mid, extents_.end());
      median = *mid;
    }
    // log-space so that huge spans do not overflow the volume.
    double log_volume = 0;
    for (size_t a = 0; a < kAxes; ++a) {
      double span = std::max(hi[a] - lo[a] + median, 1e-300);
      log_volume += std::log(span);
    }
    double size = std::exp((log_volume + std::log(options_.objects_per_cell) -
                            std::log(static_cast<double>(std::max<size_t>(n, 1)))) /
                           static_cast<double>(kDim));
    size = std::max(size, median);
    // Degenerate input (all points at one spot): no smaller than 2^-20 of the centres' distance
    // from their middle (the origin), rather than a denormal size that clamps every later box
    // into one edge cell.
    Sizing out{0, {}};
    double magnitude = 0;
    for (size_t a = 0; a < kAxes; ++a) {
      const double middle = lo[a] * 0.5 + hi[a] * 0.5;  // not finite without finite centres
      out.middle[a] = std::isfinite(middle) ? middle : 0.0;
      magnitude = std::max({magnitude, hi[a] - out.middle[a], out.middle[a] - lo[a]});
    }
    double floor = magnitude > 0 && std::isfinite(magnitude) ? magnitude * 0x1p-20 : 1.0;
    if (!(size >= floor) || !std::isfinite(size)) size = floor;
    out.size = size;
    return out;
  }

  // Sizes again when the live count has changed fourfold since the size was chosen; rebuilds
  // only if the ideal size differs by more than 2x.
  void MaybeResize() {
    if (options_.cell_size > 0) return;
    if (live_ < 64 || (live_ <= 4 * sized_for_ && 4 * live_ >= sized_for_)) return;
    sized_for_ = live_;
    Sizing ideal = IdealCellSize(live_, [&](auto&& f) {
      for (uint32_t h = 0; h < objects_.size(); ++h) {
        if (objects_[h].state == State::kLive) f(objects_[h].box);
      }
    });
    if (ideal.size > 0.5 * cell_size_ && ideal.size < 2 * cell_size_) return;
    Regrid(ideal);
  }

  // --- objects ---------------------------------------------------------------------------------

  void Reserve(uint32_t h) {
    if (h >= objects_.size()) {
      objects_.resize(h + 1);
      stamp_.resize(h + 1, 0);
      mark_.resize(h + 1, 0);
    }
  }

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
  // The cell-table key of the lowest cell box enters.
  uint64_t FirstCellKey(const BoxType& box) const {
    CellCoord lo;
    for (size_t a = 0; a < kAxes; ++a) {
      lo[a] = static_cast<typename Space::Scalar>(CellOf(box.lo[a], a));
    }
    return Space::Pack(lo);
  }

  void InsertObject(uint32_t h, const BoxType& box) {
    Reserve(h);
    Object& o = objects_[h];
    BP_ASSERT(o.state == State::kDead);
    o.state = State::kLive;
    objects_[h].box = box;
    CellCoord lo, hi;
    RangeOf(box, &lo, &hi);
    if (CellCount(lo, hi) > options_.max_cells_per_object) {
      InsertLarge(h, lo, hi);
      return;
    }
    EnterCells(h, lo, hi);
    if (large_count_ != 0) {
      BeginLargeCandidates();
      AddLargeCandidates(h);
      TestLargeCandidates(h, nullptr);
    }
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
      EraseLarge(h);
      return;
    }
    if (large_count_ != 0) {
      BeginLargeCandidates();
      AddLargeCandidates(h);
      TestLargeCandidates(h, &objects_[h].box);  // dead: every listed pair goes
    }
    LeaveCells(h);
  }

  // kept_routed: h stays small and migrates, and its updates in the cells it keeps were routed
  // (RouteRun).
  void UpdateObject(uint32_t h, const BoxType& box, bool kept_routed = false) {
    Object& o = objects_[h];
    BP_ASSERT(o.state == State::kLive);
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
      if (large_count_ != 0) {
        BeginLargeCandidates();
        AddLargeCandidates(h);
        TestLargeCandidates(h, nullptr);
      }
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
    const bool with_large = large_count_ != 0;
    if (with_large) {
      BeginLargeCandidates();
      AddLargeCandidates(h);
    }
    BP_ASSERT(!kept_routed || !same_range);
    if (same_range) {
      for (uint32_t i = 0; i < o.nrefs; ++i) RouteUpdate(refs_[o.refs + i], box);
    } else {
      Migrate(h, lo, hi, kept_routed);
      if (with_large) AddLargeCandidates(h);
    }
    if (with_large) TestLargeCandidates(h, &before);
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

  // Allocates global handle h's local handle in cell, for an insert whose local was deferred,
  // and writes it into the object's reference to the cell (refs_[ref_at]); returns it.
  uint32_t ClaimLocal(GridCell& cell, uint32_t h, uint32_t ref_at) {
    const uint32_t local = AllocLocal(cell, h);
    refs_[ref_at].local = local;
    return local;
  }

  void LeaveCells(uint32_t h) {
    Object& o = objects_[h];
    for (uint32_t i = 0; i < o.nrefs; ++i) RouteErase(refs_[o.refs + i]);
    FreeRefs(o.refs, o.nrefs);
    o.nrefs = 0;
  }

  // --- routing updates -------------------------------------------------------------------------

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

  // Updates come in handle order, not memory order: the loads of each object's records miss the
  // cache, so they are prefetched a few updates ahead, in the order they depend on each other
  // (object and box, then its cell references). An update that stays in its cells touches no
  // cell here: it is appended to routed_ (see RouteUpdate). With a pool, see RouteOnPool.
  void RouteUpdates(std::span<const HandleBox<kDim, Coord>> updates) {
    const size_t n = updates.size();
    routed_.reserve(n);
    for (size_t i = 0; i < n; ++i) {
      BP_GRID_PREFETCH_UPDATE(updates, i, n);
      if (i + 8 < n && cell_work_.size() > kWorkInCache) {
        // A third stage, when the work table outgrows the L2: the work entry of the object's
        // first cell, which routing counts in (where the table fits, these loads only cost).
        const Object& ahead = objects_[updates[i + 8].handle];
        if (ahead.nrefs != 0) Prefetch(&cell_work_[refs_[ahead.refs].cell]);
      }
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

#undef BP_GRID_PREFETCH_UPDATE

  // True iff small object o's cell range is the same for box (its update touches no cell,
  // handle or reference): one axis bound at a time, stopping at the first that differs.
  bool StaysInCells(const Object& o, const BoxType& box) const {
    bool same_range = o.large == kNone;
    for (size_t a = 0; a < kAxes && same_range; ++a) {
      same_range = CellOf(box.lo[a], a) == o.lo[a] && CellOf(box.hi[a], a) == o.hi[a];
    }
    return same_range;
  }

  // --- cells -----------------------------------------------------------------------------------

  // The cell at c, created (or recycled) if absent; a new cell lists the large objects over it.
  uint32_t CellAt(const CellCoord& c) {
    bool inserted = false;
    uint64_t key = Space::Pack(c);
    uint32_t& slot = cell_of_.FindOrInsert(key, kNone, &inserted);
    if (!inserted) return slot;
    uint32_t idx;
    if (!free_cells_.empty()) {
      idx = free_cells_.back();
      free_cells_.pop_back();
    } else {
      idx = static_cast<uint32_t>(cells_.size());
      cells_.push_back(std::make_unique<GridCell>(options_.cell));
      cell_work_.emplace_back();
    }
    slot = idx;  // FindOrInsert's reference is still valid: nothing was inserted since
    GridCell& cell = *cells_[idx];
    cell.coord = c;
    cell.key = key;
    cell.in_use = true;
    for (uint32_t l = 0; l < large_.size(); ++l) {
      uint32_t lh = large_[l].handle;
      if (lh != kNone && Space::Contains(objects_[lh].lo, objects_[lh].hi, c))
        cell.large.push_back(l);
    }
    return idx;
  }

  uint32_t AllocLocal(GridCell& cell, uint32_t h) {
    uint32_t local;
    if (!cell.free_local.empty()) {
      local = cell.free_local.back();
      cell.free_local.pop_back();
    } else {
      local = static_cast<uint32_t>(cell.global.size());
      cell.global.push_back(kNone);
    }
    cell.global[local] = h;
    if (tracker_.filtering()) CellPairs(cell.core).SetOptions(local, tracker_.options(h));
    return local;
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
      cell.large.clear();
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

  // Folds every applied cell's changes into the witness counts, then recycles the cells that
  // emptied, in the order of touched_. A cell's changes wait in the buffer of the thread that
  // applied it and of each pair's shard of the tracker (ApplyCell). With a pool and enough
  // changes, each shard is folded by one thread (FoldShard): a pair's witness count and sets
  // lie in its shard alone. The changes are folded in any order (each thread's buffer whole, one
  // after the other, which is cheaper than merging them in the order of touched_):
  // the events do not depend on it. A cell removes only a pair it held at the last query, which
  // the pair's count includes, so no order takes a count below zero; a pair whose count passes
  // through zero leaves the overlap set and comes back, which the tracker cancels; and the
  // counts and sets end the same. (The layout of the sets' tables may differ, and with it the
  // order of ForEachOverlap: it never promised one.) A rebuild's recount (see Regrid) folds
  // serially. A change's fold (three probes of hash tables) counts as kWitnessWeight routed
  // updates or key look-ups, PoolFor's unit: a few thousand changes a frame fold faster on two
  // threads than on one.
  static constexpr size_t kWitnessWeight = 4;
  void FoldCells() {
    size_t changes = 0;
    for (const auto& w : witnessed_) changes += w.size();
    const size_t shards = tracker_.shards();
    if (shards > 1 && !recount_ && PoolFor(kWitnessWeight * changes) != nullptr) {
      pool_->ParallelFor(shards, 1, [this](size_t begin, size_t end, unsigned) {
        for (size_t shard = begin; shard < end; ++shard) FoldShard(shard);
      });
    } else {
      for (size_t shard = 0; shard < shards; ++shard) FoldShard(shard);
    }
    // The counters, and the cells that emptied, recycled in the order of touched_.
    emptied_.clear();
    for (const ThreadOut& to : thread_out_) {
      swaps_ += to.swaps;
      tests_ += to.tests;
      global_ = global_ || to.global_sort;
      emptied_.insert(emptied_.end(), to.emptied.begin(), to.emptied.end());
    }
    std::sort(emptied_.begin(), emptied_.end());
    for (uint32_t i : emptied_) {
      const uint32_t idx = touched_[i];
      GridCell& cell = *cells_[idx];
      cell_of_.Erase(cell.key);
      cell.in_use = false;
      free_cells_.push_back(idx);
    }
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
    for (size_t at = shard; at < witnessed_.size(); at += shards) {
      const std::vector<Witnessed>& buf = witnessed_[at];
      for (size_t k = 0; k < buf.size(); ++k) {
        if (k + kFoldAhead < buf.size()) BP_GRID_PREFETCH_WITNESS(&buf[k + kFoldAhead]);
        WitnessIn(shard, buf[k].a, buf[k].b, buf[k].now);
      }
    }
  }
#undef BP_GRID_PREFETCH_WITNESS

  // One more (add) or one fewer (remove) witness of the pair a, b.
  void Witness(uint32_t a, uint32_t b, bool add) {
    WitnessIn(tracker_.ShardOf(HandlePair(a, b)), a, b, add);
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

  // --- large objects ---------------------------------------------------------------------------

  void InsertLarge(uint32_t h, const CellCoord& lo, const CellCoord& hi) {
    if (defer_locals_) AssignDeferredLocals();
    uint32_t l;
    if (!free_large_.empty()) {
      l = free_large_.back();
      free_large_.pop_back();
    } else {
      l = static_cast<uint32_t>(large_.size());
      large_.emplace_back();
      large_stamp_.push_back(0);
    }
    large_[l].handle = h;
    Object& o = objects_[h];
    o.large = l;
    o.lo = lo;
    o.hi = hi;
    o.nrefs = 0;
    ++large_count_;
    ForEachExistingCell(lo, hi, [&](uint32_t idx) { cells_[idx]->large.push_back(l); });
    MarkChanged(l);
  }

  void MoveLarge(uint32_t l, const CellCoord& lo, const CellCoord& hi) {
    Object& o = objects_[large_[l].handle];
    if (lo != o.lo || hi != o.hi) {
      Unregister(l);
      o.lo = lo;
      o.hi = hi;
      ForEachExistingCell(lo, hi, [&](uint32_t idx) { cells_[idx]->large.push_back(l); });
    }
    MarkChanged(l);
  }

  void Unregister(uint32_t l) {
    const Object& o = objects_[large_[l].handle];
    ForEachExistingCell(o.lo, o.hi, [&](uint32_t idx) {
      std::vector<uint32_t>& list = cells_[idx]->large;
      auto it = std::find(list.begin(), list.end(), l);
      BP_ASSERT(it != list.end());
      *it = list.back();
      list.pop_back();
    });
  }

  void EraseLarge(uint32_t h) {
    uint32_t l = objects_[h].large;
    Unregister(l);
    Large& lg = large_[l];
    scratch_.clear();
    lg.partners.ForEach([&](uint32_t x) { scratch_.push_back(x); });
    for (uint32_t x : scratch_) {
      Witness(h, x, false);
      if (objects_[x].large != kNone) large_[objects_[x].large].partners.Erase(h);
    }
    lg.partners.Clear();
    lg.handle = kNone;
    free_large_.push_back(l);
    objects_[h].large = kNone;
    --large_count_;
  }

  void MarkChanged(uint32_t l) {
    if (!large_[l].changed) {
      large_[l].changed = true;
      changed_large_.push_back(l);
    }
  }

  void BeginLargeCandidates() {
    NextEpoch(&large_epoch_, &large_stamp_, nullptr);
    candidates_.clear();
  }
  // Stamps are compared with an epoch; when it wraps, the stamps restart from zero.
  static void NextEpoch(uint32_t* epoch, std::vector<uint32_t>* a, std::vector<uint32_t>* b) {
    if (++*epoch != 0) return;
    std::fill(a->begin(), a->end(), 0);
    if (b != nullptr) std::fill(b->begin(), b->end(), 0);
    *epoch = 1;
  }
  // The large objects listed in h's current cells, each once.
  void AddLargeCandidates(uint32_t h) {
    const Object& o = objects_[h];
    for (uint32_t i = 0; i < o.nrefs; ++i) {
      for (uint32_t l : cells_[refs_[o.refs + i].cell]->large) {
        if (large_stamp_[l] != large_epoch_) {
          large_stamp_[l] = large_epoch_;
          candidates_.push_back(l);
        }
      }
    }
  }
  // Brings the pairs of small object h with the candidates up to date (h dead: removes them).
  // `before` is h's box at the last query (nullptr: h was in no partner set), which tells, for a
  // candidate unchanged this query, whether h is its partner without a look-up; a candidate
  // that changed is rescanned afterwards, which settles its pairs anyway.
  void TestLargeCandidates(uint32_t h, const BoxType* before) {
    const bool alive = objects_[h].state == State::kLive;
    for (uint32_t l : candidates_) {
      Large& lg = large_[l];
      if (!tracker_.Accepts(h, lg.handle)) continue;  // never a partner
      const BoxType& lbox = objects_[lg.handle].box;
      ++tests_;
      bool now = alive && Overlaps(objects_[h].box, lbox);
      if (!lg.changed) {
        bool had = before != nullptr && Overlaps(*before, lbox);
        if (had == now) continue;
      }
      if (now ? lg.partners.Insert(h) : lg.partners.Erase(h)) Witness(h, lg.handle, now);
    }
  }

  // Sets a changed large object's partners to exactly the live objects overlapping it: the small
  // ones in the cells its range covers and the other large ones.
  void Rescan(uint32_t l) {
    const uint32_t h = large_[l].handle;
    const BoxType& box = objects_[h].box;
    const Object& o = objects_[h];
    NextEpoch(&epoch_, &stamp_, &mark_);
    found_.clear();
    ForEachExistingCell(o.lo, o.hi, [&](uint32_t idx) {
      for (uint32_t g : cells_[idx]->global) {
        if (g == kNone || stamp_[g] == epoch_) continue;
        stamp_[g] = epoch_;
        const Object& x = objects_[g];
        if (x.state != State::kLive || x.large != kNone) continue;  // left, or now large
        if (!tracker_.Accepts(g, h)) continue;
        ++tests_;
        if (Overlaps(objects_[g].box, box)) {
          mark_[g] = epoch_;
          found_.push_back(g);
        }
      }
    });
    for (const Large& other : large_) {
      uint32_t g = other.handle;
      if (g == kNone || g == h || !tracker_.Accepts(g, h)) continue;
      ++tests_;
      if (Overlaps(objects_[g].box, box)) {
        mark_[g] = epoch_;
        found_.push_back(g);
      }
    }
    Large& lg = large_[l];
    scratch_.clear();
    lg.partners.ForEach([&](uint32_t x) {
      if (mark_[x] != epoch_) scratch_.push_back(x);
    });
    for (uint32_t x : scratch_) {
      lg.partners.Erase(x);
      Witness(h, x, false);
      if (objects_[x].large != kNone) large_[objects_[x].large].partners.Erase(h);
    }
    for (uint32_t x : found_) {
      if (!lg.partners.Insert(x)) continue;
      Witness(h, x, true);
      if (objects_[x].large != kNone) large_[objects_[x].large].partners.Insert(h);
    }
  }

  // --- resizing ----------------------------------------------------------------------------------

  // Rebuilds every cell with a new cell size once the query's changes are applied. The overlap
  // set does not change, so the tracker is kept; only the witness counts are recounted.
  void Regrid(const Sizing& sizing) {
    rebuilt_ = true;
    cells_.clear();
    cell_work_.clear();
    free_cells_.clear();
    cell_of_.Clear();
    large_.clear();
    large_stamp_.clear();
    free_large_.clear();
    changed_large_.clear();
    large_count_ = 0;
    defer_locals_ = true;
    refs_.clear();
    for (auto& list : free_refs_) list.clear();
    for (auto& extra : extra_) extra.Clear();
    SetCellSize(sizing.size, sizing.middle);
    recount_ = true;
    for (uint32_t h = 0; h < objects_.size(); ++h) {
      Object& o = objects_[h];
      o.large = kNone;
      o.nrefs = 0;
      if (o.state != State::kLive) continue;
      CellCoord lo, hi;
      RangeOf(objects_[h].box, &lo, &hi);
      if (CellCount(lo, hi) > options_.max_cells_per_object) {
        InsertLarge(h, lo, hi);
      } else {
        EnterCells(h, lo, hi);
      }
    }
    // Small-large pairs come from the rescans (every large object is marked changed).
    for (uint32_t l : changed_large_) {
      large_[l].changed = false;
      Rescan(l);
    }
    changed_large_.clear();
    route_ms_ += phase_.Lap();  // a rebuild's routing (its cells and fold lap in QueryCells)
    QueryCells();
    recount_ = false;
    BP_ASSERT(recount_seen_.size() == tracker_.overlaps());
    recount_seen_.Clear();
  }

  // --- cell reference pool: blocks of 2^k refs, free lists by k ------------------------------

  uint32_t AllocRefs(uint32_t n) {
    size_t k = static_cast<size_t>(std::bit_width(n - 1));
    if (k >= free_refs_.size()) free_refs_.resize(k + 1);
    if (!free_refs_[k].empty()) {
      uint32_t at = free_refs_[k].back();
      free_refs_[k].pop_back();
      return at;
    }
    uint32_t at = static_cast<uint32_t>(refs_.size());
    refs_.resize(refs_.size() + (size_t{1} << k));
    return at;
  }
  void FreeRefs(uint32_t at, uint32_t n) {
    if (n == 0) return;
    free_refs_[static_cast<size_t>(std::bit_width(n - 1))].push_back(at);
  }

  Options options_;
  std::unique_ptr<WorkerPool> pool_;  // when threads > 1
  double cell_size_ = 0;
  double inv_size_ = 0;                 // 0 until the size is chosen
  std::array<double, kAxes> origin_{};  // cell (0, ..., 0) starts here
  bool placed_ = false;                 // the origin is chosen (at the first inserts)
  size_t sized_for_ = 0;
  size_t live_ = 0;
  HugeVector<Object> objects_;
  HugeVector<CellRef> refs_;
  std::vector<std::vector<uint32_t>> free_refs_;
  std::vector<std::unique_ptr<GridCell>> cells_;
  std::vector<uint32_t> free_cells_;
  FlatMap<uint64_t, uint32_t> cell_of_;  // packed coordinate -> cell index
  std::vector<uint32_t> touched_;
  HugeVector<Routed> routed_;
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
  const std::function<void()>* beside_ = nullptr;  // see Apply
  bool beside_ran_ = false;
  // A parallel routing's shard updates grouped by cell (ScatterShard), each part's run in cell
  // order; the serially routed ones go to grouped_ (GroupUpdates).
  HugeVector<HandleBox<kDim, Coord>> grouped_shard_;
  HugeVector<HandleBox<kDim, Coord>> grouped_;
  std::vector<CellRef> routed_erases_;        // this query's erases of cell slots, as routed
  HugeVector<Routed> routed_inserts_;         // and its inserts
  std::vector<uint32_t> routed_insert_refs_;  // per routed insert: see RouteInsert's ref_at
  std::vector<uint32_t> grouped_erases_;
  HugeVector<HandleBox<kDim, Coord>> grouped_inserts_;
  std::vector<uint32_t> grouped_insert_refs_;
  // This query allocates cell-local handles of inserts when it applies the cells (EnterCell).
  // Only while no large object exists: a large object's scans read the cells' tables, so the
  // first one to appear ends the deferral (AssignDeferredLocals).
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
  // What applying a cell leaves for the fold: its changes, as global handle pairs (Witnessed, in
  // witnessed_), and in its thread's ThreadOut its counters (summed) and, if it emptied, its
  // position in touched_.
  struct Witnessed {
    uint32_t a, b;
    bool now;
  };
  // Line-aligned: the threads write theirs at once. (Per thread rather than a record per cell
  // added up serially after, which would be a serial loop over every touched cell.)
  struct alignas(64) ThreadOut {
    size_t swaps = 0, tests = 0, cells = 0;
    bool global_sort = false;
    std::vector<uint32_t> emptied;
  };
  // Per pool thread and shard of the tracker: witnessed_[thread * shards + shard].
  std::vector<std::vector<Witnessed>> witnessed_;
  std::vector<ThreadOut> thread_out_;  // per pool thread (one without a pool)
  std::vector<uint32_t> cell_runs_;    // the pool's runs of touched_ (GuidedRuns)
  std::vector<uint32_t> emptied_;      // FoldCells' scratch: the emptied cells' positions
  std::vector<Large> large_;
  std::vector<uint32_t> free_large_;
  std::vector<uint32_t> changed_large_;
  size_t large_count_ = 0;
  PairTracker tracker_;
  // Witnesses beyond the first, by shard of the tracker; line-aligned, as the folding threads
  // write their shards' headers.
  struct alignas(64) Extra : FlatMap<uint64_t, uint32_t> {};
  std::vector<Extra> extra_;
  bool recount_ = false;
  FlatSet<uint64_t> recount_seen_;
  // Scratch of the large-object paths.
  std::vector<uint32_t> stamp_, mark_;  // by global handle, against epoch_
  uint32_t epoch_ = 0;
  std::vector<uint32_t> large_stamp_;  // by large index, against large_epoch_
  uint32_t large_epoch_ = 0;
  std::vector<uint32_t> candidates_, found_, scratch_;
  std::vector<double> extents_;
  // Counters of the last query.
  size_t swaps_ = 0, tests_ = 0, cells_queried_ = 0, pool_routed_ = 0, worker_cells_ = 0;
  bool global_ = false, rebuilt_ = false;
  Stopwatch phase_;  // laps the phases of Apply: route_ms_, cells_ms_, fold_ms_ (Stats)
  double route_ms_ = 0, cells_ms_ = 0, fold_ms_ = 0;
};

}  // namespace detail

/// The grid over segmented-interval-list cells (few movers, few events per cell).
template <int K, Coordinate T, class Key = uint64_t>
using GridSegmentedSap = detail::KeyedEngine<detail::GridCore<detail::SegmentedSapCore<K, T>>, Key>;
/// The grid over batch insertion and removal cells (many movers or many events per cell).
template <int K, Coordinate T, class Key = uint64_t>
using GridBatchSap = detail::KeyedEngine<detail::GridCore<detail::BatchSapCore<K, T>>, Key>;
/// The grid over dense cells (boxes in flat arrays, brute force within a cell; beyond the paper:
/// fastest with small cells on scenes that spread their objects, see bp/dense_cell.h).
template <int K, Coordinate T, class Key = uint64_t>
using GridDense = detail::KeyedEngine<detail::GridCore<detail::DenseCellCore<K, T>>, Key>;
/// Options of GridSegmentedSap, GridBatchSap and GridDense.
using GridSegmentedSapOptions = GridOptions<SegmentedSapOptions>;
using GridBatchSapOptions = GridOptions<BatchSapOptions>;
using GridDenseOptions = GridOptions<DenseCellOptions>;

}  // namespace bp

#include "bp/detail/grid_validate.h"  // NOLINT(build/include_order): defines Validate
