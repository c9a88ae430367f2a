// Named edge cases, typed over every engine: touching, points, extreme and signed-zero values,
// bad calls that must change nothing, coalescing of calls between queries, canonical order,
// chunk split/merge under heavy churn, fast movers whose min crosses their max (R sets), key
// types other than integers, and dimensions other than 2 and 3.
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

namespace bp::test {
namespace {

using Pairs = std::vector<std::pair<uint64_t, uint64_t>>;

template <class Config>
class EdgeCaseTest : public ::testing::Test {
 protected:
  static constexpr int K = Config::K;
  using T = typename Config::T;
  using BoxType = Box<K, T>;

  EdgeCaseTest() : engine_(Config::Create()) {}

  static BoxType Cube(T lo, T hi) {
    BoxType b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = lo;
      b.hi[a] = hi;
    }
    return b;
  }
  // A cube [lo, lo + e] with lo drawn below `range`, then e below `extent` (in that order).
  static BoxType RandomCube(std::mt19937_64& rng, uint64_t range, uint64_t extent) {
    T lo = static_cast<T>(rng() % range);
    return Cube(lo, static_cast<T>(lo + static_cast<T>(rng() % extent)));
  }
  void Query() {
    sink_.Clear();
    engine_->Query(sink_);
  }
  // Queries the engine and the model; both event lists must be equal.
  void QueryAndCompare(ModelOracle<K, T>& model) {
    Query();
    Pairs collides, uncollides;
    model.Query(&collides, &uncollides);
    ASSERT_EQ(sink_.collides, collides);
    ASSERT_EQ(sink_.uncollides, uncollides);
  }
  void Insert(uint64_t key, const BoxType& b) { ASSERT_TRUE(engine_->Insert(key, b).ok()); }
  void Update(uint64_t key, const BoxType& b) { ASSERT_TRUE(engine_->Update(key, b).ok()); }

