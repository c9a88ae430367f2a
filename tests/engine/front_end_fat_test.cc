// The front end's fattened boxes (detail/front_end_fat.h), through every engine: with a margin,
// every engine reports exactly what brute force with the same margin reports, never misses an
// overlapping pair of the real boxes, reports only pairs whose real boxes grown by 4 margins
// overlap, and skips the updates its fat boxes absorb; margins saturate at the coordinate
// limits; a negative or NaN margin is exact.
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

namespace bp::test {
namespace {

using Pair = std::pair<uint64_t, uint64_t>;

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

}  // namespace
}  // namespace bp::test
