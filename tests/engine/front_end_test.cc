// The shared front end's object options and fattened boxes, through every engine:
//  - options: a changed reinsert (a rekey) reports only real status changes; static pairs and
//    filtered pairs never appear; rejected pairs cost no box test in the grid's large set.
//  - fat boxes: with a margin, every engine reports exactly what brute force with the same
//    margin reports, never misses an overlapping pair of the real boxes, reports only pairs whose
//    real boxes grown by 4 margins overlap, and skips the updates its fat boxes absorb.
//  - epochs: the front end's query counter, which dates each slot's pending call, wraps around
//    without losing or inventing a call (exact and with a margin).
// Replay one seed with BP_TEST_SEED=<seed>.
#include <algorithm>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

#include "bp/engines.h"

namespace bp::detail {
// Moves a front end's epoch (see KeyedEngine) between queries.
struct KeyedEngineTestPeer {
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
};
}  // namespace bp::detail

namespace bp::test {
namespace {

using Pair = std::pair<uint64_t, uint64_t>;

// ---- options ------------------------------------------------------------------------------

template <class Config>
class OptionsTest : public ::testing::Test {};

using OptionEngines = ::testing::Types<
    EngineConfig<3, float, MakeBruteForce>, EngineConfig<3, float, MakeSegmentedSap<32, 7>>,
    EngineConfig<2, double, MakeBatchSap<7>>, EngineConfig<3, double, MakeDynamicOctree<>>,
    EngineConfig<3, float, MakeGrid<CellKind::kSegmented, 0>>,
    EngineConfig<2, int32_t, MakeGrid<CellKind::kBatch, 10, 4>>,
    EngineConfig<3, double, MakeGrid<CellKind::kDense, 10, 4>>>;
TYPED_TEST_SUITE(OptionsTest, OptionEngines);

// A refusal callback may call the engine, and a batch then sees the key index as the callback
// left it. Here the callback rekeys key 100 (its erase or update staged earlier in the batch,
// then reinserted with other options: a fresh handle) after the batch looked ahead at its last
// item, 100 again: that item must reach the new handle, not the one its look-ahead found
// (KeyedEngine::Lookup's hint, dropped once the index changed).
TYPED_TEST(OptionsTest, BatchSeesTheIndexItsRefusalCallbackChanged) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  const std::vector<uint64_t> keys = {100, 1, 2, 3, 999, 5, 6, 7, 0, 100};
  const std::map<size_t, StatusCode> only_999 = {{4, StatusCode::kNotFound}};
  auto fill = [](Broadphase<K, T>& engine) {
    for (uint64_t k = 0; k < 8; ++k) {
      const auto lo = static_cast<T>(10 * k);
      ASSERT_TRUE(engine.Insert(k, Cube<K, T>(lo, static_cast<T>(lo + 1))).ok());
    }
    ASSERT_TRUE(engine.Insert(100, Cube<K, T>(0, 4)).ok());
  };
  auto objects = [](const Broadphase<K, T>& engine) {
    std::set<uint64_t> out;
    engine.ForEachObject([&](const uint64_t& key) { out.insert(key); });
    return out;
  };
  RecordingSink<uint64_t> sink;
  {
    auto engine = TypeParam::Create();
    fill(*engine);
    engine->Query(sink);
    std::map<size_t, StatusCode> refused;
    const size_t count = engine->EraseMany(keys, [&](size_t i, const Status& s) {
      refused.emplace(i, s.code());
      if (i == 4) {
        EXPECT_TRUE(engine->Insert(100, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
      }
    });
    EXPECT_EQ(count, 1u);
    EXPECT_EQ(refused, only_999);
    engine->Query(sink);
    EXPECT_EQ(objects(*engine), (std::set<uint64_t>{4}));
  }
  {
    auto engine = TypeParam::Create();
    fill(*engine);
    engine->Query(sink);
    std::vector<typename Broadphase<K, T>::Item> items;
    for (uint64_t key : keys) {
      const auto lo = static_cast<T>(key < 8 ? 10 * key : 0);  // the others stay where they are
      items.push_back({key, Cube<K, T>(lo, static_cast<T>(lo + 1))});
    }
    items.back().box = Cube<K, T>(0, 12);  // 100's last box: it meets 0 (0..1) and 1 (10..11)
    std::map<size_t, StatusCode> refused;
    const size_t count = engine->UpdateMany(items, [&](size_t i, const Status& s) {
      refused.emplace(i, s.code());
      if (i == 4) {
        EXPECT_TRUE(engine->Erase(100).ok());
        EXPECT_TRUE(engine->Insert(100, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
      }
    });
    EXPECT_EQ(count, 1u);
    EXPECT_EQ(refused, only_999);
    sink.Clear();
    engine->Query(sink);
    EXPECT_EQ(objects(*engine).count(100), 1u);
    std::set<Pair> pairs;
    engine->ForEachOverlap([&](const uint64_t& a, const uint64_t& b) { pairs.insert({a, b}); });
    EXPECT_TRUE(pairs.count({1, 100}) == 1) << "100 kept a box other than its last";
  }
}

TYPED_TEST(OptionsTest, ReinsertWithOtherOptionsReportsOnlyRealChanges) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  auto engine = TypeParam::Create();
  RecordingSink<uint64_t> sink;
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4)).ok());
  ASSERT_TRUE(engine->Insert(2, Cube<K, T>(2, 6)).ok());
  ASSERT_TRUE(engine->Insert(3, Cube<K, T>(3, 9)).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.collides, (std::vector<Pair>{{1, 2}, {1, 3}, {2, 3}}));

