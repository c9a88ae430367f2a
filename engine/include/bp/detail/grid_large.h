// bp::detail::GridLargeSet: objects too big for the cells. An object whose box would cover more
// than max_cells_per_object cells is not copied into cells: it joins the large set. The large
// objects are listed in bins, a coarse grid of at most kMaxBins bins over the cells in use (each
// bin a block of 2^bin_shift_ cells per axis; cells beyond the bins' range map to the edge
// bins): a large object in every bin its cell range touches. A changed small object is tested
// against the large objects listed in the bins of its old and new cell ranges (the
// candidates): the bins are few and small, so they stay in the cache where per-cell lists, read
// from cold cell records, each cost a miss. A changed large object is rescanned against the
// objects of the cells it covers and against the other large objects (Rescan, at the end of
// the routing). Each large object keeps its witnessed partners; for large pairs both sides hold
// each other and count once.
//
// Binning is monotone on every axis, so a small object whose cell range overlaps a large
// object's shares a bin with it whatever the bins' origin and size: the bins are only rebuilt
// (after the query) when a large object was inserted, moved or erased. In between, a large
// object changed in the current query is skipped by the candidate tests: its rescan, after the
// routing, settles all its pairs.
//
// Thread safety: none (the large set is touched by the serial routing only: a query with a
// large object routes serially).
// Invariants (checked by GridCore::Validate):
//  1. Between queries, each live large object is listed exactly in the bins its cell range
//     touches, once each, and the bins list nothing else.
//  2. A large object's partners are exactly the live objects overlapping it (and accepted by
//     the filters); large partners hold each other.
//  3. A large slot that is free (handle kNone) has no partners and is on free_large_.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <vector>

#include "bp/detail/flat_set.h"
#include "bp/detail/grid_witness.h"

namespace bp::detail {

template <class Cell>
class GridLargeSet : public GridWitness<Cell> {
  using Base = GridWitness<Cell>;

 protected:
  using Base::cells_;
  using Base::ForEachExistingCell;
  using Base::grid;
  using Base::kAxes;
  using Base::kNone;
  using Base::objects_;
  using Base::tests_;
  using Base::tracker_;
  using Base::Witness;
  using typename Base::BoxType;
  using typename Base::CellCoord;
  using typename Base::Object;
  using typename Base::Options;
  using typename Base::Space;
  using typename Base::State;

  explicit GridLargeSet(const Options& options) : Base(options) {}

  struct Large {
    uint32_t handle = kNone;
    bool changed = false;
    FlatSet<uint32_t> partners;  // live objects overlapping this one (global handles)
  };

  void InsertLarge(uint32_t h, const CellCoord& lo, const CellCoord& hi) {
    grid().EndLocalDeferral();
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
    MarkChanged(l);
  }

  void MoveLarge(uint32_t l, const CellCoord& lo, const CellCoord& hi) {
    grid().EndLocalDeferral();  // its rescan reads the cells' tables
    Object& o = objects_[large_[l].handle];
    o.lo = lo;
    o.hi = hi;
    MarkChanged(l);
  }

  void EraseLarge(uint32_t h) {
    uint32_t l = objects_[h].large;
    Large& lg = large_[l];
    scratch_.clear();
    lg.partners.ForEach([&](uint32_t x) { scratch_.push_back(x); });
    for (uint32_t x : scratch_) {
      Witness(h, x, false);
      if (objects_[x].large != kNone) large_[objects_[x].large].partners.Erase(h);
    }
    lg.partners.Clear();
    lg.handle = kNone;
    bins_stale_ = true;
    free_large_.push_back(l);
    objects_[h].large = kNone;
    --large_count_;
  }

