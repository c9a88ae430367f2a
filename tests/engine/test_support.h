// Test support shared by the engine suites: a recording sink, a model oracle that is simpler
// than any engine (std::map of boxes, all pairs recomputed at every query), engine configs for
// the typed suites, and seed handling (BP_TEST_SEED replays one seed).
#pragma once

#include <cstdint>
#include <cstdlib>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "bp/batch_sap.h"
#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/brute_force.h"
#include "bp/dynamic_octree.h"
#include "bp/grid.h"
#include "bp/segmented_sap.h"

namespace bp::test {

/// The box [lo, hi] on every axis.
template <int K, class T>
Box<K, T> Cube(T lo, T hi) {
  Box<K, T> b;
  for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
    b.lo[a] = lo;
    b.hi[a] = hi;
  }
  return b;
}

/// Records the events of queries, in order.
template <class Key = uint64_t>
class RecordingSink final : public EventSink<Key> {
 public:
  void Collide(const Key& a, const Key& b) override { collides.emplace_back(a, b); }
  void Uncollide(const Key& a, const Key& b) override { uncollides.emplace_back(a, b); }
  void Clear() {
    collides.clear();
    uncollides.clear();
  }
  std::vector<std::pair<Key, Key>> collides;
  std::vector<std::pair<Key, Key>> uncollides;
};

/// The model: boxes (and options) by key as of the calls made so far; pairs recomputed from
/// scratch, keeping those the options accept.
template <int K, Coordinate T>
class ModelOracle {
 public:
  using BoxType = Box<K, T>;
  using Pair = std::pair<uint64_t, uint64_t>;

  std::map<uint64_t, BoxType>& boxes() { return boxes_; }
  const std::map<uint64_t, BoxType>& boxes() const { return boxes_; }
  /// Non-default options by key (absent: the defaults).
  std::map<uint64_t, ObjectOptions>& options() { return options_; }

  /// All overlapping, accepted pairs (a < b) of the current boxes.
  std::set<Pair> Pairs() const {
    std::set<Pair> out;
    for (auto i = boxes_.begin(); i != boxes_.end(); ++i) {
      for (auto j = std::next(i); j != boxes_.end(); ++j) {
        if (Overlaps(i->second, j->second) && Accepts(OptionsOf(i->first), OptionsOf(j->first)))
          out.emplace(i->first, j->first);
      }
    }
    return out;
  }
  ObjectOptions OptionsOf(uint64_t key) const {
    auto it = options_.find(key);
    return it == options_.end() ? ObjectOptions{} : it->second;
  }

  /// The events a query must report now, in canonical order; remembers the new pair set.
  void Query(std::vector<Pair>* out_collides, std::vector<Pair>* out_uncollides) {
    std::set<Pair> now = Pairs();
    out_collides->clear();
    out_uncollides->clear();
    for (const Pair& p : now) {
      if (!last_.count(p)) out_collides->push_back(p);
    }
    for (const Pair& p : last_) {
      if (!now.count(p)) out_uncollides->push_back(p);
    }
    last_ = std::move(now);
  }
  const std::set<Pair>& last_pairs() const { return last_; }

 private:
  std::map<uint64_t, BoxType> boxes_;
  std::map<uint64_t, ObjectOptions> options_;
  std::set<Pair> last_;
};

/// An engine configuration for the typed suites.
template <int K_, class T_, class Make>
struct EngineConfig {
  static constexpr int K = K_;
  using T = T_;
  static std::unique_ptr<Broadphase<K, T>> Create() { return Make::template Create<K, T>(); }
  static std::string Name() { return Make::Name(); }
};

struct MakeBruteForce {
  template <int K, class T>
  static std::unique_ptr<Broadphase<K, T>> Create() {
    return std::make_unique<BruteForce<K, T>>();
  }
  static std::string Name() { return "BruteForce"; }
};

/// SegmentedSap with the given chunk capacity, global-sort fraction (percent; -1: never),
/// bulk-load minimum (0: never) and presorted minimum (0: never; 1: every insert and erase).
template <uint32_t kCapacity, int kGlobalPercent, uint32_t kBulkMin = 64,
          uint32_t kPresortedMin = SegmentedSapOptions{}.presorted_min>
