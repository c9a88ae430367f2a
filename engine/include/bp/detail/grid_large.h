// bp::detail::GridLargeSet: objects too big for the cells. An object whose box would cover more
// than max_cells_per_object cells is not copied into cells: it joins the large set. The large
// objects are listed in bins, a coarse grid of at most kMaxBins bins over the cells in use (each
// bin a block of 2^bin_shift_ cells per axis; cells beyond the bins' range map to the edge
// bins): a large object in every bin its cell range touches. A changed small object is tested
// against the large objects listed in the bins of its old and new cell ranges (the
// candidates), 16 at a time and each once (TestLargeInBins): the bins are few and small, so
// they stay in the cache where per-cell lists, read from cold cell records, each cost a miss. A
// changed large object is rescanned against the objects of the cells it covers and against the
// other large objects (Rescan, at the end of the routing). Each large object keeps its witnessed
// partners; for large pairs both sides hold each other and count once.
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
#include <bit>
#include <cstdint>
#include <limits>
#include <span>
#include <utility>
#include <vector>

#include "bp/detail/dense_kernels.h"
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
  using Base::Prefetch;
  using Base::tests_;
  using Base::tracker_;
  using Base::Witness;
  using typename Base::BoxType;
  using typename Base::CellCoord;
  using typename Base::Coord;
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

  // Stamps are compared with an epoch; when it wraps, the stamps restart from zero.
  static void NextEpoch(uint32_t* epoch, std::vector<uint32_t>* a, std::vector<uint32_t>* b) {
    if (++*epoch != 0) return;
    std::fill(a->begin(), a->end(), 0);
    if (b != nullptr) std::fill(b->begin(), b->end(), 0);
    *epoch = 1;
  }

  // Brings the pairs of small object h with the large objects up to date (h dead: removes
  // them). `before` is h's box at the last query (nullptr: h was in no partner set), and
  // [then_lo, then_hi] its cell range then; its record holds the box and range now. Which
  // pairs h had tells `before` without a look-up.
  // The candidates are the large objects listed in the bins of the two ranges' union, tested 16
  // at a time (a block of a bin, BlockOverlaps) against both boxes; a large object listed in
  // several of those bins is taken in one only, the first on every axis of the bins it shares
  // with the union (the block's owned masks), so no candidate counts twice. Only a candidate
  // whose overlap differs then and now is looked at alone: one changed in this query (or
  // erased) is skipped, its rescan settles its pairs; for the others the change waits in
  // large_changes_ until the routing ends (ApplyLargeChanges).
  void TestLargeInBins(uint32_t h, const BoxType* before, const CellCoord& then_lo,
                       const CellCoord& then_hi) {
    if (bin_begin_.size() < 2) return;  // no bins: every large object is new in this query
#ifdef BP_DENSE_WIDE
    if constexpr (kHasWideRows<Coord>) {
      if (block_kernel_ == BlockKernel::kWide) {
        TestLargeInBinsWide(h, before, then_lo, then_hi);
        return;
      }
    }
#endif
    ScanLargeBins(h, before, then_lo, then_hi,
                  [this](const Coord* rows, const auto& boxes, uint32_t* bits) {
                    BlockOverlaps<Coord, kAxes>(block_kernel_, rows, boxes, bits);
                  });
  }
#ifdef BP_DENSE_WIDE
  // The scan compiled for AVX-512 as a whole, so that the kernel is inlined into it (a call
  // into a function of another target is not inlined).
  BP_WIDE_TARGET void TestLargeInBinsWide(uint32_t h, const BoxType* before,
                                          const CellCoord& then_lo, const CellCoord& then_hi) {
    ScanLargeBins(h, before, then_lo, then_hi, WideKernel{});
  }
  struct WideKernel {
    BP_WIDE_TARGET void operator()(const Coord* rows, const BlockBoxes<Coord, kAxes>& boxes,
                                   uint32_t* bits) const {
      WideBlockBoxes<Coord, kAxes>(rows, boxes, bits);
    }
  };