  // 1 comes back in category 2: 2 and 3 (masks all ones) still accept it: no event.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_TRUE(sink.uncollides.empty());
  EXPECT_EQ(engine->GetStats().overlaps, 3u);

  // 2 comes back masking category 2 out: only (1, 2) goes.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(2).ok());
  ASSERT_TRUE(engine->Insert(2, Cube<K, T>(2, 6), ObjectOptions{.mask = ~uint64_t{2}}).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.uncollides, (std::vector<Pair>{{1, 2}}));
  EXPECT_TRUE(sink.collides.empty());

  // 2 and 3 become static: (2, 3) goes. Then 3 becomes dynamic and moves: (2, 3) returns.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(2).ok());
  ASSERT_TRUE(engine->Insert(2, Cube<K, T>(2, 6), ObjectOptions{.is_static = true}).ok());
  ASSERT_TRUE(engine->Erase(3).ok());
  ASSERT_TRUE(engine->Insert(3, Cube<K, T>(3, 9), ObjectOptions{.is_static = true}).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.uncollides, (std::vector<Pair>{{2, 3}}));
  EXPECT_EQ(sink.collides, (std::vector<Pair>{{1, 2}}));
  sink.Clear();
  ASSERT_TRUE(engine->Erase(3).ok());
  ASSERT_TRUE(engine->Insert(3, Cube<K, T>(4, 8)).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.uncollides.empty());
  EXPECT_EQ(sink.collides, (std::vector<Pair>{{2, 3}}));

  // Reinsert, erase again and reinsert with the first options within one frame.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4), ObjectOptions{.category = 4}).ok());
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_TRUE(sink.uncollides.empty());
  EXPECT_EQ(engine->Size(), 3u);
  EXPECT_TRUE(engine->Validate().ok()) << engine->Validate().ToString();

