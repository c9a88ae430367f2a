// bp::detail::GridCellTable: the grid's cells by coordinates. A cell coordinate is
// floor((x - origin) / cell_size) (up to rounding: see CellOf) clamped to [-2^(b-1), 2^(b-1))
// with b = 63 / K bits, so coordinates far from the origin land in the edge cells instead of
// overflowing; any monotone map keeps the grid exact (two boxes that overlap share a cell on
// every axis). Cells are hashed by their packed coordinates (the world is unbounded), created
// when an object first enters them (CellAt) and recycled when their last object leaves
// (FreeCell). A cell knows its objects by local handles (its core's handles), allocated and
// recycled here, with a table back to the global handles.
//
// Thread safety: none, except that ClaimLocal and the cell's own fields may be written by the
// pool thread applying that cell (one thread per cell).
// Invariants (checked by GridCore::Validate):
//  1. A cell in use is in cell_of_ under its packed coordinate (and nothing else is), and holds
//     members > 0 live objects, its core's live count; global[local] names each of them, the
//     other locals are on free_local, each once.
//  2. A cell not in use is on free_cells_, with empty tables.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "bp/detail/flat_map.h"
#include "bp/detail/grid_objects.h"

namespace bp::detail {

template <class Cell>
class GridCellTable : public GridObjects<Cell> {
  using Base = GridObjects<Cell>;

 protected:
  using Base::CellPairs;
  using Base::kAxes;
  using Base::kLimit;
  using Base::kNone;
  using Base::options_;
  using Base::refs_;
  using Base::tracker_;
  using typename Base::BoxType;
  using typename Base::CellCoord;
  using typename Base::CellRef;
  using typename Base::Coord;
  using typename Base::Options;
  using typename Base::Space;

  struct GridCell {
    explicit GridCell(const typename Cell::Options& o) : core(o) {}
    Cell core;
    CellCoord coord{};
    uint64_t key = 0;
    std::vector<uint32_t> global;      // local handle -> global handle (kNone: free)
    std::vector<uint32_t> free_local;  // reusable local handles
    uint32_t members = 0;              // live objects as of the cell's last apply
    bool in_use = false;
  };

  explicit GridCellTable(const Options& options) : Base(options) {}

  // The grid this part is of (the composer, which befriends its parts).
  GridCore<Cell>& grid() { return static_cast<GridCore<Cell>&>(*this); }

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
  void ForEachExistingCell(const CellCoord& lo, const CellCoord& hi, F&& f) const {
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
  // The cell-table key of the lowest cell box enters.
  uint64_t FirstCellKey(const BoxType& box) const {
    CellCoord lo;
    for (size_t a = 0; a < kAxes; ++a) {
      lo[a] = static_cast<typename Space::Scalar>(CellOf(box.lo[a], a));
    }
    return Space::Pack(lo);
  }

  // The cell at c, created (or recycled) if absent; the composer is told of a new one
  // (GridCore::CellCreated: its work entry).
  uint32_t CellAt(const CellCoord& c) {
    bool inserted = false;
    uint64_t key = Space::Pack(c);
    uint32_t& slot = cell_of_.FindOrInsert(key, kNone, &inserted);
    if (!inserted) return slot;
    uint32_t idx;
    bool fresh = false;
    if (!free_cells_.empty()) {
      idx = free_cells_.back();
      free_cells_.pop_back();
    } else {
      idx = static_cast<uint32_t>(cells_.size());
      cells_.push_back(std::make_unique<GridCell>(options_.cell));
      fresh = true;
    }
    slot = idx;  // FindOrInsert's reference is still valid: nothing was inserted since
    GridCell& cell = *cells_[idx];
    cell.coord = c;
    cell.key = key;
    cell.in_use = true;
    grid().CellCreated(idx, fresh);
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

  // Allocates global handle h's local handle in cell, for an insert whose local was deferred,
  // and writes it into the object's reference to the cell (refs_[ref_at]); returns it.
  uint32_t ClaimLocal(GridCell& cell, uint32_t h, uint32_t ref_at) {
    const uint32_t local = AllocLocal(cell, h);
    refs_[ref_at].local = local;
    return local;
  }

  // Recycles cell idx, whose last object left in the query just applied.
  void FreeCell(uint32_t idx) {
    GridCell& cell = *cells_[idx];
    cell_of_.Erase(cell.key);
    cell.in_use = false;
    free_cells_.push_back(idx);
  }
  // Drops every cell (a rebuild: see GridSizing::Regrid).
  void ClearCells() {
    cells_.clear();
    free_cells_.clear();
    cell_of_.Clear();
  }

  double cell_size_ = 0;
  double inv_size_ = 0;                 // 0 until the size is chosen
  std::array<double, kAxes> origin_{};  // cell (0, ..., 0) starts here
  std::vector<std::unique_ptr<GridCell>> cells_;
  std::vector<uint32_t> free_cells_;
  FlatMap<uint64_t, uint32_t> cell_of_;  // packed coordinate -> cell index
};

}  // namespace bp::detail
