// What the front end's tests share: FrontEndTestPeer, white-box access to a front end
// (detail/front_end.h): the epoch, UpdateMany's claims run in an order two threads take only by
// chance, and corruptions of each part that Validate must notice; and FrontEndEngines, one engine
// of each family with a variety of coordinates.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <span>

#include "test_support.h"
#include <gtest/gtest.h>

namespace bp::detail {
// Moves a front end's epoch (see FrontEnd) between queries.
struct FrontEndTestPeer {
  template <class Engine>
  static uint32_t epoch(const Engine& e) {
    return e.epoch_;
  }
  template <class Engine>
  static void set_epoch(Engine& e, uint32_t epoch) {
    e.epoch_ = epoch;
  }
  // UpdateMany as on a pool whose threads claimed the runs from the last to the first: every
  // item named again in an earlier run is deferred behind a later item's claim (one thread).
  template <class Engine>
  static size_t UpdateManyRunsReversed(Engine& e, std::span<const typename Engine::Item> items,
                                       const typename Engine::RefusedFn& refused) {
    const size_t base = e.updates_.size();
    const size_t runs = e.BeginClaims(items.size());
    for (size_t r = runs; r-- > 0;) {
      const size_t begin = r * Engine::kResolveRun;
      e.ClaimRun(items, base, begin, std::min(items.size(), begin + Engine::kResolveRun));
    }
    return e.EndClaims(items, base, runs, refused);
  }

  // One corruption per part of the front end, for Validate to notice (see ValidateSlots and
  // the others, detail/front_end_validate.h): what is broken, and the word its message names.
  enum class Corruption { kTombstones, kKeyMap, kFreeList, kFatBoxes, kUndrainedEvent };
  template <class Engine>
  static void Corrupt(Engine& e, Corruption what) {
    switch (what) {
      case Corruption::kTombstones:  // the slots' staged lists
        ++e.tombstones_;
        break;
      case Corruption::kKeyMap:  // a present key no longer mapped
        for (uint32_t h = 0; h < e.slots_.size(); ++h) {
          if (e.Present(e.slots_[h])) {
            e.index_.Erase(e.slots_[h].key, h);
            return;
          }
        }
        break;
      case Corruption::kFreeList:  // a live handle on the free list
        for (uint32_t h = 0; h < e.slots_.size(); ++h) {
          if (e.LiveOf(e.slots_[h])) {
            e.free_.push_back(h);
            return;
          }
        }
        break;
      case Corruption::kFatBoxes:
        e.fat_.pop_back();
        break;
      case Corruption::kUndrainedEvent:  // a pair changed in the tracker, never drained
        e.core_.tracker().Add(0, 1);
        break;
    }
  }
};
}  // namespace bp::detail

namespace bp::test {

// One engine of each family, over 2-D and 3-D and float, double and int32 coordinates.
using FrontEndEngines = ::testing::Types<
    EngineConfig<3, float, MakeBruteForce>, EngineConfig<3, float, MakeSegmentedSap<32, 7>>,
    EngineConfig<2, double, MakeBatchSap<7>>, EngineConfig<3, double, MakeDynamicOctree<>>,
    EngineConfig<3, float, MakeGrid<CellKind::kSegmented, 0>>,
    EngineConfig<2, int32_t, MakeGrid<CellKind::kBatch, 10, 4>>,
    EngineConfig<3, double, MakeGrid<CellKind::kDense, 10, 4>>>;

}  // namespace bp::test
