// What the grid's white-box tests share: GridTestPeer, white-box access to a grid's core
// (detail/grid_core.h); a twin of an engine and brute force that must report the same events on
// every query, cubes, and a random scene far from or near the origin.
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <span>
#include <string>
#include <tuple>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

#include "bp/grid.h"
#include "bp/scene_runner.h"
#include "bp/segmented_sap.h"
#include "bp/workload.h"

namespace bp::detail {

// Reaches into a GridCore: runs a query's routing phase alone, reads what it routed, and
// corrupts the core to prove Validate notices.
struct GridTestPeer {
  // Apply's first phase as Apply runs it on one thread (keep in step with GridCore::Apply):
  // the changes routed, no cell applied yet.
  template <class Core, class HB>
  static void Route(Core& core, std::span<const uint32_t> erases, std::span<const HB> updates,
                    std::span<const HB> inserts) {
    core.PlaceFirst(inserts);
    core.defer_locals_ = core.large_count_ == 0;
    core.EraseObjects(erases);
    core.RouteUpdates(updates);
    core.InsertObjects(inserts);
    core.RescanChanged();
  }
  // The rest of Apply, after Route: the cells applied, their changes folded, the size checked.
  template <class Core>
  static void ApplyRouted(Core& core, size_t inserted, size_t erased) {
    core.QueryCells();
    core.live_ = core.live_ + inserted - erased;
    core.MaybeResize();
  }
  // Groups the routed operations by cell (GroupUpdates), as QueryCells would first; the core
  // can then only be dropped.
  template <class Core>
  static void Group(Core& core) {
    core.GroupUpdates();
  }

  // One routed operation of a cell slot: the cell and the object's global handle.
  using Op = std::pair<uint32_t, uint32_t>;
  struct Routed {
    std::vector<Op> updates, erases, inserts;  // in routing order
    std::vector<uint32_t> touched;             // the cells touched, in order
  };
  template <class Core>
  static Routed RoutedOps(const Core& core) {
    Routed out;
    const auto global = [&](uint32_t cell, uint32_t local) {
      return core.cells_[cell]->global[local];
    };
    for (const auto& r : core.routed_)
      out.updates.emplace_back(r.cell, global(r.cell, r.update.handle));
    for (const auto& r : core.routed_erases_)
      out.erases.emplace_back(r.cell, global(r.cell, r.local));
    for (size_t k = 0; k < core.routed_inserts_.size(); ++k) {
      const auto& r = core.routed_inserts_[k];
      // A deferred insert still carries its global handle (see GridRouting::EnterCell).
      const bool deferred = core.routed_insert_refs_[k] != Core::kNone;
      out.inserts.emplace_back(r.cell,
                               deferred ? r.update.handle : global(r.cell, r.update.handle));
    }
    out.touched = core.touched_;
    return out;
  }
  // A cell's work entry: its routed updates, erases and inserts.
  template <class Core>
  static std::tuple<uint32_t, uint32_t, uint32_t> Work(const Core& core, uint32_t cell) {
    const auto& w = core.cell_work_[cell];
    return {w.updates, w.erases, w.inserts};
  }
  // After Group: where the cell's run of updates starts in the grouped array, and its entries
  // as (cell, global handle).
  template <class Core>
  static std::vector<Op> GroupedUpdates(const Core& core, uint32_t cell, uint32_t* begin) {
    const auto& w = core.cell_work_[cell];
    *begin = w.begin;
    std::vector<Op> out;
    for (uint32_t i = w.begin; i < w.begin + w.updates; ++i) {
      out.emplace_back(cell, core.cells_[cell]->global[core.grouped_[i].handle]);
    }
    return out;
  }
  // The cells small object h lies in, in row-major order of its cell range.
  template <class Core>
  static std::vector<uint32_t> CellsOf(const Core& core, uint32_t h) {
    const auto& o = core.objects_[h];
    std::vector<uint32_t> out;
    for (uint32_t i = 0; i < o.nrefs; ++i) out.push_back(core.refs_[o.refs + i].cell);
    return out;
  }

