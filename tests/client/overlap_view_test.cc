// bp::client::OverlapView without DDS: hand-made parts in the order a subscriber could receive
// them. Snapshots of several parts, events after them, gaps, a new epoch, contradictions, a
// snapshot cut by a gap, and other subscribers' snapshots while synced.
#include "bp/client/overlap_view.h"

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace bp::client {
namespace {

using PairList = std::vector<std::pair<uint64_t, uint64_t>>;

// Builds parts with consecutive sequence numbers, like the daemon.
class Stream {
 public:
  explicit Stream(uint64_t epoch) : epoch_(epoch) {}
  wire::EventBatch Snapshot(uint64_t frame, const PairList& pairs, uint32_t part, bool last) {
    wire::EventBatch b = Part(frame, part, last);
    b.set_snapshot(true);
    for (auto [a, c] : pairs) {
      b.add_snapshot_pairs(a);
      b.add_snapshot_pairs(c);
    }
    return b;
  }
  wire::EventBatch Events(uint64_t frame, const PairList& uncollide, const PairList& collide,
                          uint32_t part = 0, bool last = true) {
    wire::EventBatch b = Part(frame, part, last);
    for (auto [a, c] : uncollide) {
      b.add_uncollide(a);
      b.add_uncollide(c);
    }
    for (auto [a, c] : collide) {
      b.add_collide(a);
      b.add_collide(c);
    }
    return b;
  }
  void Skip() { ++seq_; }  // a part the subscriber never receives

 private:
  wire::EventBatch Part(uint64_t frame, uint32_t part, bool last) {
    wire::EventBatch b;
    b.set_version(wire::SCHEMA_VERSION_1);
    b.set_epoch(epoch_);
    b.set_sequence(++seq_);
    b.set_frame(frame);
    b.set_part(part);
    b.set_last_part(last);
    return b;
  }
  uint64_t epoch_;
  uint64_t seq_ = 0;
};

TEST(OverlapView, SyncsFromASnapshotOfSeveralPartsThenFollowsEvents) {
  Stream s(7);
  OverlapView v;
  EXPECT_TRUE(v.Apply(s.Events(1, {}, {{1, 2}})));  // joined mid-stream: ask
  EXPECT_FALSE(v.synced());
  EXPECT_FALSE(v.Apply(s.Events(2, {}, {{3, 4}})));  // still waiting: asked already
  EXPECT_FALSE(v.Apply(s.Snapshot(2, {{1, 2}}, 0, false)));
  EXPECT_FALSE(v.synced());
  EXPECT_FALSE(v.Apply(s.Snapshot(2, {{3, 4}, {5, 6}}, 1, true)));
  ASSERT_TRUE(v.synced());
  EXPECT_EQ(v.frame(), 2u);
  EXPECT_EQ(v.SortedPairs(), (PairList{{1, 2}, {3, 4}, {5, 6}}));
  EXPECT_FALSE(v.Apply(s.Events(3, {{1, 2}}, {{2, 9}})));
  EXPECT_EQ(v.SortedPairs(), (PairList{{2, 9}, {3, 4}, {5, 6}}));
  EXPECT_EQ(v.frame(), 3u);
  EXPECT_TRUE(v.Contains(9, 2));
  // Another subscriber's snapshot changes nothing.
  EXPECT_FALSE(v.Apply(s.Snapshot(3, {{2, 9}, {3, 4}, {5, 6}}, 0, true)));
  EXPECT_EQ(v.size(), 3u);
  EXPECT_EQ(v.snapshots(), 1u);
  EXPECT_EQ(v.resyncs(), 0u);
}

TEST(OverlapView, NotSyncedBetweenThePartsOfAFrame) {
  Stream s(7);
  OverlapView v;
  v.Apply(s.Snapshot(1, {{1, 2}}, 0, true));
  ASSERT_TRUE(v.synced());
  EXPECT_FALSE(v.Apply(s.Events(2, {{1, 2}}, {}, 0, false)));
  EXPECT_FALSE(v.synced()) << "half of frame 2 applied: the set is neither frame 1's nor 2's";
  EXPECT_FALSE(v.wants_snapshot());
  EXPECT_FALSE(v.Apply(s.Events(2, {}, {{3, 4}}, 1, true)));
  EXPECT_TRUE(v.synced());
  EXPECT_EQ(v.frame(), 2u);
  EXPECT_EQ(v.SortedPairs(), (PairList{{3, 4}}));
}

TEST(OverlapView, AGapDropsTheSetUntilTheNextSnapshot) {
  Stream s(7);
  OverlapView v;
  v.Apply(s.Snapshot(1, {{1, 2}}, 0, true));
  ASSERT_TRUE(v.synced());
  s.Skip();  // frame 2's events lost
  EXPECT_TRUE(v.Apply(s.Events(3, {}, {{3, 4}})));
  EXPECT_FALSE(v.synced());
  EXPECT_EQ(v.size(), 0u);
  EXPECT_EQ(v.gaps(), 1u);
  EXPECT_EQ(v.resyncs(), 1u);
  v.Apply(s.Snapshot(3, {{1, 2}, {3, 4}, {7, 8}}, 0, true));
  ASSERT_TRUE(v.synced());
  EXPECT_EQ(v.SortedPairs(), (PairList{{1, 2}, {3, 4}, {7, 8}}));
}

TEST(OverlapView, ASnapshotCutByAGapIsNotUsed) {
  Stream s(7);
  OverlapView v;
  v.Apply(s.Snapshot(4, {{1, 2}}, 0, false));
  s.Skip();  // part 1 lost
  v.Apply(s.Snapshot(4, {{5, 6}}, 2, true));
  EXPECT_FALSE(v.synced()) << "a snapshot with a missing part must not count";
  EXPECT_EQ(v.gaps(), 1u);
  // A later part 1..last without its part 0 does not count either.
  v.Apply(s.Snapshot(5, {{1, 2}}, 1, true));
  EXPECT_FALSE(v.synced());
  v.Apply(s.Snapshot(5, {{1, 2}}, 0, true));
  EXPECT_TRUE(v.synced());
}

TEST(OverlapView, ANewEpochIsARestart) {
  Stream a(7);
  OverlapView v;
  v.Apply(a.Snapshot(9, {{1, 2}}, 0, true));
  ASSERT_TRUE(v.synced());
  Stream b(8);  // the daemon restarted: frames and sequence from 1 again
  EXPECT_TRUE(v.Apply(b.Events(1, {}, {{1, 2}})));
  EXPECT_FALSE(v.synced());
  EXPECT_EQ(v.restarts(), 1u);
  EXPECT_EQ(v.gaps(), 0u);
  EXPECT_EQ(v.epoch(), 8u);
  v.Apply(b.Snapshot(1, {{1, 2}}, 0, true));
  EXPECT_TRUE(v.synced());
  EXPECT_EQ(v.frame(), 1u);
}

TEST(OverlapView, ContradictionsAreCaughtAndResynced) {
  Stream s(7);
  OverlapView v;
  v.Apply(s.Snapshot(1, {{1, 2}}, 0, true));
  EXPECT_TRUE(v.Apply(s.Events(2, {{3, 4}}, {})));  // uncollide of an absent pair
  EXPECT_FALSE(v.synced());
  EXPECT_EQ(v.contradictions(), 1u);
  v.Apply(s.Snapshot(2, {{1, 2}}, 0, true));
  ASSERT_TRUE(v.synced());
  EXPECT_TRUE(v.Apply(s.Events(3, {}, {{2, 1}})));  // collide of a present pair
  EXPECT_EQ(v.contradictions(), 2u);
  EXPECT_NE(v.last_loss().find("already holds"), std::string::npos) << v.last_loss();
}

}  // namespace
}  // namespace bp::client
