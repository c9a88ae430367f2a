// DynamicOctreeCore::Validate: every invariant of bp/dynamic_octree.h recomputed from scratch
// (lists and entries, containment and straddling, child bounds and links, subtree counts, the
// free list, adjacency against the tracker, the candidate set against an independent sweep).
// O(n log n + nodes + pairs); run after every query when BP_VALIDATE is set.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "bp/detail/sweep.h"
#include "bp/dynamic_octree.h"

namespace bp::detail {

template <int K, Coordinate T>
Status DynamicOctreeCore<K, T>::Validate() const {
  auto fail = [](const std::string& what) {
    return Status(StatusCode::kInternal, std::string(kName) + ": " + what);
  };
  std::vector<uint32_t> live;
  for (uint32_t h = 0; h < state_.size(); ++h) {
    if (state_[h] == kLive) {
      live.push_back(h);
    } else if (state_[h] != kDead) {
      return fail("a moved flag left set after a query");
    } else if (!adj_[h].empty()) {
      return fail("a dead object has an adjacency");
    }
  }
  if (live.size() != live_) return fail("live count differs");
  std::vector<uint8_t> seen(state_.size(), 0);
  auto check_entry = [&](uint32_t n, size_t i, const Entry& e) -> std::string {
    uint32_t h = e.handle;
    if (h >= state_.size() || state_[h] != kLive) return "entry of a dead object";
    if (seen[h]++) return "object in two lists";
    if (node_of_[h] != n || slot_[h] != i) return "node_of/slot point astray";
    if (!(e.box == boxes_[h])) return "stale box in an entry";
    return "";
  };
  for (size_t i = 0; i < overflow_.size(); ++i) {
    if (std::string s = check_entry(kOverflow, i, overflow_[i]); !s.empty()) return fail(s);
    if (root_ != kNone && Contains(nodes_[root_], overflow_[i].box)) {
      return fail("overflow object inside the root");
    }
  }
  std::vector<uint8_t> node_seen(nodes_.size(), 0);
  for (uint32_t f : free_nodes_) {
    if (f >= nodes_.size() || node_seen[f] || !nodes_[f].free) return fail("free list broken");
    if (!nodes_[f].objects.empty()) return fail("free node holds objects");
    node_seen[f] = 1;
  }
  size_t reachable = 0;
  if (root_ != kNone) {
    if (root_ >= nodes_.size() || nodes_[root_].parent != kNone) return fail("bad root");
    std::vector<uint32_t> stack = {root_};
    while (!stack.empty()) {
      uint32_t n = stack.back();
      stack.pop_back();
      const Node& node = nodes_[n];
      if (node.free || node_seen[n]) return fail("node reached twice or free");
      node_seen[n] = 2;
      ++reachable;
      size_t count = node.objects.size();
      for (size_t a = 0; a < kAxes; ++a) {
        if (!(node.lo[a] <= node.mid[a] && node.mid[a] <= node.hi[a])) return fail("bad mid");
      }
      for (size_t i = 0; i < node.objects.size(); ++i) {
        const Entry& e = node.objects[i];
        if (std::string s = check_entry(n, i, e); !s.empty()) return fail(s);
        if (!Contains(node, e.box)) return fail("object outside its node");
        if (node.split && Octant(node, e.box) != kChildren) return fail("object fits a child");
      }
      for (size_t o = 0; o < kChildren; ++o) {
        uint32_t c = node.child[o];
        if (c == kNone) continue;
        if (!node.split) return fail("leaf with a child");
        if (c >= nodes_.size()) return fail("child out of range");
        const Node& child = nodes_[c];
        if (child.parent != n || child.which != o) return fail("parent link broken");
        if (child.level != node.level - 1) return fail("bad level");
        for (size_t a = 0; a < kAxes; ++a) {
          bool upper = (o >> a) & 1;
          if (!(child.lo[a] == (upper ? node.mid[a] : node.lo[a])) ||
              !(child.hi[a] == (upper ? node.hi[a] : node.mid[a]))) {
            return fail("child bounds are not its octant");
          }
        }
        if (child.count == 0) return fail("empty subtree not freed");
        count += child.count;
        stack.push_back(c);
      }
      if (count != node.count) return fail("subtree count differs");
    }
  }
  if (reachable + free_nodes_.size() != nodes_.size()) return fail("node leaked");
  for (uint32_t h : live) {
    if (!seen[h]) return fail("live object in no list");
  }
  // Adjacency: no duplicates, every entry a tracked pair, and each pair seen from both ends.
  size_t degrees = 0;
  std::vector<uint32_t> last(state_.size(), kNone);
  for (uint32_t h : live) {
    for (uint32_t o : adj_[h]) {
      if (o >= state_.size() || state_[o] != kLive || o == h) return fail("adjacency astray");
      if (last[o] == h) return fail("adjacency duplicate");
      last[o] = h;
      if (!tracker_.Contains(h, o)) return fail("adjacency pair not in the tracker");
      ++degrees;
    }
  }
  if (degrees != 2 * tracker_.overlaps()) return fail("adjacency and tracker disagree");
  return CheckOverlapSet(boxes_, std::move(live), tracker_, kName);
}

}  // namespace bp::detail
