// The typed differential suite: every engine, 2-D and 3-D, float/double/int32 coordinates, driven
// by seeded random operation sequences; every query's events must equal the model oracle's set
// difference exactly (same pairs, same canonical order), and the engine's validators must pass.
// Replay one seed with BP_TEST_SEED=<seed>.
#include <algorithm>
#include <cstdint>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

namespace bp::test {
namespace {

// How a scenario draws its operations.
struct Scenario {
  const char* name;
  int lattice;                // coordinates are integers in [-lattice, lattice]
  int max_extent;             // box extents are in [0, max_extent]
  int initial;                // objects inserted before the first query
  int frames;                 // queries after the first
  int ops_per_frame;          // upper bound of random operations per frame
  bool filtered = false;      // objects get random categories, masks and static flags
  bool statics_only = false;  // filtered by static flags alone (the options' compact form)
};

constexpr Scenario kScenarios[] = {
    // Few distinct coordinates: equal values and exact touching everywhere.
    {"dense_lattice", 12, 4, 60, 70, 30},
    // Wider world, more objects, more motion.
    {"sparse", 400, 30, 160, 50, 60},
    // Few objects, many operations per frame: churn dominates.
    {"churn_heavy", 40, 10, 20, 80, 40},
    // A larger population with hundreds of operations per frame: many chunks, mass teleports,
    // moved fractions above the global-sort threshold.
    {"large", 300, 20, 700, 8, 500},
    // Random object options: three category bits, masks that drop some of them, a third of the
    // objects static; reinserts in one frame may change them (a new handle for an old key).
    {"filtered", 40, 10, 120, 40, 50, true},
    // About a third of the objects static (half of those given options), every category and
    // mask the default: the options' compact form (static flags only) all the way through;
    // reinserts may flip the flag.
    {"static_flags", 40, 10, 120, 40, 50, true, true},
};

// The driver depends on the shape alone, so that it is compiled once per shape rather than once
// per engine and shape; the engine comes from a factory.
template <int K, class T>
class DifferentialCore : public ::testing::Test {
 protected:
  using BoxType = Box<K, T>;
  using Factory = std::unique_ptr<Broadphase<K, T>> (*)();

  void Run(const std::string& engine, Factory create, const Scenario& sc, uint64_t seed) {
    SCOPED_TRACE("engine=" + engine + " scenario=" + sc.name + " K=" + std::to_string(K) +
                 " seed=" + std::to_string(seed) +
                 " (replay with BP_TEST_SEED=" + std::to_string(seed) + ")");
    sc_ = &sc;
    rng_.seed(seed);
    engine_ = create();
    model_ = {};
    next_key_ = 1;
    erased_keys_.clear();
    for (int i = 0; i < sc.initial; ++i) DoInsert(next_key_++, RandomBox());
    Check(0);
    for (int frame = 1; frame <= sc.frames && !HasFatalFailure() && !HasFailure(); ++frame) {
      int ops =
          Below(5) == 0 ? 0 : static_cast<int>(Below(static_cast<uint64_t>(sc.ops_per_frame)));
      for (int i = 0; i < ops; ++i) RandomOp();
      Check(frame);
    }
  }

 private:
  uint64_t Below(uint64_t n) { return std::uniform_int_distribution<uint64_t>(0, n - 1)(rng_); }
  int Coord() {
    return static_cast<int>(Below(static_cast<uint64_t>(2 * sc_->lattice + 1))) - sc_->lattice;
  }
  BoxType RandomBox() {
    BoxType b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      int lo = Coord();
      int ext = static_cast<int>(Below(static_cast<uint64_t>(sc_->max_extent + 1)));
      b.lo[a] = static_cast<T>(lo);
      b.hi[a] = static_cast<T>(lo + ext);
    }
    return b;
  }
  BoxType Everything() {
    BoxType b;
    bool extreme = Below(2) == 0;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = extreme ? std::numeric_limits<T>::lowest() : static_cast<T>(-2 * sc_->lattice);
      b.hi[a] = extreme ? std::numeric_limits<T>::max()
                        : static_cast<T>(2 * sc_->lattice + sc_->max_extent);
    }
    return b;
  }
  uint64_t RandomLiveKey() {
    auto it = model_.boxes().begin();
    std::advance(it, static_cast<long>(Below(model_.boxes().size())));
    return it->first;
  }

