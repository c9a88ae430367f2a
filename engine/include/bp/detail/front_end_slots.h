// bp::detail::FrontEndSlots: the front end's keys, handles and staged calls. Each client key
// maps to a dense 32-bit handle (index_), the handle to a slot (the key, and its state), and
// Insert, Update and Erase are validated and staged into the core's next batch
// (InsertTagged, UpdateTagged, EraseTagged).
//
// Calls are staged straight into the core's batch: each slot names its entry (stage) in the list
// of its pending kind (erases_, updates_, inserts_), a second call on the key overwrites or
// retires (tombstones) that entry, and Query hands the lists to the core as they are. The slots
// of updated and inserted objects are not visited again at the query: a slot carries the epoch
// (query count) its pending state belongs to, and a pending insert or update of an earlier epoch
// reads as applied (live, nothing pending) until a later call settles it (see Settle).
//
//
// Object options reach the core's tracker (SetOptions) before the batch that inserts them.
// Erase + insert of a live key with the same options is an update of its handle; with other
// options the insert takes a fresh handle (a "rekey"; FrontEndEvents cancels the pairs it keeps).
//
// Thread safety: none, except the claims of UpdateMany on a pool (FrontEndLookAhead).
// Invariants (checked by FrontEnd::Validate):
//  1. index_ maps key iff the key is present (live at the last query and not erased since,
//     or pending insert), or is live with a pending erase and was not reinserted.
//  2. A handle has at most one live (non-tombstone) entry in the staged lists, the one its slot
//     names, of its pending kind, and only while its slot's epoch is epoch_; handles are freed
//     only inside Query, after the core has applied the batch, so a handle never means two keys
//     within one batch.
//  3. erase + insert of one live key with equal options between queries becomes an update of
//     the same handle (unless the key was rekeyed in between: then it is a fresh handle again,
//     and the cancellation keeps the events exact).
//  4. A live handle's options are held by the core's tracker alone (set at the query that
//     inserts it); a pending insert's options wait in insert_options_ (unless they are the
//     defaults and no object has had others).
//  5. A slot that is neither live nor pending is in free_ or (inserted and erased since the last
//     query) in cancelled_, and in no staged list (a cancelled insert's insert_options_ entry
//     stays until the query, which skips it).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/front_end_contract.h"
#include "bp/detail/front_end_fat.h"
#include "bp/detail/huge_alloc.h"
#include "bp/detail/key_index.h"
#include "bp/detail/pair_tracker.h"
#include "bp/detail/worker_pool.h"
#include "bp/object_options.h"

namespace bp::detail {

template <class Core, class Key>
class FrontEndSlots : public FatBoxes<Core::kDim, typename Core::Coord> {
 protected:
  static constexpr int K = Core::kDim;
  using T = typename Core::Coord;
  using Fat = FatBoxes<K, T>;
  using typename Fat::BoxType;
  using KeyedItem = KeyedBox<K, T, Key>;
  using Refused = typename Broadphase<K, T, Key>::RefusedFn;
  using Fat::fat_;
  using Fat::fat_skips_;
  using Fat::FatEnough;
  using Fat::Keep;
  using Fat::margin_;

  FrontEndSlots(const typename Core::Options& options, T margin) : Fat(margin), core_(options) {}

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

  // The handle key maps to, or kNoHandle. hint is a handle the index gave for key's tag at its
  // current version (KeyIndex::Guess, see ForEachAhead) or kNoHandle: if its slot holds key, it
  // is key's handle (an entry's handle holds the key it is stored for, and the table has not
  // changed since), and the probe is saved; else the index is searched.
  uint32_t Lookup(const Key& key, uint32_t tag, uint32_t hint) const {
    if (hint < slots_.size() && slots_[hint].key == key) return hint;
    return index_.Find(key, tag, [this](uint32_t x) -> const Key& { return slots_[x].key; });
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

  // Update, with key's KeyIndex tag computed by the caller. Flattened: every update of a frame
  // comes here, and GCC leaves the staging's emplace_back out of line (a call per update) once
  // a translation unit has used its inlining budget, which any change elsewhere in the unit
  // can bring about; the error paths it would inline are out of line (noinline).
  [[gnu::flatten]] Status UpdateTagged(const Key& key, uint32_t tag, const BoxType& box,
                                       uint32_t hint) {
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

  [[gnu::noinline, gnu::cold]] static Status Annotate(const Status& s, const char* what) {
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
  bool rekeyed_ = false;  // a key took a fresh handle since the last query
  uint32_t epoch_ = 1;  // 1 + queries so far, wrapping past 0 (NextEpoch); a new slot's 0 is stale
  HugeVector<Slot> slots_;
  KeyIndex<Key> index_;  // key -> handle (see invariant 1)
  std::vector<uint32_t> free_;
  std::vector<uint32_t> cancelled_;  // handles inserted and erased since the last query
  // The batch being staged: the pending calls by kind (kNoHandle: retired by a later call).
  HugeVector<uint32_t> erases_;
  HugeVector<HandleBox<K, T>> updates_;
  HugeVector<HandleBox<K, T>> inserts_;
  size_t tombstones_ = 0;
  std::vector<std::pair<uint32_t, ObjectOptions>> insert_options_;  // pending inserts' options
};

}  // namespace bp::detail