  std::unique_ptr<Broadphase<K, T>> engine_;
  RecordingSink<uint64_t> sink_;
};

template <class Make>
using EdgeShapes = ::testing::Types<EngineConfig<3, float, Make>, EngineConfig<3, double, Make>,
                                    EngineConfig<3, int32_t, Make>, EngineConfig<3, uint32_t, Make>,
                                    EngineConfig<2, float, Make>>;
template <class C>
class BruteForceEdge : public EdgeCaseTest<C> {};
template <class C>
class SegmentedSapEdge : public EdgeCaseTest<C> {};
template <class C>
class SegmentedSapTinyEdge : public EdgeCaseTest<C> {};
template <class C>
class BatchSapEdge : public EdgeCaseTest<C> {};
template <class C>
class DynamicOctreeEdge : public EdgeCaseTest<C> {};
template <class C>
class DynamicOctreeTinyEdge : public EdgeCaseTest<C> {};
using BruteForceEdgeShapes = EdgeShapes<MakeBruteForce>;
using SapEdgeShapes = EdgeShapes<MakeSegmentedSap<32, 7>>;
using SapTinyEdgeShapes = EdgeShapes<MakeSegmentedSap<4, -1>>;
using BatchEdgeShapes = EdgeShapes<MakeBatchSap<7>>;
using OctreeEdgeShapes = EdgeShapes<MakeDynamicOctree<>>;
using OctreeTinyEdgeShapes = EdgeShapes<MakeDynamicOctree<1, 4>>;
TYPED_TEST_SUITE(BruteForceEdge, BruteForceEdgeShapes);
TYPED_TEST_SUITE(BatchSapEdge, BatchEdgeShapes);
TYPED_TEST_SUITE(SegmentedSapEdge, SapEdgeShapes);
TYPED_TEST_SUITE(SegmentedSapTinyEdge, SapTinyEdgeShapes);
TYPED_TEST_SUITE(DynamicOctreeEdge, OctreeEdgeShapes);
TYPED_TEST_SUITE(DynamicOctreeTinyEdge, OctreeTinyEdgeShapes);

// The body of each edge case, shared by the suites.
#define BP_EDGE_CASES(Suite)                                                                      \
  TYPED_TEST(Suite, TouchingFacesEdgesAndCornersOverlap) {                                        \
    using Coord = typename TestFixture::T;                                                        \
    auto box = TestFixture::Cube(Coord(0), Coord(2));                                             \
    this->Insert(1, box);                                                                         \
    auto face = box;                                                                              \
    face.lo[0] = Coord(2);                                                                        \
    face.hi[0] = Coord(4); /* shares the face x = 2 */                                            \
    this->Insert(2, face);                                                                        \
    auto corner = TestFixture::Cube(Coord(2), Coord(3)); /* shares one corner */                  \
    this->Insert(3, corner);                                                                      \
    auto apart = TestFixture::Cube(Coord(5), Coord(6));                                           \
    this->Insert(4, apart);                                                                       \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.collides, (Pairs{{1, 2}, {1, 3}, {2, 3}}));                             \
    /* Move 4 to touch 3 exactly, then one step away. */                                          \
    this->Update(4, TestFixture::Cube(Coord(3), Coord(4)));                                       \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.collides, (Pairs{{3, 4}}));                                             \
    this->Update(4, TestFixture::Cube(Coord(4), Coord(5)));                                       \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.uncollides, (Pairs{{3, 4}}));                                           \
  }                                                                                               \
  TYPED_TEST(Suite, PointsOverlapWhatContainsThem) {                                              \
    using Coord = typename TestFixture::T;                                                        \
    this->Insert(10, TestFixture::Cube(Coord(0), Coord(10)));                                     \
    this->Insert(11, TestFixture::Cube(Coord(5), Coord(5)));   /* inside */                       \
    this->Insert(12, TestFixture::Cube(Coord(10), Coord(10))); /* on the max corner */            \
    this->Insert(13, TestFixture::Cube(Coord(5), Coord(5)));   /* the same point as 11 */         \
    this->Insert(14, TestFixture::Cube(Coord(11), Coord(11))); /* outside */                      \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.collides, (Pairs{{10, 11}, {10, 12}, {10, 13}, {11, 13}}));             \
  }                                                                                               \
  TYPED_TEST(Suite, ExtremeValuesAndSignedZero) {                                                 \
    using Coord = typename TestFixture::T;                                                        \
    using L = std::numeric_limits<Coord>;                                                         \
    this->Insert(1, TestFixture::Cube(L::lowest(), L::max()));                                    \
    this->Insert(2, TestFixture::Cube(L::lowest(), L::lowest()));                                 \
    this->Insert(3, TestFixture::Cube(L::max(), L::max()));                                       \
    this->Insert(4, TestFixture::Cube(Coord(0), Coord(0)));                                       \
    if constexpr (std::is_floating_point_v<Coord>) {                                              \
      this->Insert(5, TestFixture::Cube(Coord(-0.0), Coord(-0.0))); /* -0.0 == +0.0 */            \
      this->Insert(6, TestFixture::Cube(L::denorm_min(), L::denorm_min()));                       \
      this->Insert(7, TestFixture::Cube(-L::denorm_min(), Coord(0)));                             \
      this->Query();                                                                              \
      EXPECT_EQ(this->sink_.collides,                                                             \
                (Pairs{{1, 2}, {1, 3}, {1, 4}, {1, 5}, {1, 6}, {1, 7}, {4, 5}, {4, 7}, {5, 7}})); \
    } else if constexpr (std::is_signed_v<Coord>) {                                               \
      this->Query();                                                                              \
      EXPECT_EQ(this->sink_.collides, (Pairs{{1, 2}, {1, 3}, {1, 4}}));                           \
    } else { /* unsigned: lowest() is 0, so 2 and 4 are the same point */                         \
      this->Query();                                                                              \
      EXPECT_EQ(this->sink_.collides, (Pairs{{1, 2}, {1, 3}, {1, 4}, {2, 4}}));                   \
    }                                                                                             \
    /* Teleport the giant to a point: every pair of it ends, and only those. */                   \
    this->Update(1, TestFixture::Cube(Coord(100), Coord(100)));                                   \
    this->Query();                                                                                \
    Pairs ended = std::is_floating_point_v<Coord>                                                 \
                      ? Pairs{{1, 2}, {1, 3}, {1, 4}, {1, 5}, {1, 6}, {1, 7}}                     \
                      : Pairs{{1, 2}, {1, 3}, {1, 4}};                                            \
    EXPECT_EQ(this->sink_.uncollides, ended);                                                     \
    EXPECT_TRUE(this->sink_.collides.empty());                                                    \
  }                                                                                               \
  TYPED_TEST(Suite, BadCallsChangeNothing) {                                                      \
    using Coord = typename TestFixture::T;                                                        \
    auto& e = *this->engine_;                                                                     \
    this->Insert(1, TestFixture::Cube(Coord(0), Coord(1)));                                       \
    this->Query();                                                                                \
    EXPECT_EQ(e.Insert(1, TestFixture::Cube(Coord(0), Coord(1))).code(),                          \
              StatusCode::kAlreadyExists);                                                        \
    EXPECT_EQ(e.Update(2, TestFixture::Cube(Coord(0), Coord(1))).code(), StatusCode::kNotFound);  \
    EXPECT_EQ(e.Erase(2).code(), StatusCode::kNotFound);                                          \
    auto inverted = TestFixture::Cube(Coord(0), Coord(1));                                        \
    inverted.lo[0] = Coord(2);                                                                    \
    Status s = e.Update(1, inverted);                                                             \
    EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);                                            \
    EXPECT_NE(s.message().find("lo > hi on axis 0"), std::string::npos) << s.message();           \
    EXPECT_EQ(e.Insert(3, inverted).code(), StatusCode::kInvalidArgument);                        \
    if constexpr (std::is_floating_point_v<Coord>) {                                              \
      auto nan = TestFixture::Cube(Coord(0), Coord(1));                                           \
      nan.hi[1] = std::numeric_limits<Coord>::quiet_NaN();                                        \
      s = e.Insert(3, nan);                                                                       \
      EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);                                          \
      EXPECT_NE(s.message().find("NaN"), std::string::npos) << s.message();                       \
      auto inf = TestFixture::Cube(Coord(0), Coord(1));                                           \
      inf.lo[0] = -std::numeric_limits<Coord>::infinity();                                        \
      EXPECT_EQ(e.Update(1, inf).code(), StatusCode::kInvalidArgument);                           \
    }                                                                                             \
    /* Key 3 was refused: it can be erased by nobody, inserted by anybody. */                     \
    EXPECT_EQ(e.Erase(3).code(), StatusCode::kNotFound);                                          \
    this->Insert(3, TestFixture::Cube(Coord(1), Coord(2)));                                       \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.collides, (Pairs{{1, 3}})); /* 1 kept its box [0,1] */                  \
    EXPECT_EQ(e.Size(), 2u);                                                                      \
  }                                                                                               \
  TYPED_TEST(Suite, CallsBetweenQueriesCoalesce) {                                                \
    using Coord = typename TestFixture::T;                                                        \
    auto& e = *this->engine_;                                                                     \
    this->Insert(1, TestFixture::Cube(Coord(0), Coord(4)));                                       \
    this->Insert(2, TestFixture::Cube(Coord(1), Coord(2)));                                       \
    this->Query();                                                                                \
    ASSERT_EQ(this->sink_.collides, (Pairs{{1, 2}}));                                             \
    /* Erase and re-insert overlapping again: no change, no event. */                             \
    ASSERT_TRUE(e.Erase(2).ok());                                                                 \
    this->Insert(2, TestFixture::Cube(Coord(2), Coord(3)));                                       \
    this->Query();                                                                                \
    EXPECT_TRUE(this->sink_.collides.empty());                                                    \
    EXPECT_TRUE(this->sink_.uncollides.empty());                                                  \
    /* Erase and re-insert elsewhere: one uncollide. */                                           \
    ASSERT_TRUE(e.Erase(2).ok());                                                                 \
    this->Insert(2, TestFixture::Cube(Coord(8), Coord(9)));                                       \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.uncollides, (Pairs{{1, 2}}));                                           \
    /* Insert, update and erase before a query: nothing at all. */                                \
    this->Insert(3, TestFixture::Cube(Coord(0), Coord(9)));                                       \
    this->Update(3, TestFixture::Cube(Coord(1), Coord(9)));                                       \
    ASSERT_TRUE(e.Erase(3).ok());                                                                 \
    EXPECT_EQ(e.Erase(3).code(), StatusCode::kNotFound);                                          \
    this->Query();                                                                                \
    EXPECT_TRUE(this->sink_.collides.empty());                                                    \
    EXPECT_EQ(e.Size(), 2u);                                                                      \
    /* An empty frame reports nothing. */                                                         \
    this->Query();                                                                                \
    EXPECT_TRUE(this->sink_.collides.empty() && this->sink_.uncollides.empty());                  \
    /* Erasing uncollides every pair of the object. */                                            \
    this->Insert(4, TestFixture::Cube(Coord(0), Coord(9)));                                       \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.collides, (Pairs{{1, 4}, {2, 4}}));                                     \
    ASSERT_TRUE(e.Erase(4).ok());                                                                 \
    this->Query();                                                                                \
    EXPECT_EQ(this->sink_.uncollides, (Pairs{{1, 4}, {2, 4}}));                                   \
  }                                                                                               \
  TYPED_TEST(Suite, HeavyChurnSplitsAndMergesChunks) {                                            \
    using Coord = typename TestFixture::T;                                                        \
    auto& e = *this->engine_;                                                                     \
    std::mt19937_64 rng(99);                                                                      \
    ModelOracle<TestFixture::K, Coord> model;                                                     \
    for (int round = 0; round < 6; ++round) {                                                     \
      /* Fill with 300 boxes on few coordinates, then erase nearly all. */                        \
      for (uint64_t k = 0; k < 300; ++k) {                                                        \
        auto b = TestFixture::RandomCube(rng, 50, 4);                                             \
        uint64_t key = static_cast<uint64_t>(round) * 1000 + k;                                   \
        this->Insert(key, b);                                                                     \
        model.boxes()[key] = b;                                                                   \
      }                                                                                           \
      this->QueryAndCompare(model);                                                               \
      if (this->HasFatalFailure()) return;                                                        \
      size_t full_chunks = e.GetStats().segmented_sap.value_or(SegmentedSapStats{}).chunks;       \
      for (auto it = model.boxes().begin(); it != model.boxes().end();) {                         \
        if (rng() % 10 != 0) {                                                                    \
          ASSERT_TRUE(e.Erase(it->first).ok());                                                   \
          it = model.boxes().erase(it);                                                           \
        } else {                                                                                  \
          ++it;                                                                                   \
        }                                                                                         \
      }                                                                                           \
      this->QueryAndCompare(model);                                                               \
      if (this->HasFatalFailure()) return;                                                        \
      ASSERT_EQ(e.Size(), model.boxes().size());                                                  \
      if (e.Name() == "segmented_sap") { /* chunks split while filling, merged while emptying */  \
        EXPECT_GE(full_chunks, static_cast<size_t>(TestFixture::K) * 600u / 32u);                 \
        EXPECT_LT(e.GetStats().segmented_sap.value().chunks, full_chunks / 2);                    \
      }                                                                                           \
    }                                                                                             \
  }

