// SegmentedSap's presorted path (options.presorted_min; paper, end of 4.1): inserts and erases
// integrated chunk by chunk. A randomized differential suite against the model oracle (bursts
// into one chunk, inserts into an empty engine, erasing everything, equal coordinates, touching
// and spanning boxes) and targeted cases; events and Validate() are checked after every query,
// and the core's counter proves the path ran. Replay one seed with BP_TEST_SEED=<seed>.
#include <algorithm>
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

SegmentedSapOptions PresortedOptions(uint32_t capacity, uint32_t bulk_min, uint32_t presorted) {
  SegmentedSapOptions options;
  options.chunk_capacity = capacity;
  options.bulk_load_min = bulk_min;
  options.presorted_min = presorted;
  return options;
}

// An engine and the model fed the same calls; every query compares events and validates.
template <int K, class T>
class Harness {
 public:
  using BoxType = Box<K, T>;
  explicit Harness(const SegmentedSapOptions& options) : engine_(options) {}

  void Insert(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_.Insert(key, b).ok()) << key;
    model_.boxes()[key] = b;
  }
  void Update(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_.Update(key, b).ok()) << key;
    model_.boxes()[key] = b;
  }
  void Erase(uint64_t key) {
    ASSERT_TRUE(engine_.Erase(key).ok()) << key;
    model_.boxes().erase(key);
  }
  void Query() {
    sink_.Clear();
    engine_.Query(sink_);
    Pairs collides, uncollides;
    model_.Query(&collides, &uncollides);
    ASSERT_EQ(sink_.uncollides, uncollides);
    ASSERT_EQ(sink_.collides, collides);
    ASSERT_EQ(engine_.Size(), model_.boxes().size());
    Status s = engine_.Validate();
    ASSERT_TRUE(s.ok()) << s.ToString();
  }

  static BoxType Cube(T lo, T hi) {
    BoxType b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = lo;
      b.hi[a] = hi;
    }
    return b;
  }

  SegmentedSap<K, T>& engine() { return engine_; }
  ModelOracle<K, T>& model() { return model_; }
  const RecordingSink<uint64_t>& sink() const { return sink_; }
  size_t presorted() const { return engine_.core().presorted_queries(); }

 private:
  SegmentedSap<K, T> engine_;
  ModelOracle<K, T> model_;
  RecordingSink<uint64_t> sink_;
};

// ---- randomized differential suite ----

template <int K_, class T_, uint32_t kCapacity, uint32_t kBulkMin>
struct PresortedConfig {
  static constexpr int K = K_;
  using T = T_;
  static SegmentedSapOptions Options() { return PresortedOptions(kCapacity, kBulkMin, 1); }
  static std::string Name() {
    return "c" + std::to_string(kCapacity) + "_b" + std::to_string(kBulkMin);
  }
};

template <class Config>
class SegmentedPresortedDiff : public ::testing::Test {
 protected:
  static constexpr int K = Config::K;
  using T = typename Config::T;
  using BoxType = Box<K, T>;
  static constexpr int kLattice = 60;

  void Run(uint64_t seed) {
    SCOPED_TRACE("config=" + Config::Name() + " K=" + std::to_string(K) + " seed=" +
                 std::to_string(seed) + " (replay with BP_TEST_SEED=" + std::to_string(seed) + ")");
    rng_.seed(seed);
    Harness<K, T> h(Config::Options());
    h_ = &h;
    keys_.clear();
    for (int i = 0; i < 120; ++i) Insert(RandomBox(kLattice, 8));
    h.Query();
    size_t before = h.presorted();
    bool refill = false;
    const int frames = 60;
    for (int frame = 1; frame <= frames && !HasFailure(); ++frame) {
      SCOPED_TRACE("frame " + std::to_string(frame));
      if (refill) {
        Burst(1 + Below(150), Below(2) == 0);  // into an empty engine
        refill = false;
      } else {
        switch (Below(8)) {
          case 0:
          case 1:
          case 2:
            Mixed(static_cast<int>(Below(80)));
            break;
          case 3:  // many new objects on a few coordinates of one spot: one target chunk
            Burst(10 + Below(150), true);
            break;
          case 4:  // a run of neighbours on axis 0: whole chunks empty
            EraseRun(Below(60));
            Mixed(static_cast<int>(Below(10)));
            break;
          case 5:  // erase everything, sometimes refilling in the same frame
            while (!keys_.empty()) Erase(keys_.size() - 1);
            if (Below(2) == 0) {
              Burst(Below(100), Below(2) == 0);
            } else {
              refill = true;
            }
            break;
          case 6:  // boxes spanning many chunks come and go
            for (uint64_t i = Below(6); i > 0; --i) Insert(RandomBox(kLattice, 4 * kLattice));
            Mixed(static_cast<int>(Below(20)));
            break;
          default:  // moves only, or moves and one event
            for (uint64_t i = Below(40); i > 0 && !keys_.empty(); --i) Move();
            if (Below(2) == 0) Insert(RandomBox(kLattice, 8));
            break;
        }
      }
      h.Query();
    }
    EXPECT_GT(h.presorted(), before + frames / 2);
  }