  // Erasing reports the remaining pairs once.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Erase(2).ok());
  ASSERT_TRUE(engine->Erase(3).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.uncollides, (std::vector<Pair>{{1, 2}, {1, 3}, {2, 3}}));
  EXPECT_EQ(engine->GetStats().overlaps, 0u);
}

TYPED_TEST(OptionsTest, StaticWorldPairsOnlyWithMovers) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  auto engine = TypeParam::Create();
  RecordingSink<uint64_t> sink;
  // A row of 200 touching static boxes and 4 dynamic boxes among them.
  for (uint64_t i = 0; i < 200; ++i) {
    T lo = static_cast<T>(i);
    ASSERT_TRUE(
        engine->Insert(i, Cube<K, T>(lo, static_cast<T>(lo + 1)), ObjectOptions{.is_static = true})
            .ok());
  }
  for (uint64_t i = 0; i < 4; ++i) {
    T lo = static_cast<T>(50 * i + 10);
    ASSERT_TRUE(engine->Insert(1000 + i, Cube<K, T>(lo, static_cast<T>(lo + 2))).ok());
  }
  engine->Query(sink);
  // Each dynamic box [lo, lo+2] touches statics lo-1 .. lo+2.
  EXPECT_EQ(sink.collides.size(), 16u);
  for (const Pair& p : sink.collides) EXPECT_GE(p.second, 1000u);
  EXPECT_TRUE(engine->Validate().ok()) << engine->Validate().ToString();
  // Moving a static box changes nothing among statics.
  sink.Clear();
  ASSERT_TRUE(engine->Update(100, Cube<K, T>(99, 103)).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_TRUE(sink.uncollides.empty());
}

// ---- fattened boxes -------------------------------------------------------------------------

// Every engine, built by bp::NewEngine (compiled once, in bp_engines) with the margin.
std::vector<std::pair<std::string, EngineSpec>> MarginEngines() {
  std::vector<std::pair<std::string, EngineSpec>> all;
  for (std::string_view algorithm : kEngineAlgorithms) {
    EngineSpec spec;
    spec.algorithm = std::string(algorithm);
    std::string name = spec.algorithm;
    if (algorithm == "grid_batch_sap" || algorithm == "grid_dense") {  // small cells
      spec.grid_batch_sap.cell_size = spec.grid_dense.cell_size = 4;
      spec.grid_batch_sap.max_cells_per_object = spec.grid_dense.max_cells_per_object = 8;
      name += "_small_cells";
    }
    all.emplace_back(name, spec);
  }
  return all;
}

template <class Config>
class FatBoxTest : public ::testing::Test {};
using FatShapes =
    ::testing::Types<EngineConfig<2, float, MakeBruteForce>, EngineConfig<3, float, MakeBruteForce>,
                     EngineConfig<3, double, MakeBruteForce>,
                     EngineConfig<2, int32_t, MakeBruteForce>>;
TYPED_TEST_SUITE(FatBoxTest, FatShapes);

TYPED_TEST(FatBoxTest, EveryEngineMatchesBruteForceAndBoundsTheError) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  using BoxT = Box<K, T>;
  const T margin = 2;
  for (const auto& [name, spec] : MarginEngines()) {
    for (uint64_t seed : TestSeeds(77, 3)) {
      SCOPED_TRACE(name + " K=" + std::to_string(K) + " seed=" + std::to_string(seed));
      std::mt19937_64 rng(seed);
      auto below = [&](int n) { return std::uniform_int_distribution<int>(0, n - 1)(rng); };
      std::unique_ptr<Broadphase<K, T>> engine = NewEngine<K, T>(spec, margin);
      ASSERT_TRUE(engine != nullptr);
      BruteForce<K, T> reference(BruteForceOptions(), margin);
      ModelOracle<K, T> exact, loose;  // the real boxes, and the real boxes grown by 4 margins
      auto random_box = [&]() {
        BoxT b;
        for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
          b.lo[a] = static_cast<T>(below(120) - 60);
          b.hi[a] = static_cast<T>(b.lo[a] + static_cast<T>(below(6)));
        }
        return b;
      };
      auto grow = [&](BoxT b) {
        for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
          b.lo[a] = static_cast<T>(b.lo[a] - 4 * margin);
          b.hi[a] = static_cast<T>(b.hi[a] + 4 * margin);
        }
        return b;
      };
      auto set = [&](uint64_t key, const BoxT& b) {
        exact.boxes()[key] = b;
        loose.boxes()[key] = grow(b);
      };
      for (uint64_t key = 0; key < 150; ++key) {
        BoxT b = random_box();
        ASSERT_TRUE(engine->Insert(key, b).ok());
        ASSERT_TRUE(reference.Insert(key, b).ok());
        set(key, b);
      }
      uint64_t next = 150;
      size_t skipped = 0;
      // Odd frames pass their updates through UpdateMany, in runs between erases.
      std::vector<typename Broadphase<K, T>::Item> batch;
      auto flush = [&]() {
        EXPECT_EQ(engine->UpdateMany(batch), 0u);
        batch.clear();
      };
      for (int frame = 0; frame < 60 && !this->HasFailure(); ++frame) {
        if (frame > 0) {
          for (int op = 0; op < 40; ++op) {
            auto it = exact.boxes().begin();
            std::advance(it, below(static_cast<int>(exact.boxes().size())));
            uint64_t key = it->first;
            BoxT b = it->second;
            int kind = below(20);
            if (kind == 0) {  // erase, and insert a new key
              flush();
              ASSERT_TRUE(engine->Erase(key).ok());
              ASSERT_TRUE(reference.Erase(key).ok());
              exact.boxes().erase(key);
              loose.boxes().erase(key);
              b = random_box();
              ASSERT_TRUE(engine->Insert(next, b).ok());
              ASSERT_TRUE(reference.Insert(next, b).ok());
              set(next++, b);
              continue;
            }
            if (kind == 1) {
              b = random_box();  // teleport
            } else {             // a small step, or a shrink that leaves a loose fat box
              for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
                T d = static_cast<T>(below(3) - 1);
                b.lo[a] = static_cast<T>(b.lo[a] + d);
                b.hi[a] = static_cast<T>(kind == 2 ? b.lo[a] : b.hi[a] + d);
              }
            }
            if (frame % 2 == 1) {
              batch.push_back({key, b});
            } else {
              ASSERT_TRUE(engine->Update(key, b).ok());
            }
            ASSERT_TRUE(reference.Update(key, b).ok());
            set(key, b);
          }
          flush();
        }
        RecordingSink<uint64_t> got, want;
        engine->Query(got);
        reference.Query(want);
        ASSERT_EQ(got.uncollides, want.uncollides) << "frame " << frame;
        ASSERT_EQ(got.collides, want.collides) << "frame " << frame;
        skipped += engine->GetStats().fat_skips;
        EXPECT_EQ(engine->GetStats().margin, static_cast<double>(margin));
        std::set<Pair> reported;
        engine->ForEachOverlap([&](uint64_t a, uint64_t b) { reported.emplace(a, b); });
        for (const Pair& p : exact.Pairs()) {
          ASSERT_TRUE(reported.count(p)) << "missed " << p.first << "," << p.second;
        }
        std::set<Pair> bound = loose.Pairs();
        for (const Pair& p : reported) {
          ASSERT_TRUE(bound.count(p)) << "too far apart " << p.first << "," << p.second;
        }
      }
      EXPECT_GT(skipped, 0u) << "no update was absorbed by a fat box";
    }
  }
}

