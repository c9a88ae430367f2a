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

// The engines are built out of line (test_engines.cc, by bp::NewEngine, compiled once in
// bp_engines for the daemon, bpbench and the tests alike), so that a test which sees them only as
// Broadphase<K, T> does not compile every engine again: under ASan the typed suites took half an
// hour to build when each of them did.
/// The cell type of a test grid (kDensePortable: dense cells forced onto the portable kernel, so
/// that a CPU with a wide kernel checks the portable one too; kDenseRows: dense cells that never
/// keep a pair matrix; kDenseSmallMatrix: dense cells whose matrix is capped at 32 slots, so that
/// cells cross between the two modes, on the AVX2 kernel where the CPU has it, so that a CPU
/// with AVX-512 checks AVX2 too).
enum class CellKind { kSegmented, kBatch, kDense, kDensePortable, kDenseRows, kDenseSmallMatrix };
/// True iff the kind is one of dense cells.
constexpr bool IsDense(CellKind kind) {
  return kind == CellKind::kDense || kind == CellKind::kDensePortable ||
         kind == CellKind::kDenseRows || kind == CellKind::kDenseSmallMatrix;
}

/// A grid for the tests: its cell type, cell size (0: automatic), the most cells an object may
/// span before it is kept as a large object, and the pool's threads.
struct GridSpec {
  CellKind cell = CellKind::kSegmented;
  double cell_size = 0;
  uint32_t max_cells = 16;
  unsigned threads = 1;
};

/// A grid's options from a spec (any of the grids' option structs).
template <class Options>
Options GridOptionsOf(const GridSpec& spec) {
  Options options;
  options.cell_size = spec.cell_size;
  options.max_cells_per_object = spec.max_cells;
  options.threads = spec.threads;
  options.parallel_routing_from = 2;  // the tests' queries are small
  return options;
}

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewBruteForce();
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSegmentedSap(const SegmentedSapOptions& options);
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewBatchSap(const BatchSapOptions& options);
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDynamicOctree(const DynamicOctreeOptions& options);
/// Segmented and batch cells.
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSapCellGrid(const GridSpec& spec);
/// Dense cells, on the widest kernel, the portable one or AVX2.
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDenseGrid(const GridSpec& spec);

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewGrid(const GridSpec& spec) {
  return IsDense(spec.cell) ? NewDenseGrid<K, T>(spec) : NewSapCellGrid<K, T>(spec);
}

/// The shapes the typed suites run the grids on: 2-D and 3-D; float, double and int32
/// coordinates. The single-structure engines also run 3-D uint32 (the edge cases' unsigned
/// coordinates).
#define BP_TEST_FOR_EACH_SHAPE(X) \
  X(2, float) X(3, float) X(2, double) X(3, double) X(2, int32_t) X(3, int32_t)

struct MakeBruteForce {
  template <int K, class T>
  static std::unique_ptr<Broadphase<K, T>> Create() {
    return NewBruteForce<K, T>();
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
    return NewSegmentedSap<K, T>(options);
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
    return NewBatchSap<K, T>(options);
  }
  static std::string Name() { return "BatchSap_g" + std::to_string(kGlobalPercent); }
};

/// A grid over SegmentedSap, BatchSap or dense cells with cell size kCellTenths / 10 (0:
/// automatic), at most kMaxCells cells per object before it counts as large, and kThreads
/// threads applying the cells.
template <CellKind kCell, int kCellTenths, uint32_t kMaxCells = 16, unsigned kThreads = 1>
struct MakeGrid {
  template <int K, class T>
  static std::unique_ptr<Broadphase<K, T>> Create() {
    return NewGrid<K, T>(GridSpec{kCell, kCellTenths / 10.0, kMaxCells, kThreads});
  }
  static std::string Name() {
    const char* kind = kCell == CellKind::kBatch              ? "GridBatchSap"
                       : kCell == CellKind::kDense            ? "GridDense"
                       : kCell == CellKind::kDensePortable    ? "GridDensePortable"
                       : kCell == CellKind::kDenseRows        ? "GridDenseRows"
                       : kCell == CellKind::kDenseSmallMatrix ? "GridDenseSmallMatrix"
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
    return NewDynamicOctree<K, T>(options);
  }
  static std::string Name() {
    return "DynamicOctree_c" + std::to_string(kCapacity) + "_d" + std::to_string(kMaxDepth);
  }
};

/// Seeds to run: BP_TEST_SEED alone if set, else `count` seeds derived from `base`, or
/// BP_TEST_SEEDS of them (a soak run: BP_TEST_SEEDS=500). A sanitizer build (BP_TEST_SANITIZED,
/// tests/CMakeLists.txt) runs the first half of them, rounded up: there the seeds look for
/// memory errors and undefined behaviour on the paths the first seeds already take, at five times
/// the release stage's cost, while the release stage (validators on) checks every seed against
/// the oracle.
inline std::vector<uint64_t> TestSeeds(uint64_t base, int count) {
  if (const char* env = std::getenv("BP_TEST_SEED")) return {std::strtoull(env, nullptr, 0)};
#if defined(BP_TEST_SANITIZED)
  count = (count + 1) / 2;
#endif
  if (const char* env = std::getenv("BP_TEST_SEEDS")) count = std::atoi(env);
  std::vector<uint64_t> seeds;
  for (int i = 0; i < count; ++i) seeds.push_back(base + static_cast<uint64_t>(i) * 7919);
  return seeds;
}

}  // namespace bp::test
