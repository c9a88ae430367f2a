// BatchSap white-box cases: the floating array of section 3.2.1 (growth, backward pass, the gap a
// forward pass closes, compaction after a mass erase), empty and huge batches, and insert and
// erase of one key between two queries. Every query is compared with the model oracle.
#include <cstdint>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

namespace bp::test {
namespace {

using Pairs = std::vector<std::pair<uint64_t, uint64_t>>;
using Engine = BatchSap<3, float>;
using Layout = detail::BatchSapCore<3, float>::Layout;

class BatchSapTest : public ::testing::Test {
 protected:
  Box<3, float> RandomBox(float range = 100, float extent = 8) {
    Box<3, float> b;
    for (size_t a = 0; a < 3; ++a) {
      b.lo[a] = static_cast<float>(rng_() % static_cast<uint64_t>(range));
      b.hi[a] = b.lo[a] + static_cast<float>(rng_() % static_cast<uint64_t>(extent));
    }
    return b;
  }
  void Insert(uint64_t key) {
    Box<3, float> b = RandomBox();
    ASSERT_TRUE(engine_.Insert(key, b).ok());
    model_.boxes()[key] = b;
  }
  void Erase(uint64_t key) {
    ASSERT_TRUE(engine_.Erase(key).ok());
    model_.boxes().erase(key);
  }
  void QueryAndCompare() {
    sink_.Clear();
    engine_.Query(sink_);
    Pairs collides, uncollides;
    model_.Query(&collides, &uncollides);
    ASSERT_EQ(sink_.collides, collides);
    ASSERT_EQ(sink_.uncollides, uncollides);
    ASSERT_TRUE(engine_.Validate().ok()) << engine_.Validate().ToString();
  }
  const detail::BatchSapCore<3, float>& core() const { return engine_.core(); }
  // Every axis has the same layout: the passes of one query all run the same way.
  Layout Axis0() const {
    Layout l = core().layout(0);
    for (size_t a = 1; a < 3; ++a) {
      EXPECT_EQ(core().layout(a).begin, l.begin);
      EXPECT_EQ(core().layout(a).end, l.end);
      EXPECT_EQ(core().layout(a).capacity, l.capacity);
    }
    return l;
  }

