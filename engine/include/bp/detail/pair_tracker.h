// bp::detail::PairTracker: the candidate set (pairs of dense handles that overlap now) and the
// set of pairs whose status differs from the last query, from which events are drawn. It also
// keeps each handle's ObjectOptions once any object has non-default ones: Add refuses the pairs
// that fail Accepts, so filtered pairs never enter any set. The cores test the boxes first: in
// their hot paths the box test usually fails, and it reads memory they touch anyway.
//
// Thread safety: none; owned by one engine.
// Invariants:
//  1. overlaps_ holds exactly the overlapping pairs of the current boxes (when a core is idle).
//  2. A pair is in changed_ iff its membership in overlaps_ differs from that at the last Drain.
//  3. Every pair in overlaps_ passes Accepts.
//  4. Every pair in changed_ has an entry in toggled_; its first entry there since the last
//     Drain records the direction of the pair's first toggle since then.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "bp/detail/flat_set.h"
#include "bp/object_options.h"

namespace bp::detail {

/// Key of an unordered handle pair: min << 32 | max.
inline uint64_t HandlePair(uint32_t a, uint32_t b) {
  return a < b ? (uint64_t{a} << 32 | b) : (uint64_t{b} << 32 | a);
}
inline uint32_t PairFirst(uint64_t p) { return static_cast<uint32_t>(p >> 32); }
inline uint32_t PairSecond(uint64_t p) { return static_cast<uint32_t>(p); }

/// Each handle's ObjectOptions, stored only once some handle has non-default ones (until then a
/// look-up costs a branch). Shared by PairTracker and the grid's dense cell.
class OptionsTable {
 public:
  /// Sets the options of handle h (before any of its pairs is formed).
  void Set(uint32_t h, const ObjectOptions& options) {
    if (!filtering_) {
      if (options == ObjectOptions{}) return;
      filtering_ = true;
    }
    if (h >= options_.size()) options_.resize(size_t{h} + 1);
    options_[h] = options;
  }
  /// The options of handle h.
  const ObjectOptions& Get(uint32_t h) const {
    static const ObjectOptions kDefault;
    return h < options_.size() ? options_[h] : kDefault;
  }
  /// True iff some handle has had non-default options (then Set must see every insert).
  bool filtering() const { return filtering_; }
  /// True iff the pair (a, b) may be tracked (see bp/object_options.h).
  bool Accepts(uint32_t a, uint32_t b) const { return !filtering_ || bp::Accepts(Get(a), Get(b)); }

 private:
  std::vector<ObjectOptions> options_;  // by handle; empty while filtering_ is false
  bool filtering_ = false;
};

class PairTracker {
 public:
  /// Records that a and b overlap (idempotent); true if they did not before. A pair that fails
  /// Accepts is not recorded (false).
  bool Add(uint32_t a, uint32_t b) {
    if (!Accepts(a, b)) return false;
    uint64_t p = HandlePair(a, b);
    if (!overlaps_.Insert(p)) return false;
    Toggle(p, true);
    return true;
  }
  /// Records that a and b do not overlap (idempotent); true if they did before.
  bool Remove(uint32_t a, uint32_t b) {
    uint64_t p = HandlePair(a, b);
    if (!overlaps_.Erase(p)) return false;
    Toggle(p, false);
    return true;
  }
  bool Contains(uint32_t a, uint32_t b) const { return overlaps_.Contains(HandlePair(a, b)); }

  /// Sets the options of handle h (before any of its pairs is added). Default options cost
  /// nothing until some handle has non-default ones.
  void SetOptions(uint32_t h, const ObjectOptions& options) { options_.Set(h, options); }
  /// The options of handle h.
  const ObjectOptions& options(uint32_t h) const { return options_.Get(h); }
  /// True iff some handle has had non-default options (then SetOptions must see every insert).
  bool filtering() const { return options_.filtering(); }
  /// True iff the pair (a, b) may be tracked (see bp/object_options.h).
  bool Accepts(uint32_t a, uint32_t b) const { return options_.Accepts(a, b); }

  /// Calls f(a, b, overlapping_now) for every pair changed since the last drain, then forgets
  /// them. O(toggles since the last drain): the section 3.3 bound, whatever earlier queries did.
  /// A pair is in changed_ iff it toggled an odd number of times since the last drain, and its
  /// first entry in toggled_ is that of its first toggle: toggles alternate (Add only when it
  /// was absent, Remove only when present), so the first's direction is the state now, and
  /// overlaps_ need not be probed. changed_'s lines are prefetched ahead (pairs come in toggle
  /// order, all over the table).
  template <class F>
  void DrainChanges(F&& f) {
    const size_t n = toggled_.size();
    for (size_t i = 0; i < n; ++i) {
      if (i + kDrainAhead < n)
        __builtin_prefetch(changed_.HomeLine(toggled_[i + kDrainAhead].pair));
      const Toggled& t = toggled_[i];
      // A pair toggled back to its old state is no longer in changed_ (or was reported already).
      if (changed_.Erase(t.pair, /*shrink=*/false)) f(PairFirst(t.pair), PairSecond(t.pair), t.now);
    }
    changed_.ShrinkToFit(n);
    toggled_.clear();
    // Memory held after a burst is given back; a steady rate of toggles keeps its buffer.
    if (toggled_.capacity() > std::max<size_t>(4096, 4 * n)) toggled_.shrink_to_fit();
  }
  /// Calls f(a, b) for every overlapping pair.
  template <class F>
  void ForEachOverlap(F&& f) const {
    overlaps_.ForEach([&](uint64_t p) { f(PairFirst(p), PairSecond(p)); });
  }
  /// Where Add or Remove of pair p starts probing the overlap set and the changed set (nullptr
  /// when empty), for the caller to prefetch a few pairs ahead.
  const void* OverlapLine(uint64_t p) const { return overlaps_.HomeLine(p); }
  const void* ChangedLine(uint64_t p) const { return changed_.HomeLine(p); }
  size_t overlaps() const { return overlaps_.size(); }
  size_t pending_changes() const { return changed_.size(); }
  const FlatSet<uint64_t>& overlap_set() const { return overlaps_; }

 private:
  struct Toggled {
    uint64_t pair;
    bool now;  // overlapping after this toggle
  };
  static constexpr size_t kDrainAhead = 16;

  void Toggle(uint64_t p, bool now) {
    if (!changed_.Erase(p) && changed_.Insert(p)) toggled_.push_back(Toggled{p, now});
  }

  FlatSet<uint64_t> overlaps_;
  OptionsTable options_;
  FlatSet<uint64_t> changed_;     // pairs whose state differs from the last drain
  std::vector<Toggled> toggled_;  // every entry of a pair into changed_ since the last drain
};

}  // namespace bp::detail
