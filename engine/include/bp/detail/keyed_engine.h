// bp::detail::KeyedEngine: the front end every broadphase shares. It maps client keys to dense
// 32-bit handles once, validates and buffers Insert/Update/Erase, coalesces several calls on one
// key between two queries into at most one operation, hands the core one batch per Query, and
// turns the core's changed handle pairs into canonical key events.
//
// Object options reach the core's tracker (SetOptions) before the batch that inserts them.
// Erase + insert of a live key with the same options is an update of its handle; with other
// options the insert takes a fresh handle (a "rekey"), and the pairs the key keeps, reported
// once as uncollide and once as collide, cancel out before the events go out.
//
// Fattened boxes (margin > 0): the core sees, per object, a fat box (the box grown by margin on
// every side). An update whose box still lies inside the fat box, and whose fat box is not more
// than 4 margins wider than the box on any side, does not reach the core; otherwise the fat box
// is recomputed. Events and ForEachOverlap are then those of the fat boxes: no overlapping pair
// is missed, and every reported pair's boxes lie within 8 margins of each other on every axis.
//
// A core works on handles only (it never sees keys) and must provide:
//   static constexpr int kDim; using Coord = T; static constexpr const char* kName;
//   static constexpr size_t kMaxHandles;   // handles are 0..kMaxHandles-1
//   void Apply(span<const uint32_t> erases, span<const HandleBox> updates,
//              span<const HandleBox> inserts);   // in this order
//   PairTracker& tracker(); const PairTracker& tracker() const; size_t live() const;
//   void FillStats(Stats* out) const; Status Validate() const;
//
// Calls are staged straight into the core's batch: each slot names its entry (stage) in the list
// of its pending kind (erases_, updates_, inserts_), a second call on the key overwrites or
// retires (tombstones) that entry, and Query hands the lists to the core as they are. The slots
// of updated and inserted objects are not visited again at the query: a slot carries the epoch
// (query count) its pending state belongs to, and a pending insert or update of an earlier epoch
// reads as applied (live, nothing pending) until a later call settles it (see Settle).
//
// Thread safety: none (see bp/broadphase.h).
// Invariants:
//  1. index_ maps key iff the key is present (live at the last query and not erased since,
//     or pending insert), or is live with a pending erase and was not reinserted.
//  2. A handle has at most one live (non-tombstone) entry in the staged lists, the one its slot
//     names, of its pending kind, and only while its slot's epoch is epoch_; handles are freed
//     only inside Query, after the core has applied the batch, so a handle never means two keys
//     within one batch.
//  3. erase + insert of one live key with equal options between queries becomes an update of
//     the same handle (unless the key was rekeyed in between: then it is a fresh handle again,
//     and the cancellation keeps the events exact).
//  4. With a margin, fat_[h] (what the core holds, or is about to) contains the client's last
//     box.
//  5. A live handle's options are held by the core's tracker alone (set at the query that
//     inserts it); a pending insert's options wait in insert_options_ (unless they are the
//     defaults and no object has had others).
//  6. A slot that is neither live nor pending is in free_ or (inserted and erased since the last
//     query) in cancelled_, and in no staged list (a cancelled insert's insert_options_ entry
//     stays until the query, which skips it).
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <span>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/huge_alloc.h"
#include "bp/detail/key_index.h"
#include "bp/detail/pair_tracker.h"
#include "bp/detail/prefetch.h"
#include "bp/detail/stopwatch.h"
#include "bp/detail/worker_pool.h"
#include "bp/object_options.h"

namespace bp::detail {

/// A box addressed by a dense handle: the unit of the core interface.
template <int K, Coordinate T>
struct HandleBox {
  uint32_t handle = 0;
  Box<K, T> box;
};

/// Appends {h, box} to v, written in place: a braced temporary is stored piecewise and read back
/// whole, a failed store-to-load forward that took most of the grid's routing time (perf, S3).
template <int K, Coordinate T, class Alloc>
inline void PushBox(std::vector<HandleBox<K, T>, Alloc>& v, uint32_t h, const Box<K, T>& box) {
  HandleBox<K, T>& out = v.emplace_back();
  out.handle = h;
  out.box = box;
}

template <class Core, class Key>
class KeyedEngine final : public Broadphase<Core::kDim, typename Core::Coord, Key> {
  static constexpr int K = Core::kDim;
  using T = typename Core::Coord;
  using Base = Broadphase<K, T, Key>;

 public:
  using BoxType = typename Base::BoxType;
  using Options = typename Core::Options;

  using Base::Insert;

  /// margin > 0 keeps fattened boxes (see above); 0, negative or NaN keeps exact boxes.
  explicit KeyedEngine(const Options& options = Options(), T margin = T{})
      : core_(options), margin_(margin > T{} ? margin : T{}) {}

  Status Insert(const Key& key, const BoxType& box, const ObjectOptions& options) override {
    return InsertTagged(key, KeyIndex<Key>::Tag(key), box, options);
  }

  /// As Insert per item, with the look-ups of later items started early, as in UpdateMany, and
  /// the slots of the handles the inserts will take from the free list (churn frees handles all
  /// over the table).
  size_t InsertMany(std::span<const typename Base::Item> items,
                    std::span<const ObjectOptions> options = {},
                    const typename Base::RefusedFn& refused = nullptr) override {
    if (!options.empty() && options.size() != items.size()) {
      return Base::InsertMany(items, options, refused);  // refuses every item, saying why
    }
    static const ObjectOptions kDefault;
    return ForEachAhead(
        items, [](const typename Base::Item& item) -> const Key& { return item.key; }, refused,
        [&](size_t i, uint32_t tag, uint32_t /*hint: new keys are mostly absent*/) {
          constexpr size_t kFreeAhead = 8;
          if (free_.size() > kFreeAhead) {
            PrefetchForWrite(&slots_[free_[free_.size() - 1 - kFreeAhead]]);
          }
          return InsertTagged(items[i].key, tag, items[i].box,
                              options.empty() ? kDefault : options[i]);
        });
  }