// One frame that moves, erases and inserts more objects than are live: SegmentedSap takes its
// bulk-load path, which must report exactly the same events as everybody else.
#define BP_BULK_CASE(Suite)                                                         \
  TYPED_TEST(Suite, BulkFrameWithMovesAndErases) {                                  \
    using Coord = typename TestFixture::T;                                          \
    auto& e = *this->engine_;                                                       \
    std::mt19937_64 rng(7);                                                         \
    ModelOracle<TestFixture::K, Coord> model;                                       \
    auto random_box = [&] { return TestFixture::RandomCube(rng, 40, 5); };          \
    for (uint64_t k = 0; k < 100; ++k) {                                            \
      auto b = random_box();                                                        \
      this->Insert(k, b);                                                           \
      model.boxes()[k] = b;                                                         \
    }                                                                               \
    for (int frame = 0; frame < 3; ++frame) {                                       \
      this->QueryAndCompare(model);                                                 \
      if (this->HasFatalFailure()) return;                                          \
      uint64_t base = 1000 * static_cast<uint64_t>(frame + 1);                      \
      for (uint64_t k = 0; k < 30; ++k) { /* teleports */                           \
        auto it = model.boxes().begin();                                            \
        std::advance(it, static_cast<long>(rng() % model.boxes().size()));          \
        auto b = random_box();                                                      \
        this->Update(it->first, b);                                                 \
        it->second = b;                                                             \
      }                                                                             \
      for (uint64_t k = 0; k < 20; ++k) { /* erases */                              \
        auto it = model.boxes().begin();                                            \
        std::advance(it, static_cast<long>(rng() % model.boxes().size()));          \
        ASSERT_TRUE(e.Erase(it->first).ok());                                       \
        model.boxes().erase(it);                                                    \
      }                                                                             \
      for (uint64_t k = 0, n = model.boxes().size() + 10; k < n; ++k) { /* burst */ \
        auto b = random_box();                                                      \
        this->Insert(base + k, b);                                                  \
        model.boxes()[base + k] = b;                                                \
      }                                                                             \
    }                                                                               \
    this->QueryAndCompare(model);                                                   \
    if (this->HasFatalFailure()) return;                                            \
    if (e.Name() == "segmented_sap") {                                              \
      EXPECT_TRUE(e.GetStats().rebuilt);                                            \
    }                                                                               \
  }

