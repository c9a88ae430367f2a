// bp::detail::DenseCellCore: a third cell type for bp::Grid, beyond the paper. A cell keeps its
// objects' boxes in flat per-axis arrays (structure of arrays), both as they are now and as they
// were at the last query, and finds the pair changes of a query by testing each changed object
// against every object of the cell, then and now: a pair changes iff the two tests differ.
//
// Why: with the grid's cells small (tens of objects), sorting buys nothing, while the SAP cells'
// bookkeeping (sorted lists, positions, a pair set per cell, swaps that touch their neighbours'
// records) is scattered memory traffic, and that is what a frame of S1-200k spends its time on
// (perf: the first touches of each moved extremum and of its neighbours' boxes). Here a changed
// object costs two sequential, vectorisable passes over at most a few kilobytes, and a cell
// reports only changes (the grid's witness counts need nothing else), so it holds no pair set.
// The cost per changed object is linear in the cell's population: keep the cells small (the
// grid's objects_per_cell) and prefer SAP cells for scenes whose objects crowd into few cells.
//
// Exactness: a pair (a, b) of the cell is reported iff [a and b live then and their old boxes
// overlapped] differs from [both live now and their new boxes overlap]; a pair of two changed
// objects is decided once, by the one changed first. Unchanged pairs keep their status. So the
// cell's reports are exactly the changes of its overlap set, which is what a SAP cell's tracker
// drains. The differential suite runs the grid over this cell like over the others.
//
// Thread safety: none; owned by one grid cell (the grid's pool applies each cell on one thread).
// Invariants (checked by Validate, between queries):
//  1. was_[h] == is_[h] for every slot, and the previous boxes equal the current ones.
//  2. live_ is the number of slots with is_[h] set; no change is pending, no rank is set.
#pragma once

#include <algorithm>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/keyed_engine.h"
#include "bp/object_options.h"

namespace bp {

/// Tuning of the dense cell (none yet: its cost is set by the grid's objects_per_cell).
struct DenseCellOptions {};

namespace detail {

template <int K, Coordinate T>
class DenseCellCore {
 public:
  static constexpr int kDim = K;
  static constexpr size_t kAxes = static_cast<size_t>(K);
  using Coord = T;
  static constexpr const char* kGridName = "grid_dense";
  using Options = DenseCellOptions;

  explicit DenseCellCore(const Options& options = Options()) : options_(options) {}

  void Apply(std::span<const uint32_t> erases, std::span<const HandleBox<K, T>> updates,
             std::span<const HandleBox<K, T>> inserts) {
    tests_ = 0;
    changed_.clear();
    for (uint32_t h : erases) {
      BP_ASSERT(h < size_ && is_[h] != 0);
      is_[h] = 0;
      Mark(h);
    }
    for (const auto& [h, box] : updates) {
      BP_ASSERT(h < size_ && is_[h] != 0);
      Store(cur_, h, box);
      Mark(h);
    }
    for (const auto& [h, box] : inserts) {
      Reserve(h);
      BP_ASSERT(is_[h] == 0 && was_[h] == 0);
      is_[h] = 1;
      Store(cur_, h, box);
      Mark(h);
    }
    for (uint32_t h : changed_) Scan(h);
    for (uint32_t h : changed_) {
      was_[h] = is_[h];
      for (size_t a = 0; a < kAxes; ++a) {
        prev_.lo[a][h] = cur_.lo[a][h];
        prev_.hi[a][h] = cur_.hi[a][h];
      }
      rank_[h] = 0;
    }
    live_ = live_ + inserts.size() - erases.size();
    if (live_ == 0) Resize(0);  // an emptied cell is recycled by the grid with fresh handles
  }

  // ---- the grid's view of the cell's pairs (a SAP cell answers these through its tracker) ----