  Status Update(const Key& key, const BoxType& box) override {
    return UpdateTagged(key, KeyIndex<Key>::Tag(key), box, kNoHandle);
  }

  /// As Update per item, with the look-ups of later items started early (ForEachAhead): a loop
  /// of Update calls waits on the key index's line and the slot, one item after the other.
  size_t UpdateMany(std::span<const typename Base::Item> items,
                    const typename Base::RefusedFn& refused = nullptr) override {
    if (margin_ == T{}) {
      if (WorkerPool* pool = LookupPool(items.size())) return UpdateManyOn(pool, items, refused);
    }
    return ForEachResolved(
        items, [](const typename Base::Item& item) -> const Key& { return item.key; }, refused,
        [&](size_t i, uint32_t tag, uint32_t hint) {
          return UpdateTagged(items[i].key, tag, items[i].box, hint);
        });
  }

  Status Erase(const Key& key) override {
    return EraseTagged(key, KeyIndex<Key>::Tag(key), kNoHandle);
  }

  /// As Erase per key, with the look-ups of later keys started early, as in UpdateMany (churn
  /// names keys all over the table).
  size_t EraseMany(std::span<const Key> keys,
                   const typename Base::RefusedFn& refused = nullptr) override {
    return ForEachResolved(
        keys, [](const Key& key) -> const Key& { return key; }, refused,
        [&](size_t i, uint32_t tag, uint32_t hint) { return EraseTagged(keys[i], tag, hint); });
  }

  void Query(EventSink<Key>& sink) override {
    Stopwatch phase;
    PairTracker& tracker = core_.tracker();
    // The tracker learns an inserted object's options before the core pairs it (invariant 5).
    // Default options need no call until some object has others (see PairTracker::SetOptions);
    // an object inserted and erased since is skipped (its handle is not reused before commit).
    for (const auto& [h, options] : insert_options_) {
      if (PendingOf(slots_[h]) == Pending::kInsert) tracker.SetOptions(h, options);
    }
    insert_options_.clear();
    // The staged lists are the batch, once the entries that later calls retired are gone.
    if (tombstones_ != 0) {
      std::erase(erases_, kNoHandle);
      std::erase_if(updates_, [](const HandleBox<K, T>& hb) { return hb.handle == kNoHandle; });
      std::erase_if(inserts_, [](const HandleBox<K, T>& hb) { return hb.handle == kNoHandle; });
      tombstones_ = 0;
    }
    prepare_ms_ = phase.Lap();
    // The commit of the erased slots (CommitErases) touches nothing of the core's: a core that
    // can runs it on its pool among its own parallel work (GridCore::Apply).
    bool committed = false;
    if constexpr (requires { Core::kAppliesBeside; }) {
      if (erases_.empty()) {
        core_.Apply(erases_, updates_, inserts_);
      } else {
        committed = core_.Apply(erases_, updates_, inserts_, [this] { CommitErases(); });
      }
    } else {
      core_.Apply(erases_, updates_, inserts_);
    }
    core_ms_ = phase.Lap();

    // The changed pairs' handles, then (ConvertDrained) their keys, sorted, the collides and the
    // uncollides apart; and the commit of the erased slots if not done yet. The three share
    // nothing but reads of slots_' keys, so with a worker pool they run side by side (in a large
    // frame each is a sizeable share of the events phase).
    for (std::vector<Drained>& d : drained_) d.clear();
    core_.tracker().DrainChanges([&](uint32_t a, uint32_t b, bool now) {
      drained_[now ? 1 : 0].push_back(Drained{a, b});
    });
    const size_t commits = committed ? 0 : erases_.size();
    WorkerPool* pool = PoolFor(drained_[0].size() + drained_[1].size() + kEraseWeight * commits);
    const size_t tasks = commits != 0 ? 3 : 2;
    const auto task = [&](size_t t) {
      if (t < 2) {
        ConvertDrained(t);
      } else {
        CommitErases();
      }
    };
    if (pool != nullptr) {
      pool->ParallelFor(tasks, 1, [&](size_t begin, size_t end, unsigned) {
        for (size_t t = begin; t < end; ++t) task(t);
      });
    } else {
      for (size_t t = 0; t < tasks; ++t) task(t);
    }
    free_.insert(free_.end(), cancelled_.begin(), cancelled_.end());
    cancelled_.clear();
    last_erases_ = erases_.size();
    last_updates_ = updates_.size();
    last_inserts_ = inserts_.size();
    erases_.clear();
    updates_.clear();
    inserts_.clear();
    NextEpoch();

    if (rekeyed_) CancelRekeyedPairs();
    last_fat_skips_ = fat_skips_;
    fat_skips_ = 0;
    if constexpr (kValidateEachQuery) {
      if (Status v = Validate(); !v.ok()) ReportFailure(__FILE__, __LINE__, v.message().c_str());
    }
    for (const auto& [a, b] : uncollides_) sink.Uncollide(a, b);
    for (const auto& [a, b] : collides_) sink.Collide(a, b);
    events_ms_ = phase.Lap();
  }

