// Tests of bp::workload: the generator against the golden values of docs/WORKLOADS.md,
// checked by an independent, simple exact oracle (sort-and-sweep over all live boxes).
#include "bp/workload.h"

#include <algorithm>
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <unordered_map>
#include <vector>

#include <gtest/gtest.h>

namespace bp::workload {
namespace {

bool LongTestsEnabled() {
  const char* env = std::getenv("BP_LONG_TESTS");
  return env != nullptr && std::strcmp(env, "1") == 0;
}

// True in an optimised build without sanitizers, where the 100k-object rows take ~5 s each
// (under Debug + ASan they take minutes, so there they need BP_LONG_TESTS=1).
constexpr bool kFastBuild =
#if defined(__OPTIMIZE__) && !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
    true;
#else
    false;
#endif

// How long a golden row takes to check: kQuick always runs, kHeavy runs in fast builds,
// kLong only with BP_LONG_TESTS=1.
enum class Cost { kQuick, kHeavy, kLong };

bool ShouldRun(Cost cost) {
  switch (cost) {
    case Cost::kQuick:
      return true;
    case Cost::kHeavy:
      return kFastBuild || LongTestsEnabled();
    case Cost::kLong:
      return LongTestsEnabled();
  }
  return false;
}

std::string Hex(uint64_t v) {
  char buf[17];
  std::snprintf(buf, sizeof(buf), "%016" PRIx64, v);
  return buf;
}

// The full overlap set of boxes as sorted pair keys: sort by lo[0], sweep forward while
// other.lo[0] <= this.hi[0], test the remaining axes with the closed test. The remaining-axes
// test runs branch-free over blocks of candidates (structure of arrays) so the compiler can
// vectorise it; a block is scanned for its hits only when one of its candidates overlaps.
std::vector<uint64_t> OverlapSet(std::vector<SceneBox> boxes) {
  std::sort(boxes.begin(), boxes.end(),
            [](const SceneBox& a, const SceneBox& b) { return a.lo[0] < b.lo[0]; });
  const size_t n = boxes.size();
  std::vector<float> lo0(n), lo1(n), hi1(n), lo2(n), hi2(n);
  for (size_t i = 0; i < n; ++i) {
    lo0[i] = boxes[i].lo[0];
    lo1[i] = boxes[i].lo[1];
    hi1[i] = boxes[i].hi[1];
    lo2[i] = boxes[i].lo[2];
    hi2[i] = boxes[i].hi[2];
  }
  const float* l1 = lo1.data();
  const float* h1 = hi1.data();
  const float* l2 = lo2.data();
  const float* h2 = hi2.data();
  constexpr size_t kBlock = 32;
  std::vector<uint64_t> keys;
  for (size_t i = 0; i < n; ++i) {
    const float hi0 = boxes[i].hi[0];
    const float a_lo1 = l1[i], a_hi1 = h1[i], a_lo2 = l2[i], a_hi2 = h2[i];
    auto overlaps = [=](size_t j) {
      return static_cast<int>(l1[j] <= a_hi1) & static_cast<int>(a_lo1 <= h1[j]) &
             static_cast<int>(l2[j] <= a_hi2) & static_cast<int>(a_lo2 <= h2[j]);
    };
    // Candidates: j in (i, end) with lo0[j] <= hi0 (lo0 is sorted).
    const size_t end = static_cast<size_t>(
        std::upper_bound(lo0.begin() + static_cast<std::ptrdiff_t>(i) + 1, lo0.end(), hi0) -
        lo0.begin());
    for (size_t b = i + 1; b < end; b += kBlock) {
      const size_t e = std::min(end, b + kBlock);
      int any = 0;
      for (size_t j = b; j < e; ++j) any |= overlaps(j);
      if (any == 0) continue;
      for (size_t j = b; j < e; ++j) {
        if (overlaps(j) != 0) keys.push_back(PairKey(boxes[i].id, boxes[j].id));
      }
    }
  }
  std::sort(keys.begin(), keys.end());
  return keys;
}

size_t IntersectionSize(const std::vector<uint64_t>& a, const std::vector<uint64_t>& b) {
  size_t i = 0, j = 0, count = 0;
  while (i < a.size() && j < b.size()) {
    if (a[i] < b[j]) {
      ++i;
    } else if (b[j] < a[i]) {
      ++j;
    } else {
      ++count;
      ++i;
      ++j;
    }
  }
  return count;
}

uint64_t SumHash(const std::vector<uint64_t>& keys) {
  uint64_t sum = 0;
  for (uint64_t k : keys) sum += PairHash(k);
  return sum;
}

struct Golden {
  const char* name;
  int dim;
  uint32_t n, moving, churn, frames;
  uint64_t pairs0, pairs_end, collides, uncollides;
  const char* set_hash_end;
  const char* chain;
  Cost cost;
};

void PrintTo(const Golden& g, std::ostream* os) { *os << g.name; }

class WorkloadGoldenTest : public ::testing::TestWithParam<Golden> {};

TEST_P(WorkloadGoldenTest, MatchesGoldenValues) {
  const Golden& g = GetParam();
  if (!ShouldRun(g.cost)) GTEST_SKIP() << "set BP_LONG_TESTS=1 to run " << g.name;

  SceneParams params;
  params.dim = g.dim;
  params.n = g.n;
  params.moving = g.moving;
  params.churn = g.churn;
  Scene scene(params);

  std::unordered_map<uint64_t, SceneBox> live;
  live.reserve(g.n * 2);
  for (const SceneBox& box : scene.Initial()) live.emplace(box.id, box);
  ASSERT_EQ(live.size(), g.n);

  auto snapshot = [&live] {
    std::vector<SceneBox> boxes;
    boxes.reserve(live.size());
    for (const auto& [id, box] : live) boxes.push_back(box);
    return boxes;
  };

  std::vector<uint64_t> pairs = OverlapSet(snapshot());
  EXPECT_EQ(pairs.size(), g.pairs0);
  HashChain chain;
  chain.AddFrame(SumHash(pairs));

  uint64_t collides = 0, uncollides = 0;
  FrameOps ops;
  for (uint32_t f = 1; f <= g.frames; ++f) {
    scene.NextFrame(&ops);
    ASSERT_EQ(ops.erases.size(), g.churn);
    ASSERT_EQ(ops.inserts.size(), g.churn);
    for (uint64_t id : ops.erases) ASSERT_EQ(live.erase(id), 1u) << "frame " << f;
    for (const SceneBox& box : ops.updates) {
      auto it = live.find(box.id);
      ASSERT_NE(it, live.end()) << "frame " << f;
      it->second = box;
    }
    for (const SceneBox& box : ops.inserts) {
      ASSERT_TRUE(live.emplace(box.id, box).second) << "frame " << f;
    }
    ASSERT_EQ(live.size(), g.n);

    std::vector<uint64_t> next = OverlapSet(snapshot());
    const size_t common = IntersectionSize(pairs, next);
    collides += next.size() - common;
    uncollides += pairs.size() - common;
    pairs = std::move(next);
    chain.AddFrame(SumHash(pairs));
  }
  EXPECT_EQ(pairs.size(), g.pairs_end);
  EXPECT_EQ(collides, g.collides);
  EXPECT_EQ(uncollides, g.uncollides);
  EXPECT_EQ(Hex(SumHash(pairs)), g.set_hash_end);
  EXPECT_EQ(Hex(chain.value()), g.chain);
}

// The golden table of docs/WORKLOADS.md (seed 12345).
INSTANTIATE_TEST_SUITE_P(
    Golden, WorkloadGoldenTest,
    ::testing::Values(Golden{"S2a", 3, 3000, 150, 1, 100, 618, 616, 461, 463, "4c5481efcc6b8142",
                             "6274793c8a9520a7", Cost::kQuick},
                      Golden{"S2b", 3, 3000, 150, 10, 100, 618, 606, 814, 826, "99bc3a682398a0b2",
                             "56762576cf62e0f8", Cost::kQuick},
                      Golden{"S2c", 3, 3000, 150, 40, 100, 618, 642, 2096, 2072, "24f0cde31b8772da",
                             "f9bf9debdb1ec8ad", Cost::kQuick},
                      Golden{"S1_10k", 3, 10000, 1000, 50, 100, 2091, 2036, 4844, 4899,
                             "452f9a10ed565172", "8345d52362006c12", Cost::kQuick},
                      Golden{"S1_100k", 3, 100000, 10000, 500, 100, 20185, 20225, 48547, 48507,
                             "9daf7bc27bdb0bf0", "116364493e9a2610", Cost::kHeavy},
                      Golden{"S1_200k", 3, 200000, 20000, 1000, 100, 40554, 40327, 96223, 96450,
                             "5f410c55499b8fec", "00f104cfea5b41a5", Cost::kLong},
                      Golden{"S3", 3, 100000, 100000, 0, 100, 20087, 20237, 194523, 194373,
                             "88b27919275dcb9d", "8fb8ee8db6ed1fca", Cost::kLong},
                      Golden{"S4", 3, 100000, 1000, 50, 100, 20014, 20169, 4948, 4793,
                             "4e3138f6f44efe52", "6d6113b0730825f8", Cost::kHeavy},
                      Golden{"TwoD", 2, 10000, 1000, 50, 100, 975, 980, 2159, 2154,
                             "147c669596380529", "f11fe373f509505a", Cost::kQuick}),
    [](const ::testing::TestParamInfo<Golden>& param_info) {
      return std::string(param_info.param.name);
    });

TEST(Xoshiro256Test, SameSeedSameSequence) {
  Xoshiro256 a(12345), b(12345), c(54321);
  bool differs = false;
  for (int i = 0; i < 1000; ++i) {
    const uint64_t x = a.Next();
    EXPECT_EQ(x, b.Next());
    if (x != c.Next()) differs = true;
  }
  EXPECT_TRUE(differs);
}

TEST(Xoshiro256Test, SplitMixReferenceValue) {
  // splitmix64 with state 0: the first output of the reference implementation.
  uint64_t state = 0;
  EXPECT_EQ(SplitMix64(state), 0xE220A8397B1DCDAFULL);
  EXPECT_EQ(state, 0x9E3779B97F4A7C15ULL);
}

TEST(Xoshiro256Test, BelowIsInRange) {
  Xoshiro256 rng(7);
  for (uint64_t bound :
       {uint64_t{1}, uint64_t{2}, uint64_t{3}, uint64_t{1000}, uint64_t{1} << 40, ~uint64_t{0}}) {
    for (int i = 0; i < 1000; ++i) EXPECT_LT(rng.Below(bound), bound);
  }
}

TEST(Xoshiro256Test, Uniform01IsInRange) {
  Xoshiro256 rng(9);
  for (int i = 0; i < 10000; ++i) {
    const double u = rng.Uniform01();
    EXPECT_GE(u, 0.0);
    EXPECT_LT(u, 1.0);
  }
}

void ExpectOnGrid(const SceneBox& box, double grid, int dim, float width) {
  for (size_t a = 0; a < 3; ++a) {
    for (float c : {box.lo[a], box.hi[a]}) {
      const double q = static_cast<double>(c) / grid;
      EXPECT_EQ(q, std::floor(q)) << "id " << box.id << " axis " << a;
      EXPECT_LT(std::fabs(q), 0x1.0p24) << "id " << box.id << " axis " << a;
    }
    EXPECT_EQ(box.hi[a] - box.lo[a], width);
    if (static_cast<int>(a) >= dim) {
      EXPECT_EQ(box.lo[a], 0.0f);
      EXPECT_EQ(box.hi[a], width);
    }
  }
}

TEST(SceneTest, CoordinatesAreGridMultiplesAndRoundTrip) {
  for (int dim : {2, 3}) {
    SceneParams params;
    params.dim = dim;
    params.n = 2000;
    params.moving = 500;
    params.churn = 20;
    Scene scene(params);
    const double grid = scene.grid();
    // grid is a power of two with 2 side + 2 w < 2^24 grid.
    int e = 0;
    EXPECT_EQ(std::frexp(grid, &e), 0.5);
    EXPECT_LT(2 * scene.side() + 2 * params.width, 0x1.0p24 * grid);
    EXPECT_GE(2 * scene.side() + 2 * params.width, 0x1.0p23 * grid);

    auto check = [&](const SceneBox& box) {
      ExpectOnGrid(box, grid, dim, static_cast<float>(params.width));
      const Box<3, int32_t> ibox = ToBox<3, int32_t>(box, grid);
      const Box<3, float> fbox = ToBox<3, float>(box, grid);
      for (size_t a = 0; a < 3; ++a) {
        EXPECT_EQ(static_cast<double>(ibox.lo[a]) * grid, static_cast<double>(box.lo[a]));
        EXPECT_EQ(static_cast<double>(ibox.hi[a]) * grid, static_cast<double>(box.hi[a]));
        EXPECT_EQ(fbox.lo[a], box.lo[a]);
        EXPECT_EQ(fbox.hi[a], box.hi[a]);
      }
    };
    for (const SceneBox& box : scene.Initial()) check(box);
    FrameOps ops;
    for (int f = 0; f < 50; ++f) {
      scene.NextFrame(&ops);
      for (const SceneBox& box : ops.updates) check(box);
      for (const SceneBox& box : ops.inserts) check(box);
    }
  }
}

TEST(SceneTest, SameSeedSameFramesDifferentSeedDiffers) {
  SceneParams params;
  params.n = 1000;
  params.moving = 100;
  params.churn = 5;
  Scene a(params), b(params);
  params.seed = 999;
  Scene c(params);
  ASSERT_EQ(a.Initial().size(), b.Initial().size());
  for (size_t i = 0; i < a.Initial().size(); ++i) {
    EXPECT_EQ(a.Initial()[i].lo, b.Initial()[i].lo);
    EXPECT_EQ(a.Initial()[i].id, i);
  }
  EXPECT_NE(a.Initial()[0].lo, c.Initial()[0].lo);
  FrameOps oa, ob;
  for (int f = 0; f < 10; ++f) {
    a.NextFrame(&oa);
    b.NextFrame(&ob);
    EXPECT_EQ(oa.erases, ob.erases);
    ASSERT_EQ(oa.updates.size(), ob.updates.size());
    for (size_t i = 0; i < oa.updates.size(); ++i) {
      EXPECT_EQ(oa.updates[i].id, ob.updates[i].id);
      EXPECT_EQ(oa.updates[i].lo, ob.updates[i].lo);
    }
    ASSERT_EQ(oa.inserts.size(), ob.inserts.size());
    for (size_t i = 0; i < oa.inserts.size(); ++i) {
      EXPECT_EQ(oa.inserts[i].id, ob.inserts[i].id);
      EXPECT_EQ(oa.inserts[i].lo, ob.inserts[i].lo);
    }
  }
}

TEST(SceneTest, FrameOpsShape) {
  SceneParams params;
  params.n = 1000;
  params.moving = 100;
  params.churn = 30;
  Scene scene(params);
  FrameOps ops;
  uint64_t next_id = params.n;
  for (int f = 0; f < 20; ++f) {
    scene.NextFrame(&ops);
    ASSERT_EQ(ops.erases.size(), params.churn);
    ASSERT_EQ(ops.inserts.size(), params.churn);
    // Inserted ids are fresh and consecutive in generation order.
    for (const SceneBox& box : ops.inserts) EXPECT_EQ(box.id, next_id++);
    // Erased ids are distinct.
    std::vector<uint64_t> erased = ops.erases;
    std::sort(erased.begin(), erased.end());
    EXPECT_EQ(std::adjacent_find(erased.begin(), erased.end()), erased.end());
    // Updates: moving slots not replaced this frame.
    EXPECT_LE(ops.updates.size(), params.moving);
    EXPECT_GE(ops.updates.size(), params.moving - params.churn);
  }
}

// The shapes of WORKLOADS.md's "scenes where uniform grids suffer" (Shape): what each promises.
// The boxes a scene places in its first `frames` frames (initial and inserted); moved boxes
// go to *moved.
std::vector<SceneBox> ShapeFrames(int frames, Scene* scene, std::vector<SceneBox>* moved) {
  FrameOps ops;
  std::vector<SceneBox> all = scene->Initial();
  for (int f = 0; f < frames; ++f) {
    scene->NextFrame(&ops);
    all.insert(all.end(), ops.inserts.begin(), ops.inserts.end());
    moved->insert(moved->end(), ops.updates.begin(), ops.updates.end());
  }
  return all;
}

TEST(SceneShapes, ClusteredKeepsNineTenthsInOnePercentOfTheVolume) {
  SceneParams p;
  p.n = 5000;
  p.moving = 2000;
  p.churn = 50;
  p.shape = Shape::kClustered;
  Scene scene(p);
  std::vector<SceneBox> moved;
  std::vector<SceneBox> placed = ShapeFrames(30, &scene, &moved);
  const double side = scene.side(), cluster = side * std::cbrt(0.01);
  const double base = (side - cluster) / 2;
  auto inside = [&](const SceneBox& b) {
    for (size_t a = 0; a < 3; ++a) {
      if (b.lo[a] < base - scene.grid() || b.hi[a] > base + cluster + scene.grid()) return false;
    }
    return true;
  };
  size_t in = 0, total = 0;
  for (const auto* list : {&placed, &moved}) {
    for (const SceneBox& b : *list) {
      in += inside(b);
      ++total;
    }
  }
  // Slots i % 10 != 9 stay in the cluster; the uniform tenth lands there 1% of the time.
  EXPECT_NEAR(static_cast<double>(in) / static_cast<double>(total), 0.9, 0.01);
}

TEST(SceneShapes, MixedSpansSixDecadesOfWidth) {
  SceneParams p;
  p.n = 20000;
  p.moving = 2000;
  p.churn = 100;
  p.shape = Shape::kMixed;
  Scene scene(p);
  std::vector<SceneBox> moved;
  std::vector<SceneBox> placed = ShapeFrames(5, &scene, &moved);
  std::array<int, 8> decades{};
  size_t points = 0;
  for (const SceneBox& b : placed) {
    const double w = static_cast<double>(b.hi[0]) - static_cast<double>(b.lo[0]);
    ASSERT_GE(w, 0.0);
    ASSERT_LE(b.hi[0], scene.side());
    if (w < scene.grid()) {
      ++points;  // below the snap grid: a point
    } else {
      ++decades[static_cast<size_t>(
          std::clamp(static_cast<int>(std::floor(std::log10(w))) + 3, 0, 7))];
    }
  }
  // Log-uniform in [1e-3, 1e3]: every decade from the snap grid's up to 1e2..1e3 is populated.
  for (int d = static_cast<int>(std::ceil(std::log10(scene.grid()))) + 3; d < 6; ++d) {
    EXPECT_GT(decades[static_cast<size_t>(d)], 1000) << "decade 1e" << d - 3;
  }
  EXPECT_EQ(decades[6] + decades[7], 0);
  EXPECT_GT(points, 0u);
}

TEST(SceneShapes, FastMoversCrossManyWidthsPerFrame) {
  SceneParams p;
  p.n = 3000;
  p.moving = 300;
  p.churn = 0;
  p.shape = Shape::kFast;
  Scene scene(p);
  FrameOps a, b;
  scene.NextFrame(&a);
  scene.NextFrame(&b);
  ASSERT_EQ(a.updates.size(), b.updates.size());
  for (size_t i = 0; i < a.updates.size(); ++i) {
    double d2 = 0;
    for (size_t k = 0; k < 3; ++k) {
      const double d = static_cast<double>(b.updates[i].lo[k]) - a.updates[i].lo[k];
      d2 += d * d;
    }
    // Bounces shorten a step; away from the walls it is the speed (to the snap grid).
    if (i % 10 == 0) {
      EXPECT_GT(std::sqrt(d2), 2.0) << "slot " << i;
    } else {
      EXPECT_LT(std::sqrt(d2), 0.1 + 4 * scene.grid()) << "slot " << i;
    }
  }
}

TEST(SceneShapes, OffsetIsAddedInTheEnginesType) {
  SceneBox box;
  box.lo = {1.0f, 2.5f, 3.0f};
  box.hi = {2.0f, 3.5f, 4.0f};
  Box<3, float> f = ToBox<3, float>(box, 1.0 / 1024, 1e6);
  EXPECT_EQ(f.lo[1], 1e6f + 2.5f);  // 1000002.5 is a float
  Box<3, double> d = ToBox<3, double>(box, 1.0 / 1024, 1e12);
  EXPECT_EQ(d.lo[1], 1e12 + 2.5);
  EXPECT_EQ(d.hi[2], 1e12 + 4.0);
  SceneBox frac = box;
  frac.lo[0] = 0.03125f;  // 1e6 + 1/32 rounds to 1e6 in float (a unit of 1/16 there)
  EXPECT_EQ((ToBox<3, float>(frac, 1.0 / 1024, 1e6).lo[0]), 1e6f);
}

TEST(SceneShapes, NamesRoundTrip) {
  for (Shape s : {Shape::kUniform, Shape::kClustered, Shape::kMixed, Shape::kFast}) {
    Shape back = Shape::kUniform;
    ASSERT_TRUE(ParseShape(ShapeName(s), &back));
    EXPECT_EQ(back, s);
  }
  Shape unused;
  EXPECT_FALSE(ParseShape("spiral", &unused));
}

TEST(HashTest, ChainAndSetHash) {
  SetHash set;
  set.Collide(3, 1);
  set.Collide(2, 5);
  EXPECT_EQ(set.pairs(), 2u);
  EXPECT_EQ(set.value(), PairHash(PairKey(1, 3)) + PairHash(PairKey(5, 2)));
  set.Uncollide(1, 3);
  EXPECT_EQ(set.value(), PairHash(PairKey(2, 5)));
  EXPECT_EQ(PairKey(7, 2), (uint64_t{2} << 32) | 7);

  HashChain chain;
  chain.AddFrame(11);
  EXPECT_EQ(chain.value(), Mix64(11));
  chain.AddFrame(22);
  EXPECT_EQ(chain.value(), Mix64(Mix64(11) ^ (22 + 1)));
}

}  // namespace
}  // namespace bp::workload
