// White-box tests of DynamicOctree: the root grows towards boxes far from the origin (1e6,
// +-1e30 in float, +-1e300 in double), extreme values of every coordinate type (lowest()/max()
// go to the overflow list only where doubles cannot hold a root around them), straddling boxes
// stay in the split node, leaves split past their capacity, updates inside their node do not
// move, empty subtrees are freed and small ones collapsed after mass erases, a new root adopts
// the overflow objects it holds; K = 1 and 4 against brute force. Each step compares the events
// with BruteForce and validates the tree.
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

// A DynamicOctree and the brute-force oracle fed the same calls; Query compares their events.
template <int K, class T>
class Lockstep {
 public:
  using BoxType = Box<K, T>;
  explicit Lockstep(const DynamicOctreeOptions& options = {}) : tree_(options) {}

  void Insert(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(tree_.Insert(key, b).ok());
    ASSERT_TRUE(oracle_.Insert(key, b).ok());
  }
  void Update(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(tree_.Update(key, b).ok());
    ASSERT_TRUE(oracle_.Update(key, b).ok());
  }
  void Erase(uint64_t key) {
    ASSERT_TRUE(tree_.Erase(key).ok());
    ASSERT_TRUE(oracle_.Erase(key).ok());
  }
  // Queries both; returns the number of events (and fails the test if they differ).
  size_t Query() {
    RecordingSink<uint64_t> a, b;
    tree_.Query(a);
    oracle_.Query(b);
    EXPECT_EQ(a.collides, b.collides);
    EXPECT_EQ(a.uncollides, b.uncollides);
    Status v = tree_.Validate();
    EXPECT_TRUE(v.ok()) << v.ToString();
    return b.collides.size() + b.uncollides.size();
  }
  const detail::DynamicOctreeCore<K, T>& core() const { return tree_.core(); }
  size_t overlaps() const { return tree_.GetStats().overlaps; }

 private:
  DynamicOctree<K, T> tree_;
  BruteForce<K, T> oracle_;
};

// n random cubes of extent 0..3 at integer positions in [0, 40) shifted by `at`.
template <int K, class T>
void InsertCluster(Lockstep<K, T>& s, uint64_t first_key, int n, T at, uint64_t seed) {
  std::mt19937_64 rng(seed);
  for (int i = 0; i < n; ++i) {
    Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = static_cast<T>(at + static_cast<T>(rng() % 40));
      b.hi[a] = static_cast<T>(b.lo[a] + static_cast<T>(rng() % 4));
    }
    s.Insert(first_key + static_cast<uint64_t>(i), b);
  }
}

TEST(DynamicOctree, RootGrowsTowardsFarBoxes) {
  Lockstep<3, double> s;
  InsertCluster<3, double>(s, 0, 200, 0.0, 1);
  s.Query();
  ASSERT_TRUE(s.core().has_root());
  auto [lo0, hi0] = s.core().root_bounds();
  int depth0 = s.core().depth();
  // Far away on +x and on -y: the root doubles outward until it holds both.
  s.Insert(1000, Box<3, double>{{1e6, 0, 0}, {1e6 + 1, 1, 1}});
  s.Insert(1001, Box<3, double>{{1e6, -3e6, 0}, {1e6 + 1, -3e6 + 1, 1}});  // overlaps nothing
  s.Insert(1002, Box<3, double>{{1e6 + 0.5, 0.5, 0.5}, {1e6 + 2, 2, 2}});  // overlaps 1000
  EXPECT_EQ(s.Query(), 1u);
  auto [lo, hi] = s.core().root_bounds();
  EXPECT_GE(hi[0], 1e6 + 2);
  EXPECT_LE(lo[1], -3e6);
  EXPECT_LE(lo[0], lo0[0]);
  EXPECT_GE(hi[2], hi0[2]);
  EXPECT_GT(s.core().depth(), depth0);
  EXPECT_EQ(s.core().overflow(), 0u);
  // The far boxes leave: the root shrinks back over the cluster (single-child roots go).
  s.Erase(1000);
  s.Erase(1001);
  s.Erase(1002);
  s.Query();
  auto [lo2, hi2] = s.core().root_bounds();
  EXPECT_LT(hi2[0], 1e6);
  EXPECT_GT(lo2[1], -3e6);
}

