// The front end's event drain (detail/front_end_events.h), through every engine family: each
// query delivers every uncollide before every collide, each pair with its smaller key first and
// each list in strictly increasing key order, whatever order the handles were given in; a key
// erased and inserted again in the same frame with its pairs kept reports nothing.
#include <cstdint>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "front_end_test_support.h"
#include "test_support.h"
#include <gtest/gtest.h>

#include "bp/engines.h"

namespace bp::test {
namespace {

using Pair = std::pair<uint64_t, uint64_t>;

// Records the calls in the order they came.
struct OrderSink : EventSink<uint64_t> {
  struct Call {
    bool collide;
    Pair pair;
  };
  std::vector<Call> calls;
  void Collide(const uint64_t& a, const uint64_t& b) override { calls.push_back({true, {a, b}}); }
  void Uncollide(const uint64_t& a, const uint64_t& b) override {
    calls.push_back({false, {a, b}});
  }
};

template <class Config>
class EventsTest : public ::testing::Test {};

TYPED_TEST_SUITE(EventsTest, FrontEndEngines);

TYPED_TEST(EventsTest, UncollidesFirstThenCollidesEachInKeyOrder) {
  constexpr int K = TypeParam::K;
  using T = typename TypeParam::T;
  auto engine = TypeParam::Create();
  std::mt19937_64 rng(11);
  // Keys far apart and in no relation to the handles the front end gives them.
  std::vector<uint64_t> keys;
  for (int i = 0; i < 48; ++i) keys.push_back(rng() >> 1);
  const auto box = [&] {
    const T lo = static_cast<T>(rng() % 20);
    return Cube<K, T>(lo, static_cast<T>(lo + 1 + static_cast<T>(rng() % 4)));
  };
  for (uint64_t k : keys) ASSERT_TRUE(engine->Insert(k, box()).ok());
  size_t collides = 0, uncollides = 0;
  for (int frame = 0; frame < 12; ++frame) {
    OrderSink sink;
    engine->Query(sink);
    bool seen_collide = false;
    std::set<Pair> seen;
    for (size_t i = 0; i < sink.calls.size(); ++i) {
      const auto& [collide, pair] = sink.calls[i];
      EXPECT_FALSE(seen_collide && !collide) << "an uncollide after a collide, frame " << frame;
      seen_collide = seen_collide || collide;
      EXPECT_LT(pair.first, pair.second) << "frame " << frame;
      if (i > 0 && sink.calls[i - 1].collide == collide) {
        EXPECT_LT(sink.calls[i - 1].pair, pair) << "out of key order, frame " << frame;
      }
      EXPECT_TRUE(seen.insert(pair).second) << "a pair twice, frame " << frame;
      ++(collide ? collides : uncollides);
    }
    for (uint64_t k : keys) {
      if (rng() % 2 == 0) {
        ASSERT_TRUE(engine->Update(k, box()).ok());
      }
    }
  }
  EXPECT_GT(collides, 50u);
  EXPECT_GT(uncollides, 50u);

  // A key erased and inserted again at the same place (same options: an update of its handle),
  // and one reinserted elsewhere and back: nothing changed, nothing to report.
  OrderSink drained;
  engine->Query(drained);
  ASSERT_TRUE(engine->Erase(keys[0]).ok());
  ASSERT_TRUE(engine->Insert(keys[0], Cube<K, T>(5, 8)).ok());
  engine->Query(drained);
  ASSERT_TRUE(engine->Erase(keys[0]).ok());
  ASSERT_TRUE(engine->Insert(keys[0], Cube<K, T>(50, 51)).ok());
  ASSERT_TRUE(engine->Update(keys[0], Cube<K, T>(5, 8)).ok());
  OrderSink sink;
  engine->Query(sink);
  EXPECT_TRUE(sink.calls.empty());
}

}  // namespace
}  // namespace bp::test
