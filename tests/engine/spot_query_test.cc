// Broadphase::ForEachOverlapping (the spot query: which objects overlap this box now) against the
// boxes the test keeps: every engine of bp::NewEngine, on 3-D float, 2-D double and 3-D int32,
// after each query of a scene that moves, inserts and erases objects, with large objects (for
// the grids), statics and objects that pair with nothing; calls made since the last query do
// not count until the next. With a margin, the answer holds every overlapping object and only
// objects within the margin of the box.
#include <algorithm>
#include <cstdint>
#include <iterator>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <string_view>
#include <vector>

#include <gtest/gtest.h>

#include "bp/engines.h"

namespace bp::test {
namespace {

struct NullSink final : EventSink<uint64_t> {
  void Collide(const uint64_t&, const uint64_t&) override {}
  void Uncollide(const uint64_t&, const uint64_t&) override {}
};

EngineSpec SpecOf(const std::string& algorithm) {
  EngineSpec spec;
  spec.algorithm = algorithm;
  // Cells small enough that boxes cross them and the widest boxes are large objects.
  for (auto* grid : {&spec.grid_dense.cell_size, &spec.grid_segmented_sap.cell_size,
                     &spec.grid_batch_sap.cell_size}) {
    *grid = 4;
  }
  spec.grid_dense.max_cells_per_object = 8;
  spec.grid_segmented_sap.max_cells_per_object = 8;
  spec.grid_batch_sap.max_cells_per_object = 8;
  return spec;
}

template <int K, class T>
class Scene {
 public:
  explicit Scene(uint64_t seed) : rng_(seed) {}
  Box<K, T> RandomBox(double max_extent) {
    std::uniform_real_distribution<double> at(0, 100), extent(0, max_extent);
    Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      const double lo = at(rng_);
      b.lo[a] = static_cast<T>(lo);
      b.hi[a] = static_cast<T>(lo + extent(rng_));
    }
    return b;
  }
  uint64_t Draw(uint64_t n) { return rng_() % n; }

 private:
  std::mt19937_64 rng_;
};

template <class T>
bool Near(const Box<3, T>& a, const Box<3, T>& b, double d) {
  for (size_t i = 0; i < 3; ++i) {
    if (static_cast<double>(a.lo[i]) > static_cast<double>(b.hi[i]) + d ||
        static_cast<double>(b.lo[i]) > static_cast<double>(a.hi[i]) + d) {
      return false;
    }
  }
  return true;
}

template <int K, class T>
void CheckSpotQueries(const std::string& algorithm) {
  SCOPED_TRACE(algorithm + " K=" + std::to_string(K));
  std::unique_ptr<Broadphase<K, T>> engine = NewEngine<K, T>(SpecOf(algorithm));
  ASSERT_NE(engine, nullptr);
  Scene<K, T> scene(31);
  NullSink sink;
  std::map<uint64_t, Box<K, T>> live, next;  // as of the last query; as of the calls made
  const auto check = [&](const char* stage) {
    for (int q = 0; q < 30 && !::testing::Test::HasFailure(); ++q) {
      const Box<K, T> query = scene.RandomBox(q % 6 == 0 ? 70 : 8);
      std::vector<uint64_t> got, want;
      engine->ForEachOverlapping(query, [&](const uint64_t& key) { got.push_back(key); });
      std::sort(got.begin(), got.end());
      for (const auto& [key, box] : live) {
        if (Overlaps(box, query)) want.push_back(key);
      }
      ASSERT_EQ(got, want) << stage << ", query " << q;
    }
  };
  const auto insert = [&](uint64_t key) {
    const Box<K, T> box = scene.RandomBox(key % 40 == 0 ? 45 : 3);
    ObjectOptions options;
    options.is_static = key % 5 == 0;
    if (key % 7 == 0) options.mask = 0;  // pairs with nothing
    ASSERT_TRUE(engine->Insert(key, box, options).ok());
    next[key] = box;
  };
  for (uint64_t key = 0; key < 300; ++key) insert(key);
  check("before the first query");  // nothing is live yet
  engine->Query(sink);
  live = next;
  check("after the first query");
  uint64_t fresh = 300;
  for (int frame = 0; frame < 6 && !::testing::Test::HasFailure(); ++frame) {
    for (int i = 0; i < 60; ++i) {
      auto it = next.begin();
      std::advance(it, static_cast<long>(scene.Draw(next.size())));
      const uint64_t key = it->first;
      if (i % 10 == 0) {
        ASSERT_TRUE(engine->Erase(key).ok());
        next.erase(key);
      } else {
        const Box<K, T> box = scene.RandomBox(key % 40 == 0 ? 45 : 3);
        ASSERT_TRUE(engine->Update(key, box).ok());
        next[key] = box;
      }
    }
    for (int i = 0; i < 8; ++i) insert(fresh++);
    check("calls made, not queried");
    engine->Query(sink);
    live = next;
    check("after a query");
  }
}

TEST(SpotQuery, EveryEngineAnswersWhatItsBoxesOverlap) {
  for (std::string_view name : kEngineAlgorithms) {
    CheckSpotQueries<3, float>(std::string(name));
    CheckSpotQueries<2, double>(std::string(name));
    CheckSpotQueries<3, int32_t>(std::string(name));
  }
}

TEST(SpotQuery, WithAMarginTheAnswerHoldsTheOverlapsAndOnlyObjectsNearTheBox) {
  for (const char* name : {"grid_dense", "segmented_sap"}) {
    SCOPED_TRACE(name);
    constexpr float kMargin = 0.5f;
    std::unique_ptr<Broadphase<3, float>> engine = NewEngine<3, float>(SpecOf(name), kMargin);
    Scene<3, float> scene(32);
    NullSink sink;
    std::map<uint64_t, Box<3, float>> boxes;
    for (uint64_t key = 0; key < 400; ++key) {
      boxes[key] = scene.RandomBox(3);
      ASSERT_TRUE(engine->Insert(key, boxes[key]).ok());
    }
    engine->Query(sink);
    for (int frame = 0; frame < 4; ++frame) {
      for (uint64_t key = 0; key < 400; key += 3) {  // small moves, absorbed by the fat boxes
        Box<3, float> b = boxes[key];
        for (size_t a = 0; a < 3; ++a) {
          b.lo[a] += 0.1f;
          b.hi[a] += 0.1f;
        }
        boxes[key] = b;
        ASSERT_TRUE(engine->Update(key, b).ok());
      }
      engine->Query(sink);
      for (int q = 0; q < 30; ++q) {
        const Box<3, float> query = scene.RandomBox(10);
        std::vector<uint64_t> got;
        engine->ForEachOverlapping(query, [&](const uint64_t& key) { got.push_back(key); });
        std::sort(got.begin(), got.end());
        for (const auto& [key, box] : boxes) {
          if (Overlaps(box, query)) {
            EXPECT_TRUE(std::binary_search(got.begin(), got.end(), key)) << key;
          }
        }
        for (uint64_t key : got) EXPECT_TRUE(Near(boxes[key], query, 2 * kMargin + 1e-3)) << key;
      }
    }
  }
}

}  // namespace
}  // namespace bp::test
