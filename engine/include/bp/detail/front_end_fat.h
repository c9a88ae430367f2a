// bp::detail::FatBoxes: the front end's fattened boxes (margin > 0). The core sees, per object,
// a fat box: the box grown by margin on every side. An update whose box still lies inside the
// fat box, and whose fat box is not more than 4 margins wider than the box on any side, does not
// reach the core (FatEnough); otherwise the fat box is recomputed (Keep). Events and overlaps
// are then those of the fat boxes: no overlapping pair is missed, and every reported pair's
// boxes lie within 8 margins of each other on every axis. With margin 0 (or negative, or NaN)
// boxes are exact and nothing is kept.
//
// Thread safety: none.
// Invariants (checked by FrontEnd::Validate):
//  1. With a margin, fat_[h] (what the core holds, or is about to) contains the client's last
//     box of handle h, and fat_ has one entry per handle.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <type_traits>

#include "bp/box.h"
#include "bp/detail/huge_alloc.h"

namespace bp::detail {

template <int K, Coordinate T>
class FatBoxes {
 protected:
  using BoxType = Box<K, T>;

  explicit FatBoxes(T margin) : margin_(margin > T{} ? margin : T{}) {}

  // The box the core is to get for h's new box: box itself, or with a margin its fat box, kept
  // in fat_.
  const BoxType& Keep(uint32_t h, const BoxType& box) {
    if (margin_ > T{}) {
      fat_[h] = Grow(box, margin_);
      return fat_[h];
    }
    return box;
  }

  // Grows box by m on every side, saturating at the limits of T (m >= 0).
  static BoxType Grow(const BoxType& box, T m) {
    constexpr T kLowest = std::numeric_limits<T>::lowest();
    constexpr T kMax = std::numeric_limits<T>::max();
    BoxType out = box;
    for (size_t i = 0; i < static_cast<size_t>(K); ++i) {
      if constexpr (std::is_floating_point_v<T>) {
        out.lo[i] = std::max(box.lo[i] - m, kLowest);  // -inf becomes lowest
        out.hi[i] = std::min(box.hi[i] + m, kMax);
      } else {
        out.lo[i] = box.lo[i] < kLowest + m ? kLowest : static_cast<T>(box.lo[i] - m);
        out.hi[i] = box.hi[i] > kMax - m ? kMax : static_cast<T>(box.hi[i] + m);
      }
    }
    return out;
  }
  static bool Contains(const BoxType& outer, const BoxType& inner) {
    for (size_t i = 0; i < static_cast<size_t>(K); ++i) {
      if (inner.lo[i] < outer.lo[i] || outer.hi[i] < inner.hi[i]) return false;
    }
    return true;
  }
  // True iff fat may stay the fat box of box: it contains box and is not too loose.
  bool FatEnough(const BoxType& fat, const BoxType& box) const {
    return Contains(fat, box) && Contains(Grow(box, loose_), fat);
  }
  static T LooseLimit(T margin) {
    constexpr T kMax = std::numeric_limits<T>::max();
    return margin > kMax / 4 ? kMax : static_cast<T>(margin * 4);
  }

  T margin_;
  T loose_ = LooseLimit(margin_);
  size_t fat_skips_ = 0;  // updates absorbed by fat boxes since the last query
  size_t last_fat_skips_ = 0;
  HugeVector<BoxType> fat_;  // with a margin: each handle's fat box (invariant 1)
};

}  // namespace bp::detail
