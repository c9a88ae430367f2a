// bp::detail::FrontEndLookAhead: the batch calls (InsertMany, UpdateMany, EraseMany) with their
// look-ups started early. A loop of single calls waits on the key index's line and the slot, one
// item after the other; these loops keep many look-ups in flight (ForEachAhead), or resolve the
// keys on every thread of the core's pool first (ForEachResolved), or stage a large UpdateMany
// itself on the pool (UpdateManyOn). Each ends as the loop of single calls would, item by item:
// the same staged batch, the same refusals in the same order.
//
// Thread safety: none for callers; on the pool, the look-ups read only the key index and the
// slots, and a claimed slot is written by the one thread that claimed it (an atomic compare-and-
// swap of its epoch).
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "bp/detail/assert.h"
#include "bp/detail/front_end_events.h"
#include "bp/detail/prefetch.h"
#include "bp/detail/worker_pool.h"

namespace bp::detail {

template <class Core, class Key>
class FrontEndLookAhead : public FrontEndEvents<Core, Key> {
  using Base = FrontEndEvents<Core, Key>;

 protected:
  using Base::epoch_;
  using Base::fat_;
  using Base::index_;
  using Base::kNoHandle;
  using Base::Lookup;
  using Base::LookupPool;
  using Base::margin_;
  using Base::PendingOf;
  using Base::slots_;
  using Base::tombstones_;
  using Base::updates_;
  using Base::UpdateTagged;
  using typename Base::KeyedItem;
  using typename Base::Pending;
  using typename Base::Refused;
  using typename Base::Slot;
  using typename Base::T;

  using Base::Base;

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
  size_t ForEachAhead(std::span<const Item> items, KeyOf&& key_of, const Refused& refused,
                      Apply&& apply) {
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
  size_t UpdateManyOn(WorkerPool* pool, std::span<const KeyedItem> items, const Refused& refused) {
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
  // white-box test runs the runs in another order (FrontEndTestPeer).
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
  void ClaimRun(std::span<const KeyedItem> items, size_t base, size_t begin, size_t end) {
    // Whole deferred lists: no other run pushes to this run's.
    BP_ASSERT(begin % kResolveRun == 0 && (end % kResolveRun == 0 || end == items.size()));
    const auto key_of = [](const KeyedItem& item) -> const Key& { return item.key; };
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
  size_t EndClaims(std::span<const KeyedItem> items, size_t base, size_t runs,
                   const Refused& refused) {
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
      const KeyedItem& item = items[at];
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
  void Rewind(std::span<const KeyedItem> items, size_t base, size_t at) {
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
      const KeyedItem& item = items[i];
      const Status s = UpdateTagged(item.key, KeyIndex<Key>::Tag(item.key), item.box, kNoHandle);
      BP_ASSERT(s.ok());
      (void)s;
    }
  }

  // Stages item as updates_[entry] if it can claim the slot of its key (see UpdateManyOn);
  // false if not (the entry is then left for the caller to retire). Runs on a pool thread.
  bool ClaimUpdate(const KeyedItem& item, uint32_t tag, uint32_t hint, size_t entry) {
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
  Status UpdateDeferred(const KeyedItem& item, size_t base, size_t entry, size_t end) {
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
  size_t ForEachResolved(std::span<const Item> items, KeyOf&& key_of, const Refused& refused,
                         Apply&& apply) {
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

  struct Resolved {
    uint32_t tag, handle;
  };
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
};

}  // namespace bp::detail
