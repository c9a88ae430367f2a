// bp::detail::PairTracker: the candidate set (pairs of dense handles that overlap now) and the
// set of pairs whose status differs from the last query, from which events are drawn. It also
// keeps each handle's ObjectOptions once any object has non-default ones: Add refuses the pairs
// that fail Accepts, so filtered pairs never enter any set. The cores test the boxes first: in
// their hot paths the box test usually fails, and it reads memory they touch anyway.
//
// The sets may be split into shards by a hash of the pair (SetShards; one by default), so that
// the grid's threads fold their cells' changes side by side, each into its own shards.
//
// Thread safety: none; owned by one engine. Add and Remove of pairs in different shards
// (ShardOf) may run concurrently, while nothing else is called (options are only read).
// Invariants (per shard, for the pairs of that shard):
//  1. overlaps holds exactly the overlapping pairs of the current boxes (when a core is idle).
//  2. A pair is in changed iff its membership in overlaps differs from that at the last Drain.
//  3. Every pair in overlaps passes Accepts.
//  4. Every pair in changed has an entry in toggled; its first entry there since the last
//     Drain records the direction of the pair's first toggle since then.
//  5. Every pair lies in shard ShardOf(pair); there are 2^shard_bits_ shards.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "bp/detail/assert.h"
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
/// look-up costs a branch). While every category and mask keeps its default (static flags are
/// the only options set: the usual case), a handle's options are its static flag, one byte of a
/// compact table, and Accepts reads two of those; the whole options are stored from the first
/// handle with another category or mask on. Shared by PairTracker and the grid's dense cell.
class OptionsTable {
 public:
  /// Sets the options of handle h (before any of its pairs is formed).
  void Set(uint32_t h, const ObjectOptions& options) {
    if (!filtering_) {
      if (options == ObjectOptions{}) return;
      filtering_ = true;
    }
    if (!masking_ &&
        (options.category != ObjectOptions{}.category || options.mask != ObjectOptions{}.mask)) {
      StartMasking();
    }
    if (h >= static_.size()) static_.resize(size_t{h} + 1, 0);
    static_[h] = options.is_static ? 1 : 0;
    if (masking_) {
      if (h >= options_.size()) options_.resize(size_t{h} + 1);
      options_[h] = options;
    }
  }
  /// The options of handle h.
  ObjectOptions Get(uint32_t h) const {
    if (masking_) return h < options_.size() ? options_[h] : ObjectOptions{};
    ObjectOptions o;
    o.is_static = IsStatic(h);
    return o;
  }
  /// True iff some handle has had non-default options (then Set must see every insert).
  bool filtering() const { return filtering_; }
  /// True iff some handle has had another category or mask than the defaults.
  bool masking() const { return masking_; }
  bool IsStatic(uint32_t h) const { return h < static_.size() && static_[h] != 0; }
  /// False when no pair of h can be refused (Accepts(h, x) holds for every x): callers that
  /// test many pairs of h skip the look-ups.
  bool MayRefuse(uint32_t h) const { return filtering_ && (masking_ || IsStatic(h)); }
  /// True iff the pair (a, b) may be tracked (see bp/object_options.h).
  bool Accepts(uint32_t a, uint32_t b) const {
    if (!filtering_) return true;
    if (!masking_) return !(IsStatic(a) && IsStatic(b));
    return bp::Accepts(Get(a), Get(b));
  }

 private:
  // From here on the whole options are stored: those set so far differ from the defaults only
  // by their static flags.
  void StartMasking() {
    masking_ = true;
    options_.assign(static_.size(), ObjectOptions{});
    for (size_t h = 0; h < static_.size(); ++h) options_[h].is_static = static_[h] != 0;
  }

  std::vector<uint8_t> static_;         // by handle; empty while filtering_ is false
  std::vector<ObjectOptions> options_;  // by handle; empty while masking_ is false
  bool filtering_ = false;
  bool masking_ = false;
};

class PairTracker {
 public:
  /// Splits the sets into 2^bits shards (at most 2^6); only while no pair is tracked.
  void SetShards(unsigned bits) {
    BP_ASSERT(overlaps() == 0 && pending_changes() == 0);
    shard_bits_ = std::min(bits, 6u);
    more_.clear();
    more_.resize((size_t{1} << shard_bits_) - 1);
  }
  size_t shards() const { return more_.size() + 1; }
  /// The shard of pair p: the top bits of a multiplicative hash whose multiplier differs from
  /// the sets' own (FlatSet places p by the top bits of p * 0x9E3779B97F4A7C15, which within
  /// a shard of those same bits would leave half the table's homes unused).
  size_t ShardOf(uint64_t p) const {
    return shard_bits_ == 0
               ? 0
               : static_cast<size_t>((p * 0xD6E8FEB86659FD93ULL) >> (64 - shard_bits_));
  }