template <class T>
void FarCornersCase(T far) {
  SCOPED_TRACE(std::to_string(far));
  Lockstep<3, T> s;
  InsertCluster<3, T>(s, 0, 100, T(0), 2);
  s.Query();
  // Pairs around +far and -far, each pair overlapping; with extents of 1e-7 of the coordinate,
  // which float and double still resolve.
  T d = far * T(1e-6);
  s.Insert(500, Cube<3, T>(far, far + d));
  s.Insert(501, Cube<3, T>(far + d, far + 2 * d));  // touches 500
  s.Insert(502, Cube<3, T>(-far - d, -far));
  s.Insert(503, Cube<3, T>(-far - 3 * d, -far - 2 * d));  // apart from 502
  s.Insert(504, Cube<3, T>(-far, far));                   // over everything
  s.Query();
  EXPECT_EQ(s.core().overflow(), 0u);
  auto [lo, hi] = s.core().root_bounds();
  EXPECT_LE(lo[0], -far - 3 * d);
  EXPECT_GE(hi[0], far + 2 * d);
  // Move the far boxes among themselves and into the cluster; then erase the giant.
  s.Update(503, Cube<3, T>(-far - d, -far - d));  // now touches 502
  s.Update(501, Cube<3, T>(T(5), T(6)));          // into the cluster
  s.Query();
  s.Erase(504);
  s.Update(500, Cube<3, T>(-far, -far));  // touches 502 (and the cluster is far away)
  s.Query();
}

TEST(DynamicOctree, FloatBoxesAtPlusMinus1e30) { FarCornersCase<float>(1e30f); }
TEST(DynamicOctree, DoubleBoxesAtPlusMinus1e300) { FarCornersCase<double>(1e300); }
TEST(DynamicOctree, FloatBoxesNearFloatMax) { FarCornersCase<float>(3e38f); }

template <class T>
void ExtremesCase() {
  using L = std::numeric_limits<T>;
  Lockstep<3, T> s;
  InsertCluster<3, T>(s, 0, 50, T(0), 3);
  s.Query();
  s.Insert(100, Cube<3, T>(L::lowest(), L::max()));
  s.Insert(101, Cube<3, T>(L::lowest(), L::lowest()));
  s.Insert(102, Cube<3, T>(L::max(), L::max()));
  s.Insert(103, Box<3, T>{{L::lowest(), T(0), T(0)}, {L::max(), T(1), T(1)}});
  s.Query();
  // Doubles cannot hold a root around +-DBL_MAX (the root doubles in steps): those boxes go to
  // the overflow list. Every other type fits in a root of doubles.
  if constexpr (std::is_same_v<T, double>) {
    EXPECT_GT(s.core().overflow(), 0u);
  } else {
    EXPECT_EQ(s.core().overflow(), 0u);
  }
  s.Update(100, Cube<3, T>(T(1), T(2)));
  s.Update(103, Cube<3, T>(L::max(), L::max()));  // onto 102
  s.Query();
  s.Erase(101);
  s.Erase(102);
  s.Query();
  s.Update(103, Cube<3, T>(T(0), T(0)));
  s.Query();
  EXPECT_EQ(s.core().overflow(), 0u);
}

TEST(DynamicOctree, LowestAndMaxFloat) { ExtremesCase<float>(); }
TEST(DynamicOctree, LowestAndMaxDouble) { ExtremesCase<double>(); }
TEST(DynamicOctree, LowestAndMaxInt32) { ExtremesCase<int32_t>(); }
TEST(DynamicOctree, LowestAndMaxUint32) { ExtremesCase<uint32_t>(); }