struct MakeSegmentedSap {
  template <int K, class T>
  static std::unique_ptr<Broadphase<K, T>> Create() {
    SegmentedSapOptions options;
    options.chunk_capacity = kCapacity;
    options.global_sort_fraction = kGlobalPercent < 0 ? 1e300 : kGlobalPercent / 100.0;
    options.bulk_load_min = kBulkMin;
    options.presorted_min = kPresortedMin;
    return std::make_unique<SegmentedSap<K, T>>(options);
  }
  static std::string Name() {
    return "SegmentedSap_c" + std::to_string(kCapacity) + "_g" + std::to_string(kGlobalPercent) +
           "_b" + std::to_string(kBulkMin) + "_p" + std::to_string(kPresortedMin);
  }
};

/// BatchSap with the given global-sort fraction (percent; -1: never, so queries without inserts
/// or erases always sort per moved object).
template <int kGlobalPercent>
struct MakeBatchSap {
  template <int K, class T>
  static std::unique_ptr<Broadphase<K, T>> Create() {
    BatchSapOptions options;
    options.global_sort_fraction = kGlobalPercent < 0 ? 1e300 : kGlobalPercent / 100.0;
    return std::make_unique<BatchSap<K, T>>(options);
  }
  static std::string Name() { return "BatchSap_g" + std::to_string(kGlobalPercent); }
};

/// The cell type of a test grid.
/// The cell type of a test grid (kDensePortable: dense cells forced onto the portable kernel, so
/// that a CPU with AVX-512 checks both kernels).
enum class CellKind { kSegmented, kBatch, kDense, kDensePortable };

/// A grid over SegmentedSap, BatchSap or dense cells with cell size kCellTenths / 10 (0:
/// automatic), at most kMaxCells cells per object before it counts as large, and kThreads
/// threads applying the cells.
template <CellKind kCell, int kCellTenths, uint32_t kMaxCells = 16, unsigned kThreads = 1>
struct MakeGrid {
  template <int K, class T>
  static std::unique_ptr<Broadphase<K, T>> Create() {
    auto set = [](auto& options) {
      options.cell_size = kCellTenths / 10.0;
      options.max_cells_per_object = kMaxCells;
      options.threads = kThreads;
      options.parallel_routing_from = 2;  // the tests' queries are small
    };
    if constexpr (kCell == CellKind::kBatch) {
      GridBatchSapOptions options;
      set(options);
      return std::make_unique<GridBatchSap<K, T>>(options);
    } else if constexpr (kCell == CellKind::kDense || kCell == CellKind::kDensePortable) {
      GridDenseOptions options;
      set(options);
      options.cell.wide_kernel = kCell == CellKind::kDense;
      return std::make_unique<GridDense<K, T>>(options);
    } else {
      GridSegmentedSapOptions options;
      set(options);
      return std::make_unique<GridSegmentedSap<K, T>>(options);
    }
  }
  static std::string Name() {
    const char* kind = kCell == CellKind::kBatch           ? "GridBatchSap"
                       : kCell == CellKind::kDense         ? "GridDense"
                       : kCell == CellKind::kDensePortable ? "GridDensePortable"
                                                           : "GridSegmentedSap";
    return std::string(kind) + "_s" + std::to_string(kCellTenths) + "_m" +
           std::to_string(kMaxCells) + (kThreads > 1 ? "_t" + std::to_string(kThreads) : "");
  }
};

/// DynamicOctree with the given node capacity and maximum depth (0: the defaults).
template <uint32_t kCapacity = 0, uint32_t kMaxDepth = 0>
struct MakeDynamicOctree {
  template <int K, class T>
  static std::unique_ptr<Broadphase<K, T>> Create() {
    DynamicOctreeOptions options;
    if (kCapacity != 0) options.max_objects_per_node = kCapacity;
    if (kMaxDepth != 0) options.max_depth = kMaxDepth;
    return std::make_unique<DynamicOctree<K, T>>(options);
  }
  static std::string Name() {
    return "DynamicOctree_c" + std::to_string(kCapacity) + "_d" + std::to_string(kMaxDepth);
  }
};

/// Seeds to run: BP_TEST_SEED alone if set, else `count` seeds derived from `base`, or
/// BP_TEST_SEEDS of them (a soak run: BP_TEST_SEEDS=500).
inline std::vector<uint64_t> TestSeeds(uint64_t base, int count) {
  if (const char* env = std::getenv("BP_TEST_SEED")) return {std::strtoull(env, nullptr, 0)};
  if (const char* env = std::getenv("BP_TEST_SEEDS")) count = std::atoi(env);
  std::vector<uint64_t> seeds;
  for (int i = 0; i < count; ++i) seeds.push_back(base + static_cast<uint64_t>(i) * 7919);
  return seeds;
}

}  // namespace bp::test