#endif
  // TestLargeInBins' scan, with kernel(rows, boxes, bits) the block test. Inlined into each
  // caller (written without lambdas, which would not take the wide caller's target).
  template <class Kernel>
  [[gnu::always_inline]] inline void ScanLargeBins(uint32_t h, const BoxType* before,
                                                   const CellCoord& then_lo,
                                                   const CellCoord& then_hi, Kernel kernel) {
    const Object& o = objects_[h];
    // at: the bins of [blo, bhi], row-major (as ForEachBin); each element stored on its own (a
    // copy of blo, read back whole while its parts were just stored, stalled the scan's start).
    std::array<uint32_t, kAxes> blo, bhi, at;
    // Box 0: now (if alive), box 1: then (if h had pairs; else a copy of now, masked out).
    BlockBoxes<Coord, kAxes> boxes;
    boxes.in[0] = o.state == State::kLive ? 1u : 0u;
    boxes.in[1] = before != nullptr ? 1u : 0u;
    const BoxType& then = before != nullptr ? *before : o.box;
    for (size_t a = 0; a < kAxes; ++a) {
      at[a] = blo[a] = BinOf(std::min(then_lo[a], o.lo[a]), a);
      bhi[a] = BinOf(std::max(then_hi[a], o.hi[a]), a);
      boxes.lo[0][a] = o.box.lo[a];
      boxes.hi[0][a] = o.box.hi[a];
      boxes.lo[1][a] = then.lo[a];
      boxes.hi[1][a] = then.hi[a];
    }
    const uint32_t live[2] = {boxes.in[0], boxes.in[1]};
    // Room for every change the scan may find, made before it: a call in the scan's loop (a
    // push_back's growth) would make the compiler keep the boxes' broadcast rows on the stack.
    // At most one change per large object (the owned masks take each in one bin only), and at
    // most one per slot of the blocks visited.
    size_t bins = 1;
    for (size_t a = 0; a < kAxes; ++a) bins *= bhi[a] - blo[a] + 1;
    const size_t room =
        large_change_count_ + std::min(bins * max_bin_blocks_ * kBlockSlots, large_.size());
    if (large_changes_.size() < room) {
      large_changes_.resize(std::max(room, 2 * large_changes_.size()));
    }
    LargeChange* out = large_changes_.data() + large_change_count_;
    uint32_t blocks = 0;
    while (true) {
      uint32_t bin = 0, beyond = 0;  // beyond: the axes on which this bin is past blo
      for (size_t a = kAxes; a-- > 0;) {
        bin = bin * bins_[a] + at[a];
        beyond |= static_cast<uint32_t>(at[a] != blo[a]) << a;
      }
      for (uint32_t k = bin_begin_[bin]; k < bin_begin_[bin + 1]; ++k) {
        const LargeBlock& block = blocks_[k];
        const uint32_t own = block.owned[beyond];
        boxes.in[0] = own & (0u - live[0]);
        boxes.in[1] = own & (0u - live[1]);
        uint32_t bits[2];
        kernel(block.rows, boxes, bits);
        ++blocks;
        const uint32_t now = bits[0];
        for (uint32_t diff = now ^ bits[1]; diff != 0; diff &= diff - 1) {
          const auto i = static_cast<uint32_t>(std::countr_zero(diff));
          const uint32_t l = block.large[i];
          const Large& lg = large_[l];
          if (lg.changed || lg.handle == kNone || !tracker_.Accepts(h, lg.handle)) continue;
          *out++ = LargeChange{l, h, ((now >> i) & 1u) != 0};
        }
      }
      size_t a = 0;
      while (a < kAxes && at[a] == bhi[a]) {
        at[a] = blo[a];
        ++a;
      }
      if (a == kAxes) break;
      ++at[a];
    }
    large_change_count_ = static_cast<size_t>(out - large_changes_.data());
    // Counted as the dense cell counts: each block tested, a test per slot and box.
    tests_ += blocks * static_cast<uint32_t>(kBlockSlots) * (live[0] + live[1]);
  }

  // Applies the candidate tests' changes to the partner sets, grouped by large object (each
  // set's lines then come in once, where in the routing's order every change was a miss), and
  // witnesses them. A change for a large object that changed later in the query (or was
  // erased) is dropped: its rescan, or its erase, settles its pairs from the sets as they were.
  void ApplyLargeChanges() {
    if (large_change_count_ == 0) return;
    const std::span<const LargeChange> changes(large_changes_.data(), large_change_count_);
    std::vector<uint32_t>& begin = scratch_;
    begin.assign(large_.size() + 1, 0);
    for (const LargeChange& c : changes) ++begin[c.large + 1];
    for (size_t l = 0; l < large_.size(); ++l) begin[l + 1] += begin[l];
    sorted_changes_.resize(changes.size());
    for (const LargeChange& c : changes) sorted_changes_[begin[c.large]++] = c;
    const size_t n = sorted_changes_.size();
    for (size_t k = 0; k < n; ++k) {
      if (k + 8 < n) {  // the partner sets are large: their slots are all over the memory
        const LargeChange& ahead = sorted_changes_[k + 8];
        if (const void* line = large_[ahead.large].partners.HomeLine(ahead.h)) Prefetch(line);
      }
      const LargeChange& c = sorted_changes_[k];
      Large& lg = large_[c.large];
      if (lg.changed || lg.handle == kNone) continue;
      const bool done = c.now ? lg.partners.Insert(c.h) : lg.partners.Erase(c.h);
      BP_ASSERT(done);
      (void)done;
      Witness(c.h, lg.handle, c.now);
    }
    large_change_count_ = 0;
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
  // Calls f(bin index, bin coordinates) for each bin of a bin range, row-major.
  template <class F>
  void ForEachBin(const std::array<uint32_t, kAxes>& lo, const std::array<uint32_t, kAxes>& hi,
                  F&& f) const {
    if (lo[0] > hi[0]) return;
    std::array<uint32_t, kAxes> at = lo;
    while (true) {
      uint32_t index = 0;
      for (size_t a = kAxes; a-- > 0;) index = index * bins_[a] + at[a];
      f(index, std::as_const(at));
      size_t a = 0;
      while (a < kAxes && at[a] == hi[a]) {
        at[a] = lo[a];
        ++a;
      }
      if (a == kAxes) return;
      ++at[a];
    }
  }
  // Lays the bins over the cells in use and lists every live large object in the blocks of the
  // bins its cell range touches. The bins are 2^bin_shift_ cells wide: the finest width at which
  // there are at most kMaxBins bins and the entries fill a block per bin on average (a bin's
  // blocks are tested whole, so bins emptier than a block only cost more bins per object and more
  // memory). O(cells + large objects x widths tried + the bins the large objects touch).
  void RebuildBins() {
    bins_stale_ = false;
    bin_begin_.clear();
    blocks_.clear();
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
    std::array<uint32_t, kAxes> blo, bhi;
    const auto bin_range = [&](const Object& o) {  // BinRange, before the bins are listed
      for (size_t a = 0; a < kAxes; ++a) {
        blo[a] = BinOf(o.lo[a], a);
        bhi[a] = BinOf(o.hi[a], a);
      }
    };
    for (;; ++bin_shift_) {
      size_t total = 1;
      for (size_t a = 0; a < kAxes; ++a) {
        bin_origin_[a] = lo[a];
        bins_[a] = static_cast<uint32_t>(
            ((static_cast<uint64_t>(int64_t{hi[a]} - lo[a])) >> bin_shift_) + 1);
        total *= bins_[a];
      }
      if (total == 1) break;
      size_t entries = 0;
      for (const Large& lg : large_) {
        if (lg.handle == kNone) continue;
        bin_range(objects_[lg.handle]);
        size_t n = 1;
        for (size_t a = 0; a < kAxes; ++a) n *= bhi[a] - blo[a] + 1;
        entries += n;
      }
      if (entries >= kBlockSlots * total) break;
    }
    size_t total = 1;
    for (size_t a = 0; a < kAxes; ++a) total *= bins_[a];
    // Entries per bin, then blocks per bin (bin_begin_: prefix sums of blocks).
    std::vector<uint32_t>& count = scratch_;
    count.assign(total, 0);
    for (const Large& lg : large_) {
      if (lg.handle == kNone) continue;
      bin_range(objects_[lg.handle]);
      ForEachBin(blo, bhi, [&](uint32_t bin, const auto&) { ++count[bin]; });
    }
    bin_begin_.assign(total + 1, 0);
    max_bin_blocks_ = 0;
    for (size_t b = 0; b < total; ++b) {
      const auto bin_blocks = static_cast<uint32_t>((count[b] + kBlockSlots - 1) / kBlockSlots);
      bin_begin_[b + 1] = bin_begin_[b] + bin_blocks;
      max_bin_blocks_ = std::max(max_bin_blocks_, bin_blocks);
      count[b] = 0;  // from here: the bin's slots filled
    }
    blocks_.assign(bin_begin_[total], LargeBlock{});
    for (uint32_t l = 0; l < large_.size(); ++l) {
      const uint32_t h = large_[l].handle;
      if (h == kNone) continue;
      const BoxType& box = objects_[h].box;
      bin_range(objects_[h]);
      ForEachBin(blo, bhi, [&](uint32_t bin, const std::array<uint32_t, kAxes>& at) {
        const uint32_t slot = count[bin]++;
        LargeBlock& block = blocks_[bin_begin_[bin] + slot / kBlockSlots];
        const uint32_t i = slot % kBlockSlots;
        for (size_t a = 0; a < kAxes; ++a) {
          block.rows[2 * a * kBlockSlots + i] = box.lo[a];
          block.rows[(2 * a + 1) * kBlockSlots + i] = box.hi[a];
        }
        block.large[i] = l;
        uint32_t starts = 0;  // the axes on which l's bin range starts at this bin
        for (size_t a = 0; a < kAxes; ++a) starts |= static_cast<uint32_t>(at[a] == blo[a]) << a;
        for (uint32_t m = 0; m < kMasks; ++m) {
          if ((starts & m) == m) block.owned[m] = static_cast<uint16_t>(block.owned[m] | 1u << i);
        }
      });
    }
  }
  // Drops the whole set (a rebuild: see GridSizing::Regrid).
  void ClearLarge() {
    large_.clear();
    free_large_.clear();
    changed_large_.clear();
    large_change_count_ = 0;
    large_count_ = 0;
    bin_begin_.clear();
    blocks_.clear();
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
  // The bins (invariant 1): bin b lists its large objects in blocks_[bin_begin_[b],
  // bin_begin_[b + 1]); bins_[a] bins on axis a from cell bin_origin_[a], 2^bin_shift_ cells
  // each. No bins: bin_begin_ empty.
  // A block holds up to kBlockSlots large objects of one bin as the box-test kernels read them
  // (BlockOverlaps: 2 K rows of kBlockSlots coordinates, lo and hi per axis; the boxes as at the
  // last rebuild), their indices in large_, and owned[m]: the slots in use whose large object's
  // bin range starts at this bin on every axis in m (bit a: axis a). A small object whose bin
  // range (of the union of its ranges then and now) starts before this bin on exactly the axes
  // in m owns those slots here: of the bins the two ranges share, this is the first.
  static constexpr size_t kBlockSlots = 16;
  static constexpr uint32_t kMasks = uint32_t{1} << kAxes;
  struct alignas(64) LargeBlock {
    Coord rows[2 * kAxes * kBlockSlots];
    uint32_t large[kBlockSlots];
    uint16_t owned[kMasks];
  };
  std::vector<uint32_t> bin_begin_;
  std::vector<LargeBlock> blocks_;
  uint32_t max_bin_blocks_ = 0;                             // the most blocks of one bin
  BlockKernel block_kernel_ = ResolveBlockKernel<Coord>();  // tests may force a narrower one
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
  std::vector<uint32_t> found_, scratch_;
  // A small object's change of status with an unchanged large object, found by the candidate
  // tests, applied after the routing (ApplyLargeChanges): the first large_change_count_ of
  // large_changes_ (whose size is only room).
  struct LargeChange {
    uint32_t large, h;
    bool now;
  };
  std::vector<LargeChange> large_changes_, sorted_changes_;
  size_t large_change_count_ = 0;
};

}  // namespace bp::detail