BP_BULK_CASE(BruteForceEdge)
BP_BULK_CASE(SegmentedSapEdge)
BP_BULK_CASE(SegmentedSapTinyEdge)
BP_BULK_CASE(BatchSapEdge)
BP_BULK_CASE(DynamicOctreeEdge)
BP_BULK_CASE(DynamicOctreeTinyEdge)

BP_EDGE_CASES(BruteForceEdge)
BP_EDGE_CASES(SegmentedSapEdge)
BP_EDGE_CASES(SegmentedSapTinyEdge)
BP_EDGE_CASES(BatchSapEdge)
BP_EDGE_CASES(DynamicOctreeEdge)
BP_EDGE_CASES(DynamicOctreeTinyEdge)

// A fast mover's min passes its own max and crosses chunk boundaries before the max follows:
// the paper's R set must absorb it (white-box: the counter proves the path ran).
TEST(SegmentedSapWhiteBox, FastMoversUseTheRSet) {
  SegmentedSapOptions options;
  options.chunk_capacity = 4;
  options.global_sort_fraction = 1e300;  // local sort only
  SegmentedSap<1, int32_t> engine(options);
  ModelOracle<1, int32_t> model;
  RecordingSink<uint64_t> sink;
  Pairs collides, uncollides;
  for (uint64_t k = 0; k < 40; ++k) {
    Box<1, int32_t> b{{static_cast<int32_t>(k * 3)}, {static_cast<int32_t>(k * 3 + 4)}};
    ASSERT_TRUE(engine.Insert(k, b).ok());
    model.boxes()[k] = b;
  }
  engine.Query(sink);
  model.Query(&collides, &uncollides);
  for (int jump = 0; jump < 20; ++jump) {
    uint64_t k = static_cast<uint64_t>(jump) % 40;
    int32_t to = (jump % 2 == 0) ? 200 + jump : -50 - jump;  // far right, far left
    Box<1, int32_t> b{{to}, {to + 1}};
    ASSERT_TRUE(engine.Update(k, b).ok());
    model.boxes()[k] = b;
    sink.Clear();
    engine.Query(sink);
    model.Query(&collides, &uncollides);
    ASSERT_EQ(sink.collides, collides);
    ASSERT_EQ(sink.uncollides, uncollides);
  }
  EXPECT_GT(engine.core().r_set_entries(), 0u);
}

