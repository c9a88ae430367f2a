// bp::detail::KeyIndex: the front end's map from client keys to dense handles, an open-addressing
// table of handles (linear probing, backward-shift deletion, no tombstones). The keys themselves
// stay in the caller's slots: an entry is a handle and 32 bits of the key's hash, and a probe
// compares the key (through the caller's key_of(handle)) only when the hash bits match. So an
// entry is 8 bytes, a look-up usually reads one line of the table and then the slot the caller
// touches anyway, and any hashable Key works.
//
// Why not std::unordered_map: one node per key, so each look-up chased two or three pointers
// into a table of nodes spread over the heap: two or three cache misses per look-up.
//
// Thread safety: none; owned by one engine.
// Invariants:
//  1. Capacity is 0 or a power of two, at most 2^32, and size <= capacity / 2 after any insert;
//     a table above kMinCapacity shrinks when it falls under capacity / 8.
//  2. An entry's tag is Tag(key of its handle); it lies in the probe run that starts at
//     Home(tag).
//  3. No key is held twice.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "bp/detail/assert.h"
#include "bp/detail/huge_alloc.h"

namespace bp::detail {

template <class Key>
class KeyIndex {
 public:
  static constexpr uint32_t kNone = ~uint32_t{0};
  static constexpr size_t kMinCapacity = 16;

  /// The handle of key, or kNone. key_of(handle) gives the key a stored handle stands for.
  template <class KeyOf>
  uint32_t Find(const Key& key, KeyOf&& key_of) const {
    return Find(key, Tag(key), key_of);
  }
  /// Find with key's Tag computed by the caller (batch look-ups compute it once for three uses).
  template <class KeyOf>
  uint32_t Find(const Key& key, uint32_t tag, KeyOf&& key_of) const {
    if (size_ == 0) return kNone;
    for (size_t i = Home(tag);; i = (i + 1) & mask_) {
      const Entry& e = entries_[i];
      if (e.handle == kNone) return kNone;
      if (e.tag == tag && key_of(e.handle) == key) return e.handle;
    }
  }

  /// Where the probe run of a key with this Tag starts (nullptr for an empty table), for the caller
  /// to prefetch before a Find soon after. The caller prefetches, not a member: GCC 12 finds a
  /// member whose only effect is a prefetch pure (a prefetch touches no memory it models), and
  /// deletes calls to it as unused.
  const void* HomeLine(uint32_t tag) const { return size_ == 0 ? nullptr : &entries_[Home(tag)]; }

  /// The first handle stored under tag in its probe run, or kNone: the handle of the key
  /// with this Tag unless 32 hash bits collide. A hint for prefetching the caller's slot, never an
  /// answer.
  uint32_t Guess(uint32_t tag) const {
    if (size_ == 0) return kNone;
    for (size_t i = Home(tag);; i = (i + 1) & mask_) {
      const Entry& e = entries_[i];
      if (e.handle == kNone || e.tag == tag) return e.handle;
    }
  }

  // Keys that differ only in their low kRunBits bits of hash share a run of 2^kRunBits slots,
  // one slot each (those bits, xor-ed with bits of the run's hash): std::hash of an integer is
  // the integer itself, so consecutive ids (the usual client numbering) land in the same few
  // lines, and a frame that updates them in id order reads the table almost sequentially. The
  // run is placed by a mix64 finaliser of the remaining bits, and the xor spreads keys whose low
  // bits never vary (ids in steps of 16, aligned addresses) over the whole run.
  static constexpr int kRunBits = 4;
  /// 32 hash bits of key: where it lives and what a probe compares before the key itself.
  static uint32_t Tag(const Key& key) {
    const uint64_t h = static_cast<uint64_t>(std::hash<Key>{}(key));
    uint64_t z = h >> kRunBits;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    z ^= z >> 31;
    const uint32_t run = static_cast<uint32_t>(z >> (64 - (32 - kRunBits)));
    return run << kRunBits | static_cast<uint32_t>((h ^ z) & ((1u << kRunBits) - 1));
  }
  /// Changes with every insert and erase (and so every rehash): a Guess taken at one version
  /// still names the same entry while the version is the same.
  uint64_t version() const { return version_; }