  ObjectOptions RandomOptions() {
    ObjectOptions o;
    if (!sc_->filtered || Below(4) == 0) return o;
    if (sc_->statics_only) {
      o.is_static = Below(2) == 0;
      return o;
    }
    o.category = uint64_t{1} << Below(3);
    o.mask = Below(2) == 0 ? ~uint64_t{0} : ~(uint64_t{1} << Below(3));
    o.is_static = Below(3) == 0;
    return o;
  }
  void DoInsert(uint64_t key, const BoxType& box) {
    ObjectOptions options = RandomOptions();
    Status s = engine_->Insert(key, box, options);
    ASSERT_TRUE(s.ok()) << s.ToString();
    model_.boxes()[key] = box;
    model_.options()[key] = options;
  }
  void DoUpdate(uint64_t key, const BoxType& box) {
    Status s = engine_->Update(key, box);
    ASSERT_TRUE(s.ok()) << s.ToString();
    model_.boxes()[key] = box;
  }
  void DoErase(uint64_t key) {
    Status s = engine_->Erase(key);
    ASSERT_TRUE(s.ok()) << s.ToString();
    model_.boxes().erase(key);
    model_.options().erase(key);
    erased_keys_.push_back(key);
  }

  void RandomOp() {
    bool empty = model_.boxes().empty();
    switch (Below(16)) {
      case 0:
      case 1:  // insert a new key, or re-insert a key erased earlier
        if (!erased_keys_.empty() && Below(3) == 0) {
          uint64_t key = erased_keys_[Below(erased_keys_.size())];
          if (!model_.boxes().count(key)) DoInsert(key, RandomBox());
        } else {
          DoInsert(next_key_++, RandomBox());
        }
        return;
      case 2:  // erase, one key or a batch through EraseMany
        if (!empty) {
          if (Below(4) == 0) {
            EraseBatch();
          } else {
            DoErase(RandomLiveKey());
          }
        }
        return;
      case 3:
      case 4:
      case 5:  // small move
        if (!empty) {
          uint64_t key = RandomLiveKey();
          BoxType b = model_.boxes()[key];
          for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
            T d = static_cast<T>(static_cast<int>(Below(5)) - 2);
            if (b.lo[a] > static_cast<T>(-4 * sc_->lattice) &&
                b.hi[a] < static_cast<T>(4 * sc_->lattice)) {
              b.lo[a] = static_cast<T>(b.lo[a] + d);
              b.hi[a] = static_cast<T>(b.hi[a] + d);
            }
          }
          DoUpdate(key, b);
        }
        return;
      case 6:  // teleport across the whole list
        if (!empty) DoUpdate(RandomLiveKey(), RandomBox());
        return;
      case 7:  // shrink to a point
        if (!empty) {
          uint64_t key = RandomLiveKey();
          BoxType b = model_.boxes()[key];
          for (size_t a = 0; a < static_cast<size_t>(K); ++a) b.hi[a] = b.lo[a];
          DoUpdate(key, b);
        }
        return;
      case 8:  // grow over everything
        if (!empty && Below(3) == 0) DoUpdate(RandomLiveKey(), Everything());
        return;
      case 9:  // erase and re-insert one key in the same frame
        if (!empty) {
          uint64_t key = RandomLiveKey();
          BoxType b = Below(2) == 0 ? model_.boxes()[key] : RandomBox();
          DoErase(key);
          DoInsert(key, b);
        }
        return;
      case 10: {  // insert, update, maybe erase a new key in one frame
        uint64_t key = next_key_++;
        DoInsert(key, RandomBox());
        DoUpdate(key, RandomBox());
        if (Below(2) == 0) DoErase(key);
        return;
      }
      case 11:  // two updates of one key in one frame
        if (!empty) {
          uint64_t key = RandomLiveKey();
          DoUpdate(key, RandomBox());
          DoUpdate(key, RandomBox());
        }
        return;
      case 12:  // bad calls are refused and change nothing
        BadCalls();
        return;
      case 14:  // a batch of updates through UpdateMany, with a repeated key and bad items
        if (!empty) UpdateBatch();
        return;
      case 13:  // a burst: more new objects than live ones (bulk loads), among other changes
        if (Below(4) == 0 && model_.boxes().size() < 150) {
          size_t n = model_.boxes().size() + 1 + Below(8);
          for (size_t i = 0; i < n; ++i) DoInsert(next_key_++, RandomBox());
        } else if (Below(3) == 0) {
          InsertBatch();
        }
        return;
      default:  // many objects onto one coordinate
        if (!empty) {
          uint64_t key = RandomLiveKey();
          BoxType b = model_.boxes()[key];
          for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
            b.lo[a] = static_cast<T>(0);
            b.hi[a] = static_cast<T>(Below(2));
          }
          DoUpdate(key, b);
        }
        return;
    }
  }

  // Items past the front end's look-ahead (16), so that its ring of hashes wraps; a later item
  // on a key wins; refused items are reported by index with Update's code and change nothing.
  void UpdateBatch() {
    std::vector<typename Broadphase<K, T>::Item> items;
    std::map<size_t, StatusCode> bad;  // index -> the code it must be refused with
    const size_t n = 1 + Below(40);
    for (size_t i = 0; i < n; ++i) {
      const uint64_t pick = Below(12);
      if (pick == 0) {
        bad[items.size()] = StatusCode::kNotFound;
        items.push_back({next_key_ + 1000000 + i, RandomBox()});
      } else if (pick == 1) {
        BoxType inverted = RandomBox();
        inverted.lo[0] = static_cast<T>(inverted.hi[0] + 1);
        bad[items.size()] = StatusCode::kInvalidArgument;
        items.push_back({RandomLiveKey(), inverted});
      } else if (pick == 2 && !items.empty() && !bad.count(items.size() - 1)) {
        items.push_back({items.back().key, RandomBox()});  // the same key again: this box wins
      } else {
        items.push_back({RandomLiveKey(), RandomBox()});
      }
    }
    std::map<size_t, StatusCode> refused;
    const size_t count = engine_->UpdateMany(items, [&](size_t i, const Status& s) {
      EXPECT_TRUE(refused.emplace(i, s.code()).second) << "item " << i << " refused twice";
    });
    EXPECT_EQ(count, refused.size());
    ASSERT_EQ(refused, bad);
    for (size_t i = 0; i < items.size(); ++i) {
      if (!bad.count(i)) model_.boxes()[items[i].key] = items[i].box;
    }
  }

  // Items past the front end's look-ahead (16) at times; a live key, a key named twice, an
  // erased key inserted again (with its old options: an update of its handle; with others: a
  // fresh handle) and invalid boxes among them; options per item, or none (the defaults).
  // Refused items are reported by index with Insert's code and change nothing.
  void InsertBatch() {
    std::vector<typename Broadphase<K, T>::Item> items;
    std::vector<ObjectOptions> options;
    const bool with_options = Below(2) == 0;
    std::map<size_t, StatusCode> bad;  // index -> the code it must be refused with
    std::set<uint64_t> named;          // inserted by this batch
    const size_t n = 1 + Below(Below(3) == 0 ? 40 : 6);
    for (size_t i = 0; i < n; ++i) {
      const uint64_t pick = Below(10);
      uint64_t key = next_key_;
      BoxType box = RandomBox();
      if (pick == 0 && !model_.boxes().empty()) {
        key = RandomLiveKey();
      } else if (pick == 1 && !items.empty()) {
        key = items.back().key;
      } else if (pick == 2) {  // an invalid box, under a new or a live key
        if (!model_.boxes().empty() && Below(2) == 0) key = RandomLiveKey();
        box.lo[0] = static_cast<T>(box.hi[0] + 1);
      } else if (pick == 3 && !erased_keys_.empty()) {
        key = erased_keys_[Below(erased_keys_.size())];
      }
      if (key == next_key_) ++next_key_;
      const ObjectOptions o = with_options ? RandomOptions() : ObjectOptions{};
      if (!(box.lo[0] <= box.hi[0])) {
        bad[items.size()] = StatusCode::kInvalidArgument;
      } else if (model_.boxes().count(key) != 0 || named.count(key) != 0) {
        bad[items.size()] = StatusCode::kAlreadyExists;
      } else {
        named.insert(key);
      }
      items.push_back({key, box});
      if (with_options) options.push_back(o);
    }
    std::map<size_t, StatusCode> refused;
    const size_t count = engine_->InsertMany(items, options, [&](size_t i, const Status& s) {
      EXPECT_TRUE(refused.emplace(i, s.code()).second) << "item " << i << " refused twice";
    });
    EXPECT_EQ(count, refused.size());
    ASSERT_EQ(refused, bad);
    for (size_t i = 0; i < items.size(); ++i) {
      if (bad.count(i)) continue;
      model_.boxes()[items[i].key] = items[i].box;
      model_.options()[items[i].key] = with_options ? options[i] : ObjectOptions{};
    }
  }

  // Keys past the front end's look-ahead (16) at times; a key named twice, an unknown key and
  // a key inserted in this frame (a cancelled insert) among them. Refused keys are reported by
  // index with Erase's code and change nothing.
  void EraseBatch() {
    std::vector<uint64_t> keys;
    std::map<size_t, StatusCode> bad;  // index -> the code it must be refused with
    std::set<uint64_t> named;
    const size_t n = 1 + Below(Below(3) == 0 ? 40 : 6);
    for (size_t i = 0; i < n && named.size() < model_.boxes().size(); ++i) {
      const uint64_t pick = Below(10);
      if (pick == 0) {
        bad[keys.size()] = StatusCode::kNotFound;
        keys.push_back(next_key_ + 1000000 + i);
      } else if (pick == 1 && !keys.empty()) {
        bad[keys.size()] = StatusCode::kNotFound;
        keys.push_back(keys.back());  // already erased by this batch, or unknown
      } else if (pick == 2) {
        const uint64_t key = next_key_++;
        DoInsert(key, RandomBox());
        named.insert(key);
        keys.push_back(key);
      } else {
        uint64_t key = RandomLiveKey();
        while (named.count(key)) key = RandomLiveKey();
        named.insert(key);
        keys.push_back(key);
      }
    }
    std::map<size_t, StatusCode> refused;
    const size_t count = engine_->EraseMany(keys, [&](size_t i, const Status& s) {
      EXPECT_TRUE(refused.emplace(i, s.code()).second) << "key " << i << " refused twice";
    });
    EXPECT_EQ(count, refused.size());
    ASSERT_EQ(refused, bad);
    for (uint64_t key : named) {
      model_.boxes().erase(key);
      model_.options().erase(key);
      erased_keys_.push_back(key);
    }
  }

  void BadCalls() {
    uint64_t unknown = next_key_ + 1000000;
    {
      // Options of another length than the items: every item refused, nothing inserted.
      const std::vector<typename Broadphase<K, T>::Item> items = {{unknown, RandomBox()},
                                                                  {unknown + 1, RandomBox()}};
      const std::vector<ObjectOptions> one(1);
      size_t seen = 0;
      EXPECT_EQ(engine_->InsertMany(items, one,
                                    [&](size_t, const Status& s) {
                                      EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
                                      ++seen;
                                    }),
                2u);
      EXPECT_EQ(seen, 2u);
    }
    EXPECT_EQ(engine_->Update(unknown, RandomBox()).code(), StatusCode::kNotFound);
    EXPECT_EQ(engine_->Erase(unknown).code(), StatusCode::kNotFound);
    if (!model_.boxes().empty()) {
      uint64_t key = RandomLiveKey();
      EXPECT_EQ(engine_->Insert(key, RandomBox()).code(), StatusCode::kAlreadyExists);
      BoxType inverted = RandomBox();
      inverted.lo[K - 1] = static_cast<T>(inverted.hi[K - 1] + 1);
      EXPECT_EQ(engine_->Update(key, inverted).code(), StatusCode::kInvalidArgument);
      if constexpr (std::is_floating_point_v<T>) {
        BoxType nan = RandomBox();
        nan.lo[0] = std::numeric_limits<T>::quiet_NaN();
        EXPECT_EQ(engine_->Update(key, nan).code(), StatusCode::kInvalidArgument);
        BoxType inf = RandomBox();
        inf.hi[K - 1] = std::numeric_limits<T>::infinity();
        EXPECT_EQ(engine_->Insert(next_key_ + 7, inf).code(), StatusCode::kInvalidArgument);
      }
    }
    if (!erased_keys_.empty()) {
      uint64_t key = erased_keys_.back();
      if (!model_.boxes().count(key)) {
        EXPECT_EQ(engine_->Erase(key).code(), StatusCode::kNotFound);
      }
    }
  }

  void Check(int frame) {
    SCOPED_TRACE("frame " + std::to_string(frame));
    if (frame % 10 == 0) {  // the present keys, with this frame's calls still buffered
      std::set<uint64_t> keys;
      engine_->ForEachObject([&](uint64_t key) { EXPECT_TRUE(keys.insert(key).second) << key; });
      std::set<uint64_t> expected;
      for (const auto& entry : model_.boxes()) expected.insert(entry.first);
      ASSERT_EQ(keys, expected);
    }
    RecordingSink<uint64_t> sink;
    engine_->Query(sink);
    std::vector<std::pair<uint64_t, uint64_t>> collides, uncollides;
    model_.Query(&collides, &uncollides);
    ASSERT_EQ(sink.uncollides, uncollides);
    ASSERT_EQ(sink.collides, collides);
    ASSERT_EQ(engine_->Size(), model_.boxes().size());
    Stats stats = engine_->GetStats();
    ASSERT_EQ(stats.overlaps, model_.last_pairs().size());
    ASSERT_EQ(stats.collides, collides.size());
    ASSERT_EQ(stats.uncollides, uncollides.size());
    // The engine validated itself inside Query (BP_VALIDATE; failures reach failure_handler.cc).
    if (frame % 10 == 0) {
      std::set<std::pair<uint64_t, uint64_t>> all;
      engine_->ForEachOverlap([&](uint64_t a, uint64_t b) {
        EXPECT_LT(a, b);
        all.emplace(a, b);
      });
      ASSERT_EQ(all, model_.last_pairs());
    }
  }

  const Scenario* sc_ = nullptr;
  std::mt19937_64 rng_;
  std::unique_ptr<Broadphase<K, T>> engine_;
  ModelOracle<K, T> model_;
  uint64_t next_key_ = 1;
  std::vector<uint64_t> erased_keys_;
};

