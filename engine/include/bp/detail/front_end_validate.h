// FrontEnd::Validate: every invariant of the front end's parts recomputed from scratch (key map
// against the slots, staged entries against pending slots, free lists, fat boxes), then the
// core's own Validate. O(n); run after every query when BP_VALIDATE is set.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "bp/detail/front_end.h"

namespace bp::detail {

template <class Core, class Key>
Status FrontEnd<Core, Key>::Validate() const {
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

}  // namespace bp::detail