// Keys need only hashing and ordering; any K compiles and is exact.
TEST(EngineKeys, StringKeysAndOtherDimensions) {
  SegmentedSap<3, double, std::string> engine;
  RecordingSink<std::string> sink;
  ASSERT_TRUE(engine.Insert("zeta", {{0, 0, 0}, {1, 1, 1}}).ok());
  ASSERT_TRUE(engine.Insert("alpha", {{1, 1, 1}, {2, 2, 2}}).ok());
  engine.Query(sink);
  EXPECT_EQ(sink.collides, (std::vector<std::pair<std::string, std::string>>{{"alpha", "zeta"}}));

  SegmentedSap<4, float> four;
  BruteForce<4, float> four_oracle;
  RecordingSink<uint64_t> a, b;
  std::mt19937_64 rng(5);
  for (uint64_t k = 0; k < 200; ++k) {
    Box<4, float> box;
    for (size_t i = 0; i < 4; ++i) {
      box.lo[i] = static_cast<float>(rng() % 20);
      box.hi[i] = box.lo[i] + static_cast<float>(rng() % 5);
    }
    ASSERT_TRUE(four.Insert(k, box).ok());
    ASSERT_TRUE(four_oracle.Insert(k, box).ok());
  }
  four.Query(a);
  four_oracle.Query(b);
  EXPECT_EQ(a.collides, b.collides);
  EXPECT_FALSE(a.collides.empty());
}

}  // namespace
}  // namespace bp::test