TEST(FatBoxes, MarginSaturatesAtTheCoordinateLimits) {
  using BoxI = Box<2, int32_t>;
  constexpr int32_t kMin = std::numeric_limits<int32_t>::lowest();
  constexpr int32_t kMax = std::numeric_limits<int32_t>::max();
  GridSegmentedSap<2, int32_t> engine(GridSegmentedSapOptions(), 1000);
  RecordingSink<uint64_t> sink;
  ASSERT_TRUE(engine.Insert(1, BoxI{{kMin, kMin}, {kMin + 5, kMin + 5}}).ok());
  ASSERT_TRUE(engine.Insert(2, BoxI{{kMax - 5, kMax - 5}, {kMax, kMax}}).ok());
  ASSERT_TRUE(engine.Insert(3, BoxI{{kMin + 1500, kMin}, {kMin + 1600, kMin + 3}}).ok());
  engine.Query(sink);
  // 1's fat box reaches kMin + 1005, 3's starts at kMin + 500: they pair; 2 pairs with neither.
  EXPECT_EQ(sink.collides, (std::vector<Pair>{{1, 3}}));
  EXPECT_TRUE(engine.Validate().ok());

  GridSegmentedSap<3, float> fl(GridSegmentedSapOptions(), 1e38f);
  const float big = std::numeric_limits<float>::max();
  ASSERT_TRUE(fl.Insert(1, Box<3, float>{{-big, -big, -big}, {-big, -big, -big}}).ok());
  ASSERT_TRUE(fl.Insert(2, Box<3, float>{{big, big, big}, {big, big, big}}).ok());
  sink.Clear();
  fl.Query(sink);  // the fat boxes stay finite (no inf reaches the cells)
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_TRUE(fl.Validate().ok());
}

