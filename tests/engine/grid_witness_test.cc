// The grid's witness counts (detail/grid_witness.h), on the part alone: a pair is overlapping
// while at least one cell witnesses it, only its first and last witness are events, a pair that
// moves between cells within one query is none, the fold gives the same counts and events in any
// order of the threads' buffers and on a pool, and a rebuild's recount rebuilds the counts
// without an event.
#include <algorithm>
#include <cstdint>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <tuple>
#include <utility>
#include <vector>

#include "grid_test_support.h"

namespace bp::detail {

// GridWitness over a tracker of 2^shard_bits shards, with buffers for `threads` folding threads
// and, for more than one, a pool (as GridCore sets them up).
template <class Cell>
class WitnessProbe : public GridWitness<Cell> {
  using Base = GridWitness<Cell>;

 public:
  WitnessProbe(unsigned shard_bits, unsigned threads) : Base(OptionsFor(threads)) {
    if (threads > 1) pool_ = std::make_unique<WorkerPool>(threads);
    tracker_.SetShards(shard_bits);
    extra_.resize(tracker_.shards());
    witnessed_.resize(size_t{threads} * tracker_.shards());
  }

  using Base::BeginRecount;
  using Base::EndRecount;
  using Base::Witness;

  // A cell's change of pair (a, b), left in thread `thread`'s buffer for the next Fold.
  void Buffer(unsigned thread, uint32_t a, uint32_t b, bool now) {
    const size_t shard = tracker_.ShardOf(HandlePair(a, b));
    witnessed_[size_t{thread} * tracker_.shards() + shard].push_back({a, b, now});
  }
  // Folds the buffered changes (in parallel when the probe has a pool), then empties the buffers.
  void Fold() {
    this->FoldWitnessed();
    for (auto& w : witnessed_) w.clear();
  }
  // Witnesses of (a, b): 0 when not overlapping, else 1 + the count beyond the first.
  uint32_t Count(uint32_t a, uint32_t b) const {
    if (!tracker_.Contains(a, b)) return 0;
    const uint64_t p = HandlePair(a, b);
    const uint32_t* e = extra_[tracker_.ShardOf(p)].Find(p);
    return 1 + (e != nullptr ? *e : 0);
  }
  // Every pair's count beyond one, whatever its shard.
  std::map<uint64_t, uint32_t> Extras() const {
    std::map<uint64_t, uint32_t> out;
    for (const auto& extra : extra_) extra.ForEach([&](uint64_t p, uint32_t n) { out[p] = n; });
    return out;
  }
  // The events since the last call: (pair, overlapping now), sorted.
  std::vector<std::pair<uint64_t, bool>> Events() {
    std::vector<std::pair<uint64_t, bool>> out;
    tracker_.DrainChanges(
        [&](uint32_t a, uint32_t b, bool now) { out.emplace_back(HandlePair(a, b), now); });
    std::sort(out.begin(), out.end());
    return out;
  }
  const PairTracker& tracker() const { return tracker_; }

 private:
  using Base::extra_;
  using Base::pool_;
  using Base::tracker_;
  using Base::witnessed_;

  static typename Base::Options OptionsFor(unsigned threads) {
    typename Base::Options o;
    o.threads = threads;
    o.parallel_routing_from = 2;  // any fold of two changes or more runs on the pool
    return o;
  }
};

}  // namespace bp::detail