  void ForEachOverlap(const std::function<void(const Key&, const Key&)>& f) const override {
    core_.tracker().ForEachOverlap([&](uint32_t a, uint32_t b) {
      const Key& ka = slots_[a].key;
      const Key& kb = slots_[b].key;
      if (std::less<Key>()(ka, kb)) {
        f(ka, kb);
      } else {
        f(kb, ka);
      }
    });
  }

  void ForEachObject(const std::function<void(const Key&)>& f) const override {
    for (const Slot& slot : slots_) {
      if (Present(slot)) f(slot.key);
    }
  }

  size_t Size() const override { return core_.live(); }

  Stats GetStats() const override {
    Stats s;
    core_.FillStats(&s);
    s.objects = core_.live();
    s.overlaps = core_.tracker().overlaps();
    s.inserts = last_inserts_;
    s.updates = last_updates_;
    s.erases = last_erases_;
    s.collides = collides_.size();
    s.uncollides = uncollides_.size();
    s.margin = static_cast<double>(margin_);
    s.fat_skips = last_fat_skips_;
    s.prepare_ms = prepare_ms_;
    s.core_ms = core_ms_;
    s.events_ms = events_ms_;
    return s;
  }

  Status Validate() const override {
    auto fail = [](const char* what) {
      return Status(StatusCode::kInternal, std::string("front end: ") + what);
    };
    if (core_.tracker().pending_changes() != 0) return fail("changed pairs left after a query");
    if (!insert_options_.empty()) return fail("insert options left after a query");
    size_t live = 0, present = 0, pending = 0, dead = 0;
    for (uint32_t h = 0; h < slots_.size(); ++h) {
      const Slot& slot = slots_[h];
      if (LiveOf(slot)) ++live;
      if (Present(slot)) {
        ++present;
        if (Find(slot.key) != h) return fail("present key not mapped");
      }
      switch (PendingOf(slot)) {
        case Pending::kNone:
          if (!LiveOf(slot)) ++dead;
          break;
        case Pending::kErase:
          if (!slot.live) return fail("erase pending for a dead slot");
          if (slot.stage >= erases_.size() || erases_[slot.stage] != h) {
            return fail("pending erase not staged");
          }
          ++pending;
          break;
        case Pending::kUpdate:
          if (!slot.live) return fail("update pending for a dead slot");
          if (slot.stage >= updates_.size() || updates_[slot.stage].handle != h) {
            return fail("pending update not staged");
          }
          ++pending;
          break;
        case Pending::kInsert:
          if (slot.live) return fail("insert pending for a live slot");
          if (slot.stage >= inserts_.size() || inserts_[slot.stage].handle != h) {
            return fail("pending insert not staged");
          }
          ++pending;
          break;
      }
    }
    if (live != core_.live()) return fail("live counts disagree");
    size_t staged = 0, tombstones = 0;
    for (uint32_t h : erases_) ++(h == kNoHandle ? tombstones : staged);
    for (const auto& hb : updates_) ++(hb.handle == kNoHandle ? tombstones : staged);
    for (const auto& hb : inserts_) ++(hb.handle == kNoHandle ? tombstones : staged);
    if (staged != pending) return fail("staged entries differ from pending slots");
    if (tombstones != tombstones_) return fail("tombstone count off");
    const char* index_error = nullptr;
    index_.ForEach([&](uint32_t h) {
      if (index_error != nullptr) return;
      if (h >= slots_.size() || !index_.HoldsUnder(slots_[h].key, h)) {
        index_error = "key map points astray";
        return;
      }
      const Slot& slot = slots_[h];
      if (Find(slot.key) != h) {
        index_error = "key map holds a key twice";
      } else if (!Present(slot) && PendingOf(slot) != Pending::kErase) {
        index_error = "key map names a dead slot";
      }
    });
    if (index_error != nullptr) return fail(index_error);
    if (index_.size() < present) return fail("key map smaller than the present slots");
    std::vector<uint8_t> free_seen(slots_.size(), 0);
    for (const auto* list : {&free_, &cancelled_}) {
      for (uint32_t h : *list) {
        if (h >= slots_.size() || free_seen[h]++) return fail("free list broken");
        const Slot& slot = slots_[h];
        if (LiveOf(slot) || PendingOf(slot) != Pending::kNone) return fail("free handle in use");
      }
    }
    if (dead != free_.size() + cancelled_.size()) return fail("a dead slot is lost");
    if (margin_ > T{} && fat_.size() != slots_.size()) return fail("fat boxes missing");
    return core_.Validate();
  }

  std::string Name() const override { return Core::kName; }

  /// The core, for white-box tests.
  const Core& core() const { return core_; }
  /// White-box tests move the epoch to its wrap-around through this peer.
  friend struct KeyedEngineTestPeer;

 private:
  enum class Pending : uint8_t { kNone, kInsert, kUpdate, kErase };
  struct Slot {
    Key key{};
    uint32_t epoch = 0;  // the epoch (query count) that pending and stage belong to
    uint32_t stage = 0;  // the entry of a pending call in the list of its kind
    bool live = false;   // in the core as of the last query, once settled
    Pending pending = Pending::kNone;
  };

