// bp::BatchSap: one sweep-and-prune instance with batch insertion and removal (Tracy, Buss and
// Woods, IEEE VR 2009, section 3.2.1, Table 2, Figures 5 and 6) and event output (section 3.3).
//
// Per axis the sorted extrema are one array that "floats" inside a larger allocation. Inserts and
// erases are buffered until the query; then, per axis, the insertion records I (sorted) and the
// removal records R (positions of the erased extrema, sorted) are integrated in one pass over
// the list L that also insertion-sorts the moved extrema: the new list replaces the old one in
// the same allocation, written ahead of the read position. A forward pass needs a gap of at
// least |I| in front of the list and closes it; otherwise a backward pass writes towards the end
// of the allocation (grown when the gap behind is too small too), which leaves a gap in front
// for the next forward pass. Cost O(k (m log m + n)) for m records and n extrema.
//
// The candidate set: while passing, three sweep sets hold the objects whose interval is open at
// the read position: S_L (retained), S_I (inserted) and S_R (erased). An object is added when
// its first extremum in pass order is read and removed at its second, where it is checked:
//  - on the first axis, an erased object's pairs with S_L and S_R are removed, and a retained
//    object's pairs with S_R are removed (erasures uncollide on the first axis);
//  - on the last axis, an inserted object is tested against S_L and S_I, and a retained object
//    against S_I (insertions collide on the last axis);
//  - every swap of the insertion sort is handled as in incremental sweep and prune (a min
//    passing a max tests the full boxes, a max passing a min separates them), including swaps
//    of moved extrema with inserted ones.
// Why this is exact: pass order is the old list order with the insertion records merged in, so
// two objects whose intervals overlap in pass order meet in the sets, and two whose order
// changes swap exactly once. Every addition tests the new boxes; every removal follows an
// erasure or a separation in the new order; pairs with an erased object were all formed in the
// old order. The differential suite checks it against the oracle.
//
// With no insert or erase pending and few moved objects (at most global_sort_fraction of the
// live ones), a query re-sorts per moved object instead (local sort, paper section 4).
//
// Thread safety: none (see bp/broadphase.h).
// Invariants (checked by Validate):
//  1. Every axis list buf[begin, end) is sorted by (value, min before max at equal value) and
//     holds the two extrema of every live object, with the object's current coordinates.
//  2. pos[ref] is the index of extremum ref in buf.
//  3. The tracker's overlap set equals the overlapping pairs of the live boxes.
#pragma once

#include <algorithm>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/front_end.h"
#include "bp/detail/pair_tracker.h"
#include "bp/detail/sweep.h"

namespace bp {

/// Tuning of BatchSap.
struct BatchSapOptions {
  /// A query with no insert or erase pending re-sorts globally (one pass per axis) when the
  /// moved objects exceed this fraction of the live ones, and per moved object otherwise. Any
  /// pending insert or erase makes the query one global pass (paper, section 4). Measured with
  /// `bpbench --threshold-sweep --engine batch_sap` (docs/TUNING.md).
  double global_sort_fraction = 0.07;
};

namespace detail {

template <int K, Coordinate T>
class BatchSapCore {
 public:
  static constexpr int kDim = K;
  static constexpr size_t kAxes = static_cast<size_t>(K);
  using Coord = T;
  static constexpr const char* kName = "batch_sap";
  static constexpr const char* kGridName = "grid_batch_sap";  // as the cell of bp::Grid
  // Indices are 32 bits. After a query the allocation holds at most 4 x its list + 4096 slots
  // (compaction), during one at most that plus 2 x the insertion records: below 2^32 here.
  static constexpr size_t kMaxHandles = size_t{1} << 28;
  using Options = BatchSapOptions;

  explicit BatchSapCore(const Options& options = Options()) : options_(options) {}

