// The front end's batch calls (detail/front_end_lookahead.h): a batch sees the key index as its
// refusal callback left it (the look-ahead's hint dropped), and UpdateMany staged on the pool
// ends as the serial loop, whatever order the runs are claimed in.
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

#include "front_end_test_support.h"
#include "test_support.h"
#include <gtest/gtest.h>

#include "bp/engines.h"

namespace bp::test {
namespace {

using Pair = std::pair<uint64_t, uint64_t>;

// ---- batch calls --------------------------------------------------------------------------

template <class Config>
class BatchCallTest : public ::testing::Test {};

TYPED_TEST_SUITE(BatchCallTest, FrontEndEngines);

// A refusal callback may call the engine, and a batch then sees the key index as the callback
// left it. Here the callback rekeys key 100 (its erase or update staged earlier in the batch,
// then reinserted with other options: a fresh handle) after the batch looked ahead at its last
// item, 100 again: that item must reach the new handle, not the one its look-ahead found
// (FrontEnd::Lookup's hint, dropped once the index changed).
TYPED_TEST(BatchCallTest, BatchSeesTheIndexItsRefusalCallbackChanged) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  const std::vector<uint64_t> keys = {100, 1, 2, 3, 999, 5, 6, 7, 0, 100};
  const std::map<size_t, StatusCode> only_999 = {{4, StatusCode::kNotFound}};
  auto fill = [](Broadphase<K, T>& engine) {
    for (uint64_t k = 0; k < 8; ++k) {
      const auto lo = static_cast<T>(10 * k);
      ASSERT_TRUE(engine.Insert(k, Cube<K, T>(lo, static_cast<T>(lo + 1))).ok());
    }
    ASSERT_TRUE(engine.Insert(100, Cube<K, T>(0, 4)).ok());
  };
  auto objects = [](const Broadphase<K, T>& engine) {
    std::set<uint64_t> out;
    engine.ForEachObject([&](const uint64_t& key) { out.insert(key); });
    return out;
  };
  RecordingSink<uint64_t> sink;
  {
    auto engine = TypeParam::Create();
    fill(*engine);
    engine->Query(sink);
    std::map<size_t, StatusCode> refused;
    const size_t count = engine->EraseMany(keys, [&](size_t i, const Status& s) {
      refused.emplace(i, s.code());
      if (i == 4) {
        EXPECT_TRUE(engine->Insert(100, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
      }
    });
    EXPECT_EQ(count, 1u);
    EXPECT_EQ(refused, only_999);
    engine->Query(sink);
    EXPECT_EQ(objects(*engine), (std::set<uint64_t>{4}));
  }
  {
    auto engine = TypeParam::Create();
    fill(*engine);
    engine->Query(sink);
    std::vector<typename Broadphase<K, T>::Item> items;
    for (uint64_t key : keys) {
      const auto lo = static_cast<T>(key < 8 ? 10 * key : 0);  // the others stay where they are
      items.push_back({key, Cube<K, T>(lo, static_cast<T>(lo + 1))});
    }
    items.back().box = Cube<K, T>(0, 12);  // 100's last box: it meets 0 (0..1) and 1 (10..11)
    std::map<size_t, StatusCode> refused;
    const size_t count = engine->UpdateMany(items, [&](size_t i, const Status& s) {
      refused.emplace(i, s.code());
      if (i == 4) {
        EXPECT_TRUE(engine->Erase(100).ok());
        EXPECT_TRUE(engine->Insert(100, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
      }
    });
    EXPECT_EQ(count, 1u);
    EXPECT_EQ(refused, only_999);
    sink.Clear();
    engine->Query(sink);
    EXPECT_EQ(objects(*engine).count(100), 1u);
    std::set<Pair> pairs;
    engine->ForEachOverlap([&](const uint64_t& a, const uint64_t& b) { pairs.insert({a, b}); });
    EXPECT_TRUE(pairs.count({1, 100}) == 1) << "100 kept a box other than its last";
  }
}

// UpdateMany on a pool stages the items on every thread, claiming each key's slot, and defers
// the rest (bad boxes, unknown keys, keys with an earlier call this epoch or named again) to an
// ordered pass; a refusal callback that calls the engine rewinds the batch to its item. Each
// batch must end exactly as the serial loop (a one-thread grid) ends it, with the same
// refusals and events: on a two-thread grid, and with the runs claimed from the last to the
// first (so that items named again in an earlier run wait behind a later item's claim, which
// two threads do only by chance). Batches of 5 000 items (three runs) name keys again near and
// far, hold bad items and keys with pending inserts, updates and erases, and their callbacks
// erase, reinsert (with other options: a rekey), update and query.
TEST(FrontEnd, UpdateManyOnThePoolEndsAsTheSerialLoop) {
  using Engine = GridDense<3, float>;
  using BoxType = Box<3, float>;
  using Item = Engine::Item;
  constexpr size_t kSerial = 0, kPooled = 1, kReversed = 2, kEngines = 3;
  for (uint64_t seed : TestSeeds(0x5EA1, 2)) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937_64 rng(seed);
    GridDenseOptions options;
    options.cell_size = 8;
    options.parallel_routing_from = 2;
    Engine serial(options), reversed(options);
    options.threads = 2;
    Engine pooled(options);
    Engine* engines[kEngines] = {&serial, &pooled, &reversed};
    auto below = [&](uint64_t n) { return std::uniform_int_distribution<uint64_t>(0, n - 1)(rng); };
    auto random_box = [&] {
      BoxType b;
      for (size_t a = 0; a < 3; ++a) {
        b.lo[a] = static_cast<float>(below(48));  // about 8 partners per box
        b.hi[a] = b.lo[a] + static_cast<float>(below(6));
      }
      return b;
    };
    std::vector<std::pair<std::string, std::vector<Pair>>> events[kEngines];
    auto query = [&](size_t e, const std::string& when) {
      RecordingSink<uint64_t> sink;
      engines[e]->Query(sink);
      events[e].push_back({when + " uncollides", sink.uncollides});
      events[e].push_back({when + " collides", sink.collides});
    };
    constexpr uint64_t kKeys = 4000;
    for (size_t e = 0; e < kEngines; ++e) {
      rng.seed(seed);
      for (uint64_t k = 0; k < kKeys; ++k) ASSERT_TRUE(engines[e]->Insert(k, random_box()).ok());
      query(e, "first");
    }
    for (int round = 0; round < 4; ++round) {
      // The calls before the batch, the batch and the callback's calls: the same for every
      // engine (the same seed).
      std::vector<Item> items;
      std::vector<std::pair<size_t, StatusCode>> refused[kEngines];
      size_t counts[kEngines] = {};
      for (size_t e = 0; e < kEngines; ++e) {
        Engine& engine = *engines[e];
        rng.seed(seed * 131 + static_cast<uint64_t>(round));
        for (int k = 0; k < 50; ++k) {
          const uint64_t key = below(kKeys);
          switch (below(3)) {
            case 0:
              (void)engine.Erase(key);
              break;
            case 1:
              (void)engine.Insert(key, random_box());
              break;
            default:
              (void)engine.Update(key, random_box());
          }
        }
        items.clear();
        for (size_t i = 0; i < 5000; ++i) {
          const uint64_t pick = below(100);
          if (pick == 0) {
            items.push_back({kKeys + 1000 + i, random_box()});  // unknown
          } else if (pick == 1) {
            BoxType bad = random_box();
            bad.lo[1] = bad.hi[1] + 1;
            items.push_back({below(kKeys), bad});
          } else if (pick < 6 && !items.empty()) {
            items.push_back({items[below(items.size())].key, random_box()});  // named again
          } else {
            items.push_back({below(kKeys), random_box()});
          }
        }
        size_t ordinal = 0;
        const Engine::RefusedFn callback = [&](size_t i, const Status& s) {
          refused[e].push_back({i, s.code()});
          const size_t later = std::min(items.size() - 1, i + 1 + (i * 7919) % 3000);
          switch (ordinal++ % 6) {
            case 0:
              (void)engine.Erase(items[later].key);
              break;
            case 1:
              (void)engine.Erase(items[later].key);
              (void)engine.Insert(items[later].key, items[i].box, ObjectOptions{.category = 2});
              break;
            case 2:
              (void)engine.Update(items[later].key, items[0].box);
              break;
            case 3:
              if (round % 2 == 0) query(e, "callback of item " + std::to_string(i));
              break;
            default:
              break;
          }
        };
        // The last round without a callback (no rewind: every deferred item in one pass).
        const Engine::RefusedFn& pass = round == 3 ? Engine::RefusedFn() : callback;
        counts[e] = e == kReversed
                        ? detail::FrontEndTestPeer::UpdateManyRunsReversed(engine, items, pass)
                        : engine.UpdateMany(items, pass);
        query(e, "round " + std::to_string(round));
        ASSERT_TRUE(engine.Validate().ok()) << engine.Validate().ToString();
      }
      for (size_t e = 1; e < kEngines; ++e) {
        SCOPED_TRACE(e == kPooled ? "two threads" : "runs reversed");
        EXPECT_EQ(counts[e], counts[kSerial]);
        EXPECT_EQ(refused[e], refused[kSerial]);
        ASSERT_EQ(events[e], events[kSerial]);
      }
      EXPECT_GT(counts[kSerial], 0u);
    }
    std::set<Pair> pairs[kEngines];
    for (size_t e = 0; e < kEngines; ++e) {
      engines[e]->ForEachOverlap([&](const uint64_t& a, const uint64_t& b) {
        pairs[e].insert({a, b});
      });
    }
    EXPECT_EQ(pairs[kPooled], pairs[kSerial]);
    EXPECT_EQ(pairs[kReversed], pairs[kSerial]);
    EXPECT_GT(pooled.GetStats().threads, 1u);
  }
}

}  // namespace
}  // namespace bp::test