  // A slot's state as of now. An insert or update staged in an earlier epoch was applied by that
  // epoch's query: the slot is live with nothing pending (erases and cancelled inserts are
  // committed in Query itself, so no other kind is left from an earlier epoch).
  bool LiveOf(const Slot& slot) const {
    return slot.live || (slot.epoch != epoch_ && slot.pending != Pending::kNone);
  }
  Pending PendingOf(const Slot& slot) const {
    return slot.epoch == epoch_ ? slot.pending : Pending::kNone;
  }
  bool Present(const Slot& slot) const {
    const Pending p = PendingOf(slot);
    return p == Pending::kInsert || (LiveOf(slot) && p != Pending::kErase);
  }
  // Writes the state as of now into a slot about to take a call.
  void Settle(Slot& slot) {
    if (slot.epoch == epoch_) return;
    slot.live = LiveOf(slot);
    slot.pending = Pending::kNone;
    slot.epoch = epoch_;
  }
  // Ends the epoch after a query. Once in 2^32 queries the counter wraps: every slot is settled
  // first, so that no stale epoch can equal a new one.
  void NextEpoch() {
    if (epoch_ == std::numeric_limits<uint32_t>::max()) {
      ++epoch_;  // every pending state now reads as applied: settle it under this epoch
      for (Slot& slot : slots_) {
        slot.epoch = epoch_ + 1;
        Settle(slot);
      }
    }
    ++epoch_;
  }

  // Appends h's pending call of kind p, with box, to list and names the entry in the slot
  // (settled, with nothing pending).
  void Stage(HugeVector<HandleBox<K, T>>& list, uint32_t h, Slot& slot, Pending p,
             const BoxType& box) {
    slot.pending = p;
    slot.stage = static_cast<uint32_t>(list.size());
    PushBox(list, h, box);
  }
  // Turns the slot's staged entry (if any) into a tombstone, which Query drops.
  void Retire(Slot& slot) {
    switch (slot.pending) {
      case Pending::kNone:
        return;
      case Pending::kErase:
        erases_[slot.stage] = kNoHandle;
        break;
      case Pending::kUpdate:
        updates_[slot.stage].handle = kNoHandle;
        break;
      case Pending::kInsert:
        inserts_[slot.stage].handle = kNoHandle;
        break;
    }
    slot.pending = Pending::kNone;
    ++tombstones_;
  }
  // The box the core is to get for h's new box: box itself, or with a margin its fat box, kept
  // in fat_.
  const BoxType& Keep(uint32_t h, const BoxType& box) {
    if (margin_ > T{}) {
      fat_[h] = Grow(box, margin_);
      return fat_[h];
    }
    return box;
  }

  // The handle key maps to, or kNoHandle. hint is a handle the index gave for key's tag at its
  // current version (KeyIndex::Guess, see ForEachAhead) or kNoHandle: if its slot holds key, it
  // is key's handle (an entry's handle holds the key it is stored for, and the table has not
  // changed since), and the probe is saved; else the index is searched.
  uint32_t Lookup(const Key& key, uint32_t tag, uint32_t hint) const {
    if (hint < slots_.size() && slots_[hint].key == key) return hint;
    return index_.Find(key, tag, [this](uint32_t x) -> const Key& { return slots_[x].key; });
  }

  // Calls apply(i, tag of key_of(items[i]), hint) for every item in order, with the key index's
  // line of the item kAhead ahead and the slot its entry names kAhead / 2 ahead prefetched (in
  // a large scene both are cache misses, which a plain loop waits for one after the other).
  // Each key's tag is computed once, kAhead items ahead, and kept in a ring until its item's
  // turn. The handle found for the prefetch is kept too, and passed as the item's hint while
  // the index has not changed since (else kNoHandle): see Lookup; that saves a second probe of
  // the key's run per update.
  // apply returns the item's Status; a refused item is passed to refused (when set) with its
  // index. Returns the number refused. kAhead is 64 because a miss on a virtual machine lasts
  // long enough to need that many look-ups in flight (docs/TUNING.md, front end).
  template <class Item, class KeyOf, class Apply>
  size_t ForEachAhead(std::span<const Item> items, KeyOf&& key_of,
                      const typename Base::RefusedFn& refused, Apply&& apply) {
    constexpr size_t kAhead = 64;
    uint32_t tags[kAhead];
    uint32_t guesses[kAhead];
    uint64_t versions[kAhead];
    std::fill_n(guesses, kAhead, kNoHandle);
    std::fill_n(versions, kAhead, uint64_t{0});
    const size_t n = items.size();
    const size_t first = std::min(n, kAhead);
    for (size_t i = 0; i < first; ++i) {
      tags[i] = KeyIndex<Key>::Tag(key_of(items[i]));
      if (const void* line = index_.HomeLine(tags[i])) __builtin_prefetch(line);
    }
    size_t count = 0;
    for (size_t i = 0; i < n; ++i) {
      if (i + kAhead / 2 < n) {
        const size_t r = (i + kAhead / 2) % kAhead;
        const uint32_t guess = index_.Guess(tags[r]);
        guesses[r] = guess;
        versions[r] = index_.version();
        if (guess < slots_.size()) {
          const char* slot = reinterpret_cast<const char*>(&slots_[guess]);
          __builtin_prefetch(slot);
          __builtin_prefetch(slot + sizeof(Slot) - 1);
          if (margin_ > T{}) __builtin_prefetch(&fat_[guess]);
        }
      }
      const uint32_t tag = tags[i % kAhead];
      const uint32_t guess = guesses[i % kAhead];
      const uint32_t hint =
          guess != kNoHandle && versions[i % kAhead] == index_.version() ? guess : kNoHandle;
      if (i + kAhead < n) {
        const uint32_t ahead = KeyIndex<Key>::Tag(key_of(items[i + kAhead]));
        tags[i % kAhead] = ahead;
        if (const void* line = index_.HomeLine(ahead)) __builtin_prefetch(line);
      }
      const Status s = apply(i, tag, hint);
      if (s.ok()) continue;
      ++count;
      if (refused) refused(i, s);
    }
    return count;
  }