  void Apply(std::span<const uint32_t> erases, std::span<const HandleBox<K, T>> updates,
             std::span<const HandleBox<K, T>> inserts) {
    swaps_ = 0;
    tests_ = 0;
    global_ = !erases.empty() || !inserts.empty() ||
              (!updates.empty() && static_cast<double>(updates.size()) >
                                       options_.global_sort_fraction * static_cast<double>(live_));
    if (!global_) {
      for (const auto& [h, box] : updates) LocalUpdate(h, box);
      return;
    }
    for (const auto& [h, box] : inserts) {
      Reserve(h);
      BP_ASSERT(state_[h] == kDead);
      boxes_[h] = box;
      state_[h] = kInserting;
    }
    for (uint32_t h : erases) {
      BP_ASSERT(h < state_.size() && state_[h] == kLive);
      state_[h] = kErasing;
    }
    for (const auto& [h, box] : updates) {
      boxes_[h] = box;
      for (size_t a = 0; a < kAxes; ++a) {
        Axis& ax = axes_[a];
        ax.buf[ax.pos[2 * h]].value = box.lo[a];
        ax.buf[ax.pos[2 * h + 1]].value = box.hi[a];
      }
    }
    for (size_t a = 0; a < kAxes; ++a) {
      Axis& ax = axes_[a];
      removals_.clear();
      for (uint32_t h : erases) {
        removals_.push_back(ax.pos[2 * h]);
        removals_.push_back(ax.pos[2 * h + 1]);
      }
      std::sort(removals_.begin(), removals_.end());
      insertions_.clear();
      for (const auto& [h, box] : inserts) {
        insertions_.push_back(Ext{box.lo[a], 2 * h});
        insertions_.push_back(Ext{box.hi[a], 2 * h + 1});
      }
      // Ties broken by ref, so the layout does not depend on the sort algorithm.
      std::sort(insertions_.begin(), insertions_.end(), [](const Ext& x, const Ext& y) {
        return Less(x, y) || (!Less(y, x) && x.ref < y.ref);
      });
      IntegrateAxis(a);
    }
    for (uint32_t h : erases) state_[h] = kDead;
    for (const auto& [h, box] : inserts) state_[h] = kLive;
    live_ = live_ + inserts.size() - erases.size();
  }

  PairTracker& tracker() { return tracker_; }
  const PairTracker& tracker() const { return tracker_; }
  size_t live() const { return live_; }
  /// The box of live handle h as of the last Apply (the spot query's, see Broadphase).
  const Box<K, T>& box(uint32_t h) const { return boxes_[h]; }

  void FillStats(Stats* out) const {
    out->swaps = swaps_;
    out->overlap_tests = tests_;
    out->global_sort = global_;
    out->rebuilt = false;
  }

  Status Validate() const;

  const Options& options() const { return options_; }

  /// The floating array of one axis, for white-box tests and statistics.
  struct Layout {
    size_t begin = 0;     ///< index of the first extremum in the allocation
    size_t end = 0;       ///< one past the last extremum
    size_t capacity = 0;  ///< slots of the allocation
  };
  Layout layout(size_t axis) const {
    const Axis& ax = axes_[axis];
    return Layout{ax.begin, ax.end, ax.buf.size()};
  }
  /// Passes since construction, over all axes: forward, backward, and backward after growing.
  size_t forward_passes() const { return forward_passes_; }
  size_t backward_passes() const { return backward_passes_; }
  size_t growths() const { return growths_; }
  /// White-box tests corrupt internals through this peer to prove Validate() notices.
  friend struct BatchSapTestPeer;

 private:
  struct Ext {
    T value;
    uint32_t ref;  // handle << 1 | is_max
  };
  struct Axis {
    std::vector<Ext> buf;  // the allocation; the list is buf[begin, end)
    uint32_t begin = 0;
    uint32_t end = 0;
    std::vector<uint32_t> pos;  // pos[ref]: index of extremum ref in buf
  };
  enum State : uint8_t { kDead, kLive, kInserting, kErasing };