 private:
  uint64_t Below(uint64_t n) { return std::uniform_int_distribution<uint64_t>(0, n - 1)(rng_); }
  T Coord(int lo, int hi) {
    return static_cast<T>(lo + static_cast<int>(Below(static_cast<uint64_t>(hi - lo + 1))));
  }
  BoxType RandomBox(int lattice, int max_extent) {
    BoxType b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = Coord(-lattice, lattice);
      b.hi[a] = static_cast<T>(b.lo[a] + Coord(0, max_extent));
    }
    return b;
  }
  void Insert(const BoxType& b) {
    uint64_t key = next_key_++;
    h_->Insert(key, b);
    keys_.push_back(key);
  }
  void Erase(size_t i) {
    h_->Erase(keys_[i]);
    keys_[i] = keys_.back();
    keys_.pop_back();
  }
  void Move() {
    uint64_t key = keys_[Below(keys_.size())];
    h_->Update(key, Below(4) == 0 ? RandomBox(kLattice, 8) : Nudged(h_->model().boxes()[key]));
  }
  BoxType Nudged(BoxType b) {
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      T d = Coord(-2, 2);
      b.lo[a] = static_cast<T>(b.lo[a] + d);
      b.hi[a] = static_cast<T>(b.hi[a] + d);
    }
    return b;
  }
  void Mixed(int ops) {
    for (int i = 0; i < ops; ++i) {
      uint64_t what = Below(10);
      if (what < 4 || keys_.empty()) {
        Insert(RandomBox(kLattice, 8));
      } else if (what < 7) {
        Erase(Below(keys_.size()));
      } else {
        Move();
      }
    }
  }
  // n new objects, all on a few coordinates around one spot (equal and touching extrema) when
  // clustered, spread over the world otherwise; a few erases among them.
  void Burst(uint64_t n, bool clustered) {
    int at = static_cast<int>(Coord(-kLattice, kLattice));
    for (uint64_t i = 0; i < n; ++i) {
      if (!clustered) {
        Insert(RandomBox(kLattice, 8));
        continue;
      }
      BoxType b;
      for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
        b.lo[a] = Coord(at, at + 2);
        b.hi[a] = static_cast<T>(b.lo[a] + Coord(0, 1));
      }
      Insert(b);
    }
    for (uint64_t i = Below(4); i > 0 && !keys_.empty(); --i) Erase(Below(keys_.size()));
  }
  // Erases up to n objects whose minima are neighbours on axis 0.
  void EraseRun(uint64_t n) {
    if (keys_.empty()) return;
    std::vector<std::pair<T, uint64_t>> by_lo;
    for (uint64_t key : keys_) by_lo.emplace_back(h_->model().boxes()[key].lo[0], key);
    std::sort(by_lo.begin(), by_lo.end());
    size_t from = Below(by_lo.size());
    std::vector<uint64_t> gone;
    for (size_t i = from; i < by_lo.size() && gone.size() < n; ++i) gone.push_back(by_lo[i].second);
    for (uint64_t key : gone)
      Erase(static_cast<size_t>(std::find(keys_.begin(), keys_.end(), key) - keys_.begin()));
  }

  std::mt19937_64 rng_;
  Harness<K, T>* h_ = nullptr;
  std::vector<uint64_t> keys_;
  uint64_t next_key_ = 1;
};