template <class Config>
class DifferentialTest : public DifferentialCore<Config::K, typename Config::T> {
 protected:
  void Run(const Scenario& sc, uint64_t seed) {
    DifferentialCore<Config::K, typename Config::T>::Run(Config::Name(), &Config::Create, sc, seed);
  }
};

template <class Make>
using AllShapes = ::testing::Types<EngineConfig<2, float, Make>, EngineConfig<3, float, Make>,
                                   EngineConfig<2, double, Make>, EngineConfig<3, double, Make>,
                                   EngineConfig<2, int32_t, Make>, EngineConfig<3, int32_t, Make>>;

// gtest's type lists cannot be concatenated, so each engine family is its own instantiation.
template <class C>
class BruteForceDiff : public DifferentialTest<C> {};
template <class C>
class SegmentedSapDiff : public DifferentialTest<C> {};
template <class C>
class SegmentedSapTinyChunksLocal : public DifferentialTest<C> {};
template <class C>
class SegmentedSapTinyChunksGlobal : public DifferentialTest<C> {};

template <class C>
class SegmentedSapPresorted : public DifferentialTest<C> {};
template <class C>
class SegmentedSapTinyChunksPresorted : public DifferentialTest<C> {};
template <class C>
class BatchSapDiff : public DifferentialTest<C> {};
template <class C>
class BatchSapAlwaysLocal : public DifferentialTest<C> {};
template <class C>
class BatchSapAlwaysGlobal : public DifferentialTest<C> {};
template <class C>
class DynamicOctreeDiff : public DifferentialTest<C> {};
template <class C>
class DynamicOctreeTinyNodes : public DifferentialTest<C> {};

