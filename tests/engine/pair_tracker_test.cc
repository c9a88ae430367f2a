// PairTracker split into shards (SetShards) against one unsharded, under a seeded random
// sequence of adds, removes and drains; adds of pairs of different shards from two threads at
// once, as the grid's parallel fold makes them; and the options table, whose compact form (only
// static flags set) and whole form (categories and masks) answer as bp::Accepts does, across the
// switch from one to the other.
#include "bp/detail/pair_tracker.h"

#include <algorithm>
#include <cstdint>
#include <random>
#include <thread>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "bp/object_options.h"

namespace bp::detail {
namespace {

using Change = std::tuple<uint32_t, uint32_t, bool>;

std::vector<Change> Drained(PairTracker& tracker) {
  std::vector<Change> out;
  tracker.DrainChanges([&](uint32_t a, uint32_t b, bool now) { out.emplace_back(a, b, now); });
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<uint64_t> Overlaps(const PairTracker& tracker) {
  std::vector<uint64_t> out;
  tracker.ForEachOverlap([&](uint32_t a, uint32_t b) { out.push_back(HandlePair(a, b)); });
  std::sort(out.begin(), out.end());
  return out;
}

TEST(PairTracker, ShardsChangeNothingButWhereThePairsLie) {
  for (unsigned bits : {1u, 2u, 6u, 9u}) {
    SCOPED_TRACE("shard bits " + std::to_string(bits));
    PairTracker one, sharded;
    sharded.SetShards(bits);
    EXPECT_EQ(sharded.shards(), size_t{1} << std::min(bits, 6u));  // capped at 64
    std::mt19937_64 rng(bits);
    std::vector<size_t> used(sharded.shards(), 0);
    for (int step = 0; step < 20000; ++step) {
      const auto a = static_cast<uint32_t>(rng() % 300);
      const auto b = static_cast<uint32_t>(rng() % 300);
      if (a == b) continue;
      const uint64_t p = HandlePair(a, b);
      ASSERT_LT(sharded.ShardOf(p), sharded.shards());
      ++used[sharded.ShardOf(p)];
      switch (rng() % 8) {
        case 0:
        case 1:
        case 2:
          ASSERT_EQ(sharded.Add(a, b), one.Add(a, b));
          break;
        case 3:
        case 4:
          ASSERT_EQ(sharded.Remove(a, b), one.Remove(a, b));
          break;
        case 5:  // the calls for a known shard
          ASSERT_EQ(sharded.AddIn(sharded.ShardOf(p), a, b), one.Add(a, b));
          break;
        case 6:
          ASSERT_EQ(sharded.RemoveIn(sharded.ShardOf(p), a, b), one.Remove(a, b));
          break;
        default:
          if (rng() % 50 == 0) {
            ASSERT_EQ(Drained(sharded), Drained(one));
          }
          break;
      }
      ASSERT_EQ(sharded.Contains(a, b), one.Contains(a, b));
      ASSERT_EQ(sharded.overlaps(), one.overlaps());
      ASSERT_EQ(sharded.pending_changes(), one.pending_changes());
    }
    EXPECT_EQ(Drained(sharded), Drained(one));
    EXPECT_EQ(Overlaps(sharded), Overlaps(one));
    // The shard hash spreads the pairs: every shard got at least half its even share.
    size_t total = 0;
    for (size_t n : used) total += n;
    for (size_t n : used) EXPECT_GE(n * sharded.shards() * 2, total);
  }
}

TEST(PairTracker, ThreadsAddAndRemoveInTheirOwnShardsAtOnce) {
  PairTracker tracker, model;
  tracker.SetShards(1);
  std::vector<std::pair<uint32_t, uint32_t>> pairs;
  for (uint32_t a = 0; a < 400; ++a) {
    for (uint32_t b = a + 1; b < a + 30; ++b) pairs.emplace_back(a, b);
  }
  // Each thread adds every pair of its shard, then removes every third one.
  auto work = [&](size_t shard) {
    for (const auto& [a, b] : pairs) {
      if (tracker.ShardOf(HandlePair(a, b)) == shard) tracker.AddIn(shard, a, b);
    }
    for (size_t i = 0; i < pairs.size(); i += 3) {
      const auto& [a, b] = pairs[i];
      if (tracker.ShardOf(HandlePair(a, b)) == shard) tracker.RemoveIn(shard, a, b);
    }
  };
  std::thread other(work, size_t{1});
  work(0);
  other.join();
  for (const auto& [a, b] : pairs) model.Add(a, b);
  for (size_t i = 0; i < pairs.size(); i += 3) model.Remove(pairs[i].first, pairs[i].second);
  EXPECT_EQ(Overlaps(tracker), Overlaps(model));
  EXPECT_EQ(Drained(tracker), Drained(model));
  EXPECT_EQ(tracker.pending_changes(), 0u);
}

TEST(OptionsTable, CompactStaticFlagsThenWholeOptionsAnswerAsAccepts) {
  std::mt19937_64 rng(17);
  OptionsTable table;
  std::vector<ObjectOptions> set(64);  // what each handle was given (defaults if never set)
  const auto check = [&](const char* stage) {
    SCOPED_TRACE(stage);
    for (uint32_t a = 0; a < set.size(); ++a) {
      ASSERT_EQ(table.Get(a), set[a]) << "handle " << a;
      ASSERT_EQ(table.IsStatic(a), set[a].is_static) << "handle " << a;
      for (uint32_t b = 0; b < set.size(); ++b) {
        ASSERT_EQ(table.Accepts(a, b), Accepts(set[a], set[b])) << a << ", " << b;
        if (!table.MayRefuse(a)) {
          ASSERT_TRUE(Accepts(set[a], set[b])) << a << ", " << b;
        }
      }
    }
  };
  check("nothing set");
  EXPECT_FALSE(table.filtering());
  // Static flags only: the compact form; some handles set back to the defaults.
  for (uint32_t h = 0; h < 40; ++h) {
    set[h].is_static = rng() % 3 == 0;
    table.Set(h, set[h]);
  }
  EXPECT_TRUE(table.filtering());
  EXPECT_FALSE(table.masking());
  check("static flags only");
  // Handles set again within the compact form (reinserted with other flags), some to the
  // defaults.
  for (uint32_t h = 0; h < 40; h += 3) {
    set[h].is_static = !set[h].is_static;
    table.Set(h, set[h]);
  }
  EXPECT_FALSE(table.masking());
  check("static flags set again");
  // A category arrives: the whole options from here on, the static flags kept.
  set[50].category = 6;
  set[50].mask = 2;
  table.Set(50, set[50]);
  EXPECT_TRUE(table.masking());
  check("after the first category");
  for (uint32_t h = 0; h < set.size(); ++h) {
    set[h] = ObjectOptions{uint64_t{1} << (rng() % 3), rng() % 8, rng() % 2 == 0};
    table.Set(h, set[h]);
  }
  check("random options");
}

}  // namespace
}  // namespace bp::detail
