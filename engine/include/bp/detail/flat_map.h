// bp::detail::FlatMap: an open-addressing hash map from unsigned integers to small trivially
// copyable values (linear probing, backward-shift deletion, no tombstones). The grid keys its
// cells by packed integer coordinates and keeps the witness counts of pairs seen by more than
// one cell with it.
//
// Why not std::unordered_map: one node per element, and both maps are touched per migration or
// per multi-cell pair; the engine depends on the standard library only (see FlatSet).
//
// Thread safety: none; owned by one engine.
// Invariants:
//  1. Every stored key is != kEmpty (all bits set); kEmpty marks a free slot.
//  2. Capacity is 0 or a power of two and size <= capacity / 2; a table above kMinCapacity
//     shrinks when it falls under capacity / 8.
//  3. Every key lies in the probe run that starts at its home slot.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

#include "bp/detail/assert.h"
#include "bp/detail/huge_alloc.h"

namespace bp::detail {

template <class U, class V>
class FlatMap {
  static_assert(std::is_unsigned_v<U>, "FlatMap keys are unsigned integers");
  static_assert(std::is_trivially_copyable_v<V>, "FlatMap values are plain values");

 public:
  static constexpr U kEmpty = ~U{0};
  static constexpr size_t kMinCapacity = 8;

  /// The value of key, or nullptr.
  V* Find(U key) {
    if (size_ == 0) return nullptr;
    for (size_t i = Home(key);; i = (i + 1) & mask_) {
      if (slots_[i].key == key) return &slots_[i].value;
      if (slots_[i].key == kEmpty) return nullptr;
    }
  }
  const V* Find(U key) const { return const_cast<FlatMap*>(this)->Find(key); }

  /// Where key's probe run starts (nullptr for an empty map), for the caller to prefetch before
  /// a look-up soon after (a member that prefetched itself would be deleted by GCC 12 as pure).
  const void* HomeLine(U key) const { return size_ == 0 ? nullptr : &slots_[Home(key)]; }

  /// The value of key, inserted as `init` if absent; *out_inserted tells which.
  V& FindOrInsert(U key, V init, bool* out_inserted = nullptr) {
    BP_ASSERT(key != kEmpty);
    if ((size_ + 1) * 2 > slots_.size()) Rehash(slots_.empty() ? kMinCapacity : slots_.size() * 2);
    size_t i = Home(key);
    while (slots_[i].key != kEmpty) {
      if (slots_[i].key == key) {
        if (out_inserted != nullptr) *out_inserted = false;
        return slots_[i].value;
      }
      i = (i + 1) & mask_;
    }
    slots_[i] = {key, init};
    ++size_;
    if (out_inserted != nullptr) *out_inserted = true;
    return slots_[i].value;
  }

  /// Erases key; false if it was absent.
  bool Erase(U key) {
    if (size_ == 0) return false;
    size_t i = Home(key);
    while (slots_[i].key != key) {
      if (slots_[i].key == kEmpty) return false;
      i = (i + 1) & mask_;
    }
    size_t hole = i;
    for (size_t j = (i + 1) & mask_; slots_[j].key != kEmpty; j = (j + 1) & mask_) {
      size_t home = Home(slots_[j].key);
      bool home_in_range = hole <= j ? (hole < home && home <= j) : (hole < home || home <= j);
      if (!home_in_range) {
        slots_[hole] = slots_[j];
        hole = j;
      }
    }
    slots_[hole].key = kEmpty;
    --size_;
    if (slots_.size() > kMinCapacity && size_ * 8 < slots_.size()) Rehash(slots_.size() / 2);
    return true;
  }

  /// Calls f(key, value) for every entry, in slot order.
  template <class F>
  void ForEach(F&& f) const {
    if (size_ == 0) return;
    for (const Slot& s : slots_) {
      if (s.key != kEmpty) f(s.key, s.value);
    }
  }

  void Clear() {
    slots_.clear();
    SetCapacity(0);
    size_ = 0;
  }
  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }

 private:
  struct Slot {
    U key;
    V value;
  };

  size_t Home(U key) const {
    uint64_t h = static_cast<uint64_t>(key) * 0x9E3779B97F4A7C15ULL;
    return static_cast<size_t>(h >> shift_);
  }
  void SetCapacity(size_t cap) {
    mask_ = cap == 0 ? 0 : cap - 1;
    shift_ = cap == 0 ? 63 : 64 - std::countr_zero(cap);
  }
  void Rehash(size_t cap) {
    HugeVector<Slot> old(cap, Slot{kEmpty, V{}});
    old.swap(slots_);
    SetCapacity(cap);
    for (const Slot& s : old) {
      if (s.key == kEmpty) continue;
      size_t i = Home(s.key);
      while (slots_[i].key != kEmpty) i = (i + 1) & mask_;
      slots_[i] = s;
    }
  }

  HugeVector<Slot> slots_;
  size_t mask_ = 0;
  int shift_ = 63;
  size_t size_ = 0;
};

}  // namespace bp::detail