template <class C>
class GridSegmentedDiff : public DifferentialTest<C> {};
template <class C>
class GridSegmentedTinyCells : public DifferentialTest<C> {};
template <class C>
class GridBatchDiff : public DifferentialTest<C> {};
template <class C>
class GridBatchTinyCells : public DifferentialTest<C> {};
template <class C>
class GridDenseDiff : public DifferentialTest<C> {};
template <class C>
class GridDenseTinyCells : public DifferentialTest<C> {};
template <class C>
class GridDensePortableDiff : public DifferentialTest<C> {};
template <class C>
class GridDensePortableTinyCells : public DifferentialTest<C> {};
template <class C>
class GridDenseRowsDiff : public DifferentialTest<C> {};
template <class C>
class GridDenseSmallMatrixDiff : public DifferentialTest<C> {};
template <class C>
class GridThreadedDense : public DifferentialTest<C> {};
template <class C>
class GridThreadedSegmented : public DifferentialTest<C> {};

using BruteForceShapes = AllShapes<MakeBruteForce>;
using SapShapes = AllShapes<MakeSegmentedSap<32, 7>>;  // the default options
// Local sort and one-at-a-time inserts and erases only.
using SapTinyLocalShapes = AllShapes<MakeSegmentedSap<4, -1, 0, 0>>;
// Global sort always, and a bulk rebuild whenever a frame's inserts reach the live count.
using SapTinyGlobalShapes = AllShapes<MakeSegmentedSap<4, 0, 1>>;
// BatchSap: the default options; local sort whenever no insert or erase is pending; and a
// global pass at every query.
using BatchShapes = AllShapes<MakeBatchSap<7>>;
using BatchLocalShapes = AllShapes<MakeBatchSap<-1>>;
using BatchGlobalShapes = AllShapes<MakeBatchSap<0>>;
TYPED_TEST_SUITE(BruteForceDiff, BruteForceShapes);
TYPED_TEST_SUITE(BatchSapDiff, BatchShapes);
TYPED_TEST_SUITE(BatchSapAlwaysLocal, BatchLocalShapes);
TYPED_TEST_SUITE(BatchSapAlwaysGlobal, BatchGlobalShapes);
TYPED_TEST_SUITE(SegmentedSapDiff, SapShapes);
TYPED_TEST_SUITE(SegmentedSapTinyChunksLocal, SapTinyLocalShapes);
TYPED_TEST_SUITE(SegmentedSapTinyChunksGlobal, SapTinyGlobalShapes);
// Every insert and erase chunk by chunk (presorted), default chunks; and tiny chunks with local
// sort and no bulk loads, so that bursts spread over many new chunks.
using SapPresortedShapes = AllShapes<MakeSegmentedSap<32, 7, 64, 1>>;
using SapTinyPresortedShapes = AllShapes<MakeSegmentedSap<4, -1, 0, 1>>;
TYPED_TEST_SUITE(SegmentedSapPresorted, SapPresortedShapes);
// DynamicOctree: the default options; and one object per node with at most 4 levels, so that
// trees are as deep as allowed, leaves overfull at the depth limit and many objects straddle.
using OctreeShapes = AllShapes<MakeDynamicOctree<>>;
using OctreeTinyShapes = AllShapes<MakeDynamicOctree<1, 4>>;
TYPED_TEST_SUITE(DynamicOctreeDiff, OctreeShapes);
TYPED_TEST_SUITE(DynamicOctreeTinyNodes, OctreeTinyShapes);
TYPED_TEST_SUITE(SegmentedSapTinyChunksPresorted, SapTinyPresortedShapes);

