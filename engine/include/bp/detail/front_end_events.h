// bp::detail::FrontEndEvents: a query's events in canonical order. The core's changed handle
// pairs are drained from its tracker, turned into key pairs (the smaller key first), and sorted,
// the uncollides apart from the collides; they are delivered uncollides first. A rekeyed key's
// pairs that it keeps are reported once as uncollide and once as collide by the core, and cancel
// out here (CancelRekeyedPairs) before the events go out.
//
// Thread safety: none; with the core's pool, the two conversions (and the commit of the erased
// slots) run side by side, sharing only reads of the slots' keys.
// Invariants: between queries the tracker holds no pending change (FrontEnd::Validate).
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "bp/broadphase.h"
#include "bp/detail/front_end_slots.h"
#include "bp/detail/pair_sort.h"
#include "bp/detail/worker_pool.h"

namespace bp::detail {

template <class Core, class Key>
class FrontEndEvents : public FrontEndSlots<Core, Key> {
  using Base = FrontEndSlots<Core, Key>;

 protected:
  using Base::cancelled_;
  using Base::CommitErases;
  using Base::core_;
  using Base::erases_;
  using Base::free_;
  using Base::PoolFor;
  using Base::rekeyed_;
  using Base::slots_;
  using typename Base::T;

  using Base::Base;

  // Keys the core's changed pairs (the drained tracker's) into collides_ and uncollides_, and
  // commits the erased slots unless `committed` (the core did it beside its apply).
  void KeyEvents(bool committed) {
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
  }

  // Delivers the last query's events: every uncollide, then every collide, each in key order.
  void Deliver(EventSink<Key>& sink) const {
    for (const auto& [a, b] : uncollides_) sink.Uncollide(a, b);
    for (const auto& [a, b] : collides_) sink.Collide(a, b);
  }

  // The keys of the drained pairs drained_[now] into collides_ (now 1) or uncollides_, sorted
  // (SortKeyPairs: a radix sort for a frame of many integral-keyed events). The slots of a frame's
  // pairs lie all over the table: their keys are prefetched kKeysAhead pairs ahead.
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
    SortKeyPairs(out, &sort_scratch_[now]);
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

  struct Drained {
    uint32_t a, b;
  };
  // The tracker's changes of a query, before their keys: [0] the pairs that stopped
  // overlapping, [1] those that started.
  std::array<std::vector<Drained>, 2> drained_;
  // An erase's commit costs about as much as this many look-ups or drained pairs (a probe run
  // scanned to its end and shifted back): what the events phase weighs against PoolFor.
  static constexpr size_t kEraseWeight = 4;
  // Per-query buffers, kept to reuse their allocations.
  std::vector<std::pair<Key, Key>> collides_;
  std::vector<std::pair<Key, Key>> uncollides_;
  std::array<std::vector<std::pair<Key, Key>>, 2> sort_scratch_;  // by drained_'s index
};

}  // namespace bp::detail
