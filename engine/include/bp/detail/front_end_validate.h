// FrontEnd::Validate: every invariant of the front end's parts recomputed from scratch, one
// validator per part (the slots against the staged lists; the key map against the slots; the
// free lists; the fat boxes; no event left behind), then the core's own Validate. O(n); run
// after every query when BP_VALIDATE is set.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "bp/detail/front_end.h"

namespace bp::detail {

template <class Core, class Key>
Status FrontEnd<Core, Key>::Validate() const {
  size_t present = 0, dead = 0;
  if (Status s = ValidateSlots(&present, &dead); !s.ok()) return s;
  if (Status s = ValidateKeyMap(present); !s.ok()) return s;
  if (Status s = ValidateFreeLists(dead); !s.ok()) return s;
  if (Status s = ValidateFatBoxes(); !s.ok()) return s;
  if (Status s = ValidateEventsDrained(); !s.ok()) return s;
  return core_.Validate();
}

template <class Core, class Key>
Status FrontEnd<Core, Key>::Invalid(const char* what) {
  return Status(StatusCode::kInternal, std::string("front end: ") + what);
}

// The slots and staged calls (front_end_slots.h, invariants 2, 4 and 5): each pending slot's
// entry in its kind's list, the live count, the tombstones, no options left from the last
// query. Counts the present and the dead slots.
template <class Core, class Key>
Status FrontEnd<Core, Key>::ValidateSlots(size_t* present_out, size_t* dead_out) const {
  if (!insert_options_.empty()) return Invalid("insert options left after a query");
  size_t live = 0, present = 0, pending = 0, dead = 0;
  for (uint32_t h = 0; h < slots_.size(); ++h) {
    const Slot& slot = slots_[h];
    if (LiveOf(slot)) ++live;
    if (Present(slot)) ++present;
    switch (PendingOf(slot)) {
      case Pending::kNone:
        if (!LiveOf(slot)) ++dead;
        break;
      case Pending::kErase:
        if (!slot.live) return Invalid("erase pending for a dead slot");
        if (slot.stage >= erases_.size() || erases_[slot.stage] != h) {
          return Invalid("pending erase not staged");
        }
        ++pending;
        break;
      case Pending::kUpdate:
        if (!slot.live) return Invalid("update pending for a dead slot");
        if (slot.stage >= updates_.size() || updates_[slot.stage].handle != h) {
          return Invalid("pending update not staged");
        }
        ++pending;
        break;
      case Pending::kInsert:
        if (slot.live) return Invalid("insert pending for a live slot");
        if (slot.stage >= inserts_.size() || inserts_[slot.stage].handle != h) {
          return Invalid("pending insert not staged");
        }
        ++pending;
        break;
    }
  }
  if (live != core_.live()) return Invalid("live counts disagree");
  size_t staged = 0, tombstones = 0;
  for (uint32_t h : erases_) ++(h == kNoHandle ? tombstones : staged);
  for (const auto& hb : updates_) ++(hb.handle == kNoHandle ? tombstones : staged);
  for (const auto& hb : inserts_) ++(hb.handle == kNoHandle ? tombstones : staged);
  if (staged != pending) return Invalid("staged entries differ from pending slots");
  if (tombstones != tombstones_) return Invalid("tombstone count off");
  *present_out = present;
  *dead_out = dead;
  return Status::Ok();
}

// The key map (front_end_slots.h, invariant 1): every present key mapped to its slot, and
// nothing else but a live key with a pending erase.
template <class Core, class Key>
Status FrontEnd<Core, Key>::ValidateKeyMap(size_t present) const {
  for (uint32_t h = 0; h < slots_.size(); ++h) {
    if (Present(slots_[h]) && Find(slots_[h].key) != h) return Invalid("present key not mapped");
  }
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
  if (index_error != nullptr) return Invalid(index_error);
  if (index_.size() < present) return Invalid("key map smaller than the present slots");
  return Status::Ok();
}

// The free lists (front_end_slots.h, invariant 5): each dead slot on free_ or cancelled_, once.
template <class Core, class Key>
Status FrontEnd<Core, Key>::ValidateFreeLists(size_t dead) const {
  std::vector<uint8_t> free_seen(slots_.size(), 0);
  for (const auto* list : {&free_, &cancelled_}) {
    for (uint32_t h : *list) {
      if (h >= slots_.size() || free_seen[h]++) return Invalid("free list broken");
      const Slot& slot = slots_[h];
      if (LiveOf(slot) || PendingOf(slot) != Pending::kNone) return Invalid("free handle in use");
    }
  }
  if (dead != free_.size() + cancelled_.size()) return Invalid("a dead slot is lost");
  return Status::Ok();
}

// The fat boxes (front_end_fat.h): with a margin, one per handle.
template <class Core, class Key>
Status FrontEnd<Core, Key>::ValidateFatBoxes() const {
  if (margin_ > T{} && fat_.size() != slots_.size()) return Invalid("fat boxes missing");
  return Status::Ok();
}

// The events (front_end_events.h): every change of the last query drained from the tracker.
template <class Core, class Key>
Status FrontEnd<Core, Key>::ValidateEventsDrained() const {
  if (core_.tracker().pending_changes() != 0) return Invalid("changed pairs left after a query");
  return Status::Ok();
}

}  // namespace bp::detail