  static bool Less(const Ext& a, const Ext& b) {
    return a.value < b.value || (a.value == b.value && (a.ref & 1u) < (b.ref & 1u));
  }
  static bool IsMax(uint32_t ref) { return (ref & 1u) != 0; }
  static uint32_t HandleOf(uint32_t ref) { return ref >> 1; }

  void Reserve(uint32_t h) {
    if (h < boxes_.size()) return;
    boxes_.resize(h + 1);
    state_.resize(h + 1, kDead);
    slot_.resize(h + 1, 0);
    for (Axis& ax : axes_) ax.pos.resize(2 * (static_cast<size_t>(h) + 1));
  }

  // Extremum x moved right past y (adjacent): the incremental sweep-and-prune update.
  void Crossed(uint32_t xref, uint32_t yref) {
    ++swaps_;
    uint32_t hx = HandleOf(xref);
    uint32_t hy = HandleOf(yref);
    if (hx == hy) return;
    if (IsMax(xref) && !IsMax(yref)) {
      TestAdd(hx, hy);
    } else if (!IsMax(xref) && IsMax(yref)) {
      tracker_.Remove(hx, hy);
    }
  }
  void TestAdd(uint32_t a, uint32_t b) {
    ++tests_;
    if (Overlaps(boxes_[a], boxes_[b])) tracker_.Add(a, b);  // Add applies the filter
  }

  // ---- sweep sets: a handle is in at most one at a time; slot_ is its index there ----
  void SetAdd(std::vector<uint32_t>& s, uint32_t h) {
    slot_[h] = static_cast<uint32_t>(s.size());
    s.push_back(h);
  }
  void SetRemove(std::vector<uint32_t>& s, uint32_t h) {
    uint32_t i = slot_[h];
    BP_ASSERT(i < s.size() && s[i] == h);
    uint32_t last = s.back();
    s[i] = last;
    slot_[last] = i;
    s.pop_back();
  }

  // ---- local sort (no records pending) ----
  void SortExtremum(Axis& ax, uint32_t p) {
    Ext* L = ax.buf.data();
    const Ext e = L[p];
    uint32_t start = p;
    while (p > ax.begin && Less(e, L[p - 1])) {
      L[p] = L[p - 1];
      ax.pos[L[p].ref] = p;
      Crossed(L[p].ref, e.ref);
      --p;
    }
    if (p == start) {
      while (p + 1 < ax.end && Less(L[p + 1], e)) {
        L[p] = L[p + 1];
        ax.pos[L[p].ref] = p;
        Crossed(e.ref, L[p].ref);
        ++p;
      }
      if (p == start) return;
    }
    L[p] = e;
    ax.pos[e.ref] = p;
  }
  void LocalUpdate(uint32_t h, const Box<K, T>& box) {
    boxes_[h] = box;
    for (size_t a = 0; a < kAxes; ++a) {
      Axis& ax = axes_[a];
      uint32_t p = ax.pos[2 * h];
      ax.buf[p].value = box.lo[a];
      SortExtremum(ax, p);
      p = ax.pos[2 * h + 1];
      ax.buf[p].value = box.hi[a];
      SortExtremum(ax, p);
    }
  }

  // ---- the batch pass ----
  // Chooses the direction (Figures 5 and 6), grows the allocation if neither gap fits the
  // insertions, and runs the pass over axis a with removals_ and insertions_.
  void IntegrateAxis(size_t a) {
    Axis& ax = axes_[a];
    size_t m = insertions_.size();
    size_t n_after = ax.end - ax.begin - removals_.size() + m;
    if (ax.begin >= m) {
      ++forward_passes_;
      Pass<true>(a, ax.begin - static_cast<uint32_t>(m));
    } else {
      if (ax.buf.size() - ax.end < m) {
        // Room for this pass behind the list, and a gap in front afterwards for the next one.
        ++growths_;
        ax.buf.reserve(ax.end + 2 * m);  // exactly: capacity is what the compaction rule sees
        ax.buf.resize(ax.end + 2 * m);
      }
      ++backward_passes_;
      Pass<false>(a, static_cast<uint32_t>(ax.buf.size()));
    }
    BP_ASSERT(ax.end - ax.begin == n_after);
    // A burst of erasures must not pin its memory: compact a mostly empty allocation.
    if (ax.buf.size() > 4 * n_after + 4096) Compact(ax);
  }