// The first batch is one giant box: the root fits it, and later boxes everywhere still pair.
TEST(DynamicOctree, FirstBatchIsAGiantBox) {
  using L = std::numeric_limits<double>;
  Lockstep<2, double> s;
  s.Insert(1, Cube<2, double>(L::lowest(), L::max()));
  s.Query();
  InsertCluster<2, double>(s, 10, 100, 0.0, 4);
  s.Insert(2, Cube<2, double>(1e300, 1e300));
  s.Query();
  // The root is [-DBL_MAX, DBL_MAX]^2: nothing overflows, and the cluster lies in one leaf at
  // the depth limit (cells there are still ~1e302 wide).
  EXPECT_EQ(s.core().overflow(), 0u);
  EXPECT_EQ(s.core().depth(), 20);
  s.Erase(1);
  s.Query();
}

// Overflow objects whose tree empties: the next root may hold them (a root fitted to a giant
// box spans all doubles), so they must leave the overflow list (Validate checks it after every
// query). The root comes from a batch of inserts, or from one box moved out of the overflow list.
// Found by fuzz_update_batch: a first batch whose boxes reach -1.9e289 on one axis and sit
// near the origin on the other. The root fitted to the batch is far wider than the small boxes.
TEST(DynamicOctree, FirstBatchFromTheFuzzer) {
  Lockstep<2, double> s;
  const double boxes[][4] = {{0, 1, 2, 3},    {9, 10, 11, 12},  {4, 5, 6, 7},
                             {9, 10, 11, 12}, {7, 8, 9, 10},    {1, -1.94906280228e+289, 3, 4},
                             {1, 2, 3, 4},    {11, 12, 13, 14}, {9, 10, 11, 12},
                             {6, 7, 8, 9},    {11, 12, 13, 14}, {1, 2, 3, 4},
                             {5, 6, 7, 8},    {2, 3, 4, 5},     {-2684354560, 8, 9, 10},
                             {1, 2, 3, 4},    {10, 11, 12, 13}};
  uint64_t key = 1;
  for (const auto& v : boxes) {
    Box<2, double> b;
    b.lo = {v[0], v[1]};
    b.hi = {v[2], v[3]};
    s.Insert(key++, b);
  }
  s.Query();
}

TEST(DynamicOctree, NewRootAdoptsOverflowObjects) {
  using L = std::numeric_limits<double>;
  for (bool from_batch : {true, false}) {
    SCOPED_TRACE(from_batch ? "root from a batch" : "root from one update");
    Lockstep<2, double> s;
    InsertCluster<2, double>(s, 0, 20, 0.0, 9);
    s.Query();
    s.Insert(100, Cube<2, double>(L::lowest(), L::max()));
    s.Insert(101, Cube<2, double>(L::lowest(), L::max()));
    s.Query();
    ASSERT_EQ(s.core().overflow(), 2u);
    for (uint64_t k = 0; k < 20; ++k) s.Erase(k);
    s.Query();
    EXPECT_FALSE(s.core().has_root());
    if (from_batch) {
      s.Insert(102, Cube<2, double>(L::lowest(), L::max()));
      s.Insert(103, Cube<2, double>(5.0, 6.0));
    } else {
      s.Update(101, Cube<2, double>(L::lowest(), L::max()));
    }
    s.Query();
    EXPECT_TRUE(s.core().has_root());
    EXPECT_EQ(s.core().overflow(), 0u);
  }
}