  // Drops the last entry of the large-object bins (detail/grid_large.h).
  // Forces the large set's block tests onto kernel k (one this CPU runs).
  template <class Core>
  static void SetBlockKernel(Core& core, BlockKernel k) {
    core.block_kernel_ = k;
  }
  template <class Core>
  static void DropLargeBinEntry(Core& core) {
    // The last listed entry's slot falls out of every owned mask.
    auto& block = core.blocks_.back();
    const int last = 31 - std::countl_zero(uint32_t{block.owned[0]});
    for (auto& m : block.owned) m = static_cast<uint16_t>(m & ~(1u << last));
  }
  // The room the large set holds for its candidate tests' changes (detail/grid_large.h).
  template <class Core>
  static size_t LargeChangeRoom(const Core& core) {
    return core.large_changes_.size();
  }
  template <class Core>
  static void AddWitness(Core& core) {
    bool added = false;
    core.tracker_.ForEachOverlap([&](uint32_t a, uint32_t b) {
      if (added) return;
      const uint64_t p = HandlePair(a, b);
      ++core.extra_[core.tracker_.ShardOf(p)].FindOrInsert(p, 0);
      added = true;
    });
  }
};

}  // namespace bp::detail

namespace bp::test {

using SegmentedGridCore = detail::GridCore<detail::SegmentedSapCore<3, float>>;

// Runs the same calls on an engine and on brute force; every query must report the same events.
template <int K, class T, class Engine>
class Twin {
 public:
  using BoxType = Box<K, T>;
  explicit Twin(Engine* engine) : engine_(engine) {}

  void Insert(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_->Insert(key, b).ok());
    ASSERT_TRUE(oracle_.Insert(key, b).ok());
  }
  void Update(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_->Update(key, b).ok());
    ASSERT_TRUE(oracle_.Update(key, b).ok());
  }
  void Erase(uint64_t key) {
    ASSERT_TRUE(engine_->Erase(key).ok());
    ASSERT_TRUE(oracle_.Erase(key).ok());
  }
  void Query() {
    RecordingSink<uint64_t> got, want;
    engine_->Query(got);
    oracle_.Query(want);
    ASSERT_EQ(got.uncollides, want.uncollides) << "query " << queries_;
    ASSERT_EQ(got.collides, want.collides) << "query " << queries_;
    ASSERT_EQ(engine_->GetStats().overlaps, oracle_.GetStats().overlaps);
    events_ += got.collides.size() + got.uncollides.size();
    ++queries_;
  }
  size_t events() const { return events_; }

 private:
  Engine* engine_;
  BruteForce<K, T> oracle_;
  size_t queries_ = 0;
  size_t events_ = 0;
};

// A cube from lo, extent wide on every axis (test_support.h's Cube takes both corners).
template <int K, class T>
Box<K, T> CubeAt(T lo, T extent) {
  Box<K, T> b;
  for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
    b.lo[a] = lo;
    b.hi[a] = static_cast<T>(lo + extent);
  }
  return b;
}

// A random scene around `origin` with boxes of about `unit`, moved, churned and teleported.
template <int K, class T, class Engine>
void RandomScene(Engine* engine, double origin, double unit, uint64_t seed, int objects = 120,
                 int frames = 30) {
  SCOPED_TRACE("origin " + std::to_string(origin) + " unit " + std::to_string(unit));
  Twin<K, T, Engine> twin(engine);
  std::mt19937_64 rng(seed);
  auto coord = [&](double span) {
    double x = origin + std::uniform_real_distribution<double>(-span, span)(rng) * unit;
    return static_cast<T>(x);
  };
  auto box = [&]() {
    Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      T lo = coord(8);
      T hi = static_cast<T>(static_cast<double>(lo) +
                            std::uniform_real_distribution<double>(0, 2)(rng) * unit);
      b.lo[a] = lo;
      b.hi[a] = hi < lo ? lo : hi;
    }
    return b;
  };
  std::vector<uint64_t> live;
  uint64_t next = 1;
  for (int i = 0; i < objects; ++i) {
    twin.Insert(next, box());
    live.push_back(next++);
  }
  twin.Query();
  for (int f = 0; f < frames && !::testing::Test::HasFailure(); ++f) {
    for (int i = 0; i < objects / 4; ++i) {
      size_t j = rng() % live.size();
      switch (rng() % 5) {
        case 0:
          twin.Erase(live[j]);
          live[j] = next;
          twin.Insert(next++, box());
          break;
        default:
          twin.Update(live[j], box());
      }
    }
    twin.Query();
  }
  EXPECT_GT(twin.events(), 0u);
}

}  // namespace bp::test