  void Compact(Axis& ax) {
    std::vector<Ext> buf(ax.buf.begin() + ax.begin, ax.buf.begin() + ax.end);
    for (uint32_t i = 0; i < buf.size(); ++i) ax.pos[buf[i].ref] = i;
    ax.buf = std::move(buf);
    ax.end -= ax.begin;
    ax.begin = 0;
  }

  // One pass over axis a in direction kFwd (forward: ascending, writing from `out` upwards;
  // backward: descending, writing from `out` - 1 downwards). Writes never overtake reads: the
  // written count exceeds the read count by at most |I|, which the gap absorbs.
  template <bool kFwd>
  void Pass(size_t a, uint32_t out) {
    Axis& ax = axes_[a];
    Ext* L = ax.buf.data();
    uint32_t* pos = ax.pos.data();
    const std::vector<uint32_t>& R = removals_;
    const std::vector<Ext>& I = insertions_;
    const bool removing = a == 0 && !R.empty();
    const bool inserting = a + 1 == kAxes && !I.empty();
    const bool sweeping = removing || inserting;
    // In pass order: "before", the extremum that opens an interval, and the index steps.
    auto before = [](const Ext& x, const Ext& y) { return kFwd ? Less(x, y) : Less(y, x); };
    auto opens = [](uint32_t ref) { return kFwd ? !IsMax(ref) : IsMax(ref); };
    constexpr int64_t kStep = kFwd ? 1 : -1;
    int64_t from = kFwd ? ax.begin : int64_t{ax.end} - 1;
    const int64_t stop = kFwd ? int64_t{ax.end} : int64_t{ax.begin} - 1;
    const int64_t first_out = kFwd ? int64_t{out} : int64_t{out} - 1;
    int64_t to = first_out;
    size_t ri = 0, ii = 0;
    auto r_at = [&](size_t i) { return int64_t{R[kFwd ? i : R.size() - 1 - i]}; };
    auto i_at = [&](size_t i) -> const Ext& { return I[kFwd ? i : I.size() - 1 - i]; };
    s_l_.clear();
    s_i_.clear();
    s_r_.clear();

    for (;;) {
      if (ri < R.size() && from == r_at(ri)) {
        // An erased extremum: dropped from the list; on the first axis its pairs go.
        uint32_t ref = L[from].ref;
        from += kStep;
        ++ri;
        if (!removing) continue;
        uint32_t h = HandleOf(ref);
        if (opens(ref)) {
          SetAdd(s_r_, h);
        } else {
          SetRemove(s_r_, h);
          for (uint32_t x : s_l_) tracker_.Remove(h, x);
          for (uint32_t x : s_r_) tracker_.Remove(h, x);
        }
        continue;
      }
      bool take_i;
      if (ii < I.size()) {
        take_i = from == stop || before(i_at(ii), L[from]);
      } else if (from != stop) {
        take_i = false;
      } else {
        break;
      }
      Ext e;
      int64_t src = -1;
      if (take_i) {
        e = i_at(ii++);
      } else {
        src = from;
        e = L[from];
        from += kStep;
      }
      if (sweeping) {
        uint32_t h = HandleOf(e.ref);
        if (take_i) {
          if (inserting) {
            if (opens(e.ref)) {
              SetAdd(s_i_, h);
            } else {
              SetRemove(s_i_, h);
              for (uint32_t x : s_l_) TestAdd(h, x);
              for (uint32_t x : s_i_) TestAdd(h, x);
            }
          }
        } else if (opens(e.ref)) {
          SetAdd(s_l_, h);
        } else {
          SetRemove(s_l_, h);
          if (removing) {
            for (uint32_t x : s_r_) tracker_.Remove(h, x);
          }
          if (inserting) {
            for (uint32_t x : s_i_) TestAdd(h, x);
          }
        }
      }
      // Insertion sort into the written part.
      int64_t p = to;
      to += kStep;
      while (p != first_out && before(e, L[p - kStep])) {
        const Ext y = L[p - kStep];
        L[p] = y;
        pos[y.ref] = static_cast<uint32_t>(p);
        if constexpr (kFwd) {
          Crossed(y.ref, e.ref);
        } else {
          Crossed(e.ref, y.ref);
        }
        p -= kStep;
      }
      if (p != src) {
        L[p] = e;
        pos[e.ref] = static_cast<uint32_t>(p);
      }
    }
    BP_ASSERT(s_l_.empty() && s_i_.empty() && s_r_.empty());
    if constexpr (kFwd) {
      ax.begin = out;
      ax.end = static_cast<uint32_t>(to);
    } else {
      ax.begin = static_cast<uint32_t>(to + 1);
      ax.end = out;
    }
  }

