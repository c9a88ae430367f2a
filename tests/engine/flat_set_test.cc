// FlatSet against std::set under a seeded random operation sequence (leveldb-style model test).
#include "bp/detail/flat_set.h"

#include <cstdint>
#include <random>
#include <set>

#include "test_support.h"
#include <gtest/gtest.h>

namespace bp::detail {
namespace {

template <class U>
void RunModel(uint64_t seed, U key_range) {
  SCOPED_TRACE("seed " + std::to_string(seed));
  std::mt19937_64 rng(seed);
  FlatSet<U> set;
  std::set<U> model;
  for (int step = 0; step < 20000; ++step) {
    U v = static_cast<U>(rng() % key_range);
    switch (rng() % 4) {
      case 0:
      case 1:
        ASSERT_EQ(set.Insert(v), model.insert(v).second);
        break;
      case 2:
        ASSERT_EQ(set.Erase(v), model.erase(v) == 1);
        break;
      default:
        ASSERT_EQ(set.Contains(v), model.count(v) == 1);
    }
    ASSERT_EQ(set.size(), model.size());
    if (step % 1000 == 0) {
      std::set<U> seen;
      set.ForEach([&](U x) { EXPECT_TRUE(seen.insert(x).second); });
      ASSERT_EQ(seen, model);
    }
  }
  set.Clear();
  EXPECT_TRUE(set.empty());
  EXPECT_FALSE(set.Contains(0));
}

TEST(FlatSet, MatchesStdSet32) {
  for (uint64_t seed : test::TestSeeds(7, 3)) RunModel<uint32_t>(seed, 300);
}
TEST(FlatSet, MatchesStdSet64WideKeys) {
  // Pair keys: high and low halves both populated, long probe runs with wrap-around.
  for (uint64_t seed : test::TestSeeds(11, 3)) RunModel<uint64_t>(seed, ~uint64_t{0} - 1);
}
TEST(FlatSet, MatchesStdSetDense) {
  for (uint64_t seed : test::TestSeeds(13, 3)) RunModel<uint64_t>(seed, 64);
}
TEST(FlatSet, EmptySetAnswersWithoutAllocating) {
  FlatSet<uint32_t> set;
  EXPECT_FALSE(set.Erase(5));
  EXPECT_FALSE(set.Contains(5));
  int calls = 0;
  set.ForEach([&](uint32_t) { ++calls; });
  EXPECT_EQ(calls, 0);
}

}  // namespace
}  // namespace bp::detail