  // The keys of the drained pairs drained_[now] into collides_ (now 1) or uncollides_, sorted. The
  // slots of a frame's pairs lie all over the table: their keys are prefetched kKeysAhead pairs
  // ahead.
  void ConvertDrained(size_t now) {
    const auto& drained = drained_[now];
    std::vector<std::pair<Key, Key>>* out = now == 1 ? &collides_ : &uncollides_;
    out->clear();
    constexpr size_t kKeysAhead = 32;
    for (size_t i = 0; i < drained.size(); ++i) {
      if (i + kKeysAhead < drained.size()) {
        __builtin_prefetch(&slots_[drained[i + kKeysAhead].a].key);
        __builtin_prefetch(&slots_[drained[i + kKeysAhead].b].key);
      }
      const Key& ka = slots_[drained[i].a].key;
      const Key& kb = slots_[drained[i].b].key;
      out->push_back(std::less<Key>()(ka, kb) ? std::make_pair(ka, kb) : std::make_pair(kb, ka));
    }
    std::sort(out->begin(), out->end());
  }

  // Commits the erased slots and frees their handles (invariant 2); writes only the erased
  // slots' state (not their keys), index_ and free_. Updated and inserted slots are not
  // visited: the epoch ends after (see Settle). The core's apply (during which a grid with a
  // pool runs this) has evicted the erased slots and key-index lines since their calls: both
  // are prefetched ahead (churn erases keys all
  // over the table). An erase scans its key's probe run to the run's end (backward-shift
  // deletion: about 24 entries, three lines, at S1-1M's load), so three lines of the index are
  // prefetched from the key's home.
  void CommitErases() {
    for (size_t i = 0; i < erases_.size(); ++i) {
      if (i + 32 < erases_.size()) __builtin_prefetch(&slots_[erases_[i + 32]]);
      if (i + 16 < erases_.size()) {
        if (const void* line = index_.HomeLine(KeyIndex<Key>::Tag(slots_[erases_[i + 16]].key))) {
          // Addresses past the table's end are harmless to prefetch (no fault, no access).
          const auto at = reinterpret_cast<uintptr_t>(line);
          __builtin_prefetch(line);
          __builtin_prefetch(reinterpret_cast<const void*>(at + 64));
          __builtin_prefetch(reinterpret_cast<const void*>(at + 128));
        }
      }
      const uint32_t h = erases_[i];
      Slot& slot = slots_[h];
      index_.Erase(slot.key, h);  // false if the key was rekeyed to another handle
      slot.live = false;
      slot.pending = Pending::kNone;
      free_.push_back(h);
    }
  }

  // The core's worker pool if it has one and a loop over n light items is worth waking it for.
  WorkerPool* PoolFor(size_t n) const {
    if constexpr (requires(const Core& c) { c.PoolFor(n); }) {
      return core_.PoolFor(n);
    } else {
      return nullptr;
    }
  }

  // The core's pool for the look-ups of a batch of n keys (see ForEachResolved), or nullptr.
  WorkerPool* LookupPool(size_t n) const {
    if constexpr (requires(const Core& c) { c.LookupPoolFor(n); }) {
      return core_.LookupPoolFor(n);
    } else {
      return nullptr;
    }
  }

  // UpdateMany (exact boxes) with the items staged on every thread of pool. Item i's entry is
  // updates_[base + i]. A run's thread looks each key up (ForEachAhead) and stages the update
  // itself when it can claim the key's slot: the slot had no call yet this epoch, and this
  // thread is the first of the batch to move its epoch to the current one (an atomic compare-
  // and-swap; each slot's other fields are then written by that thread alone). Any other item
  // (a bad box, an unknown key, a slot with an earlier call this epoch or claimed by another
  // item) leaves a tombstone at its entry and is deferred: the deferred items then go through
  // UpdateTagged on this thread, in item order, except that an item whose key a later item of
  // the batch staged in parallel is skipped (the later box wins, as in order). So the batch
  // ends as the serial loop leaves it, up to the entries' order in updates_. Staging on the pool
  // matters because a serial staging after parallel look-ups would be a large serial share of
  // a two-thread frame.
  size_t UpdateManyOn(WorkerPool* pool, std::span<const typename Base::Item> items,
                      const typename Base::RefusedFn& refused) {
    const size_t base = updates_.size();
    const size_t runs = BeginClaims(items.size());
    // Whole deferred lists per run (see ClaimRun).
    GuidedRuns(items.size(), pool->threads(), kResolveRun, kResolveRun, kResolveRun * 8, &runs_);
    pool->ParallelFor(runs_.size() - 1, 1, [&](size_t begin, size_t end, unsigned) {
      for (size_t r = begin; r < end; ++r) ClaimRun(items, base, runs_[r], runs_[r + 1]);
    });
    return EndClaims(items, base, runs, refused);
  }

