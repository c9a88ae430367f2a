// bp::detail::GridObjects: what every part of the grid shares (bp/grid.h, detail/grid_core.h):
// its types and options, the worker pool, one record per global handle (the box, the cell range,
// the object's references to its cells or its index in the large set), the pool those references
// are allocated from, the pair tracker every part reports to, and the last query's counters.
//
// The grid is a chain of parts, each a class template on the cell type deriving from the one
// below it, so that a part calls the parts below it directly and the part above through the
// composer (GridCore, which befriends them all):
//   GridObjects -> GridCellTable -> GridWitness -> GridLargeSet -> GridRouting
//     -> GridParallelRouting -> GridSizing -> GridCore.
// Each part says at its top what it owns and what it uses of the parts below (its using-
// declarations). Parts are never used alone: they hold no invariant that does not involve the
// others, and GridCore::Validate (detail/grid_validate.h) checks them all.
//
// Thread safety: none; the pool's threads touch only what the part running them documents.
// Invariants (with the cell table's, see detail/grid_cells.h):
//  1. A live small object's refs list, in row-major order over its cell range, one (cell, local)
//     per cell; cells_[cell] has that coordinate and global[local] is the object. A large
//     object has no references (nrefs 0) and its index in the large set. An object that pairs
//     with nothing has no references and large kUnpaired, and unpaired_ counts them.
//  2. A block of 2^k references is either an object's or on free_refs_[k], never both.
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "bp/box.h"
#include "bp/detail/cell_space.h"
#include "bp/detail/front_end_contract.h"
#include "bp/detail/huge_alloc.h"
#include "bp/detail/pair_tracker.h"
#include "bp/detail/stopwatch.h"
#include "bp/detail/worker_pool.h"
#include "bp/grid_options.h"

namespace bp::detail {

template <class Cell>
class GridCore;

template <class Cell>
class GridObjects {
 protected:
  static constexpr int kDim = Cell::kDim;
  static constexpr size_t kAxes = static_cast<size_t>(kDim);
  using Coord = typename Cell::Coord;
  using BoxType = Box<kDim, Coord>;
  using Options = GridOptions<typename Cell::Options>;
  using Space = CellSpace<kDim>;
  using CellCoord = typename Space::Coord;
  static constexpr int64_t kLimit = Space::kLimit;
  static constexpr uint32_t kNone = ~uint32_t{0};
  // Object::large of an object that pairs with nothing (PairsWithNothing): it lives in its
  // record only, in no cell and not in the large set, and costs a query nothing but its record.
  static constexpr uint32_t kUnpaired = kNone - 1;

  struct CellRef {
    uint32_t cell;
    uint32_t local;
  };
  enum class State : uint8_t { kDead, kLive };
  // One record per global handle, box included; line-aligned when it fits a line (3-D float:
  // 61 bytes), so routing an update reads one line.
  struct ObjectFields {
    BoxType box;
    CellCoord lo{}, hi{};    // cell range
    uint32_t refs = 0;       // first CellRef in refs_ (small objects)
    uint32_t nrefs = 0;      // cells covered (0 for large objects)
    uint32_t large = kNone;  // index in large_ (large objects), or kUnpaired
    State state = State::kDead;
  };
  struct alignas(sizeof(ObjectFields) <= 64 ? 64 : alignof(ObjectFields)) Object : ObjectFields {};

  explicit GridObjects(const Options& options) : options_(options) {}

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

  // True iff handle h's options accept no object at all (mask or category 0: see
  // bp/object_options.h): its pairs are never formed, so it is kept out of the cells.
  bool PairsWithNothing(uint32_t h) const {
    if (!tracker_.masking()) return false;  // default categories and masks pair
    const ObjectOptions o = tracker_.options(h);
    return o.mask == 0 || o.category == 0;
  }

  /// The worker pool, when the grid has one and a loop over n light items (look-ups, routing)
  /// is worth waking its workers for (n >= options().parallel_routing_from); else nullptr. The
  /// front end resolves a large batch's keys through it (see FrontEnd::ForEachResolved).
  WorkerPool* PoolFor(size_t n) const {
    if (pool_ == nullptr || options_.parallel_routing_from == 0) return nullptr;
    return n >= std::max<size_t>(options_.parallel_routing_from, 2) ? pool_.get() : nullptr;
  }
  /// PoolFor for the front end's look-ups of n keys: nullptr unless options().parallel_lookups.
  WorkerPool* LookupPoolFor(size_t n) const {
    return options_.parallel_lookups ? PoolFor(n) : nullptr;
  }

  // Makes room for the record of global handle h.
  void Reserve(uint32_t h) {
    if (h >= objects_.size()) objects_.resize(h + 1);
  }

  // The cell reference pool: blocks of 2^k references, free lists by k.
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
  size_t live_ = 0;
  size_t unpaired_ = 0;  // live objects that pair with nothing (kUnpaired)
  HugeVector<Object> objects_;
  HugeVector<CellRef> refs_;
  std::vector<std::vector<uint32_t>> free_refs_;
  PairTracker tracker_;
  // Counters of the last query.
  size_t swaps_ = 0, tests_ = 0, cells_queried_ = 0, pool_routed_ = 0, worker_cells_ = 0;
  bool global_ = false, rebuilt_ = false;
  Stopwatch phase_;  // laps the phases of Apply: route_ms_, cells_ms_, fold_ms_ (Stats)
  double route_ms_ = 0, cells_ms_ = 0, fold_ms_ = 0;
};

}  // namespace bp::detail