  /// Sets the options of slot h (before its insert).
  void SetOptions(uint32_t h, const ObjectOptions& options) {
    if (!filtering_) {
      if (options == ObjectOptions{}) return;
      filtering_ = true;
    }
    if (h >= options_of_.size()) options_of_.resize(size_t{h} + 1);
    options_of_[h] = options;
  }
  const ObjectOptions& options(uint32_t h) const {
    static const ObjectOptions kDefault;
    return h < options_of_.size() ? options_of_[h] : kDefault;
  }
  /// Calls f(a, b, overlapping_now) for every pair whose status the last Apply changed.
  template <class F>
  void DrainChanges(F&& f) {
    for (const Change& c : changes_) f(c.a, c.b, c.now);
    changes_.clear();
  }
  /// Calls f(a, b) for every overlapping pair of the cell (O(n^2): for validators).
  template <class F>
  void ForEachOverlap(F&& f) const {
    for (uint32_t a = 0; a < size_; ++a) {
      if (is_[a] == 0) continue;
      for (uint32_t b = a + 1; b < size_; ++b) {
        if (is_[b] != 0 && Accepts(a, b) && OverlapAt(cur_, a, b)) f(a, b);
      }
    }
  }

  size_t live() const { return live_; }

  void FillStats(Stats* out) const {
    out->swaps = 0;
    out->overlap_tests = tests_;
    out->global_sort = false;
    out->rebuilt = false;
    out->chunks = 0;
  }

  Status Validate() const;

  const Options& options() const { return options_; }

 private:
  // Slots are tested in blocks of this many (the arrays are padded to a multiple of it; padding
  // slots are dead, so they never pair).
  static constexpr uint32_t kBlock = 16;

  struct Boxes {
    std::vector<T> lo[kAxes];
    std::vector<T> hi[kAxes];
  };
  struct Change {
    uint32_t a, b;
    bool now;
  };

  bool Accepts(uint32_t a, uint32_t b) const {
    return !filtering_ || bp::Accepts(options(a), options(b));
  }
  static bool OverlapAt(const Boxes& s, uint32_t a, uint32_t b) {
    for (size_t x = 0; x < kAxes; ++x) {
      if (s.hi[x][a] < s.lo[x][b] || s.hi[x][b] < s.lo[x][a]) return false;
    }
    return true;
  }
  static void Store(Boxes& s, uint32_t h, const Box<K, T>& box) {
    for (size_t a = 0; a < kAxes; ++a) {
      s.lo[a][h] = box.lo[a];
      s.hi[a][h] = box.hi[a];
    }
  }
  void Resize(size_t n) {
    for (Boxes* s : {&cur_, &prev_}) {
      for (size_t a = 0; a < kAxes; ++a) {
        s->lo[a].resize(n);
        s->hi[a].resize(n);
      }
    }
    was_.resize(n, 0);
    is_.resize(n, 0);
    rank_.resize(n, 0);
    size_ = static_cast<uint32_t>(n);
  }
  void Reserve(uint32_t h) {
    if (h >= size_) Resize((size_t{h} + kBlock) / kBlock * kBlock);
  }
  void Mark(uint32_t h) {
    if (rank_[h] != 0) return;
    changed_.push_back(h);
    rank_[h] = static_cast<uint32_t>(changed_.size());
  }