  /// Records that a and b overlap (idempotent); true if they did not before. A pair that fails
  /// Accepts is not recorded (false).
  bool Add(uint32_t a, uint32_t b) { return AddIn(ShardOf(HandlePair(a, b)), a, b); }
  /// Records that a and b do not overlap (idempotent); true if they did before.
  bool Remove(uint32_t a, uint32_t b) { return RemoveIn(ShardOf(HandlePair(a, b)), a, b); }
  /// Add and Remove for a caller that knows the pair's shard (ShardOf).
  bool AddIn(size_t shard, uint32_t a, uint32_t b) {
    if (!Accepts(a, b)) return false;
    const uint64_t p = HandlePair(a, b);
    BP_ASSERT(shard == ShardOf(p));
    Shard& sh = At(shard);
    if (!sh.overlaps.Insert(p)) return false;
    Toggle(sh, p, true);
    return true;
  }
  bool RemoveIn(size_t shard, uint32_t a, uint32_t b) {
    const uint64_t p = HandlePair(a, b);
    BP_ASSERT(shard == ShardOf(p));
    Shard& sh = At(shard);
    if (!sh.overlaps.Erase(p)) return false;
    Toggle(sh, p, false);
    return true;
  }
  bool Contains(uint32_t a, uint32_t b) const {
    const uint64_t p = HandlePair(a, b);
    return At(ShardOf(p)).overlaps.Contains(p);
  }

  /// Sets the options of handle h (before any of its pairs is added). Default options cost
  /// nothing until some handle has non-default ones.
  void SetOptions(uint32_t h, const ObjectOptions& options) { options_.Set(h, options); }
  /// The options of handle h.
  ObjectOptions options(uint32_t h) const { return options_.Get(h); }
  /// True iff some handle has had non-default options (then SetOptions must see every insert).
  bool filtering() const { return options_.filtering(); }
  /// True iff some handle has had another category or mask than the defaults.
  bool masking() const { return options_.masking(); }
  /// True iff the pair (a, b) may be tracked (see bp/object_options.h).
  bool Accepts(uint32_t a, uint32_t b) const { return options_.Accepts(a, b); }

  /// Calls f(a, b, overlapping_now) for every pair changed since the last drain, then forgets
  /// them, shard by shard. O(toggles since the last drain): the section 3.3 bound, whatever
  /// earlier queries did. A pair is in changed iff it toggled an odd number of times since the
  /// last drain, and its first entry in toggled is that of its first toggle: toggles alternate
  /// (Add only when it was absent, Remove only when present), so the first's direction is the
  /// state now, and overlaps need not be probed. changed's lines are prefetched ahead (pairs
  /// come in toggle order, all over the table).
  template <class F>
  void DrainChanges(F&& f) {
    for (size_t s = 0; s < shards(); ++s) {
      Shard& sh = At(s);
      const size_t n = sh.toggled.size();
      for (size_t i = 0; i < n; ++i) {
        if (i + kDrainAhead < n)
          __builtin_prefetch(sh.changed.HomeLine(sh.toggled[i + kDrainAhead].pair));
        const Toggled& t = sh.toggled[i];
        // A pair toggled back to its old state is no longer in changed (or was reported).
        if (sh.changed.Erase(t.pair, /*shrink=*/false)) {
          f(PairFirst(t.pair), PairSecond(t.pair), t.now);
        }
      }
      sh.changed.ShrinkToFit(n);
      sh.toggled.clear();
      // Memory held after a burst is given back; a steady rate of toggles keeps its buffer.
      if (sh.toggled.capacity() > std::max<size_t>(4096, 4 * n)) sh.toggled.shrink_to_fit();
    }
  }
  /// Calls f(a, b) for every overlapping pair.
  template <class F>
  void ForEachOverlap(F&& f) const {
    for (size_t s = 0; s < shards(); ++s) {
      At(s).overlaps.ForEach([&](uint64_t p) { f(PairFirst(p), PairSecond(p)); });
    }
  }
  /// Where Add or Remove of pair p starts probing the overlap set and the changed set (nullptr
  /// when empty), for the caller to prefetch a few pairs ahead.
  const void* OverlapLine(uint64_t p) const { return At(ShardOf(p)).overlaps.HomeLine(p); }
  const void* ChangedLine(uint64_t p) const { return At(ShardOf(p)).changed.HomeLine(p); }
  size_t overlaps() const {
    size_t n = 0;
    for (size_t s = 0; s < shards(); ++s) n += At(s).overlaps.size();
    return n;
  }
  size_t pending_changes() const {
    size_t n = 0;
    for (size_t s = 0; s < shards(); ++s) n += At(s).changed.size();
    return n;
  }

 private:
  struct Toggled {
    uint64_t pair;
    bool now;  // overlapping after this toggle
  };
  // Line-aligned: two threads folding two shards write their sets' headers (size, table).
  struct alignas(64) Shard {
    FlatSet<uint64_t> overlaps;
    FlatSet<uint64_t> changed;     // pairs whose state differs from the last drain
    std::vector<Toggled> toggled;  // every entry of a pair into changed since the last drain
  };
  static constexpr size_t kDrainAhead = 16;

  static void Toggle(Shard& sh, uint64_t p, bool now) {
    if (!sh.changed.Erase(p) && sh.changed.Insert(p)) sh.toggled.push_back(Toggled{p, now});
  }

  // Shard 0 lives in the tracker itself, the others (if any) in more_: the cores of one thread,
  // and the grid's SAP cells (a tracker each), pay no indirection and no allocation.
  Shard& At(size_t shard) { return shard == 0 ? first_ : more_[shard - 1]; }
  const Shard& At(size_t shard) const { return shard == 0 ? first_ : more_[shard - 1]; }

  OptionsTable options_;
  unsigned shard_bits_ = 0;
  Shard first_;
  std::vector<Shard> more_;
};

}  // namespace bp::detail
