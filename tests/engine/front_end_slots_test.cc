// The front end's keys, slots and staged calls (detail/front_end_slots.h), through every
// engine: a changed reinsert (a rekey) reports only real status changes; static pairs and
// filtered pairs never appear; the query counter (epoch), which dates each slot's pending call,
// wraps around without losing or inventing a call (exact and with a margin); and the front
// end's validator notices a corruption of each of its parts.
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

// ---- options ------------------------------------------------------------------------------

template <class Config>
class OptionsTest : public ::testing::Test {};

TYPED_TEST_SUITE(OptionsTest, FrontEndEngines);

TYPED_TEST(OptionsTest, ReinsertWithOtherOptionsReportsOnlyRealChanges) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  auto engine = TypeParam::Create();
  RecordingSink<uint64_t> sink;
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4)).ok());
  ASSERT_TRUE(engine->Insert(2, Cube<K, T>(2, 6)).ok());
  ASSERT_TRUE(engine->Insert(3, Cube<K, T>(3, 9)).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.collides, (std::vector<Pair>{{1, 2}, {1, 3}, {2, 3}}));

  // 1 comes back in category 2: 2 and 3 (masks all ones) still accept it: no event.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_TRUE(sink.uncollides.empty());
  EXPECT_EQ(engine->GetStats().overlaps, 3u);

  // 2 comes back masking category 2 out: only (1, 2) goes.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(2).ok());
  ASSERT_TRUE(engine->Insert(2, Cube<K, T>(2, 6), ObjectOptions{.mask = ~uint64_t{2}}).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.uncollides, (std::vector<Pair>{{1, 2}}));
  EXPECT_TRUE(sink.collides.empty());

  // 2 and 3 become static: (2, 3) goes. Then 3 becomes dynamic and moves: (2, 3) returns.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(2).ok());
  ASSERT_TRUE(engine->Insert(2, Cube<K, T>(2, 6), ObjectOptions{.is_static = true}).ok());
  ASSERT_TRUE(engine->Erase(3).ok());
  ASSERT_TRUE(engine->Insert(3, Cube<K, T>(3, 9), ObjectOptions{.is_static = true}).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.uncollides, (std::vector<Pair>{{2, 3}}));
  EXPECT_EQ(sink.collides, (std::vector<Pair>{{1, 2}}));
  sink.Clear();
  ASSERT_TRUE(engine->Erase(3).ok());
  ASSERT_TRUE(engine->Insert(3, Cube<K, T>(4, 8)).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.uncollides.empty());
  EXPECT_EQ(sink.collides, (std::vector<Pair>{{2, 3}}));

  // Reinsert, erase again and reinsert with the first options within one frame.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4), ObjectOptions{.category = 4}).ok());
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Insert(1, Cube<K, T>(0, 4), ObjectOptions{.category = 2}).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_TRUE(sink.uncollides.empty());
  EXPECT_EQ(engine->Size(), 3u);
  EXPECT_TRUE(engine->Validate().ok()) << engine->Validate().ToString();

  // Erasing reports the remaining pairs once.
  sink.Clear();
  ASSERT_TRUE(engine->Erase(1).ok());
  ASSERT_TRUE(engine->Erase(2).ok());
  ASSERT_TRUE(engine->Erase(3).ok());
  engine->Query(sink);
  EXPECT_EQ(sink.uncollides, (std::vector<Pair>{{1, 2}, {1, 3}, {2, 3}}));
  EXPECT_EQ(engine->GetStats().overlaps, 0u);
}

TYPED_TEST(OptionsTest, StaticWorldPairsOnlyWithMovers) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  auto engine = TypeParam::Create();
  RecordingSink<uint64_t> sink;
  // A row of 200 touching static boxes and 4 dynamic boxes among them.
  for (uint64_t i = 0; i < 200; ++i) {
    T lo = static_cast<T>(i);
    ASSERT_TRUE(
        engine->Insert(i, Cube<K, T>(lo, static_cast<T>(lo + 1)), ObjectOptions{.is_static = true})
            .ok());
  }
  for (uint64_t i = 0; i < 4; ++i) {
    T lo = static_cast<T>(50 * i + 10);
    ASSERT_TRUE(engine->Insert(1000 + i, Cube<K, T>(lo, static_cast<T>(lo + 2))).ok());
  }
  engine->Query(sink);
  // Each dynamic box [lo, lo+2] touches statics lo-1 .. lo+2.
  EXPECT_EQ(sink.collides.size(), 16u);
  for (const Pair& p : sink.collides) EXPECT_GE(p.second, 1000u);
  EXPECT_TRUE(engine->Validate().ok()) << engine->Validate().ToString();
  // Moving a static box changes nothing among statics.
  sink.Clear();
  ASSERT_TRUE(engine->Update(100, Cube<K, T>(99, 103)).ok());
  engine->Query(sink);
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_TRUE(sink.uncollides.empty());
}

// ---- epochs ------------------------------------------------------------------------------