using PresortedConfigs =
    ::testing::Types<PresortedConfig<2, float, 4, 0>, PresortedConfig<3, float, 4, 0>,
                     PresortedConfig<2, int32_t, 4, 0>, PresortedConfig<3, int32_t, 4, 64>,
                     PresortedConfig<2, float, 32, 0>, PresortedConfig<3, float, 32, 64>,
                     PresortedConfig<2, int32_t, 32, 64>, PresortedConfig<3, int32_t, 32, 0>>;
TYPED_TEST_SUITE(SegmentedPresortedDiff, PresortedConfigs);

TYPED_TEST(SegmentedPresortedDiff, RandomBatchesMatchOracle) {
  for (uint64_t seed : TestSeeds(4100, 4)) {
    this->Run(seed);
    if (this->HasFailure()) return;
  }
}

// ---- targeted cases ----

// 1000 disjoint cubes along the diagonal, bulk loaded (three quarters full chunks), then 500
// new cubes on a few coordinates inside cube 500: on every axis they all target one chunk, which
// spreads over hundreds of new ones, and the extrema already there move once.
template <class T>
void BurstIntoOneChunk(uint32_t presorted_min, size_t* out_swaps) {
  constexpr int K = 3;
  using H = Harness<K, T>;
  H h(PresortedOptions(4, 64, presorted_min));
  for (uint64_t k = 0; k < 1000; ++k) {
    T lo = static_cast<T>(10 * k);
    h.Insert(k, H::Cube(lo, static_cast<T>(lo + 5)));
  }
  ASSERT_NO_FATAL_FAILURE(h.Query());
  ASSERT_TRUE(h.engine().GetStats().rebuilt);
  size_t chunks = h.engine().GetStats().segmented_sap.value().chunks;
  size_t presorted = h.presorted();
  for (uint64_t k = 0; k < 500; ++k) {
    T lo = static_cast<T>(5001 + static_cast<int>(k % 3));  // inside [5000, 5005]
    h.Insert(1000 + k, H::Cube(lo, static_cast<T>(lo + static_cast<T>(k % 2))));
  }
  ASSERT_NO_FATAL_FAILURE(h.Query());
  Stats stats = h.engine().GetStats();
  EXPECT_FALSE(stats.rebuilt);
  EXPECT_EQ(stats.inserts, 500u);
  EXPECT_EQ(h.presorted(), presorted + (presorted_min != 0 ? 1 : 0));
  if (presorted_min != 0) {
    // 1000 + 4 extrema over chunks of 2..3 (evenly, at most 3/4 full): >= 334 per axis.
    EXPECT_GE(stats.segmented_sap.value().chunks, chunks + 3 * 333) << chunks;
    EXPECT_LE(stats.swaps, 3u * 4u);  // one chunk per axis, each extremum moved once
  }
  *out_swaps = stats.swaps;
  // Erase the burst again in one query: the chunks holding only new extrema empty, and the at
  // most two per axis that also hold old ones merge back where they got small.
  for (uint64_t k = 0; k < 500; ++k) h.Erase(1000 + k);
  ASSERT_NO_FATAL_FAILURE(h.Query());
  if (presorted_min != 0) {
    EXPECT_LE(h.engine().GetStats().segmented_sap.value().chunks, chunks + 3 * 2);
  }
}

TEST(SegmentedPresorted, BurstIntoOneChunkSpreadsOverManyChunks) {
  size_t batch = 0, single = 0;
  ASSERT_NO_FATAL_FAILURE(BurstIntoOneChunk<float>(1, &batch));
  ASSERT_NO_FATAL_FAILURE(BurstIntoOneChunk<int32_t>(1, &batch));
  ASSERT_NO_FATAL_FAILURE(BurstIntoOneChunk<int32_t>(0, &single));  // the per-event path
  EXPECT_LT(10 * batch, single);
}

// Cubes in groups of three with the six extrema of a group inside [30 j, 30 j + 10]: bulk
// loaded with capacity 8 (fill 6), chunk j of every axis holds exactly group j. The first two
// of a group overlap.
class SegmentedPresortedChunks : public ::testing::Test {
 protected:
  using H = Harness<2, int32_t>;
  static constexpr int kGroups = 40;