namespace bp::test {
namespace {

using Cell = detail::SegmentedSapCore<3, float>;
using Probe = detail::WitnessProbe<Cell>;

// Witness buffers a change (the large set's, during the routing); Fold folds it with the cells'.
TEST(GridWitness, OnlyTheFirstAndLastWitnessAreEvents) {
  Probe w(0, 1);
  for (int i = 0; i < 3; ++i) w.Witness(1, 2, true);  // three cells hold the pair
  EXPECT_EQ(w.Count(1, 2), 0u);                       // not folded yet
  w.Fold();
  EXPECT_EQ(w.Count(1, 2), 3u);
  EXPECT_EQ(w.Events(), (std::vector<std::pair<uint64_t, bool>>{{detail::HandlePair(1, 2), true}}));
  w.Witness(2, 1, false);  // either order of the handles
  w.Witness(1, 2, false);
  w.Fold();
  EXPECT_EQ(w.Count(1, 2), 1u);
  EXPECT_TRUE(w.Events().empty());
  w.Witness(1, 2, false);
  w.Fold();
  EXPECT_EQ(w.Count(1, 2), 0u);
  EXPECT_TRUE(w.Extras().empty());
  EXPECT_EQ(w.Events(),
            (std::vector<std::pair<uint64_t, bool>>{{detail::HandlePair(1, 2), false}}));
}

TEST(GridWitness, APairMovingBetweenCellsInOneQueryIsNoEvent) {
  Probe w(0, 1);
  w.Witness(3, 4, true);
  w.Fold();
  w.Events();
  // It leaves one cell before it enters the next (its count passes through zero), then the
  // other way round: the tracker cancels the first, the count covers the second.
  w.Witness(3, 4, false);
  w.Witness(3, 4, true);
  w.Fold();
  EXPECT_TRUE(w.Events().empty());
  w.Witness(3, 4, true);
  w.Witness(3, 4, false);
  w.Fold();
  EXPECT_TRUE(w.Events().empty());
  EXPECT_EQ(w.Count(3, 4), 1u);
  EXPECT_TRUE(w.Extras().empty());
}

// Cells that each hold a set of pairs; every frame some cells gain pairs and lose some they
// held, and their changes land in random threads' buffers, each thread's in a random order. The
// same changes fold on one thread (one shard), on one thread over four shards, and on a pool of
// two over four shards: every frame, each ends with every pair counted as the cells hold it, and
// reports as events exactly the pairs whose count left or reached zero.
TEST(GridWitness, TheFoldAgreesInAnyOrderAndOnAPool) {
  constexpr int kCells = 12, kHandles = 24, kFrames = 40;
  std::mt19937_64 rng(5);
  std::vector<std::set<uint64_t>> cells(kCells);
  std::vector<std::unique_ptr<Probe>> probes;
  probes.push_back(std::make_unique<Probe>(0, 1));
  probes.push_back(std::make_unique<Probe>(2, 1));
  probes.push_back(std::make_unique<Probe>(2, 2));
  std::map<uint64_t, uint32_t> before;  // per pair, the cells that held it at the last fold
  size_t events = 0;
  for (int f = 0; f < kFrames; ++f) {
    std::vector<std::tuple<uint32_t, uint32_t, bool>> changes;
    for (auto& held : cells) {
      // A cell reports a pair's change at most once a query (its net change since the last).
      std::set<uint64_t> changed;
      const int n = static_cast<int>(rng() % 6);
      for (int k = 0; k < n; ++k) {
        const auto a = static_cast<uint32_t>(rng() % kHandles);
        const auto b = static_cast<uint32_t>(rng() % kHandles);
        const uint64_t p = detail::HandlePair(a, b);
        if (a == b || !changed.insert(p).second) continue;
        const bool now = !held.count(p);
        if (now) {
          held.insert(p);
        } else {
          held.erase(p);
        }
        changes.emplace_back(a, b, now);
      }
    }
    std::shuffle(changes.begin(), changes.end(), rng);
    std::map<uint64_t, uint32_t> want;
    for (const auto& held : cells) {
      for (uint64_t p : held) ++want[p];
    }
    std::vector<std::pair<uint64_t, bool>> want_events;
    for (const auto& [p, n] : want) {
      if (!before.count(p)) want_events.emplace_back(p, true);
    }
    for (const auto& [p, n] : before) {
      if (!want.count(p)) want_events.emplace_back(p, false);
    }
    std::sort(want_events.begin(), want_events.end());
    std::map<uint64_t, uint32_t> want_extras;
    for (const auto& [p, n] : want) {
      if (n > 1) want_extras[p] = n - 1;
    }
    for (size_t i = 0; i < probes.size(); ++i) {
      SCOPED_TRACE("probe " + std::to_string(i) + " frame " + std::to_string(f));
      Probe& w = *probes[i];
      const unsigned threads = i == 2 ? 2 : 1;
      for (const auto& [a, b, now] : changes) {
        w.Buffer(static_cast<unsigned>(rng() % threads), a, b, now);
      }
      w.Fold();
      EXPECT_EQ(w.Events(), want_events);
      EXPECT_EQ(w.tracker().overlaps(), want.size());
      EXPECT_EQ(w.Extras(), want_extras);
    }
    events += want_events.size();
    before = std::move(want);
  }
  EXPECT_GT(events, 100u);  // the cells' sets change
  EXPECT_FALSE(before.empty());

  // A rebuild (GridSizing::Regrid) counts the cells' pairs again, without an event.
  for (auto& probe : probes) {
    const std::map<uint64_t, uint32_t> extras = probe->Extras();
    probe->BeginRecount();
    EXPECT_TRUE(probe->Extras().empty());
    for (const auto& held : cells) {
      for (uint64_t p : held) probe->Witness(detail::PairFirst(p), detail::PairSecond(p), true);
    }
    probe->Fold();
    probe->EndRecount();
    EXPECT_EQ(probe->Extras(), extras);
    EXPECT_EQ(probe->tracker().overlaps(), before.size());
    EXPECT_TRUE(probe->Events().empty());
  }
}

}  // namespace
}  // namespace bp::test