  // Marks large object l changed in this query (rescanned after the routing, skipped by the
  // candidate tests until then), and the bins out of date.
  void MarkChanged(uint32_t l) {
    bins_stale_ = true;
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
  // The large objects listed in the bins of h's current cell range, each once.
  void AddLargeCandidates(uint32_t h) {
    const Object& o = objects_[h];
    std::array<uint32_t, kAxes> lo, hi;
    BinRange(o.lo, o.hi, &lo, &hi);
    ForEachBin(lo, hi, [&](uint32_t bin) {
      for (uint32_t k = bin_begin_[bin]; k < bin_begin_[bin + 1]; ++k) {
        const uint32_t l = bin_large_[k];
        if (large_stamp_[l] != large_epoch_) {
          large_stamp_[l] = large_epoch_;
          candidates_.push_back(l);
        }
      }
    });
  }
  // Brings the pairs of small object h with the candidates up to date (h dead: removes them).
  // `before` is h's box at the last query (nullptr: h was in no partner set), which tells
  // whether h is a candidate's partner without a look-up. A candidate changed in this query
  // (or erased: its slot is free or changed) is skipped: its rescan settles its pairs. A change
  // waits in large_changes_ until the routing ends (ApplyLargeChanges).
  // The tests are branch-free: whether a moved object overlaps a large one then and now is
  // unpredictable per axis, and a short-circuit test mispredicted often enough to take most of
  // a frame's routing; that the two agree is predictable.
  void TestLargeCandidates(uint32_t h, const BoxType* before) {
    const uint32_t alive = objects_[h].state == State::kLive ? 1u : 0u;
    const BoxType& box = objects_[h].box;
    const BoxType& then = before != nullptr ? *before : box;
    const uint32_t was = before != nullptr ? 1u : 0u;
    for (uint32_t l : candidates_) {
      Large& lg = large_[l];
      if (lg.changed || lg.handle == kNone || !tracker_.Accepts(h, lg.handle)) continue;
      const BoxType& lbox = objects_[lg.handle].box;
      ++tests_;
      const uint32_t now = alive & OverlapsBranchFree(box, lbox);
      const uint32_t had = was & OverlapsBranchFree(then, lbox);
      if (had == now) continue;
      large_changes_.push_back(LargeChange{l, h, now != 0});
    }
  }

  // Applies the candidate tests' changes to the partner sets, grouped by large object (each
  // set's lines then come in once, where in the routing's order every change was a miss), and
  // witnesses them. A change for a large object that changed later in the query (or was
  // erased) is dropped: its rescan, or its erase, settles its pairs from the sets as they were.
  void ApplyLargeChanges() {
    if (large_changes_.empty()) return;
    std::vector<uint32_t>& begin = scratch_;
    begin.assign(large_.size() + 1, 0);
    for (const LargeChange& c : large_changes_) ++begin[c.large + 1];
    for (size_t l = 0; l < large_.size(); ++l) begin[l + 1] += begin[l];
    sorted_changes_.resize(large_changes_.size());
    for (const LargeChange& c : large_changes_) sorted_changes_[begin[c.large]++] = c;
    for (const LargeChange& c : sorted_changes_) {
      Large& lg = large_[c.large];
      if (lg.changed || lg.handle == kNone) continue;
      const bool done = c.now ? lg.partners.Insert(c.h) : lg.partners.Erase(c.h);
      BP_ASSERT(done);
      (void)done;
      Witness(c.h, lg.handle, c.now);
    }
    large_changes_.clear();
  }
  // Overlaps (closed intervals) on every axis without branches (valid boxes: no NaN).
  static uint32_t OverlapsBranchFree(const BoxType& a, const BoxType& b) {
    uint32_t ok = 1;
    for (size_t i = 0; i < kAxes; ++i) {
      ok &= static_cast<uint32_t>(a.lo[i] <= b.hi[i]) & static_cast<uint32_t>(b.lo[i] <= a.hi[i]);
    }
    return ok;
  }

  // Sets a changed large object's partners to exactly the live objects overlapping it: the small
  // ones in the cells its range covers and the other large ones.
  void Rescan(uint32_t l) {
    const uint32_t h = large_[l].handle;
    const BoxType& box = objects_[h].box;
    const Object& o = objects_[h];
    if (stamp_.size() < objects_.size()) {
      stamp_.resize(objects_.size(), 0);
      mark_.resize(objects_.size(), 0);
    }
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

  // Applies the candidate tests' changes, rescans the large objects that changed in this query
  // (after its routing), then bins them again.
  void RescanChanged() {
    ApplyLargeChanges();
    for (uint32_t l : changed_large_) {
      large_[l].changed = false;
      if (large_[l].handle != kNone) Rescan(l);
    }
    changed_large_.clear();
    if (bins_stale_) RebuildBins();
  }

  // ---- the bins ----

  // The bins of a cell range, per axis: clamp((c - bin_origin_) >> bin_shift_, 0, bins - 1),
  // monotone in c. Without bins (no large object): the empty range [1, 0].
  void BinRange(const CellCoord& lo, const CellCoord& hi, std::array<uint32_t, kAxes>* blo,
                std::array<uint32_t, kAxes>* bhi) const {
    if (bin_begin_.size() < 2) {
      blo->fill(1);
      bhi->fill(0);
      return;
    }
    for (size_t a = 0; a < kAxes; ++a) {
      (*blo)[a] = BinOf(lo[a], a);
      (*bhi)[a] = BinOf(hi[a], a);
    }
  }
  uint32_t BinOf(int64_t c, size_t a) const {
    const int64_t b = (c - bin_origin_[a]) >> bin_shift_;
    return static_cast<uint32_t>(std::clamp<int64_t>(b, 0, int64_t{bins_[a]} - 1));
  }
  // Calls f(bin index) for each bin of a bin range, row-major.
  template <class F>
  void ForEachBin(const std::array<uint32_t, kAxes>& lo, const std::array<uint32_t, kAxes>& hi,
                  F&& f) const {
    if (lo[0] > hi[0]) return;
    std::array<uint32_t, kAxes> at = lo;
    while (true) {
      uint32_t index = 0;
      for (size_t a = kAxes; a-- > 0;) index = index * bins_[a] + at[a];
      f(index);
      size_t a = 0;
      while (a < kAxes && at[a] == hi[a]) {
        at[a] = lo[a];
        ++a;
      }
      if (a == kAxes) return;
      ++at[a];
    }
  }
  // Lays the bins over the cells in use (at most kMaxBins: 2^bin_shift_ cells per bin and axis,
  // the smallest power of two that fits) and lists every live large object in the bins its cell
  // range touches. O(cells + the bins the large objects touch).
  void RebuildBins() {
    bins_stale_ = false;
    bin_begin_.clear();
    bin_large_.clear();
    if (large_count_ == 0) return;
    CellCoord lo, hi;
    lo.fill(std::numeric_limits<typename Space::Scalar>::max());
    hi.fill(std::numeric_limits<typename Space::Scalar>::lowest());
    for (const auto& cell : cells_) {
      if (!cell->in_use) continue;
      for (size_t a = 0; a < kAxes; ++a) {
        lo[a] = std::min(lo[a], cell->coord[a]);
        hi[a] = std::max(hi[a], cell->coord[a]);
      }
    }
    if (lo[0] > hi[0]) lo = hi = CellCoord{};  // no cell in use: one bin per axis will do
    uint64_t span = 1;
    for (size_t a = 0; a < kAxes; ++a) {
      span = std::max(span, static_cast<uint64_t>(int64_t{hi[a]} - lo[a]) + 1);
    }
    bin_shift_ = 0;
    while ((((span - 1) >> bin_shift_) + 1) > kBinsPerAxis) ++bin_shift_;
    size_t total = 1;
    for (size_t a = 0; a < kAxes; ++a) {
      bin_origin_[a] = lo[a];
      bins_[a] = static_cast<uint32_t>(
          ((static_cast<uint64_t>(int64_t{hi[a]} - lo[a])) >> bin_shift_) + 1);
      total *= bins_[a];
    }
    // Counting sort of (bin, large) entries into bin_begin_ / bin_large_.
    bin_begin_.assign(total + 1, 0);
    std::array<uint32_t, kAxes> blo, bhi;
    for (const Large& lg : large_) {
      if (lg.handle == kNone) continue;
      BinRange(objects_[lg.handle].lo, objects_[lg.handle].hi, &blo, &bhi);
      ForEachBin(blo, bhi, [&](uint32_t bin) { ++bin_begin_[bin + 1]; });
    }
    for (size_t b = 0; b < total; ++b) bin_begin_[b + 1] += bin_begin_[b];
    bin_large_.resize(bin_begin_[total]);
    std::vector<uint32_t>& cursor = scratch_;
    cursor.assign(bin_begin_.begin(), bin_begin_.end() - 1);
    for (uint32_t l = 0; l < large_.size(); ++l) {
      if (large_[l].handle == kNone) continue;
      BinRange(objects_[large_[l].handle].lo, objects_[large_[l].handle].hi, &blo, &bhi);
      ForEachBin(blo, bhi, [&](uint32_t bin) { bin_large_[cursor[bin]++] = l; });
    }
  }
  // Drops the whole set (a rebuild: see GridSizing::Regrid).
  void ClearLarge() {
    large_.clear();
    large_stamp_.clear();
    free_large_.clear();
    changed_large_.clear();
    large_changes_.clear();
    large_count_ = 0;
    bin_begin_.clear();
    bin_large_.clear();
    bins_stale_ = false;
  }

  // At most this many bins (per axis: kBinsPerAxis, the largest integer whose K-th power fits).
  static constexpr size_t kMaxBins = 32768;
  static constexpr uint32_t kBinsPerAxis = kAxes == 1   ? 32768
                                           : kAxes == 2 ? 181
                                           : kAxes == 3 ? 32
                                           : kAxes == 4 ? 13
                                                        : 4;

  std::vector<Large> large_;
  // The bins (invariant 1): bin b lists bin_large_[bin_begin_[b], bin_begin_[b + 1]); bins_[a]
  // bins on axis a from cell bin_origin_[a], 2^bin_shift_ cells each. No bins: bin_begin_ empty.
  std::vector<uint32_t> bin_begin_, bin_large_;
  std::array<uint32_t, kAxes> bins_{};
  std::array<int64_t, kAxes> bin_origin_{};
  uint32_t bin_shift_ = 0;
  bool bins_stale_ = false;
  std::vector<uint32_t> free_large_;
  std::vector<uint32_t> changed_large_;
  size_t large_count_ = 0;
  // Scratch of the large-object paths.
  std::vector<uint32_t> stamp_, mark_;  // by global handle, against epoch_ (sized by Rescan)
  uint32_t epoch_ = 0;
  std::vector<uint32_t> large_stamp_;  // by large index, against large_epoch_
  uint32_t large_epoch_ = 0;
  std::vector<uint32_t> candidates_, found_, scratch_;
  // A small object's change of status with an unchanged large object, found by the candidate
  // tests, applied after the routing (ApplyLargeChanges).
  struct LargeChange {
    uint32_t large, h;
    bool now;
  };
  std::vector<LargeChange> large_changes_, sorted_changes_;
};

}  // namespace bp::detail