TEST(DynamicOctree, LeafSplitsPastItsCapacity) {
  DynamicOctreeOptions options;
  options.max_objects_per_node = 4;
  Lockstep<2, float> s(options);
  // The first batch sets the root to [0, 16]^2; four boxes, one per quadrant: a single leaf.
  s.Insert(0, Box<2, float>{{0, 0}, {1, 1}});
  s.Insert(1, Box<2, float>{{15, 0}, {16, 1}});
  s.Insert(2, Box<2, float>{{0, 15}, {1, 16}});
  s.Insert(3, Box<2, float>{{15, 15}, {16, 16}});
  s.Query();
  EXPECT_EQ(s.core().nodes(), 1u);
  EXPECT_EQ(s.core().depth(), 0);
  // A fifth: the root splits and every box goes one level down.
  s.Insert(4, Box<2, float>{{2, 2}, {3, 3}});
  s.Query();
  EXPECT_EQ(s.core().depth(), 1);
  EXPECT_EQ(s.core().nodes(), 5u);
  for (uint32_t h = 0; h < 5; ++h) EXPECT_EQ(s.core().DepthOf(h), 1) << h;
  // Many in one corner: that corner splits deeper.
  for (uint64_t k = 10; k < 30; ++k) {
    float x = static_cast<float>(k - 10) * 0.1f;
    s.Insert(k, Box<2, float>{{x, x}, {x + 0.05f, x + 0.05f}});
  }
  s.Query();
  EXPECT_GT(s.core().depth(), 2);
}

TEST(DynamicOctree, StraddlingBoxesStayInTheSplitNode) {
  DynamicOctreeOptions options;
  options.max_objects_per_node = 2;
  Lockstep<2, float> s(options);
  s.Insert(0, Box<2, float>{{0, 0}, {1, 1}});
  s.Insert(1, Box<2, float>{{15, 15}, {16, 16}});
  s.Insert(2, Box<2, float>{{15, 0}, {16, 1}});
  s.Query();  // root [0, 16]^2 split at 8: every box one level down
  EXPECT_EQ(s.core().DepthOf(0), 1);
  // Across x = 8: fits no quadrant, stays in the root (handle 3).
  s.Insert(3, Box<2, float>{{7, 1}, {9, 2}});
  s.Query();
  EXPECT_EQ(s.core().DepthOf(3), 0);
  EXPECT_FALSE(s.core().InLeaf(3));
  // Moved while still straddling: stays without reinsertion.
  s.Update(3, Box<2, float>{{6, 0}, {10, 1}});  // now overlaps 0? no: 0 is [0,1]
  s.Query();
  EXPECT_EQ(s.core().relocations(), 0u);
  EXPECT_EQ(s.core().stays(), 1u);
  // Touching the split plane from below is inside the lower quadrant; crossing it is not.
  s.Update(3, Box<2, float>{{7, 1}, {8, 2}});
  s.Query();
  EXPECT_EQ(s.core().DepthOf(3), 1);
  EXPECT_EQ(s.core().relocations(), 1u);
  s.Update(3, Box<2, float>{{0.5f, 0.5f}, {15.5f, 15.5f}});  // over everything, in the root
  EXPECT_EQ(s.Query(), 3u);
  EXPECT_EQ(s.core().DepthOf(3), 0);
}

TEST(DynamicOctree, UpdatesInsideTheirNodeDoNotMove) {
  DynamicOctreeOptions options;
  options.max_objects_per_node = 4;
  Lockstep<2, float> s(options);
  s.Insert(0, Box<2, float>{{0, 0}, {1, 1}});
  s.Insert(1, Box<2, float>{{15, 0}, {16, 1}});
  s.Insert(2, Box<2, float>{{0, 15}, {1, 16}});
  s.Insert(3, Box<2, float>{{15, 15}, {16, 16}});
  s.Insert(4, Box<2, float>{{2, 2}, {3, 3}});
  s.Query();  // root [0, 16]^2, split: 0 and 4 in the lower-left quadrant
  ASSERT_EQ(s.core().DepthOf(0), 1);
  // Within the quadrant: the entry is rewritten in place.
  s.Update(0, Box<2, float>{{2.5f, 2.5f}, {4, 4}});  // onto 4
  s.Update(4, Box<2, float>{{3, 3}, {7, 8}});        // touches the plane x = 8 from below
  EXPECT_EQ(s.Query(), 1u);                          // 0 meets 4
  EXPECT_EQ(s.core().stays(), 2u);
  EXPECT_EQ(s.core().relocations(), 0u);
  // Out of the quadrant: moved to another node.
  s.Update(0, Box<2, float>{{9, 0}, {10, 1}});
  EXPECT_EQ(s.Query(), 1u);
  EXPECT_EQ(s.core().relocations(), 1u);
  EXPECT_EQ(s.core().DepthOf(0), 1);
}

