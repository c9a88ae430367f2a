// The validators must notice broken invariants: corrupt a SegmentedSap core through its test
// peer (checkpoints, sort order, candidate set, chunk links), or a BatchSap core (sort order,
// positions, stale coordinates, candidate set, a record left pending), or a DynamicOctree core
// (stale entries, child bounds, subtree counts, free list, adjacency, candidate set), and expect
// an Internal status that names the problem; undo the corruption and expect ok again.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "bp/batch_sap.h"
#include "bp/dynamic_octree.h"
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

struct DynamicOctreeTestPeer {
  using Core = DynamicOctreeCore<2, float>;
  static Box<2, float>& EntryBox(Core& core, uint32_t h) {
    return core.nodes_[core.node_of_[h]].objects[core.slot_[h]].box;
  }
  static Box<2, float>& BoxOf(Core& core, uint32_t h) { return core.boxes_[h]; }
  static uint32_t NodeOf(Core& core, uint32_t h) { return core.node_of_[h]; }
  static double& Lo(Core& core, uint32_t node, size_t axis) { return core.nodes_[node].lo[axis]; }
  static uint32_t& Count(Core& core, uint32_t node) { return core.nodes_[node].count; }
  static std::vector<uint32_t>& FreeNodes(Core& core) { return core.free_nodes_; }
  static std::vector<uint32_t>& Adj(Core& core, uint32_t h) { return core.adj_[h]; }
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

// The lattice with 4 objects per node: a root split two levels deep.
DynamicOctreeCore<2, float> MakeOctreeCore() {
  DynamicOctreeOptions options;
  options.max_objects_per_node = 4;
  DynamicOctreeCore<2, float> core(options);
  core.Apply({}, {}, LatticeInserts());
  return core;
}

TEST(DynamicOctreeValidate, NoticesStaleEntriesAndObjectsOutsideTheirNode) {
  auto core = MakeOctreeCore();
  ASSERT_TRUE(core.Validate().ok()) << core.Validate().ToString();
  ASSERT_GT(core.depth(), 1);
  using Peer = DynamicOctreeTestPeer;
  Box<2, float> saved = Peer::EntryBox(core, 0);
  Peer::EntryBox(core, 0).hi[0] += 0.25f;
  ExpectBroken(core, "stale box");
  Peer::EntryBox(core, 0) = saved;
  EXPECT_TRUE(core.Validate().ok());
  // The same move in the entry and the box: outside the node (the root starts at 0).
  Peer::EntryBox(core, 0).lo[0] = Peer::BoxOf(core, 0).lo[0] = -1;
  ExpectBroken(core, "outside its node");
  Peer::EntryBox(core, 0) = Peer::BoxOf(core, 0) = saved;
  EXPECT_TRUE(core.Validate().ok());
}

TEST(DynamicOctreeValidate, NoticesBadChildBoundsCountsAndFreeList) {
  auto core = MakeOctreeCore();
  using Peer = DynamicOctreeTestPeer;
  uint32_t leaf = Peer::NodeOf(core, 0);
  double& lo = Peer::Lo(core, leaf, 1);
  double saved = lo;
  lo = saved - 0.5;
  ExpectBroken(core, "octant");
  lo = saved;
  EXPECT_TRUE(core.Validate().ok());
  Peer::Count(core, leaf) += 1;
  ExpectBroken(core, "count");
  Peer::Count(core, leaf) -= 1;
  EXPECT_TRUE(core.Validate().ok());
  Peer::FreeNodes(core).push_back(leaf);  // a node in use on the free list
  ExpectBroken(core, "free list");
  Peer::FreeNodes(core).pop_back();
  EXPECT_TRUE(core.Validate().ok());
}

TEST(DynamicOctreeValidate, NoticesAdjacencyAndPairErrors) {
  auto core = MakeOctreeCore();
  using Peer = DynamicOctreeTestPeer;
  PairTracker& tracker = Peer::Tracker(core);
  ASSERT_TRUE(tracker.Contains(0, 1));
  tracker.Remove(0, 1);
  ExpectBroken(core, "adjacency pair not in the tracker");
  tracker.Add(0, 1);
  EXPECT_TRUE(core.Validate().ok());
  Peer::Adj(core, 0).push_back(1);
  ExpectBroken(core, "duplicate");
  Peer::Adj(core, 0).pop_back();
  // A pair missing from both the adjacency and the tracker: the recomputation notices.
  std::vector<uint32_t> adj0 = Peer::Adj(core, 0), adj1 = Peer::Adj(core, 1);
  std::erase(Peer::Adj(core, 0), 1u);
  std::erase(Peer::Adj(core, 1), 0u);
  tracker.Remove(0, 1);
  ExpectBroken(core, "missing");
  Peer::Adj(core, 0) = adj0;
  Peer::Adj(core, 1) = adj1;
  tracker.Add(0, 1);
  // A spurious pair in both.
  ASSERT_FALSE(tracker.Contains(0, 39));
  tracker.Add(0, 39);
  Peer::Adj(core, 0).push_back(39);
  Peer::Adj(core, 39).push_back(0);
  ExpectBroken(core, "spurious");
  tracker.Remove(0, 39);
  Peer::Adj(core, 0).pop_back();
  Peer::Adj(core, 39).pop_back();
  tracker.DrainChanges([](uint32_t, uint32_t, bool) {});
  EXPECT_TRUE(core.Validate().ok());
}

}  // namespace
}  // namespace bp::detail