TEST(FatBoxes, NegativeOrNanMarginMeansExact) {
  SegmentedSap<2, double> engine(SegmentedSapOptions(), -1.0);
  EXPECT_EQ(engine.GetStats().margin, 0.0);
  SegmentedSap<2, double> nan(SegmentedSapOptions(), std::numeric_limits<double>::quiet_NaN());
  EXPECT_EQ(nan.GetStats().margin, 0.0);
  RecordingSink<uint64_t> sink;
  ASSERT_TRUE(engine.Insert(1, Box<2, double>{{0, 0}, {1, 1}}).ok());
  ASSERT_TRUE(engine.Insert(2, Box<2, double>{{1.5, 0}, {2, 1}}).ok());
  engine.Query(sink);
  EXPECT_TRUE(sink.collides.empty());
}

// ---- epochs ------------------------------------------------------------------------------

// Two engines of one type take the same calls; one has its epoch moved to just below the wrap.
// Frames mix every sequence of calls on one key between two queries (update twice, erase and
// reinsert, insert and erase, insert and update, erase of an updated key), so pending calls of
// the last epoch before the wrap, and slots last touched many epochs ago, are read after it.
// Their events must be equal, and (exact) those of the model; both validators must pass.
template <int K, class T, class Engine>
void CheckEpochWrap(Engine& wrapped, Engine& plain, bool exact, uint64_t seed) {
  using BoxType = Box<K, T>;
  std::mt19937_64 rng(seed);
  ModelOracle<K, T> model;
  RecordingSink<uint64_t> ws, ps;
  std::vector<Pair> collides, uncollides;
  auto random_box = [&] {
    BoxType b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      const int lo = std::uniform_int_distribution<int>(0, 60)(rng);
      b.lo[a] = static_cast<T>(lo);
      b.hi[a] = static_cast<T>(lo + std::uniform_int_distribution<int>(0, 12)(rng));
    }
    return b;
  };
  auto both = [&](auto&& call) {
    const Status a = call(wrapped), b = call(plain);
    ASSERT_EQ(a.ok(), b.ok()) << a.ToString() << " / " << b.ToString();
  };
  auto insert = [&](uint64_t key) {
    const BoxType b = random_box();
    both([&](Engine& e) { return e.Insert(key, b); });
    model.boxes()[key] = b;
  };
  auto update = [&](uint64_t key) {
    const BoxType b = random_box();
    both([&](Engine& e) { return e.Update(key, b); });
    model.boxes()[key] = b;
  };
  auto erase = [&](uint64_t key) {
    both([&](Engine& e) { return e.Erase(key); });
    model.boxes().erase(key);
  };
  auto query = [&](const char* when) {
    ws.Clear();
    ps.Clear();
    wrapped.Query(ws);
    plain.Query(ps);
    model.Query(&collides, &uncollides);
    EXPECT_EQ(ws.collides, ps.collides) << when;
    EXPECT_EQ(ws.uncollides, ps.uncollides) << when;
    if (exact) {
      EXPECT_EQ(ws.collides, collides) << when;
      EXPECT_EQ(ws.uncollides, uncollides) << when;
    }
    EXPECT_TRUE(wrapped.Validate().ok()) << when << ": " << wrapped.Validate().ToString();
    EXPECT_TRUE(plain.Validate().ok()) << when;
  };
  uint64_t next = 0;
  for (int i = 0; i < 40; ++i) insert(next++);
  query("first frame");
  for (uint64_t k = 0; k < 10; ++k) update(k);  // pending in an epoch long before the wrap
  query("frame before the jump");
  detail::KeyedEngineTestPeer::set_epoch(wrapped, std::numeric_limits<uint32_t>::max() - 3);
  for (int frame = 0; frame < 8; ++frame) {
    auto live = [&] {
      auto it = model.boxes().begin();
      std::advance(it, std::uniform_int_distribution<size_t>(0, model.boxes().size() - 1)(rng));
      return it->first;
    };
    const uint64_t a = live(), b = live();
    update(a);
    if (b != a) {
      erase(b);
      insert(b);  // an update of the same handle
    }
    const uint64_t c = live();
    update(c);
    update(c);
    const uint64_t d = next++;
    insert(d);
    erase(d);  // nothing reaches the core
    const uint64_t e = next++;
    insert(e);
    update(e);
    const uint64_t f = live();
    if (f != e) {
      update(f);
      erase(f);
    }
    for (int k = 0; k < 4; ++k) update(live());
    query(("frame " + std::to_string(frame) + " around the wrap").c_str());
  }
  EXPECT_LT(detail::KeyedEngineTestPeer::epoch(wrapped), 8u) << "the epoch did not wrap";
}