TEST(DynamicOctree, MassEraseCollapsesTheTree) {
  DynamicOctreeOptions options;
  options.max_objects_per_node = 8;
  Lockstep<3, float> s(options);
  InsertCluster<3, float>(s, 0, 2000, 0.0f, 7);
  s.Query();
  size_t big = s.core().nodes();
  EXPECT_GT(big, 50u);
  for (uint64_t k = 4; k < 2000; ++k) s.Erase(k);
  s.Query();
  // Four objects: at most half a node's capacity, so the whole tree collapsed into one leaf.
  EXPECT_EQ(s.core().nodes(), 1u);
  EXPECT_EQ(s.core().depth(), 0);
  for (uint64_t k = 0; k < 4; ++k) s.Erase(k);
  s.Query();
  EXPECT_FALSE(s.core().has_root());
  EXPECT_EQ(s.core().nodes(), 0u);
  // Refilling reuses the freed nodes.
  size_t allocated = s.core().allocated_nodes();
  InsertCluster<3, float>(s, 5000, 2000, 100.0f, 7);  // the same shape, shifted
  s.Query();
  EXPECT_EQ(s.core().allocated_nodes(), allocated);
}

TEST(DynamicOctree, StatsCountOverlapTests) {
  DynamicOctree<3, float> tree;
  RecordingSink<uint64_t> sink;
  for (uint64_t k = 0; k < 100; ++k) {
    float x = static_cast<float>(k);
    ASSERT_TRUE(tree.Insert(k, Cube<3, float>(x, x + 1.5f)).ok());
  }
  tree.Query(sink);
  EXPECT_GT(tree.GetStats().overlap_tests, 0u);
  EXPECT_EQ(tree.GetStats().overlaps, 99u);
  EXPECT_EQ(tree.Name(), "dynamic_octree");
}

template <int K>
void RandomAgainstBruteForce(uint64_t seed) {
  SCOPED_TRACE("K=" + std::to_string(K));
  DynamicOctreeOptions options;
  options.max_objects_per_node = 3;
  Lockstep<K, int32_t> s(options);
  std::mt19937_64 rng(seed);
  auto random_box = [&] {
    Box<K, int32_t> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = static_cast<int32_t>(rng() % 60) - 30;
      b.hi[a] = b.lo[a] + static_cast<int32_t>(rng() % 8);
    }
    return b;
  };
  std::vector<uint64_t> live;
  uint64_t next = 0;
  for (int i = 0; i < 150; ++i) {
    s.Insert(next, random_box());
    live.push_back(next++);
  }
  s.Query();
  for (int frame = 0; frame < 40 && !::testing::Test::HasFailure(); ++frame) {
    for (int op = 0; op < 30; ++op) {
      uint64_t r = rng() % 10;
      size_t i = static_cast<size_t>(rng() % live.size());
      if (r == 0 && live.size() > 10) {
        s.Erase(live[i]);
        live[i] = live.back();
        live.pop_back();
      } else if (r == 1) {
        s.Insert(next, random_box());
        live.push_back(next++);
      } else {
        s.Update(live[i], random_box());
      }
    }
    s.Query();
  }
}

TEST(DynamicOctree, OneAndFourAxesAgainstBruteForce) {
  RandomAgainstBruteForce<1>(11);
  RandomAgainstBruteForce<4>(12);
}

}  // namespace
}  // namespace bp::test
