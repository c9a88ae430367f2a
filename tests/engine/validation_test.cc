// The validators must notice broken invariants: corrupt a SegmentedSap core through its test
// peer (checkpoints, sort order, candidate set, chunk links), or a BatchSap core (sort order,
// positions, stale coordinates, candidate set, a record left pending), and expect an Internal
// status that names the problem; undo the corruption and expect ok again.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "bp/batch_sap.h"
#include "bp/segmented_sap.h"

namespace bp::detail {

struct SegmentedSapTestPeer {
  template <class Core>
  static FlatSet<uint32_t>& HeadCheckpoints(Core& core) {
    return core.checkpoints_[core.axes_[0].head];
  }
  // Moves the first extremum of an axis, in the list and in its box, by delta.
  template <class Core>
  static void ShiftFirst(Core& core, size_t axis, float delta) {
    auto& ax = core.axes_[axis];
    auto& e = ax.items[core.Base(ax.head)];
    e.value += delta;
    auto& box = core.boxes_[Core::HandleOf(e.ref)];
    (Core::IsMax(e.ref) ? box.hi : box.lo)[axis] += delta;
  }
  template <class Core>
  static PairTracker& Tracker(Core& core) {
    return core.tracker_;
  }
  template <class Core>
  static uint32_t& SecondChunkPrev(Core& core, size_t axis) {
    auto& ax = core.axes_[axis];
    return ax.chunks[ax.chunks[ax.head].next].prev;
  }
};

struct BatchSapTestPeer {
  using Core = BatchSapCore<2, float>;
  static std::pair<float, uint32_t> First(Core& core, size_t axis) {
    auto& ax = core.axes_[axis];
    return {ax.buf[ax.begin].value, ax.buf[ax.begin].ref};
  }
  static void SetFirstValue(Core& core, size_t axis, float v) {
    auto& ax = core.axes_[axis];
    ax.buf[ax.begin].value = v;
  }
  static uint32_t& PosOfFirst(Core& core, size_t axis) {
    auto& ax = core.axes_[axis];
    return ax.pos[ax.buf[ax.begin].ref];
  }
  static uint8_t& State(Core& core, uint32_t h) { return core.state_[h]; }
  static PairTracker& Tracker(Core& core) { return core.tracker_; }
};

namespace {

using Core = SegmentedSapCore<2, float>;

// 40 boxes on a 10 x 4 lattice, each overlapping its neighbours along x.
std::vector<HandleBox<2, float>> LatticeInserts() {
  std::vector<HandleBox<2, float>> inserts;
  for (uint32_t h = 0; h < 40; ++h) {
    float x = static_cast<float>(h % 10);
    float y = static_cast<float>(h / 10);
    inserts.push_back({h, Box<2, float>{{x, y}, {x + 2.5f, y + 0.5f}}});
  }
  return inserts;
}

Core MakeCore() {
  SegmentedSapOptions options;
  options.chunk_capacity = 4;
  Core core(options);
  core.Apply({}, {}, LatticeInserts());
  return core;
}

template <class AnyCore>
void ExpectBroken(const AnyCore& core, const std::string& needle) {
  Status s = core.Validate();
  EXPECT_EQ(s.code(), StatusCode::kInternal);
  EXPECT_NE(s.message().find(needle), std::string::npos) << s.message();
}

TEST(SegmentedSapValidate, NoticesCorruptCheckpoints) {
  Core core = MakeCore();
  ASSERT_TRUE(core.Validate().ok()) << core.Validate().ToString();
  auto& cp = SegmentedSapTestPeer::HeadCheckpoints(core);
  ASSERT_TRUE(cp.Insert(39));  // object 39 (x = 9) does not span the first boundary
  ExpectBroken(core, "checkpoint");
  cp.Erase(39);
  EXPECT_TRUE(core.Validate().ok());
}

TEST(SegmentedSapValidate, NoticesUnsortedAxis) {
  Core core = MakeCore();
  SegmentedSapTestPeer::ShiftFirst(core, 1, 100.0f);
  ExpectBroken(core, "not sorted");
  SegmentedSapTestPeer::ShiftFirst(core, 1, -100.0f);
  EXPECT_TRUE(core.Validate().ok());
}

TEST(SegmentedSapValidate, NoticesMissingAndSpuriousPairs) {
  Core core = MakeCore();
  PairTracker& tracker = SegmentedSapTestPeer::Tracker(core);
  ASSERT_TRUE(tracker.Contains(0, 1));
  tracker.Remove(0, 1);
  ExpectBroken(core, "missing");
  tracker.Add(0, 1);
  tracker.Add(0, 39);  // far apart
  ExpectBroken(core, "spurious");
  tracker.Remove(0, 39);
  tracker.DrainChanges([](uint32_t, uint32_t, bool) {});
  EXPECT_TRUE(core.Validate().ok());
}

TEST(SegmentedSapValidate, NoticesBrokenLinks) {
  Core core = MakeCore();
  uint32_t& prev = SegmentedSapTestPeer::SecondChunkPrev(core, 0);
  uint32_t saved = prev;
  prev = saved + 1;
  ExpectBroken(core, "prev link");
  prev = saved;
  EXPECT_TRUE(core.Validate().ok());
}

BatchSapCore<2, float> MakeBatchCore() {
  BatchSapCore<2, float> core;
  core.Apply({}, {}, LatticeInserts());
  return core;
}

TEST(BatchSapValidate, NoticesStaleCoordinatesAndUnsortedLists) {
  auto core = MakeBatchCore();
  ASSERT_TRUE(core.Validate().ok());
  using Peer = BatchSapTestPeer;
  float v = Peer::First(core, 1).first;
  Peer::SetFirstValue(core, 1, v - 1);  // still sorted, but not the box's coordinate
  ExpectBroken(core, "stale coordinate");
  Peer::SetFirstValue(core, 1, v + 100);
  ExpectBroken(core, "unsorted");
  Peer::SetFirstValue(core, 1, v);
  EXPECT_TRUE(core.Validate().ok());
}

TEST(BatchSapValidate, NoticesBadPositions) {
  auto core = MakeBatchCore();
  using Peer = BatchSapTestPeer;
  Peer::PosOfFirst(core, 0) += 1;
  ExpectBroken(core, "pos points astray");
  Peer::PosOfFirst(core, 0) -= 1;
  EXPECT_TRUE(core.Validate().ok());
}

TEST(BatchSapValidate, NoticesMissingSpuriousAndPendingState) {
  auto core = MakeBatchCore();
  using Peer = BatchSapTestPeer;
  PairTracker& tracker = Peer::Tracker(core);
  ASSERT_TRUE(tracker.Contains(0, 1));
  tracker.Remove(0, 1);
  ExpectBroken(core, "missing");
  tracker.Add(0, 1);
  ASSERT_FALSE(tracker.Contains(0, 39));
  tracker.Add(0, 39);
  ExpectBroken(core, "spurious");
  tracker.Remove(0, 39);
  EXPECT_TRUE(core.Validate().ok());
  uint8_t live = Peer::State(core, 5);
  Peer::State(core, 5) = live + 1;  // a record left pending
  ExpectBroken(core, "pending");
  Peer::State(core, 5) = live;
  EXPECT_TRUE(core.Validate().ok());
}

}  // namespace
}  // namespace bp::detail