// The grid over each cell type: automatic cell size; and cells of size 3 (objects span many cells,
// migrate on most moves, and the wider ones are kept as large objects: at most 8 or 64 cells).
using GridSegmentedShapes = AllShapes<MakeGrid<CellKind::kSegmented, 0>>;
using GridSegmentedTinyShapes = AllShapes<MakeGrid<CellKind::kSegmented, 30, 64>>;
using GridBatchShapes = AllShapes<MakeGrid<CellKind::kBatch, 0>>;
using GridBatchTinyShapes = AllShapes<MakeGrid<CellKind::kBatch, 30, 8>>;
TYPED_TEST_SUITE(GridSegmentedDiff, GridSegmentedShapes);
TYPED_TEST_SUITE(GridSegmentedTinyCells, GridSegmentedTinyShapes);
TYPED_TEST_SUITE(GridBatchDiff, GridBatchShapes);
TYPED_TEST_SUITE(GridBatchTinyCells, GridBatchTinyShapes);
using GridDenseShapes = AllShapes<MakeGrid<CellKind::kDense, 0>>;
using GridDenseTinyShapes = AllShapes<MakeGrid<CellKind::kDense, 30, 8>>;
using GridDensePortableShapes = AllShapes<MakeGrid<CellKind::kDensePortable, 0>>;
using GridDensePortableTinyShapes = AllShapes<MakeGrid<CellKind::kDensePortable, 30, 8>>;
TYPED_TEST_SUITE(GridDenseDiff, GridDenseShapes);
TYPED_TEST_SUITE(GridDenseTinyCells, GridDenseTinyShapes);
TYPED_TEST_SUITE(GridDensePortableDiff, GridDensePortableShapes);
TYPED_TEST_SUITE(GridDensePortableTinyCells, GridDensePortableTinyShapes);
// Dense cells without the pair matrix (then and now tested on the rows), and with it capped at
// 32 slots, so that cells growing and shrinking around it drop and rebuild it.
using GridDenseRowsShapes = AllShapes<MakeGrid<CellKind::kDenseRows, 0>>;
using GridDenseSmallMatrixShapes = AllShapes<MakeGrid<CellKind::kDenseSmallMatrix, 0>>;
TYPED_TEST_SUITE(GridDenseRowsDiff, GridDenseRowsShapes);
TYPED_TEST_SUITE(GridDenseSmallMatrixDiff, GridDenseSmallMatrixShapes);
// Cells applied by a pool of 3 (dense, automatic size: few large objects, so most queries route
// their updates on the pool too) and 2 threads (segmented, tiny cells: many touched cells,
// migrations and large objects per query): the oracle's events, whatever the split.
using GridThreadedDenseShapes = AllShapes<MakeGrid<CellKind::kDense, 0, 16, 3>>;
using GridThreadedSegmentedShapes = AllShapes<MakeGrid<CellKind::kSegmented, 30, 64, 2>>;
TYPED_TEST_SUITE(GridThreadedDense, GridThreadedDenseShapes);
TYPED_TEST_SUITE(GridThreadedSegmented, GridThreadedSegmentedShapes);