TEST(FrontEnd, EpochWrapsAroundWithoutLosingACall) {
  for (uint64_t seed : TestSeeds(0xE90C, 3)) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    GridDense<3, float> wrapped, plain;
    CheckEpochWrap<3, float>(wrapped, plain, true, seed);
    SegmentedSap<2, double> wrapped_fat(SegmentedSapOptions(), 1.5);
    SegmentedSap<2, double> plain_fat(SegmentedSapOptions(), 1.5);
    CheckEpochWrap<2, double>(wrapped_fat, plain_fat, false, seed);
  }
}

// UpdateMany on a pool stages the items on every thread, claiming each key's slot, and defers
// the rest (bad boxes, unknown keys, keys with an earlier call this epoch or named again) to an
// ordered pass; a refusal callback that calls the engine rewinds the batch to its item. Each
// batch must end exactly as the serial loop (a one-thread grid) ends it, with the same
// refusals and events: on a two-thread grid, and with the runs claimed from the last to the
// first (so that items named again in an earlier run wait behind a later item's claim, which
// two threads do only by chance). Batches of 5 000 items (three runs) name keys again near and
// far, hold bad items and keys with pending inserts, updates and erases, and their callbacks
// erase, reinsert (with other options: a rekey), update and query.
TEST(FrontEnd, UpdateManyOnThePoolEndsAsTheSerialLoop) {
  using Engine = GridDense<3, float>;
  using BoxType = Box<3, float>;
  using Item = Engine::Item;
  constexpr size_t kSerial = 0, kPooled = 1, kReversed = 2, kEngines = 3;
  for (uint64_t seed : TestSeeds(0x5EA1, 2)) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937_64 rng(seed);
    GridDenseOptions options;
    options.cell_size = 8;
    options.parallel_routing_from = 2;
    Engine serial(options), reversed(options);
    options.threads = 2;
    Engine pooled(options);
    Engine* engines[kEngines] = {&serial, &pooled, &reversed};
    auto below = [&](uint64_t n) { return std::uniform_int_distribution<uint64_t>(0, n - 1)(rng); };
    auto random_box = [&] {
      BoxType b;
      for (size_t a = 0; a < 3; ++a) {
        b.lo[a] = static_cast<float>(below(48));  // about 8 partners per box
        b.hi[a] = b.lo[a] + static_cast<float>(below(6));
      }
      return b;
    };
    std::vector<std::pair<std::string, std::vector<Pair>>> events[kEngines];
    auto query = [&](size_t e, const std::string& when) {
      RecordingSink<uint64_t> sink;
      engines[e]->Query(sink);
      events[e].push_back({when + " uncollides", sink.uncollides});
      events[e].push_back({when + " collides", sink.collides});
    };
    constexpr uint64_t kKeys = 4000;
    for (size_t e = 0; e < kEngines; ++e) {
      rng.seed(seed);
      for (uint64_t k = 0; k < kKeys; ++k) ASSERT_TRUE(engines[e]->Insert(k, random_box()).ok());
      query(e, "first");
    }
    for (int round = 0; round < 4; ++round) {
      // The calls before the batch, the batch and the callback's calls: the same for every
      // engine (the same seed).
      std::vector<Item> items;
      std::vector<std::pair<size_t, StatusCode>> refused[kEngines];
      size_t counts[kEngines] = {};
      for (size_t e = 0; e < kEngines; ++e) {
        Engine& engine = *engines[e];
        rng.seed(seed * 131 + static_cast<uint64_t>(round));
        for (int k = 0; k < 50; ++k) {
          const uint64_t key = below(kKeys);
          switch (below(3)) {
            case 0:
              (void)engine.Erase(key);
              break;
            case 1:
              (void)engine.Insert(key, random_box());
              break;
            default:
              (void)engine.Update(key, random_box());
          }
        }
        items.clear();
        for (size_t i = 0; i < 5000; ++i) {
          const uint64_t pick = below(100);
          if (pick == 0) {
            items.push_back({kKeys + 1000 + i, random_box()});  // unknown
          } else if (pick == 1) {
            BoxType bad = random_box();
            bad.lo[1] = bad.hi[1] + 1;
            items.push_back({below(kKeys), bad});
          } else if (pick < 6 && !items.empty()) {
            items.push_back({items[below(items.size())].key, random_box()});  // named again
          } else {
            items.push_back({below(kKeys), random_box()});
          }
        }
        size_t ordinal = 0;
        const Engine::RefusedFn callback = [&](size_t i, const Status& s) {
          refused[e].push_back({i, s.code()});
          const size_t later = std::min(items.size() - 1, i + 1 + (i * 7919) % 3000);
          switch (ordinal++ % 6) {
            case 0:
              (void)engine.Erase(items[later].key);
              break;
            case 1:
              (void)engine.Erase(items[later].key);
              (void)engine.Insert(items[later].key, items[i].box, ObjectOptions{.category = 2});
              break;
            case 2:
              (void)engine.Update(items[later].key, items[0].box);
              break;
            case 3:
              if (round % 2 == 0) query(e, "callback of item " + std::to_string(i));
              break;
            default:
              break;
          }
        };
        // The last round without a callback (no rewind: every deferred item in one pass).
        const Engine::RefusedFn& pass = round == 3 ? Engine::RefusedFn() : callback;
        counts[e] = e == kReversed
                        ? detail::KeyedEngineTestPeer::UpdateManyRunsReversed(engine, items, pass)
                        : engine.UpdateMany(items, pass);
        query(e, "round " + std::to_string(round));
        ASSERT_TRUE(engine.Validate().ok()) << engine.Validate().ToString();
      }
      for (size_t e = 1; e < kEngines; ++e) {
        SCOPED_TRACE(e == kPooled ? "two threads" : "runs reversed");
        EXPECT_EQ(counts[e], counts[kSerial]);
        EXPECT_EQ(refused[e], refused[kSerial]);
        ASSERT_EQ(events[e], events[kSerial]);
      }
      EXPECT_GT(counts[kSerial], 0u);
    }
    std::set<Pair> pairs[kEngines];
    for (size_t e = 0; e < kEngines; ++e) {
      engines[e]->ForEachOverlap([&](const uint64_t& a, const uint64_t& b) {
        pairs[e].insert({a, b});
      });
    }
    EXPECT_EQ(pairs[kPooled], pairs[kSerial]);
    EXPECT_EQ(pairs[kReversed], pairs[kSerial]);
    EXPECT_GT(pooled.GetStats().threads, 1u);
  }
}

}  // namespace
}  // namespace bp::test
