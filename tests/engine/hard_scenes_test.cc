// The scenes where uniform grids suffer (WORKLOADS.md's last list; bp::workload::Shape): clustered,
// mixed sizes, fast movers, and a world far from the origin. Every engine is driven through each
// scene beside the brute-force engine; after every frame both must hold the same overlap set (set
// hash and pair count) and have reported the same numbers of events. The engines' validators run
// on every query (BP_VALIDATE). Scene properties are checked in workload_test.cc.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

#include "bp/scene_runner.h"

namespace bp::test {
namespace {

using workload::SceneParams;
using workload::SceneRunner;
using workload::Shape;

// A small scene of the shape: 800 objects, 30% moving, churn 8 (20 frames).
SceneParams HardParams(Shape shape, int dim, uint64_t seed) {
  SceneParams p;
  p.dim = dim;
  p.n = 800;
  p.moving = 240;
  p.churn = 8;
  p.shape = shape;
  p.seed = seed;
  return p;
}

// What a run shows after each frame (frame 0 first).
struct FrameRecord {
  uint64_t pairs, set_hash, collides, uncollides;
  bool operator==(const FrameRecord&) const = default;
};

template <int K, Coordinate T>
std::vector<FrameRecord> Record(Broadphase<K, T>& engine, const SceneParams& params, int frames) {
  SceneRunner<K, T> run(engine, params);
  std::vector<FrameRecord> out;
  run.Build();
  out.push_back({run.pairs(), run.set_hash(), 0, 0});
  for (int f = 1; f <= frames; ++f) {
    run.Step();
    out.push_back({run.pairs(), run.set_hash(), run.collides(), run.uncollides()});
  }
  EXPECT_EQ(run.errors(), 0u) << run.first_error();
  return out;
}

template <int K, Coordinate T, class Make>
void ExpectSameAs(const std::vector<FrameRecord>& want, const SceneParams& params) {
  SCOPED_TRACE("engine=" + Make::Name() + " shape=" + workload::ShapeName(params.shape) +
               " K=" + std::to_string(K) + " offset=" + std::to_string(params.offset) +
               " seed=" + std::to_string(params.seed));
  std::unique_ptr<Broadphase<K, T>> engine = Make::template Create<K, T>();
  std::vector<FrameRecord> got = Record(*engine, params, static_cast<int>(want.size()) - 1);
  ASSERT_EQ(got.size(), want.size());
  for (size_t f = 0; f < want.size(); ++f) {
    ASSERT_EQ(got[f].pairs, want[f].pairs) << "frame " << f;
    ASSERT_EQ(got[f].set_hash, want[f].set_hash) << "frame " << f;
    ASSERT_EQ(got[f].collides, want[f].collides) << "frame " << f;
    ASSERT_EQ(got[f].uncollides, want[f].uncollides) << "frame " << f;
  }
}

// Every engine family with its default options, plus small dense cells (objects span cells and
// the widest are kept as large objects), against one brute-force run of the scene.
template <int K, Coordinate T>
void ExpectAllEngines(const SceneParams& params, int frames = 20) {
  BruteForce<K, T> oracle;
  const std::vector<FrameRecord> want = Record(oracle, params, frames);
  EXPECT_GT(want.back().collides, 0u) << "the scene should produce events";
  ExpectSameAs<K, T, MakeSegmentedSap<32, 7>>(want, params);
  ExpectSameAs<K, T, MakeBatchSap<7>>(want, params);
  ExpectSameAs<K, T, MakeGrid<CellKind::kSegmented, 0>>(want, params);
  ExpectSameAs<K, T, MakeGrid<CellKind::kBatch, 0>>(want, params);
  ExpectSameAs<K, T, MakeGrid<CellKind::kDense, 0>>(want, params);
  ExpectSameAs<K, T, MakeGrid<CellKind::kDense, 30, 8>>(want, params);
  ExpectSameAs<K, T, MakeDynamicOctree<>>(want, params);
}

TEST(HardScenes, Clustered) {
  for (uint64_t seed : TestSeeds(41, 2)) {
    ExpectAllEngines<3, float>(HardParams(Shape::kClustered, 3, seed));
    ExpectAllEngines<3, int32_t>(HardParams(Shape::kClustered, 3, seed));
    ExpectAllEngines<2, double>(HardParams(Shape::kClustered, 2, seed));
  }
}

TEST(HardScenes, MixedSizes) {
  for (uint64_t seed : TestSeeds(43, 2)) {
    ExpectAllEngines<3, float>(HardParams(Shape::kMixed, 3, seed));
    ExpectAllEngines<3, double>(HardParams(Shape::kMixed, 3, seed));
    ExpectAllEngines<2, int32_t>(HardParams(Shape::kMixed, 2, seed));
  }
}

TEST(HardScenes, FastMovers) {
  for (uint64_t seed : TestSeeds(47, 2)) {
    ExpectAllEngines<3, float>(HardParams(Shape::kFast, 3, seed));
    ExpectAllEngines<3, int32_t>(HardParams(Shape::kFast, 3, seed));
    ExpectAllEngines<2, float>(HardParams(Shape::kFast, 2, seed));
  }
}

// A world offset by 1e6 in float (a unit of 1/16 there: boxes round, touch and merge) and by 1e12
// in double, uniform and clustered.
TEST(HardScenes, FarFromOrigin) {
  for (uint64_t seed : TestSeeds(53, 2)) {
    for (Shape shape : {Shape::kUniform, Shape::kClustered}) {
      SceneParams p = HardParams(shape, 3, seed);
      p.offset = 1e6;
      ExpectAllEngines<3, float>(p);
      p.offset = 1e12;
      ExpectAllEngines<3, double>(p);
      p.offset = -1e12;
      ExpectAllEngines<3, double>(p);
    }
  }
}

}  // namespace
}  // namespace bp::test