  // UpdateManyOn's parts: the entries and deferred lists for n items (returns the runs), the
  // claims of items [begin, end) (begin a multiple of kResolveRun), and the ordered pass. A
  // white-box test runs the runs in another order (KeyedEngineTestPeer).
  size_t BeginClaims(size_t n) {
    updates_.resize(updates_.size() + n);
    const size_t runs = (n + kResolveRun - 1) / kResolveRun;
    if (deferred_.size() < runs) deferred_.resize(runs);
    for (size_t r = 0; r < runs; ++r) {
      deferred_[r].clear();
      deferred_[r].reserve(kResolveRun);  // no allocation on the pool's threads
    }
    return runs;
  }
  // Claims items [begin, end) (whole runs of kResolveRun but the last), in one look-ahead loop;
  // an item deferred goes to its run's list.
  void ClaimRun(std::span<const typename Base::Item> items, size_t base, size_t begin, size_t end) {
    // Whole deferred lists: no other run pushes to this run's.
    BP_ASSERT(begin % kResolveRun == 0 && (end % kResolveRun == 0 || end == items.size()));
    const auto key_of = [](const typename Base::Item& item) -> const Key& { return item.key; };
    ForEachAhead(items.subspan(begin, end - begin), key_of, nullptr,
                 [&](size_t i, uint32_t tag, uint32_t hint) {
                   const size_t at = begin + i;
                   if (!ClaimUpdate(items[at], tag, hint, base + at)) {
                     updates_[base + at].handle = kNoHandle;
                     deferred_[at / kResolveRun].push_back(static_cast<uint32_t>(at));
                   }
                   return Status::Ok();
                 });
  }
  size_t EndClaims(std::span<const typename Base::Item> items, size_t base, size_t runs,
                   const typename Base::RefusedFn& refused) {
    const size_t n = items.size();
    for (size_t r = 0; r < runs; ++r) tombstones_ += deferred_[r].size();
    skipped_.clear();
    size_t count = 0;
    size_t resume = n;  // after a refused item with a callback: the later items, again
    for (size_t r = 0; r < runs && resume == n; ++r) {
      for (uint32_t at : deferred_[r]) {
        const Status s = UpdateDeferred(items[at], base, base + at, base + n);
        if (s.ok()) continue;
        ++count;
        if (refused) {
          Rewind(items, base, at);
          refused(at, s);
          resume = at + 1;
          break;
        }
      }
    }
    // The items after a refused one whose callback ran (see Rewind), in order.
    for (size_t at = resume; at < n; ++at) {
      const typename Base::Item& item = items[at];
      const Status s = UpdateTagged(item.key, KeyIndex<Key>::Tag(item.key), item.box, kNoHandle);
      if (s.ok()) continue;
      ++count;
      if (refused) refused(at, s);
    }
    return count;
  }

  // Before UpdateManyOn passes refused item `at` to the callback, which may call the engine
  // (even Query): brings the batch to where the serial loop would be, items [0, at] applied and
  // none after. The updates staged in parallel by later items are retired (their slots keep
  // their settled state, nothing pending), and the deferred items skipped for one of them
  // (skipped_) are applied again, in order. The caller then applies the later items in order.
  void Rewind(std::span<const typename Base::Item> items, size_t base, size_t at) {
    for (size_t k = base + at + 1; k < base + items.size(); ++k) {
      const uint32_t h = updates_[k].handle;
      if (h == kNoHandle) continue;
      Slot& slot = slots_[h];
      BP_ASSERT(PendingOf(slot) == Pending::kUpdate && slot.stage == k);
      slot.pending = Pending::kNone;
      updates_[k].handle = kNoHandle;
      ++tombstones_;
    }
    for (const auto& [i, by] : skipped_) {
      if (by <= base + at) continue;  // its key's later item stands
      const typename Base::Item& item = items[i];
      const Status s = UpdateTagged(item.key, KeyIndex<Key>::Tag(item.key), item.box, kNoHandle);
      BP_ASSERT(s.ok());
      (void)s;
    }
  }

  // Stages item as updates_[entry] if it can claim the slot of its key (see UpdateManyOn);
  // false if not (the entry is then left for the caller to retire). Runs on a pool thread.
  bool ClaimUpdate(const typename Base::Item& item, uint32_t tag, uint32_t hint, size_t entry) {
    if (!IsValidBox(item.box)) return false;
    const uint32_t h = Lookup(item.key, tag, hint);
    if (h == kNoHandle) return false;
    Slot& slot = slots_[h];
    std::atomic_ref<uint32_t> epoch(slot.epoch);
    uint32_t seen = epoch.load(std::memory_order_relaxed);
    if (seen == epoch_ || !epoch.compare_exchange_strong(seen, epoch_, std::memory_order_relaxed)) {
      return false;
    }
    // Settled from the epoch seen (LiveOf of a stale epoch): a pending insert or update of an
    // earlier epoch was applied.
    slot.live = slot.live || slot.pending != Pending::kNone;
    slot.pending = Pending::kNone;
    if (!slot.live) return false;  // not present: UpdateTagged says so
    slot.pending = Pending::kUpdate;
    slot.stage = static_cast<uint32_t>(entry);
    updates_[entry].handle = h;
    updates_[entry].box = item.box;
    return true;
  }

  // UpdateTagged for a deferred item of UpdateManyOn whose entry was updates_[entry]: skipped
  // (Ok) if a later item of the batch (entries [base, end)) staged its key in parallel. The
  // handle found is UpdateTagged's hint (one probe of the index).
  Status UpdateDeferred(const typename Base::Item& item, size_t base, size_t entry, size_t end) {
    const uint32_t tag = KeyIndex<Key>::Tag(item.key);
    const uint32_t h = Lookup(item.key, tag, kNoHandle);
    if (h != kNoHandle && IsValidBox(item.box)) {
      const Slot& slot = slots_[h];
      if (PendingOf(slot) == Pending::kUpdate && slot.stage >= base && slot.stage < end &&
          slot.stage > entry) {
        skipped_.push_back({static_cast<uint32_t>(entry - base), slot.stage});
        return Status::Ok();
      }
    }
    return UpdateTagged(item.key, tag, item.box, h);
  }

