// bp::detail::GridSizing: the cell size. It is either given or chosen from the objects: about
// objects_per_cell objects per cell over the bounds of the box centres, never below the median
// box extent (IdealCellSize). The first objects choose it, and the origin (the middle of their
// centres, on a multiple of the size, so that a world far from zero gets cells as small as one
// at zero); it is chosen again, and every cell rebuilt (Regrid), when the live count has changed
// fourfold and the best size differs by more than a factor of two (MaybeResize).
//
// Thread safety: none.
// Invariants: a rebuild keeps the overlap set (the tracker is kept; the witness counts are
// recounted, see GridWitness) and leaves every part as a fresh insert of the live objects would.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "bp/detail/grid_parallel_routing.h"

namespace bp::detail {

template <class Cell>
class GridSizing : public GridParallelRouting<Cell> {
  using Base = GridParallelRouting<Cell>;

 protected:
  using Base::BeginRecount;
  using Base::cell_size_;
  using Base::cell_work_;
  using Base::CellCount;
  using Base::ClearCells;
  using Base::ClearLarge;
  using Base::defer_locals_;
  using Base::EndRecount;
  using Base::EnterCells;
  using Base::free_refs_;
  using Base::grid;
  using Base::InsertLarge;
  using Base::inv_size_;
  using Base::kAxes;
  using Base::kDim;
  using Base::kNone;
  using Base::kUnpaired;
  using Base::live_;
  using Base::objects_;
  using Base::options_;
  using Base::PairsWithNothing;
  using Base::phase_;
  using Base::RangeOf;
  using Base::rebuilt_;
  using Base::refs_;
  using Base::RescanChanged;
  using Base::route_ms_;
  using Base::SetCellSize;
  using Base::unpaired_;
  using typename Base::BoxType;
  using typename Base::CellCoord;
  using typename Base::Coord;
  using typename Base::Object;
  using typename Base::Options;
  using typename Base::State;

  explicit GridSizing(const Options& options) : Base(options) {}

  // The first objects (a query's inserts before any object was placed) choose the origin, and
  // the automatic size.
  void PlaceFirst(std::span<const HandleBox<kDim, Coord>> inserts) {
    if (!placed_ && !inserts.empty()) {
      // First objects: choose the origin, and the automatic size, from those that go into
      // cells (an object that pairs with nothing never does).
      size_t n = 0;
      for (const auto& hb : inserts) n += PairsWithNothing(hb.handle) ? size_t{0} : size_t{1};
      if (n == 0) return;
      const GridSizing* self = this;  // named: GCC 12 cannot capture this in this generic lambda
      Sizing sizing = IdealCellSize(n, [self, inserts](auto&& f) {
        for (const auto& hb : inserts) {
          if (!self->PairsWithNothing(hb.handle)) f(hb.box);
        }
      });
      SetCellSize(inv_size_ == 0 ? sizing.size : cell_size_, sizing.middle);
      sized_for_ = n;
      placed_ = true;
    }
  }

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
    const size_t placed = live_ - unpaired_;  // the objects in cells or the large set
    if (placed < 64 || (placed <= 4 * sized_for_ && 4 * placed >= sized_for_)) return;
    sized_for_ = placed;
    Sizing ideal = IdealCellSize(placed, [&](auto&& f) {
      for (uint32_t h = 0; h < objects_.size(); ++h) {
        const Object& o = objects_[h];
        if (o.state == State::kLive && o.large != kUnpaired) f(o.box);
      }
    });
    if (ideal.size > 0.5 * cell_size_ && ideal.size < 2 * cell_size_) return;
    Regrid(ideal);
  }

  // Rebuilds every cell with a new cell size once the query's changes are applied. The overlap
  // set does not change, so the tracker is kept; only the witness counts are recounted.
  void Regrid(const Sizing& sizing) {
    rebuilt_ = true;
    ClearCells();
    cell_work_.clear();
    ClearLarge();
    defer_locals_ = true;
    refs_.clear();
    for (auto& list : free_refs_) list.clear();
    SetCellSize(sizing.size, sizing.middle);
    BeginRecount();
    for (uint32_t h = 0; h < objects_.size(); ++h) {
      Object& o = objects_[h];
      if (o.large == kUnpaired) continue;  // in no cell: stays as it is
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
    RescanChanged();
    route_ms_ += phase_.Lap();  // a rebuild's routing (its cells and fold lap in QueryCells)
    grid().QueryCells();
    EndRecount();
  }

  bool placed_ = false;  // the origin is chosen (at the first inserts)
  size_t sized_for_ = 0;
  std::vector<double> extents_;
};

}  // namespace bp::detail