  /// Maps key (absent) to handle h.
  void Insert(const Key& key, uint32_t h) { InsertTagged(Tag(key), h); }
  /// Insert with the key's Tag computed by the caller.
  void InsertTagged(uint32_t tag, uint32_t h) {
    BP_ASSERT(h != kNone);
    if ((size_ + 1) * 2 > entries_.size()) {
      Rehash(entries_.empty() ? kMinCapacity : entries_.size() * 2);
    }
    size_t i = Home(tag);
    while (entries_[i].handle != kNone) i = (i + 1) & mask_;
    entries_[i] = Entry{h, tag};
    ++size_;
    ++version_;
  }

  /// Removes the mapping key -> h; false if key does not map to h.
  bool Erase(const Key& key, uint32_t h) { return EraseTagged(Tag(key), h); }
  /// Erase with the key's Tag computed by the caller.
  bool EraseTagged(uint32_t tag, uint32_t h) {
    if (size_ == 0) return false;
    size_t i = Home(tag);
    while (entries_[i].handle != h) {
      if (entries_[i].handle == kNone) return false;
      i = (i + 1) & mask_;
    }
    size_t hole = i;
    for (size_t j = (i + 1) & mask_; entries_[j].handle != kNone; j = (j + 1) & mask_) {
      size_t home = Home(entries_[j].tag);
      bool home_in_range = hole <= j ? (hole < home && home <= j) : (hole < home || home <= j);
      if (!home_in_range) {
        entries_[hole] = entries_[j];
        hole = j;
      }
    }
    entries_[hole].handle = kNone;
    --size_;
    ++version_;
    if (entries_.size() > kMinCapacity && size_ * 8 < entries_.size()) {
      Rehash(entries_.size() / 2);
    }
    return true;
  }

  /// Calls f(handle) for every stored handle, in table order.
  template <class F>
  void ForEach(F&& f) const {
    for (const Entry& e : entries_) {
      if (e.handle != kNone) f(e.handle);
    }
  }

  /// True iff handle h is stored under key's hash (for validators).
  bool HoldsUnder(const Key& key, uint32_t h) const {
    if (size_ == 0) return false;
    const uint32_t tag = Tag(key);
    for (size_t i = Home(tag); entries_[i].handle != kNone; i = (i + 1) & mask_) {
      if (entries_[i].handle == h) return entries_[i].tag == tag;
    }
    return false;
  }

  size_t size() const { return size_; }

 private:
  struct Entry {
    uint32_t handle = kNone;
    uint32_t tag = 0;
  };

  // The home slot: the top bits of the run's part of the tag, then the key's low bits.
  size_t Home(uint32_t tag) const {
    if (bits_ <= kRunBits) return static_cast<size_t>(tag) & mask_;
    const uint32_t run = (tag >> kRunBits) >> (32 - bits_);
    return static_cast<size_t>(run << kRunBits | (tag & ((1u << kRunBits) - 1)));
  }

  void Rehash(size_t capacity) {
    BP_ASSERT(std::has_single_bit(capacity) && capacity <= (size_t{1} << 32));
    HugeVector<Entry> old(capacity);
    old.swap(entries_);
    mask_ = capacity - 1;
    bits_ = std::countr_zero(capacity);
    for (const Entry& e : old) {
      if (e.handle == kNone) continue;
      size_t i = Home(e.tag);
      while (entries_[i].handle != kNone) i = (i + 1) & mask_;
      entries_[i] = e;
    }
  }

  HugeVector<Entry> entries_;
  size_t mask_ = 0;
  int bits_ = 0;
  size_t size_ = 0;
  uint64_t version_ = 0;
};

}  // namespace bp::detail