  // As ForEachAhead, with the keys looked up first, in parallel, when the core lends a worker
  // pool for this many look-ups (LookupPoolFor). The look-ups (a key-index line and a slot per
  // item, both cache misses in a large scene) read only index_ and slots_, so the pool's
  // threads share them (each run through ForEachAhead, storing tag and handle in resolved_);
  // apply then runs for every item in order on this thread, with the handle found as its hint
  // and the slots prefetched from the handles, kAhead items ahead. A hint is dropped once the
  // index changed (an erase of a pending insert): Lookup then searches, as without a hint. The
  // slots are prefetched for writing: the look-ups left them shared with the other thread's
  // cache, and the first store to each would then wait for the line.
  template <class Item, class KeyOf, class Apply>
  size_t ForEachResolved(std::span<const Item> items, KeyOf&& key_of,
                         const typename Base::RefusedFn& refused, Apply&& apply) {
    const size_t n = items.size();
    WorkerPool* pool = LookupPool(n);
    if (pool == nullptr) return ForEachAhead(items, key_of, refused, apply);
    resolved_.resize(n);
    GuidedRuns(n, pool->threads(), kResolveUnit, kResolveUnit, kResolveRun * 8, &runs_);
    pool->ParallelFor(runs_.size() - 1, 1, [&](size_t first, size_t last, unsigned) {
      for (size_t r = first; r < last; ++r) {
        const size_t begin = runs_[r], end = runs_[r + 1];
        ForEachAhead(
            items.subspan(begin, end - begin), key_of, nullptr,
            [&](size_t i, uint32_t tag, uint32_t hint) {
              resolved_[begin + i] = Resolved{tag, Lookup(key_of(items[begin + i]), tag, hint)};
              return Status::Ok();
            });
      }
    });
    constexpr size_t kAhead = 16;
    const uint64_t version = index_.version();
    size_t count = 0;
    for (size_t i = 0; i < n; ++i) {
      if (i + kAhead < n) {
        const uint32_t ahead = resolved_[i + kAhead].handle;
        if (ahead < slots_.size()) {
          const char* slot = reinterpret_cast<const char*>(&slots_[ahead]);
          PrefetchForWrite(slot);
          PrefetchForWrite(slot + sizeof(Slot) - 1);
          if (margin_ > T{}) PrefetchForWrite(&fat_[ahead]);
        }
      }
      const Resolved& r = resolved_[i];
      const Status s = apply(i, r.tag, index_.version() == version ? r.handle : kNoHandle);
      if (s.ok()) continue;
      ++count;
      if (refused) refused(i, s);
    }
    return count;
  }

  Status EraseTagged(const Key& key, uint32_t tag, uint32_t hint) {
    const uint32_t h = Lookup(key, tag, hint);
    if (h == kNoHandle) return Status(StatusCode::kNotFound, "erase: unknown key");
    Slot& slot = slots_[h];
    Settle(slot);
    if (!Present(slot)) return Status(StatusCode::kNotFound, "erase: unknown key");
    Retire(slot);  // the update or insert staged for it, if any
    if (slot.live) {
      slot.pending = Pending::kErase;
      slot.stage = static_cast<uint32_t>(erases_.size());
      erases_.push_back(h);
    } else {
      // Inserted and erased between two queries: nothing reaches the core, and the handle is
      // freed after the query (invariant 2).
      index_.EraseTagged(tag, h);
      cancelled_.push_back(h);
    }
    return Status::Ok();
  }

  // Insert, with key's KeyIndex tag computed by the caller.
  Status InsertTagged(const Key& key, uint32_t tag, const BoxType& box,
                      const ObjectOptions& options) {
    if (Status s = ValidateBox(box); !s.ok()) return Annotate(s, "insert");
    const uint32_t found =
        index_.Find(key, tag, [this](uint32_t x) -> const Key& { return slots_[x].key; });
    if (found != kNoHandle) {
      Slot& slot = slots_[found];
      Settle(slot);
      if (Present(slot)) return Status(StatusCode::kAlreadyExists, "insert: key already present");
      if (core_.tracker().options(found) == options) {
        // Live at the last query and erased since: erase + insert is an update (invariant 3).
        Retire(slot);
        Stage(updates_, found, slot, Pending::kUpdate, Keep(found, box));
        return Status::Ok();
      }
    }
    if (free_.empty() && slots_.size() >= Core::kMaxHandles) {
      return Status(StatusCode::kResourceExhausted,
                    "insert: " + std::to_string(Core::kMaxHandles) + " objects are the limit");
    }
    if (found != kNoHandle) {
      // New options: the old handle stays erased and the key takes a fresh one (a rekey).
      index_.EraseTagged(tag, found);
      rekeyed_ = true;
    }
    const uint32_t h = AllocHandle();
    Slot& slot = slots_[h];
    slot.key = key;
    slot.live = false;
    slot.epoch = epoch_;
    Stage(inserts_, h, slot, Pending::kInsert, Keep(h, box));
    index_.InsertTagged(tag, h);
    if (options != ObjectOptions{} || core_.tracker().filtering()) {
      insert_options_.push_back({h, options});
    }
    return Status::Ok();
  }