  Options options_;
  Axis axes_[kAxes];
  std::vector<Box<K, T>> boxes_;
  std::vector<uint8_t> state_;  // State by handle
  std::vector<uint32_t> slot_;  // index in the sweep set holding the handle
  size_t live_ = 0;
  PairTracker tracker_;
  // Per-pass scratch, kept to reuse the allocations.
  std::vector<uint32_t> removals_;
  std::vector<Ext> insertions_;
  std::vector<uint32_t> s_l_, s_i_, s_r_;
  size_t swaps_ = 0;
  size_t tests_ = 0;
  bool global_ = false;
  size_t forward_passes_ = 0;
  size_t backward_passes_ = 0;
  size_t growths_ = 0;
};

template <int K, Coordinate T>
Status BatchSapCore<K, T>::Validate() const {
  auto fail = [](size_t axis, const std::string& what) {
    return Status(StatusCode::kInternal, "batch_sap: axis " + std::to_string(axis) + ": " + what);
  };
  std::vector<uint32_t> live;
  for (uint32_t h = 0; h < state_.size(); ++h) {
    if (state_[h] == kLive) {
      live.push_back(h);
    } else if (state_[h] != kDead) {
      return Status(StatusCode::kInternal, "batch_sap: a record left pending after a query");
    }
  }
  if (live.size() != live_) return Status(StatusCode::kInternal, "batch_sap: live count differs");
  for (size_t a = 0; a < kAxes; ++a) {
    const Axis& ax = axes_[a];
    if (ax.begin > ax.end || ax.end > ax.buf.size()) return fail(a, "list outside its allocation");
    if (ax.end - ax.begin != 2 * live_) return fail(a, "list length is not twice the objects");
    for (uint32_t i = ax.begin; i + 1 < ax.end; ++i) {
      if (Less(ax.buf[i + 1], ax.buf[i])) return fail(a, "unsorted at " + std::to_string(i));
    }
    for (uint32_t i = ax.begin; i < ax.end; ++i) {
      uint32_t ref = ax.buf[i].ref;
      if (ref >= ax.pos.size() || ax.pos[ref] != i) return fail(a, "pos points astray");
      uint32_t h = HandleOf(ref);
      if (h >= state_.size() || state_[h] != kLive) return fail(a, "extremum of a dead object");
      T want = IsMax(ref) ? boxes_[h].hi[a] : boxes_[h].lo[a];
      if (!(ax.buf[i].value == want)) return fail(a, "stale coordinate");
    }
  }
  return CheckOverlapSet(boxes_, std::move(live), tracker_, kName);
}

}  // namespace detail

/// Sweep and prune with batch insertion and removal, behind the common interface.
template <int K, Coordinate T, class Key = uint64_t>
using BatchSap = detail::FrontEnd<detail::BatchSapCore<K, T>, Key>;

}  // namespace bp
