// bp::detail::FlatSet: an open-addressing hash set of unsigned integers (linear probing,
// backward-shift deletion, no tombstones), used for overlap pairs and checkpoint sets.
//
// Why not std::unordered_set: it allocates one node per element, and the pair set is the
// engine's hottest structure; the engine must not depend on anything but the standard library
// (so no boost::unordered_flat_set). Why not a sorted vector: checkpoint sets of long axes hold
// hundreds of ids and change on every boundary-crossing swap.
//
// Thread safety: none; a FlatSet is owned by one engine.
// Invariants:
//  1. Every stored value is != kEmpty (all bits set); kEmpty marks a free slot.
//  2. Capacity is 0 or a power of two, size <= capacity / 2 after any insertion, and a table
//     above kMinCapacity shrinks when it falls under capacity / 8 (so walking the table, in
//     ForEach and Clear, costs O(size + 1) amortised, not the size of some earlier burst).
//  3. Every value lies in the probe run that starts at its home slot (no gap in between).
#pragma once

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

#include "bp/detail/assert.h"
#include "bp/detail/huge_alloc.h"

namespace bp::detail {

template <class U>
class FlatSet {
  static_assert(std::is_unsigned_v<U>, "FlatSet holds unsigned integers");

 public:
  static constexpr U kEmpty = ~U{0};
  static constexpr size_t kMinCapacity = 8;

  /// Inserts v; false if it was present.
  bool Insert(U v) {
    BP_ASSERT(v != kEmpty);
    if ((size_ + 1) * 2 > slots_.size()) Rehash(slots_.empty() ? kMinCapacity : slots_.size() * 2);
    size_t i = Home(v);
    while (slots_[i] != kEmpty) {
      if (slots_[i] == v) return false;
      i = (i + 1) & mask_;
    }
    slots_[i] = v;
    ++size_;
    return true;
  }

  /// Erases v; false if it was absent. With shrink, a table that falls under capacity / 8
  /// halves (invariant 2); without, the caller restores the invariant with ShrinkToFit.
  bool Erase(U v, bool shrink = true) {
    if (size_ == 0) return false;
    size_t i = Home(v);
    while (slots_[i] != v) {
      if (slots_[i] == kEmpty) return false;
      i = (i + 1) & mask_;
    }
    // Backward-shift deletion keeps invariant 3 without tombstones.
    size_t hole = i;
    size_t j = i;
    for (;;) {
      j = (j + 1) & mask_;
      if (slots_[j] == kEmpty) break;
      size_t home = Home(slots_[j]);
      // Move slots_[j] into the hole unless its home lies cyclically in (hole, j].
      bool home_in_range = hole <= j ? (hole < home && home <= j) : (hole < home || home <= j);
      if (!home_in_range) {
        slots_[hole] = slots_[j];
        hole = j;
      }
    }
    slots_[hole] = kEmpty;
    --size_;
    if (shrink && slots_.size() > kMinCapacity && size_ * 8 < slots_.size()) {
      Rehash(slots_.size() / 2);
    }
    return true;
  }

  /// Where v's probe run starts (nullptr for an empty set), for the caller to prefetch before a
  /// look-up soon after (a member that prefetched itself would be deleted by GCC 12 as pure).
  const void* HomeLine(U v) const { return size_ == 0 ? nullptr : &slots_[Home(v)]; }

  /// True if v is present.
  bool Contains(U v) const {
    if (size_ == 0) return false;
    size_t i = Home(v);
    while (slots_[i] != kEmpty) {
      if (slots_[i] == v) return true;
      i = (i + 1) & mask_;
    }
    return false;
  }

  /// Calls f(v) for every element, in slot order.
  template <class F>
  void ForEach(F&& f) const {
    if (size_ == 0) return;
    for (U v : slots_) {
      if (v != kEmpty) f(v);
    }
  }

  /// Removes every element; keeps a small allocation.
  void Clear() {
    if (size_ == 0) return;
    if (slots_.size() > kMinCapacity) {
      slots_.assign(kMinCapacity, kEmpty);
      SetCapacity(kMinCapacity);
    } else {
      std::fill(slots_.begin(), slots_.end(), kEmpty);
    }
    size_ = 0;
  }

  /// Shrinks the table when it is more than 8 times what max(size, expected) needs, so that a
  /// set that is emptied and refilled every frame keeps its allocation unless a burst left it
  /// oversized.
  void ShrinkToFit(size_t expected) {
    size_t need = std::max(size_, expected) + 1;
    if (slots_.size() > kMinCapacity && slots_.size() > 8 * need) {
      Rehash(std::max(kMinCapacity, std::bit_ceil(2 * need)));
    }
  }

  /// Slots allocated (for tests of invariant 2).
  size_t capacity() const { return slots_.size(); }

  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }

 private:
  size_t Home(U v) const {
    // Fibonacci hashing: the high bits of a 64-bit multiply spread sequential ids and pair keys.
    uint64_t h = static_cast<uint64_t>(v) * 0x9E3779B97F4A7C15ULL;
    return static_cast<size_t>(h >> shift_);
  }

  void SetCapacity(size_t cap) {
    mask_ = cap - 1;
    shift_ = 64 - std::countr_zero(cap);
  }

  void Rehash(size_t cap) {
    HugeVector<U> old(cap, kEmpty);
    old.swap(slots_);
    SetCapacity(cap);
    size_ = 0;
    for (U v : old) {
      if (v == kEmpty) continue;
      size_t i = Home(v);
      while (slots_[i] != kEmpty) i = (i + 1) & mask_;
      slots_[i] = v;
      ++size_;
    }
  }

  HugeVector<U> slots_;
  size_t mask_ = 0;
  int shift_ = 64;
  size_t size_ = 0;
};

}  // namespace bp::detail