// Two engines of one type take the same calls; one has its epoch moved to just below the wrap.
// Frames mix every sequence of calls on one key between two queries (update twice, erase and
// reinsert, insert and erase, insert and update, erase of an updated key), so pending calls of
// the last epoch before the wrap, and slots last touched many epochs ago, are read after it.
// Their events must be equal, and (exact) those of the model; both validators must pass.
template <int K, class T, class Engine>
void CheckEpochWrap(Engine& wrapped, Engine& plain, bool exact, uint64_t seed) {
  using BoxType = Box<K, T>;
  std::mt19937_64 rng(seed);
  ModelOracle<K, T> model;
  RecordingSink<uint64_t> ws, ps;
  std::vector<Pair> collides, uncollides;
  auto random_box = [&] {
    BoxType b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      const int lo = std::uniform_int_distribution<int>(0, 60)(rng);
      b.lo[a] = static_cast<T>(lo);
      b.hi[a] = static_cast<T>(lo + std::uniform_int_distribution<int>(0, 12)(rng));
    }
    return b;
  };
  auto both = [&](auto&& call) {
    const Status a = call(wrapped), b = call(plain);
    ASSERT_EQ(a.ok(), b.ok()) << a.ToString() << " / " << b.ToString();
  };
  auto insert = [&](uint64_t key) {
    const BoxType b = random_box();
    both([&](Engine& e) { return e.Insert(key, b); });
    model.boxes()[key] = b;
  };
  auto update = [&](uint64_t key) {
    const BoxType b = random_box();
    both([&](Engine& e) { return e.Update(key, b); });
    model.boxes()[key] = b;
  };
  auto erase = [&](uint64_t key) {
    both([&](Engine& e) { return e.Erase(key); });
    model.boxes().erase(key);
  };
  auto query = [&](const char* when) {
    ws.Clear();
    ps.Clear();
    wrapped.Query(ws);
    plain.Query(ps);
    model.Query(&collides, &uncollides);
    EXPECT_EQ(ws.collides, ps.collides) << when;
    EXPECT_EQ(ws.uncollides, ps.uncollides) << when;
    if (exact) {
      EXPECT_EQ(ws.collides, collides) << when;
      EXPECT_EQ(ws.uncollides, uncollides) << when;
    }
    EXPECT_TRUE(wrapped.Validate().ok()) << when << ": " << wrapped.Validate().ToString();
    EXPECT_TRUE(plain.Validate().ok()) << when;
  };
  uint64_t next = 0;
  for (int i = 0; i < 40; ++i) insert(next++);
  query("first frame");
  for (uint64_t k = 0; k < 10; ++k) update(k);  // pending in an epoch long before the wrap
  query("frame before the jump");
  detail::FrontEndTestPeer::set_epoch(wrapped, std::numeric_limits<uint32_t>::max() - 3);
  for (int frame = 0; frame < 8; ++frame) {
    auto live = [&] {
      auto it = model.boxes().begin();
      std::advance(it, std::uniform_int_distribution<size_t>(0, model.boxes().size() - 1)(rng));
      return it->first;
    };
    const uint64_t a = live(), b = live();
    update(a);
    if (b != a) {
      erase(b);
      insert(b);  // an update of the same handle
    }
    const uint64_t c = live();
    update(c);
    update(c);
    const uint64_t d = next++;
    insert(d);
    erase(d);  // nothing reaches the core
    const uint64_t e = next++;
    insert(e);
    update(e);
    const uint64_t f = live();
    if (f != e) {
      update(f);
      erase(f);
    }
    for (int k = 0; k < 4; ++k) update(live());
    query(("frame " + std::to_string(frame) + " around the wrap").c_str());
  }
  EXPECT_LT(detail::FrontEndTestPeer::epoch(wrapped), 8u) << "the epoch did not wrap";
}

TEST(FrontEnd, EpochWrapsAroundWithoutLosingACall) {
  for (uint64_t seed : TestSeeds(0xE90C, 3)) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    GridDense<3, float> wrapped, plain;
    CheckEpochWrap<3, float>(wrapped, plain, true, seed);
    SegmentedSap<2, double> wrapped_fat(SegmentedSapOptions(), 1.5);
    SegmentedSap<2, double> plain_fat(SegmentedSapOptions(), 1.5);
    CheckEpochWrap<2, double>(wrapped_fat, plain_fat, false, seed);
  }
}

// Each part's validator (detail/front_end_validate.h) notices its own corruption, and names it.
TEST(FrontEnd, ValidatorNoticesACorruptionOfEachPart) {
  using Peer = detail::FrontEndTestPeer;
  const std::pair<Peer::Corruption, std::string_view> cases[] = {
      {Peer::Corruption::kTombstones, "tombstone"},
      {Peer::Corruption::kKeyMap, "key"},
      {Peer::Corruption::kFreeList, "free"},
      {Peer::Corruption::kFatBoxes, "fat boxes"},
      {Peer::Corruption::kUndrainedEvent, "changed pairs"}};
  for (const auto& [what, word] : cases) {
    SCOPED_TRACE(std::string(word));
    GridSegmentedSap<3, float> engine(GridSegmentedSapOptions(), 0.25f);
    for (uint64_t k = 0; k < 6; ++k) {
      const float x = static_cast<float>(k) * 3;
      ASSERT_TRUE(engine.Insert(k, Cube<3, float>(x, x + 1)).ok());
    }
    RecordingSink<uint64_t> sink;
    engine.Query(sink);
    ASSERT_TRUE(engine.Erase(2).ok());
    ASSERT_TRUE(engine.Update(3, Cube<3, float>(0.5f, 1.5f)).ok());
    engine.Query(sink);  // a freed handle, a pair
    ASSERT_TRUE(engine.Validate().ok()) << engine.Validate().ToString();
    Peer::Corrupt(engine, what);
    const Status s = engine.Validate();
    EXPECT_FALSE(s.ok());
    EXPECT_NE(s.message().find(word), std::string::npos) << s.message();
  }
}

}  // namespace
}  // namespace bp::test
