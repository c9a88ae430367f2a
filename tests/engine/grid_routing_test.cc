// The grid's serial routing (detail/grid_routing.h), on a grid's core stopped between routing
// and applying the cells: each change reaches exactly the cells it concerns (an update in the
// cells it keeps, an insert into those it enters, an erase from those it leaves; none for a
// large object), each touched cell is listed once with its work counted, grouping gives each
// touched cell one run in routing order, and the validator notices work left behind.
#include <algorithm>
#include <cstdint>
#include <map>
#include <random>
#include <span>
#include <string>
#include <tuple>
#include <vector>

#include "grid_test_support.h"

namespace bp::test {
namespace {

using Core = detail::GridCore<detail::SegmentedSapCore<3, float>>;
using HB = detail::HandleBox<3, float>;
using Peer = detail::GridTestPeer;
using Op = Peer::Op;

Core::Options RoutingOptions() {
  Core::Options options;
  options.cell_size = 10;
  options.max_cells_per_object = 16;
  return options;  // one thread: serial routing
}

Box<3, float> BoxAt(float x, float y, float z, float extent) {
  return Box<3, float>{{x, y, z}, {x + extent, y + extent, z + extent}};
}

// What routing a batch must produce, from each object's cells before and after it.
struct Expected {
  std::vector<Op> updates, erases, inserts;
};
void AddUpdate(const std::vector<uint32_t>& before, const std::vector<uint32_t>& after, uint32_t h,
               Expected* want) {
  for (uint32_t c : after) {
    const bool kept = std::count(before.begin(), before.end(), c) != 0;
    (kept ? want->updates : want->inserts).emplace_back(c, h);
  }
  for (uint32_t c : before) {
    if (std::count(after.begin(), after.end(), c) == 0) want->erases.emplace_back(c, h);
  }
}

std::vector<Op> Sorted(std::vector<Op> v) {
  std::sort(v.begin(), v.end());
  return v;
}

// Checks what the core routed against want: the same operations, each touched cell listed once
// (and no other), and each cell's work entry counting its operations.
void ExpectRouted(const Core& core, const Expected& want) {
  const Peer::Routed got = Peer::RoutedOps(core);
  EXPECT_EQ(Sorted(got.updates), Sorted(want.updates));
  EXPECT_EQ(Sorted(got.erases), Sorted(want.erases));
  EXPECT_EQ(Sorted(got.inserts), Sorted(want.inserts));
  std::map<uint32_t, std::tuple<uint32_t, uint32_t, uint32_t>> work;
  for (const Op& op : want.updates) ++std::get<0>(work[op.first]);
  for (const Op& op : want.erases) ++std::get<1>(work[op.first]);
  for (const Op& op : want.inserts) ++std::get<2>(work[op.first]);
  std::vector<uint32_t> touched = got.touched;
  std::sort(touched.begin(), touched.end());
  EXPECT_TRUE(std::adjacent_find(touched.begin(), touched.end()) == touched.end())
      << "a cell touched twice";
  ASSERT_EQ(touched.size(), work.size());
  for (const auto& [cell, counts] : work) {
    EXPECT_TRUE(std::binary_search(touched.begin(), touched.end(), cell)) << "cell " << cell;
    EXPECT_EQ(Peer::Work(core, cell), counts) << "cell " << cell;
  }
}

// A scene of small objects over a few cells each, then two batches routed and checked before
// their cells are applied: objects that stay in their cells, migrate, are erased and inserted;
// then one that grows large (out of its cells) while others move.
TEST(GridRouting, EachChangeReachesTheCellsItConcerns) {
  Core core(RoutingOptions());
  std::mt19937_64 rng(3);
  const auto coord = [&] { return std::uniform_real_distribution<float>(0, 60)(rng); };
  const auto extent = [&] { return std::uniform_real_distribution<float>(0.5f, 14)(rng); };
  std::vector<HB> inserts;
  for (uint32_t h = 0; h < 40; ++h)
    inserts.push_back(HB{h, BoxAt(coord(), coord(), coord(), extent())});
  core.Apply({}, {}, inserts);
  ASSERT_TRUE(core.Validate().ok());

  // Batch 1: every object moves (some within their cells, some across), 5 erased, 3 inserted.
  std::vector<uint32_t> erases = {0, 7, 14, 21, 28};
  std::vector<HB> updates;
  std::vector<std::vector<uint32_t>> before(40);
  for (uint32_t h = 0; h < 40; ++h) before[h] = Peer::CellsOf(core, h);
  for (uint32_t h = 0; h < 40; ++h) {
    if (std::count(erases.begin(), erases.end(), h) != 0) continue;
    const Box<3, float> b = h % 2 == 0 ? BoxAt(coord(), coord(), coord(), extent())  // most migrate
                                       : inserts[h].box;  // the same box: its cells
    updates.push_back(HB{h, b});
  }
  std::vector<HB> fresh = {HB{40, BoxAt(5, 5, 5, 1)}, HB{41, BoxAt(15, 25, 35, 12)},
                           HB{42, BoxAt(59, 59, 59, 3)}};
  Peer::Route(core, std::span<const uint32_t>(erases), std::span<const HB>(updates),
              std::span<const HB>(fresh));
  Expected want;
  for (uint32_t h : erases) {
    for (uint32_t c : before[h]) want.erases.emplace_back(c, h);
  }
  for (const HB& u : updates)
    AddUpdate(before[u.handle], Peer::CellsOf(core, u.handle), u.handle, &want);
  for (const HB& i : fresh) AddUpdate({}, Peer::CellsOf(core, i.handle), i.handle, &want);
  EXPECT_GT(want.erases.size(), 5u);
  EXPECT_GT(want.inserts.size(), 10u);
  ExpectRouted(core, want);
  Peer::ApplyRouted(core, fresh.size(), erases.size());
  ASSERT_TRUE(core.Validate().ok()) << core.Validate().ToString();

  // Batch 2: object 1 grows over more than 16 cells (a large object: it leaves its cells and
  // enters none), and the others migrate, with a local handle now allocated at routing (a
  // large object ends the deferral).
  std::vector<std::vector<uint32_t>> cells_before(43);
  for (uint32_t h = 1; h < 43; ++h) {
    if (std::count(erases.begin(), erases.end(), h) == 0) cells_before[h] = Peer::CellsOf(core, h);
  }
  updates.clear();
  updates.push_back(HB{1, BoxAt(0, 0, 0, 45)});
  for (uint32_t h = 2; h < 43; h += 3) {
    if (std::count(erases.begin(), erases.end(), h) == 0) {
      updates.push_back(HB{h, BoxAt(coord(), coord(), coord(), extent())});
    }
  }
  fresh = {HB{0, BoxAt(30, 30, 30, 2)}};  // a freed handle again
  Peer::Route(core, {}, std::span<const HB>(updates), std::span<const HB>(fresh));
  EXPECT_TRUE(Peer::CellsOf(core, 1).empty());
  want = Expected();
  for (const HB& u : updates) {
    AddUpdate(cells_before[u.handle], Peer::CellsOf(core, u.handle), u.handle, &want);
  }
  AddUpdate({}, Peer::CellsOf(core, 0), 0, &want);
  ExpectRouted(core, want);
  Peer::ApplyRouted(core, 1, 0);
  ASSERT_TRUE(core.Validate().ok()) << core.Validate().ToString();
  Stats stats;
  core.FillStats(&stats);
  EXPECT_EQ(stats.grid.value().large_objects, 1u);
}

// Grouping (GroupUpdates): each touched cell, in the order of touched_, gets one contiguous
// run of its updates, in the order they were routed; and the validator, run mid-query, finds
// the work left.
TEST(GridRouting, GroupingGivesEachTouchedCellOneRunInRoutingOrder) {
  Core core(RoutingOptions());
  std::vector<HB> inserts;
  for (uint32_t h = 0; h < 60; ++h) {
    const float x = static_cast<float>(h % 6) * 9.0f, y = static_cast<float>(h / 6) * 5.0f;
    inserts.push_back(HB{h, BoxAt(x, y, 0, 3)});
  }
  core.Apply({}, {}, inserts);
  std::vector<HB> updates;
  for (uint32_t h = 59; h < 60; --h) {  // in reverse, so that cells interleave
    HB u = inserts[h];
    u.box.hi[2] += 0.5f;  // the same cells
    updates.push_back(u);
  }
  Peer::Route(core, {}, std::span<const HB>(updates), {});
  const Status mid = core.Validate();
  EXPECT_FALSE(mid.ok());
  EXPECT_NE(mid.message().find("work left"), std::string::npos) << mid.message();
  const Peer::Routed routed = Peer::RoutedOps(core);
  ASSERT_GT(routed.touched.size(), 4u);
  Peer::Group(core);
  uint32_t offset = 0;
  for (uint32_t cell : routed.touched) {
    std::vector<Op> want;
    for (const Op& op : routed.updates) {
      if (op.first == cell) want.push_back(op);
    }
    uint32_t begin = 0;
    EXPECT_EQ(Peer::GroupedUpdates(core, cell, &begin), want) << "cell " << cell;
    EXPECT_EQ(begin, offset) << "cell " << cell;
    offset += static_cast<uint32_t>(want.size());
  }
  EXPECT_EQ(offset, routed.updates.size());
}

}  // namespace
}  // namespace bp::test
