// bp::detail::PairTracker: the candidate set (pairs of dense handles that overlap now) and the
// set of pairs whose status differs from the last query, from which events are drawn.
//
// Thread safety: none; owned by one engine.
// Invariants:
//  1. overlaps_ holds exactly the overlapping pairs of the current boxes (when a core is idle).
//  2. A pair is in changed_ iff its membership in overlaps_ differs from that at the last Drain.
#pragma once

#include <cstdint>
#include <vector>

#include "bp/detail/flat_set.h"

namespace bp::detail {

/// Key of an unordered handle pair: min << 32 | max.
inline uint64_t HandlePair(uint32_t a, uint32_t b) {
  return a < b ? (uint64_t{a} << 32 | b) : (uint64_t{b} << 32 | a);
}
inline uint32_t PairFirst(uint64_t p) { return static_cast<uint32_t>(p >> 32); }
inline uint32_t PairSecond(uint64_t p) { return static_cast<uint32_t>(p); }

class PairTracker {
 public:
  /// Records that a and b overlap (idempotent); true if they did not before.
  bool Add(uint32_t a, uint32_t b) {
    uint64_t p = HandlePair(a, b);
    if (!overlaps_.Insert(p)) return false;
    Toggle(p);
    return true;
  }
  /// Records that a and b do not overlap (idempotent); true if they did before.
  bool Remove(uint32_t a, uint32_t b) {
    uint64_t p = HandlePair(a, b);
    if (!overlaps_.Erase(p)) return false;
    Toggle(p);
    return true;
  }
  bool Contains(uint32_t a, uint32_t b) const { return overlaps_.Contains(HandlePair(a, b)); }

  /// Calls f(a, b, overlapping_now) for every pair changed since the last drain, then forgets
  /// them. O(toggles since the last drain): the section 3.3 bound, whatever earlier queries did.
  template <class F>
  void DrainChanges(F&& f) {
    for (uint64_t p : toggled_) {
      // A pair toggled back to its old state is no longer in changed_ (or was reported already).
      if (changed_.Erase(p, /*shrink=*/false))
        f(PairFirst(p), PairSecond(p), overlaps_.Contains(p));
    }
    changed_.ShrinkToFit(toggled_.size());
    toggled_.clear();
    if (toggled_.capacity() > 4096) toggled_.shrink_to_fit();
  }
  /// Calls f(a, b) for every overlapping pair.
  template <class F>
  void ForEachOverlap(F&& f) const {
    overlaps_.ForEach([&](uint64_t p) { f(PairFirst(p), PairSecond(p)); });
  }
  size_t overlaps() const { return overlaps_.size(); }
  size_t pending_changes() const { return changed_.size(); }
  const FlatSet<uint64_t>& overlap_set() const { return overlaps_; }

 private:
  void Toggle(uint64_t p) {
    if (!changed_.Erase(p) && changed_.Insert(p)) toggled_.push_back(p);
  }

  FlatSet<uint64_t> overlaps_;
  FlatSet<uint64_t> changed_;      // pairs whose state differs from the last drain
  std::vector<uint64_t> toggled_;  // every pair that entered changed_ since the last drain
};

}  // namespace bp::detail