  // The pairs of changed slot c whose status differs between the last query and now. Blocks of
  // kBlock slots are tested branch-free (vectorised: one row per axis bound, no aliasing), and
  // only a block with a difference is looked at slot by slot.
  void Scan(uint32_t c) {
    const uint32_t rc = rank_[c];
    const uint32_t wc = was_[c], ic = is_[c];
    T plo[kAxes], phi[kAxes], nlo[kAxes], nhi[kAxes];
    const T* __restrict rplo[kAxes];
    const T* __restrict rphi[kAxes];
    const T* __restrict rnlo[kAxes];
    const T* __restrict rnhi[kAxes];
    for (size_t a = 0; a < kAxes; ++a) {
      rplo[a] = prev_.lo[a].data();
      rphi[a] = prev_.hi[a].data();
      rnlo[a] = cur_.lo[a].data();
      rnhi[a] = cur_.hi[a].data();
      plo[a] = rplo[a][c];
      phi[a] = rphi[a][c];
      nlo[a] = rnlo[a][c];
      nhi[a] = rnhi[a][c];
    }
    const uint32_t* __restrict was = was_.data();
    const uint32_t* __restrict is = is_.data();
    uint32_t diff[kBlock];
    tests_ += 2 * static_cast<size_t>(size_);
    for (uint32_t base = 0; base < size_; base += kBlock) {
      constexpr uint32_t n = kBlock;  // size_ is a multiple of kBlock: no remainder loops
      // Liveness first, then the box tests folded in axis by axis.
      uint32_t then_mask[kBlock], now_mask[kBlock];
      for (uint32_t i = 0; i < n; ++i) {
        then_mask[i] = wc & was[base + i];
        now_mask[i] = ic & is[base + i];
      }
      for (size_t a = 0; a < kAxes; ++a) {
        const T* __restrict pl = rplo[a] + base;
        const T* __restrict ph = rphi[a] + base;
        const T* __restrict nl = rnlo[a] + base;
        const T* __restrict nh = rnhi[a] + base;
        const T cpl = plo[a], cph = phi[a], cnl = nlo[a], cnh = nhi[a];
        for (uint32_t i = 0; i < n; ++i) {
          then_mask[i] &= static_cast<uint32_t>(pl[i] <= cph) & static_cast<uint32_t>(cpl <= ph[i]);
          now_mask[i] &= static_cast<uint32_t>(nl[i] <= cnh) & static_cast<uint32_t>(cnl <= nh[i]);
        }
      }
      uint32_t any = 0;
      for (uint32_t i = 0; i < n; ++i) {
        diff[i] = then_mask[i] ^ now_mask[i];
        any |= diff[i];
      }
      if (any == 0) continue;
      for (uint32_t i = 0; i < n; ++i) {
        if (diff[i] == 0) continue;
        const uint32_t j = base + i;
        if (j == c) continue;
        if (rank_[j] != 0 && rank_[j] < rc) continue;  // decided from j's side
        if (!Accepts(c, j)) continue;
        changes_.push_back(Change{c, j, now_mask[i] != 0});
      }
    }
  }

  Options options_;
  Boxes cur_, prev_;
  std::vector<uint32_t> was_, is_;  // live at the last query / now (0 or 1)
  std::vector<uint32_t> rank_;      // 1 + index in changed_ during Apply, else 0
  uint32_t size_ = 0;               // slots (the grid's local handles)
  size_t live_ = 0;
  std::vector<ObjectOptions> options_of_;  // by slot; empty while filtering_ is false
  bool filtering_ = false;
  std::vector<uint32_t> changed_;
  std::vector<Change> changes_;
  size_t tests_ = 0;
};

template <int K, Coordinate T>
Status DenseCellCore<K, T>::Validate() const {
  auto fail = [](const std::string& what) {
    return Status(StatusCode::kInternal, "dense cell: " + what);
  };
  if (!changes_.empty()) return fail("changes left after a query");
  size_t live = 0;
  for (uint32_t h = 0; h < size_; ++h) {
    if (was_[h] != is_[h] || rank_[h] != 0) return fail("slot " + std::to_string(h) + " pending");
    if (is_[h] > 1) return fail("slot " + std::to_string(h) + ": bad flag");
    live += is_[h];
    if (is_[h] == 0) continue;
    for (size_t a = 0; a < kAxes; ++a) {
      if (!(prev_.lo[a][h] == cur_.lo[a][h]) || !(prev_.hi[a][h] == cur_.hi[a][h])) {
        return fail("slot " + std::to_string(h) + ": previous box differs");
      }
      if (cur_.hi[a][h] < cur_.lo[a][h]) return fail("slot " + std::to_string(h) + ": bad box");
    }
  }
  if (live != live_) return fail("live count differs");
  return Status::Ok();
}

}  // namespace detail
}  // namespace bp