  // Update, with key's KeyIndex tag computed by the caller.
  Status UpdateTagged(const Key& key, uint32_t tag, const BoxType& box, uint32_t hint) {
    if (Status s = ValidateBox(box); !s.ok()) return Annotate(s, "update");
    const uint32_t h = Lookup(key, tag, hint);
    if (h == kNoHandle) return Status(StatusCode::kNotFound, "update: unknown key");
    Slot& slot = slots_[h];
    Settle(slot);
    if (!Present(slot)) return Status(StatusCode::kNotFound, "update: unknown key");
    if (margin_ > T{} && FatEnough(fat_[h], box)) {
      ++fat_skips_;
      return Status::Ok();
    }
    const BoxType& kept = Keep(h, box);
    switch (slot.pending) {
      case Pending::kNone:
        Stage(updates_, h, slot, Pending::kUpdate, kept);
        break;
      case Pending::kUpdate:
        updates_[slot.stage].box = kept;
        break;
      case Pending::kInsert:
        inserts_[slot.stage].box = kept;
        break;
      case Pending::kErase:  // not present
        break;
    }
    return Status::Ok();
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

  // Removes the pairs present in both sorted lists: a rekeyed key's pairs that it keeps.
  void CancelRekeyedPairs() {
    rekeyed_ = false;
    size_t u = 0, c = 0, uo = 0, co = 0;
    while (u < uncollides_.size() && c < collides_.size()) {
      if (uncollides_[u] < collides_[c]) {
        uncollides_[uo++] = std::move(uncollides_[u++]);
      } else if (collides_[c] < uncollides_[u]) {
        collides_[co++] = std::move(collides_[c++]);
      } else {
        ++u;
        ++c;
      }
    }
    while (u < uncollides_.size()) uncollides_[uo++] = std::move(uncollides_[u++]);
    while (c < collides_.size()) collides_[co++] = std::move(collides_[c++]);
    uncollides_.resize(uo);
    collides_.resize(co);
  }

  static Status Annotate(const Status& s, const char* what) {
    return Status(s.code(), std::string(what) + ": " + s.message());
  }

  static constexpr uint32_t kNoHandle = KeyIndex<Key>::kNone;  // also a retired entry's handle
  uint32_t Find(const Key& key) const {
    return index_.Find(key, [this](uint32_t h) -> const Key& { return slots_[h].key; });
  }

  uint32_t AllocHandle() {
    if (!free_.empty()) {
      uint32_t h = free_.back();
      free_.pop_back();
      return h;
    }
    slots_.emplace_back();
    if (margin_ > T{}) fat_.emplace_back();
    return static_cast<uint32_t>(slots_.size() - 1);
  }

  Core core_;
  T margin_;
  T loose_ = LooseLimit(margin_);
  bool rekeyed_ = false;  // a key took a fresh handle since the last query
  size_t fat_skips_ = 0;  // updates absorbed by fat boxes since the last query
  size_t last_fat_skips_ = 0;
  size_t last_erases_ = 0, last_updates_ = 0, last_inserts_ = 0;  // the last query's batch
  double prepare_ms_ = 0, core_ms_ = 0, events_ms_ = 0;           // the last query's phases (Stats)
  uint32_t epoch_ = 1;  // 1 + queries so far, wrapping past 0 (NextEpoch); a new slot's 0 is stale
  HugeVector<Slot> slots_;
  HugeVector<BoxType> fat_;  // with a margin: each handle's fat box (invariant 4)
  KeyIndex<Key> index_;      // key -> handle (see invariant 1)
  std::vector<uint32_t> free_;
  std::vector<uint32_t> cancelled_;  // handles inserted and erased since the last query
  // The batch being staged: the pending calls by kind (kNoHandle: retired by a later call).
  HugeVector<uint32_t> erases_;
  HugeVector<HandleBox<K, T>> updates_;
  HugeVector<HandleBox<K, T>> inserts_;
  size_t tombstones_ = 0;
  struct Drained {
    uint32_t a, b;
  };
  // The tracker's changes of a query, before their keys: [0] the pairs that stopped
  // overlapping, [1] those that started.
  std::array<std::vector<Drained>, 2> drained_;
  struct Resolved {
    uint32_t tag, handle;
  };
  // An erase's commit costs about as much as this many look-ups or drained pairs (a probe run
  // scanned to its end and shifted back): what the events phase weighs against PoolFor.
  static constexpr size_t kEraseWeight = 4;
  static constexpr size_t kResolveRun = 2048;  // items per deferred list of UpdateManyOn
  static constexpr size_t kResolveUnit = 64;   // ForEachResolved's runs: whole multiples of it
  // The pool's runs of a batch (GuidedRuns): each look-ahead loop (ForEachAhead) starts cold,
  // and runs of kResolveRun made S1-1M's 100 000 updates 49 runs, its 5 000 erased keys three
  // (2 952 keys on one thread).
  std::vector<size_t> runs_;
  std::vector<Resolved> resolved_;               // ForEachResolved: each item's key tag and handle
  std::vector<std::vector<uint32_t>> deferred_;  // UpdateManyOn: each run's deferred items
  // UpdateManyOn: the deferred items skipped for a later item's update, and its entry.
  std::vector<std::pair<uint32_t, uint32_t>> skipped_;
  std::vector<std::pair<uint32_t, ObjectOptions>> insert_options_;  // pending inserts' options
  // Per-query buffers, kept to reuse their allocations.
  std::vector<std::pair<Key, Key>> collides_;
  std::vector<std::pair<Key, Key>> uncollides_;
};

}  // namespace bp::detail