  std::mt19937_64 rng_{42};
  Engine engine_;
  ModelOracle<3, float> model_;
  RecordingSink<uint64_t> sink_;
};

// Figures 5 and 6: the first load grows the allocation and passes backward, leaving a gap in
// front; the next batch of inserts fits the gap, passes forward and closes it by the insertions;
// erasures alone pass forward in place; a batch larger than the front gap but not the back one
// passes backward without growing.
TEST_F(BatchSapTest, FloatingArrayGrowsPassesBackwardAndClosesTheGap) {
  for (uint64_t k = 0; k < 100; ++k) Insert(k);
  QueryAndCompare();
  Layout l = Axis0();
  EXPECT_EQ(core().growths(), 3u);
  EXPECT_EQ(core().backward_passes(), 3u);
  EXPECT_EQ(core().forward_passes(), 0u);
  EXPECT_EQ(l.capacity, 400u);  // grown by twice the 200 new extrema
  EXPECT_EQ(l.begin, 200u);     // the list written against the end of the allocation
  EXPECT_EQ(l.end, 400u);

  for (uint64_t k = 100; k < 150; ++k) Insert(k);
  QueryAndCompare();
  l = Axis0();
  EXPECT_EQ(core().forward_passes(), 3u);
  EXPECT_EQ(l.begin, 100u);  // the gap closed by the 100 new extrema
  EXPECT_EQ(l.end, 400u);

  for (uint64_t k = 0; k < 150; k += 2) Erase(k);
  QueryAndCompare();
  l = Axis0();
  EXPECT_EQ(core().forward_passes(), 6u);
  EXPECT_EQ(l.begin, 100u);  // in place: nothing to make room for
  EXPECT_EQ(l.end, 250u);

  for (uint64_t k = 200; k < 260; ++k) Insert(k);  // 120 extrema > 100 in front, 150 behind
  QueryAndCompare();
  l = Axis0();
  EXPECT_EQ(core().growths(), 3u);
  EXPECT_EQ(core().backward_passes(), 6u);
  EXPECT_EQ(l.begin, 130u);
  EXPECT_EQ(l.end, 400u);
  EXPECT_EQ(engine_.Size(), 135u);
}

// Passes whose gap fits the insertions exactly: forward with |I| free slots in front, then
// backward with |I| free slots behind.
TEST_F(BatchSapTest, GapsThatFitExactly) {
  for (uint64_t k = 0; k < 100; ++k) Insert(k);
  QueryAndCompare();  // [200, 400) of 400
  for (uint64_t k = 100; k < 200; ++k) Insert(k);
  QueryAndCompare();  // 200 new extrema, 200 free in front
  Layout l = Axis0();
  EXPECT_EQ(core().forward_passes(), 3u);
  EXPECT_EQ(l.begin, 0u);
  EXPECT_EQ(l.end, 400u);
  for (uint64_t k = 0; k < 100; k += 2) Erase(k);
  QueryAndCompare();  // in place: [0, 300)
  for (uint64_t k = 300; k < 350; ++k) Insert(k);
  QueryAndCompare();  // 100 new extrema, none free in front, 100 behind
  l = Axis0();
  EXPECT_EQ(core().growths(), 3u);
  EXPECT_EQ(core().backward_passes(), 6u);
  EXPECT_EQ(l.begin, 0u);
  EXPECT_EQ(l.end, 400u);
  EXPECT_EQ(l.capacity, 400u);
}

// Steady churn with movement alternates the pass directions inside a bounded allocation.
TEST_F(BatchSapTest, SteadyChurnStaysInABoundedAllocation) {
  uint64_t next = 0;
  for (; next < 300; ++next) Insert(next);
  QueryAndCompare();
  for (int frame = 0; frame < 60 && !HasFailure(); ++frame) {
    for (int i = 0; i < 20; ++i) {  // 20 erases, 20 inserts, 30 moves
      auto it = model_.boxes().begin();
      std::advance(it, static_cast<long>(rng_() % model_.boxes().size()));
      Erase(it->first);
      Insert(next++);
    }
    for (int i = 0; i < 30; ++i) {
      auto it = model_.boxes().begin();
      std::advance(it, static_cast<long>(rng_() % model_.boxes().size()));
      Box<3, float> b = RandomBox();
      ASSERT_TRUE(engine_.Update(it->first, b).ok());
      it->second = b;
    }
    QueryAndCompare();
  }
  // The first load left 600 free slots; 40 insertions a frame close the front gap in 15
  // frames, then one backward pass reopens it. No growth after the first load.
  EXPECT_GE(core().forward_passes(), 3u * 50);
  EXPECT_GE(core().backward_passes(), 3u * 4);
  EXPECT_EQ(core().growths(), 3u);
  EXPECT_EQ(Axis0().capacity, 1200u);
}

// A mass erase does not pin the allocation of the burst that preceded it.
TEST_F(BatchSapTest, MassEraseCompactsTheAllocation) {
  for (uint64_t k = 0; k < 5000; ++k) Insert(k);
  QueryAndCompare();
  EXPECT_GE(Axis0().capacity, 20000u);
  for (uint64_t k = 10; k < 5000; ++k) Erase(k);
  QueryAndCompare();
  Layout l = Axis0();
  EXPECT_EQ(l.end - l.begin, 20u);
  EXPECT_LE(l.capacity, 4u * 20 + 4096);
  // The compacted list (no gap on either side) takes more batches and moves.
  for (int frame = 0; frame < 5 && !HasFailure(); ++frame) {
    Erase(static_cast<uint64_t>(frame));
    for (uint64_t k = 0; k < 40; ++k) Insert(10000 + 100 * static_cast<uint64_t>(frame) + k);
    Box<3, float> b = RandomBox();
    ASSERT_TRUE(engine_.Update(9, b).ok());
    model_.boxes()[9] = b;
    QueryAndCompare();
  }
  EXPECT_EQ(engine_.Size(), 10u - 5 + 200);
}

TEST_F(BatchSapTest, EmptyBatchesChangeNothing) {
  QueryAndCompare();  // an empty engine
  EXPECT_EQ(engine_.GetStats().objects, 0u);
  for (uint64_t k = 0; k < 50; ++k) Insert(k);
  QueryAndCompare();
  size_t passes = core().forward_passes() + core().backward_passes();
  Layout before = Axis0();
  QueryAndCompare();  // nothing pending: no pass at all
  EXPECT_TRUE(sink_.collides.empty() && sink_.uncollides.empty());
  EXPECT_EQ(core().forward_passes() + core().backward_passes(), passes);
  EXPECT_EQ(Axis0().begin, before.begin);
  EXPECT_FALSE(engine_.GetStats().global_sort);
}

// One query inserts thousands of crowded boxes (every pair found by the sweep sets), the next
// erases them all (every pair uncollided on the first axis).
TEST_F(BatchSapTest, HugeBatchesInAndOut) {
  for (uint64_t k = 0; k < 3000; ++k) {
    Box<3, float> b = RandomBox(60, 10);
    ASSERT_TRUE(engine_.Insert(k, b).ok());
    model_.boxes()[k] = b;
  }
  QueryAndCompare();
  EXPECT_GT(sink_.collides.size(), 10000u);
  for (uint64_t k = 0; k < 3000; ++k) Erase(k);
  QueryAndCompare();
  EXPECT_EQ(engine_.Size(), 0u);
  EXPECT_EQ(engine_.GetStats().overlaps, 0u);
  for (uint64_t k = 0; k < 10; ++k) Insert(k);  // and the emptied engine still works
  QueryAndCompare();
}

// Insert and erase of one key between two queries: nothing reaches the core; erase and insert of
// a live key is an update; insert, erase, insert is an insert.
TEST_F(BatchSapTest, InsertAndEraseOfOneKeyInOneFrame) {
  for (uint64_t k = 0; k < 40; ++k) Insert(k);
  QueryAndCompare();
  Insert(100);
  Erase(100);
  Erase(5);
  Insert(5);
  Insert(101);
  Erase(101);
  Insert(101);
  QueryAndCompare();
  EXPECT_EQ(engine_.GetStats().inserts, 1u);  // 101
  EXPECT_EQ(engine_.GetStats().updates, 1u);  // 5
  EXPECT_EQ(engine_.GetStats().erases, 0u);
  EXPECT_EQ(engine_.Size(), 41u);
}

// Local and global sorting of moves alone: the pass order follows the options.
TEST_F(BatchSapTest, MovesAloneSortLocallyOrGlobally) {
  for (uint64_t k = 0; k < 200; ++k) Insert(k);
  QueryAndCompare();
  auto move = [&](int count) {
    for (int i = 0; i < count; ++i) {
      auto it = model_.boxes().begin();
      std::advance(it, static_cast<long>(rng_() % model_.boxes().size()));
      Box<3, float> b = it->second;
      for (size_t a = 0; a < 3; ++a) {
        b.lo[a] += 3;
        b.hi[a] += 3;
      }
      ASSERT_TRUE(engine_.Update(it->first, b).ok());
      it->second = b;
    }
  };
  move(5);  // 2.5% of 200: below the default 7%
  QueryAndCompare();
  EXPECT_FALSE(engine_.GetStats().global_sort);
  move(100);
  QueryAndCompare();
  EXPECT_TRUE(engine_.GetStats().global_sort);
  EXPECT_GT(engine_.GetStats().swaps, 0u);
}

// One axis (the first axis is the last: removals and insertions in the same pass) and four, for
// integer and floating coordinates, local and global sorting, against brute force.
template <int K, class T>
void RandomFramesAgainstBruteForce(double global_fraction, uint64_t seed) {
  SCOPED_TRACE("K=" + std::to_string(K) + " seed=" + std::to_string(seed) +
               " fraction=" + std::to_string(global_fraction));
  BatchSapOptions options;
  options.global_sort_fraction = global_fraction;
  BatchSap<K, T> engine(options);
  BruteForce<K, T> oracle;
  RecordingSink<uint64_t> got, want;
  std::mt19937_64 rng(seed);
  auto random_box = [&] {
    Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = static_cast<T>(rng() % 30);
      b.hi[a] = static_cast<T>(b.lo[a] + static_cast<T>(rng() % 6));
    }
    return b;
  };
  std::vector<uint64_t> live;
  uint64_t next = 0;
  for (int frame = 0; frame < 60; ++frame) {
    int ops = frame == 0 ? 80 : static_cast<int>(rng() % 20);
    for (int i = 0; i < ops; ++i) {
      uint64_t r = rng() % 10;
      if (live.empty() || r < 3) {
        Box<K, T> b = random_box();
        ASSERT_TRUE(engine.Insert(next, b).ok());
        ASSERT_TRUE(oracle.Insert(next, b).ok());
        live.push_back(next++);
      } else if (r < 5) {
        size_t j = rng() % live.size();
        ASSERT_TRUE(engine.Erase(live[j]).ok());
        ASSERT_TRUE(oracle.Erase(live[j]).ok());
        live[j] = live.back();
        live.pop_back();
      } else {
        Box<K, T> b = random_box();
        uint64_t key = live[rng() % live.size()];
        ASSERT_TRUE(engine.Update(key, b).ok());
        ASSERT_TRUE(oracle.Update(key, b).ok());
      }
    }
    got.Clear();
    want.Clear();
    engine.Query(got);
    oracle.Query(want);
    ASSERT_EQ(got.collides, want.collides) << "frame " << frame;
    ASSERT_EQ(got.uncollides, want.uncollides) << "frame " << frame;
    ASSERT_TRUE(engine.Validate().ok()) << engine.Validate().ToString();
  }
}

TEST(BatchSapAxes, OneAndFourAxes) {
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    for (double fraction : {0.0, 0.07, 1e300}) {
      RandomFramesAgainstBruteForce<1, int32_t>(fraction, seed);
      RandomFramesAgainstBruteForce<1, float>(fraction, seed);
      RandomFramesAgainstBruteForce<4, float>(fraction, seed);
      RandomFramesAgainstBruteForce<4, uint32_t>(fraction, seed);
      if (::testing::Test::HasFailure()) return;
    }
  }
}

}  // namespace
}  // namespace bp::test