  SegmentedPresortedChunks() : h_(PresortedOptions(8, 64, 1)) {}
  void SetUp() override {
    for (int j = 0; j < kGroups; ++j) {
      int32_t base = 30 * j;
      h_.Insert(Key(j, 0), H::Cube(base, base + 5));
      h_.Insert(Key(j, 1), H::Cube(base + 2, base + 8));
      h_.Insert(Key(j, 2), H::Cube(base + 9, base + 10));
    }
    ASSERT_NO_FATAL_FAILURE(h_.Query());
    ASSERT_TRUE(h_.engine().GetStats().rebuilt);
    ASSERT_EQ(h_.engine().GetStats().segmented_sap.value().chunks, 2u * kGroups);
  }
  static uint64_t Key(int group, int i) { return static_cast<uint64_t>(3 * group + i); }

  H h_;
};

TEST_F(SegmentedPresortedChunks, EraseEveryObjectOfOneChunk) {
  size_t presorted = h_.presorted();
  for (int i = 0; i < 3; ++i) h_.Erase(Key(10, i));
  ASSERT_NO_FATAL_FAILURE(h_.Query());
  EXPECT_EQ(h_.sink().uncollides, (Pairs{{Key(10, 0), Key(10, 1)}}));
  // The chunk is gone on both axes and its neighbours (6 + 6) do not merge.
  EXPECT_EQ(h_.engine().GetStats().segmented_sap.value().chunks, 2u * (kGroups - 1));
  EXPECT_EQ(h_.engine().GetStats().swaps, 0u);
  EXPECT_EQ(h_.presorted(), presorted + 1);
}

TEST_F(SegmentedPresortedChunks, EraseBothExtremaInOneChunk) {
  // One object per chunk, both extrema in it: each of three chunks per axis compacts once.
  for (int j : {3, 4, 20}) h_.Erase(Key(j, 1));
  ASSERT_NO_FATAL_FAILURE(h_.Query());
  EXPECT_EQ(h_.sink().uncollides,
            (Pairs{{Key(3, 0), Key(3, 1)}, {Key(4, 0), Key(4, 1)}, {Key(20, 0), Key(20, 1)}}));
  EXPECT_EQ(h_.engine().GetStats().segmented_sap.value().chunks,
            2u * kGroups);  // 4 + 6 > 4: no merge
  // A chunk was (a lo, b lo, a hi, b hi, c lo, c hi): a hi, c lo and c hi move once each.
  EXPECT_EQ(h_.engine().GetStats().swaps, 2u * 3u * 3u);
}

TEST_F(SegmentedPresortedChunks, ErasingHalfOfNeighbouringChunksMerges) {
  // Chunks 10..19 keep one object (2 extrema) each: adjacent pairs hold 4 = cap / 2, so they
  // merge (invariant 2b, checked by Validate) after every compaction is done.
  for (int j = 10; j < 20; ++j) {
    h_.Erase(Key(j, 0));
    h_.Erase(Key(j, 1));
  }
  ASSERT_NO_FATAL_FAILURE(h_.Query());
  EXPECT_LT(h_.engine().GetStats().segmented_sap.value().chunks, 2u * kGroups - 2u * 4u);
  // Chunks 10..19 gone entirely, with every neighbour touched: 2b must hold again.
  for (int j = 10; j < 20; ++j) h_.Erase(Key(j, 2));
  for (int j = 21; j < 30; j += 2) {
    for (int i = 0; i < 3; ++i) h_.Erase(Key(j, i));
  }
  ASSERT_NO_FATAL_FAILURE(h_.Query());
}

TEST_F(SegmentedPresortedChunks, EmptiedChunkJoinsSmallNeighbours) {
  // Chunks 11 and 13 keep two extrema each; chunk 12 between them keeps six.
  for (int j : {11, 13}) {
    h_.Erase(Key(j, 0));
    h_.Erase(Key(j, 1));
  }
  ASSERT_NO_FATAL_FAILURE(h_.Query());
  ASSERT_EQ(h_.engine().GetStats().segmented_sap.value().chunks, 2u * kGroups);
  // Emptying chunk 12 makes the untouched 11 and 13 neighbours with 2 + 2 = cap / 2: they merge.
  for (int i = 0; i < 3; ++i) h_.Erase(Key(12, i));
  ASSERT_NO_FATAL_FAILURE(h_.Query());
  EXPECT_EQ(h_.engine().GetStats().segmented_sap.value().chunks, 2u * (kGroups - 2));
}