#define BP_DIFFERENTIAL_TESTS(Suite)                                                 \
  TYPED_TEST(Suite, RandomOperationsMatchOracle) {                                   \
    for (const Scenario& sc : kScenarios) {                                          \
      for (uint64_t seed : TestSeeds(1000 + static_cast<uint64_t>(sc.lattice), 4)) { \
        this->Run(sc, seed);                                                         \
        if (this->HasFailure()) return;                                              \
      }                                                                              \
    }                                                                                \
  }

BP_DIFFERENTIAL_TESTS(BruteForceDiff)
BP_DIFFERENTIAL_TESTS(SegmentedSapDiff)
BP_DIFFERENTIAL_TESTS(SegmentedSapTinyChunksLocal)
BP_DIFFERENTIAL_TESTS(SegmentedSapTinyChunksGlobal)
BP_DIFFERENTIAL_TESTS(SegmentedSapPresorted)
BP_DIFFERENTIAL_TESTS(SegmentedSapTinyChunksPresorted)
BP_DIFFERENTIAL_TESTS(BatchSapDiff)
BP_DIFFERENTIAL_TESTS(BatchSapAlwaysLocal)
BP_DIFFERENTIAL_TESTS(BatchSapAlwaysGlobal)
BP_DIFFERENTIAL_TESTS(GridSegmentedDiff)
BP_DIFFERENTIAL_TESTS(GridSegmentedTinyCells)
BP_DIFFERENTIAL_TESTS(GridBatchDiff)
BP_DIFFERENTIAL_TESTS(GridBatchTinyCells)
BP_DIFFERENTIAL_TESTS(GridDenseDiff)
BP_DIFFERENTIAL_TESTS(GridDenseTinyCells)
BP_DIFFERENTIAL_TESTS(GridDensePortableDiff)
BP_DIFFERENTIAL_TESTS(GridDensePortableTinyCells)
BP_DIFFERENTIAL_TESTS(GridDenseRowsDiff)
BP_DIFFERENTIAL_TESTS(GridDenseSmallMatrixDiff)
BP_DIFFERENTIAL_TESTS(GridThreadedDense)
BP_DIFFERENTIAL_TESTS(GridThreadedSegmented)
BP_DIFFERENTIAL_TESTS(DynamicOctreeDiff)
BP_DIFFERENTIAL_TESTS(DynamicOctreeTinyNodes)

}  // namespace
}  // namespace bp::test
