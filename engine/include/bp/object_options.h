// bp::ObjectOptions: the per-object attributes given at Insert that decide which pairs an engine
// tracks at all. A pair (a, b) is tracked, reported and counted iff Accepts(a, b):
//   - the 64-bit category/mask filter passes both ways (Box2D's and Bullet's rule):
//     (a.category & b.mask) != 0 && (b.category & a.mask) != 0;
//   - and not both objects are static. Static objects are never paired with each other; they
//     may still move (an update of a static object is an ordinary update).
// A refused pair is never stored, counted or reported. Where an engine tests it first (box test,
// then filter, or the other way round) is the engine's choice.
// The defaults (category 1, mask all ones, dynamic) accept every pair, so an engine whose
// objects all keep the defaults tracks exactly the overlapping pairs.
//
// Thread safety: plain value type.
#pragma once

#include <cstdint>

namespace bp {

/// Attributes fixed from an object's Insert to its Erase.
struct ObjectOptions {
  uint64_t category = 1;         ///< the groups the object belongs to
  uint64_t mask = ~uint64_t{0};  ///< the groups it may pair with
  bool is_static = false;        ///< static objects never pair with static objects

  friend bool operator==(const ObjectOptions&, const ObjectOptions&) = default;
};

/// True iff a pair of objects with these options is tracked.
inline bool Accepts(const ObjectOptions& a, const ObjectOptions& b) {
  return (a.category & b.mask) != 0 && (b.category & a.mask) != 0 && !(a.is_static && b.is_static);
}

}  // namespace bp