// Long boxes spanning many chunks of axis 0 are inserted (their checkpoints), then a clustered
// burst spreads a chunk that holds some of their extrema and lies inside others (the new chunks'
// checkpoints), then both go in one erase.
TEST(SegmentedPresorted, BoxesSpanningManyChunks) {
  using H = Harness<3, float>;
  H h(PresortedOptions(4, 64, 1));
  std::mt19937_64 rng(31);
  auto small = [&](float x) {
    Box<3, float> b;
    for (size_t a = 0; a < 3; ++a) {
      b.lo[a] = a == 0 ? x : static_cast<float>(rng() % 8);
      b.hi[a] = b.lo[a] + static_cast<float>(rng() % 3);
    }
    return b;
  };
  for (uint64_t k = 0; k < 400; ++k) h.Insert(k, small(static_cast<float>(k)));
  ASSERT_NO_FATAL_FAILURE(h.Query());
  for (uint64_t k = 0; k < 30; ++k) {
    // From exactly where some small box starts (touching) to 10..300 further.
    float lo = static_cast<float>(rng() % 300);
    Box<3, float> b{{lo, 0, 0}, {lo + static_cast<float>(10 + rng() % 290), 10, 10}};
    h.Insert(1000 + k, b);
  }
  ASSERT_NO_FATAL_FAILURE(h.Query());
  // The burst lands where the long boxes start and end, too.
  for (uint64_t k = 0; k < 60; ++k) {
    float x = 150.0f + static_cast<float>(k % 4) * 0.5f;
    h.Insert(2000 + k, small(x));
  }
  Box<3, float> everything{{-1, -1, -1}, {1000, 100, 100}};
  h.Insert(3000, everything);
  ASSERT_NO_FATAL_FAILURE(h.Query());
  for (uint64_t k = 0; k < 30; k += 2) h.Erase(1000 + k);
  for (uint64_t k = 0; k < 60; k += 3) h.Erase(2000 + k);
  ASSERT_NO_FATAL_FAILURE(h.Query());
}

// With bulk loading off, inserts into an empty engine go through one empty chunk that spreads;
// erasing everything empties every list, and refilling works again.
TEST(SegmentedPresorted, EmptyEngineFillsAndEmpties) {
  using H = Harness<2, int32_t>;
  H h(PresortedOptions(4, 0, 1));
  std::mt19937_64 rng(8);
  for (int round = 0; round < 3; ++round) {
    uint64_t n = round == 0 ? 1 : (round == 1 ? 2 : 200);
    for (uint64_t k = 0; k < n; ++k) {
      auto lo = static_cast<int32_t>(rng() % 40);
      h.Insert(k, H::Cube(lo, lo + static_cast<int32_t>(rng() % 4)));
    }
    ASSERT_NO_FATAL_FAILURE(h.Query());
    EXPECT_FALSE(h.engine().GetStats().rebuilt);
    EXPECT_GE(h.engine().GetStats().segmented_sap.value().chunks, 2u * (2 * n / 3));
    for (uint64_t k = 0; k < n; ++k) h.Erase(k);
    ASSERT_NO_FATAL_FAILURE(h.Query());
    EXPECT_EQ(h.engine().GetStats().segmented_sap.value().chunks, 0u);
  }
  EXPECT_EQ(h.presorted(), 6u);
}

// presorted_min counts objects: below it a query takes the per-event path.
TEST(SegmentedPresorted, ThresholdCountsInsertsAndErases) {
  using H = Harness<2, float>;
  H h(PresortedOptions(32, 64, 3));
  for (uint64_t k = 0; k < 10; ++k) {
    h.Insert(k, H::Cube(static_cast<float>(k), static_cast<float>(k) + 1.5f));
  }
  ASSERT_NO_FATAL_FAILURE(h.Query());
  EXPECT_EQ(h.presorted(), 1u);
  h.Insert(20, H::Cube(3, 4));
  h.Erase(0);
  ASSERT_NO_FATAL_FAILURE(h.Query());
  EXPECT_EQ(h.presorted(), 1u);  // 2 < 3
  h.Insert(21, H::Cube(5, 6));
  h.Erase(1);
  h.Erase(2);
  ASSERT_NO_FATAL_FAILURE(h.Query());
  EXPECT_EQ(h.presorted(), 2u);
  h.Update(3, H::Cube(0, 9));
  ASSERT_NO_FATAL_FAILURE(h.Query());
  EXPECT_EQ(h.presorted(), 2u);  // updates do not count
}

}  // namespace
}  // namespace bp::test
