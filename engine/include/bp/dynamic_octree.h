// bp::DynamicOctree: the spatial-subdivision baseline of the paper (Tracy, Buss and Woods, IEEE VR
// 2009, section 4: "an efficient dynamic octree [27] ... uses dynamic arrays (arrays which may
// grow by reallocation) to represent object lists"), for K axes (a 2^K-tree), behind the common
// interface.
//
// The tree: every node has closed bounds [lo, hi] and a split point mid per axis; its child o
// (bit a of o set: upper half on axis a) has the bounds [lo, mid] or [mid, hi] of the parent,
// copied, never recomputed, so children nest inside their parent exactly as stored. Bounds are
// doubles: every float, double, int32 and uint32 coordinate converts exactly, and conversion is
// monotone for any other type, which is all the pruning needs (a box that overlaps an object
// overlaps every node holding it or above it). An object lives in the deepest node that
// contains it: one that fits in no child of a split node (it straddles a split plane) stays in
// that node's list. Object lists are std::vectors of (box, handle); a leaf whose list grows past
// max_objects_per_node splits, unless it is max_depth halvings below the first root's size or
// its bounds cannot be halved any more; a split node whose subtree holds at most half that many
// objects is collapsed back into a leaf; empty subtrees are freed; nodes live in one vector with
// a free list; children are created on demand.
//
// Unbounded: the first root is fitted to the first batch of inserts. A box outside the root
// makes the root double outward (towards the box on each axis it leaves; the old root becomes
// one child of the new one). When the root cannot double without leaving the finite doubles
// (coordinates near +-1.8e308), the box is kept in the overflow list, which every query scans.
// A root with no objects of its own and a single child is replaced by that child.
//
// Events: each object keeps its adjacency, the handles overlapping it. A query removes erased
// objects and their pairs, moves updated objects between nodes (an update that still fits its
// node, and fits no child of it, stays where it is), inserts new ones, then queries the tree
// with the new box of every updated or inserted object and compares the result with the old
// adjacency: pairs found and not known are added, pairs known and not found are removed. Both
// boxes of a pair are final when either is queried, so both ends agree; the tracker turns the
// adds and removes into exact events.
//
// Thread safety: none (see bp/broadphase.h).
// Invariants (checked by Validate):
//  1. Every live object is in exactly one list (a node's or the overflow list); node_of_ and
//     slot_ point at its entry, and the entry holds its current box.
//  2. A node's list holds only boxes inside the node's bounds; in a split node, only boxes that
//     fit in no child. The overflow list holds only boxes outside the root's bounds.
//  3. A child's bounds are its octant of the parent's lo/mid/hi, exactly; lo <= mid <= hi on
//     every axis; level = parent level - 1; child and parent links agree.
//  4. count = objects in the node's subtree; every node but the root has count > 0.
//  5. The free list holds exactly the nodes not reachable from the root, each once.
//  6. adj_[h] holds exactly the live handles whose boxes overlap h's; the tracker's overlap set
//     equals the overlapping pairs of the live boxes.
//
// Why one file of about 700 lines: the nodes, their leaves' lists and the overflow list are one
// structure that every operation (insert, move, erase, split, root growth) updates together, in
// one class; its validator is apart (detail/dynamic_octree_validate.h).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/front_end.h"
#include "bp/detail/pair_tracker.h"

namespace bp {

/// Tuning of DynamicOctree.
struct DynamicOctreeOptions {
  /// A leaf splits when its list holds more objects than this; a split node whose subtree holds
  /// at most half as many is collapsed into a leaf (bpbench --octree-capacity measures it). The
  /// capacity matters little: most box tests are against objects that straddle split planes
  /// high in the tree, which no capacity changes; 32 is the best of 4 to 64 on S1-100k.
  uint32_t max_objects_per_node = 32;
  /// Nodes this many halvings below the first root's size do not split (growth of the root
  /// does not count: depth is measured against the first root, whatever the root is now).
  uint32_t max_depth = 20;
};

namespace detail {

template <int K, Coordinate T>
class DynamicOctreeCore {
 public:
  static_assert(K >= 1 && K <= 16, "a node has 2^K child slots");
  static constexpr int kDim = K;
  using Coord = T;
  static constexpr const char* kName = "dynamic_octree";
  // Pair keys pack two handles; 0xFFFFFFFF stays free so no pair key is all ones.
  static constexpr size_t kMaxHandles = 0xFFFFFFFFu;
  using Options = DynamicOctreeOptions;

  explicit DynamicOctreeCore(const Options& options = Options()) : options_(options) {}

  void Apply(std::span<const uint32_t> erases, std::span<const HandleBox<K, T>> updates,
             std::span<const HandleBox<K, T>> inserts);

  PairTracker& tracker() { return tracker_; }
  const PairTracker& tracker() const { return tracker_; }
  size_t live() const { return live_; }
  /// The box of live handle h as of the last Apply (the spot query's, see Broadphase).
  const Box<K, T>& box(uint32_t h) const { return boxes_[h]; }
  void FillStats(Stats* out) const { out->overlap_tests = tests_; }
  Status Validate() const;

  const Options& options() const { return options_; }
  /// Nodes in use (reachable from the root).
  size_t nodes() const { return nodes_.size() - free_nodes_.size(); }
  /// Nodes allocated, in use or free.
  size_t allocated_nodes() const { return nodes_.size(); }
  /// The deepest node below the root (0: the root alone; -1: no root).
  int depth() const;
  /// Objects in the overflow list (outside every root the tree could grow to).
  size_t overflow() const { return overflow_.size(); }
  /// Objects of the last Apply that changed node, and updates that stayed in their node.
  size_t relocations() const { return relocations_; }
  size_t stays() const { return stays_; }
  /// Depth below the root of the node holding handle h (-1: overflow list).
  int DepthOf(uint32_t h) const;
  /// Whether h's node is a leaf (false for the overflow list).
  bool InLeaf(uint32_t h) const { return node_of_[h] != kOverflow && !nodes_[node_of_[h]].split; }
  /// The root's bounds (lo, hi); only meaningful when the tree has a root.
  std::pair<std::array<double, static_cast<size_t>(K)>, std::array<double, static_cast<size_t>(K)>>
  root_bounds() const {
    return {nodes_[root_].lo, nodes_[root_].hi};
  }
  bool has_root() const { return root_ != kNone; }
  /// White-box tests corrupt internals through this peer to prove Validate() notices.
  friend struct DynamicOctreeTestPeer;

 private:
  static constexpr size_t kAxes = static_cast<size_t>(K);
  static constexpr size_t kChildren = size_t{1} << kAxes;
  static constexpr uint32_t kNone = 0xFFFFFFFFu;
  static constexpr uint32_t kOverflow = 0xFFFFFFFEu;  // node_of_ of an overflow object
  using Bounds = std::array<double, kAxes>;
  enum : uint8_t { kDead = 0, kLive = 1, kMoved = 2 };  // state_ flags

  struct Entry {
    Box<K, T> box;
    uint32_t handle;
  };
  struct Node {
    Bounds lo{}, mid{}, hi{};
    std::array<uint32_t, kChildren> child{};
    uint32_t parent = kNone;
    uint32_t which = 0;  // octant in the parent
    uint32_t count = 0;  // objects in the subtree
    int32_t level = 0;   // the first root is level 0; children one less
    bool split = false;
    bool free = false;
    std::vector<Entry> objects;
  };

  static double ToBound(T v) { return static_cast<double>(v); }
  static double Midpoint(double lo, double hi) {
    return std::clamp(lo * 0.5 + hi * 0.5, lo, hi);  // no overflow at +-DBL_MAX
  }
  static bool Contains(const Node& n, const Box<K, T>& b) {
    for (size_t a = 0; a < kAxes; ++a) {
      if (!(n.lo[a] <= ToBound(b.lo[a]) && ToBound(b.hi[a]) <= n.hi[a])) return false;
    }
    return true;
  }
  // The child of n that b (inside n) fits in, or kChildren if b straddles a split plane.
  static size_t Octant(const Node& n, const Box<K, T>& b) {
    size_t o = 0;
    for (size_t a = 0; a < kAxes; ++a) {
      if (ToBound(b.hi[a]) <= n.mid[a]) continue;
      if (!(ToBound(b.lo[a]) >= n.mid[a])) return kChildren;
      o |= size_t{1} << a;
    }
    return o;
  }
  bool CanSplit(const Node& n) const {
    if (n.level <= -static_cast<int64_t>(options_.max_depth)) return false;
    for (size_t a = 0; a < kAxes; ++a) {
      if (!(n.lo[a] < n.mid[a] && n.mid[a] < n.hi[a])) return false;
    }
    return true;
  }

  uint32_t NewNode();
  void FreeNode(uint32_t n);
  uint32_t MakeChild(uint32_t parent, size_t o);
  void ReserveNodes(size_t more) {
    if (nodes_.capacity() < nodes_.size() + more) {
      nodes_.reserve(std::max(2 * nodes_.capacity(), nodes_.size() + more));
    }
  }
  void CreateRoot(Bounds lo, Bounds hi);
  bool GrowOnce(const Box<K, T>& b);
  void AdoptOverflow();
  void AddEntry(uint32_t n, uint32_t h) {
    std::vector<Entry>& list = n == kOverflow ? overflow_ : nodes_[n].objects;
    node_of_[h] = n;
    slot_[h] = static_cast<uint32_t>(list.size());
    list.push_back(Entry{boxes_[h], h});
  }
  void RemoveEntry(uint32_t h) {
    std::vector<Entry>& list = node_of_[h] == kOverflow ? overflow_ : nodes_[node_of_[h]].objects;
    uint32_t i = slot_[h];
    list[i] = list.back();
    slot_[list[i].handle] = i;
    list.pop_back();
    node_of_[h] = kNone;
  }
  void Insert(uint32_t h);
  void Remove(uint32_t h);
  void Relocate(uint32_t h);
  void Split(uint32_t n);
  void Merge(uint32_t top);
  void ShrinkRoot();
  void Collect(uint32_t h, std::vector<uint32_t>* out);
  static void EraseValue(std::vector<uint32_t>& v, uint32_t x) {
    auto it = std::find(v.begin(), v.end(), x);
    if (it != v.end()) {
      *it = v.back();
      v.pop_back();
    }
  }

  Options options_;
  std::vector<Node> nodes_;
  std::vector<uint32_t> free_nodes_;
  uint32_t root_ = kNone;
  std::vector<Entry> overflow_;
  // By handle.
  std::vector<Box<K, T>> boxes_;
  std::vector<uint32_t> node_of_;
  std::vector<uint32_t> slot_;  // index in the node's list
  std::vector<uint8_t> state_;
  std::vector<std::vector<uint32_t>> adj_;
  std::vector<uint32_t> mark_;
  uint32_t stamp_ = 0;
  size_t live_ = 0;
  PairTracker tracker_;
  // Scratch, kept to reuse the allocations.
  std::vector<uint32_t> moved_;
  std::vector<uint32_t> found_;
  std::vector<uint32_t> stack_;
  std::vector<uint32_t> regrow_;
  size_t tests_ = 0;
  size_t relocations_ = 0;
  size_t stays_ = 0;
};

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::Apply(std::span<const uint32_t> erases,
                                    std::span<const HandleBox<K, T>> updates,
                                    std::span<const HandleBox<K, T>> inserts) {
  tests_ = 0;
  relocations_ = 0;
  stays_ = 0;
  for (uint32_t h : erases) {
    BP_ASSERT(h < state_.size() && state_[h] == kLive);
    Remove(h);
    for (uint32_t o : adj_[h]) {
      tracker_.Remove(h, o);
      EraseValue(adj_[o], h);
    }
    adj_[h].clear();
    state_[h] = kDead;
    --live_;
  }
  for (const auto& [h, box] : updates) {
    boxes_[h] = box;
    Relocate(h);
  }
  if (root_ == kNone && !inserts.empty()) {
    // Fit the first root to the whole batch, so that a bulk load does not grow it step by step.
    Bounds lo, hi;
    lo.fill(std::numeric_limits<double>::infinity());
    hi.fill(-std::numeric_limits<double>::infinity());
    for (const auto& [h, box] : inserts) {
      for (size_t a = 0; a < kAxes; ++a) {
        lo[a] = std::min(lo[a], ToBound(box.lo[a]));
        hi[a] = std::max(hi[a], ToBound(box.hi[a]));
      }
    }
    CreateRoot(lo, hi);
    AdoptOverflow();
  }
  for (const auto& [h, box] : inserts) {
    if (h >= state_.size()) {
      size_t n = std::max<size_t>(h + size_t{1}, state_.size() + state_.size() / 2);
      boxes_.resize(n);
      node_of_.resize(n, kNone);
      slot_.resize(n);
      state_.resize(n, kDead);
      adj_.resize(n);
      mark_.resize(n, 0);
    }
    BP_ASSERT(state_[h] == kDead && adj_[h].empty());
    boxes_[h] = box;
    state_[h] = kLive;
    ++live_;
    Insert(h);
  }
  ShrinkRoot();

  // Pairs: drop the moved objects from the lists of the objects that did not move, then query
  // the tree with each moved box and compare with its old adjacency.
  moved_.clear();
  for (const auto& hb : updates) moved_.push_back(hb.handle);
  for (const auto& hb : inserts) moved_.push_back(hb.handle);
  for (uint32_t h : moved_) state_[h] |= kMoved;
  for (uint32_t h : moved_) {
    for (uint32_t o : adj_[h]) {
      if (!(state_[o] & kMoved)) EraseValue(adj_[o], h);
    }
  }
  for (uint32_t h : moved_) {
    if (++stamp_ == 0) {  // wrapped: old marks could collide
      std::fill(mark_.begin(), mark_.end(), 0);
      stamp_ = 1;
    }
    for (uint32_t o : adj_[h]) mark_[o] = stamp_;
    found_.clear();
    Collect(h, &found_);
    for (uint32_t n : found_) {
      if (mark_[n] == stamp_) {
        mark_[n] = 0;  // known and still overlapping
      } else {
        tracker_.Add(h, n);
      }
      if (!(state_[n] & kMoved)) adj_[n].push_back(h);
    }
    for (uint32_t o : adj_[h]) {
      if (mark_[o] == stamp_) tracker_.Remove(h, o);
    }
    adj_[h].swap(found_);
  }
  for (uint32_t h : moved_) state_[h] = kLive;
}

template <int K, Coordinate T>
uint32_t DynamicOctreeCore<K, T>::NewNode() {
  uint32_t n;
  if (!free_nodes_.empty()) {
    n = free_nodes_.back();
    free_nodes_.pop_back();
  } else {
    n = static_cast<uint32_t>(nodes_.size());
    nodes_.emplace_back();
  }
  Node& node = nodes_[n];
  node.child.fill(kNone);
  node.parent = kNone;
  node.which = 0;
  node.count = 0;
  node.level = 0;
  node.split = false;
  node.free = false;
  BP_ASSERT(node.objects.empty());
  return n;
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::FreeNode(uint32_t n) {
  Node& node = nodes_[n];
  node.free = true;
  node.split = false;
  node.child.fill(kNone);
  node.parent = kNone;
  node.count = 0;
  node.objects.clear();
  if (node.objects.capacity() > 4 * size_t{options_.max_objects_per_node} + 16) {
    std::vector<Entry>().swap(node.objects);
  }
  free_nodes_.push_back(n);
}

template <int K, Coordinate T>
uint32_t DynamicOctreeCore<K, T>::MakeChild(uint32_t parent, size_t o) {
  uint32_t c = NewNode();  // may reallocate nodes_: take references afterwards
  Node& child = nodes_[c];
  Node& p = nodes_[parent];
  for (size_t a = 0; a < kAxes; ++a) {
    bool upper = (o >> a) & 1;
    child.lo[a] = upper ? p.mid[a] : p.lo[a];
    child.hi[a] = upper ? p.hi[a] : p.mid[a];
    child.mid[a] = Midpoint(child.lo[a], child.hi[a]);
  }
  child.parent = parent;
  child.which = static_cast<uint32_t>(o);
  child.level = p.level - 1;
  p.child[o] = c;
  return c;
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::CreateRoot(Bounds lo, Bounds hi) {
  constexpr double kMax = std::numeric_limits<double>::max();
  // A cube as wide as the widest axis, and never so thin that lo + side == lo.
  double side = 0, magnitude = 0;
  for (size_t a = 0; a < kAxes; ++a) {
    lo[a] = std::clamp(lo[a], -kMax, kMax);
    hi[a] = std::clamp(hi[a], -kMax, kMax);
    side = std::max(side, hi[a] - lo[a]);
    magnitude = std::max({magnitude, std::abs(lo[a]), std::abs(hi[a])});
  }
  side = std::max(side, std::ldexp(magnitude, -20));
  if (!(side > 0)) side = 1;
  // lo + side rounds: widen side until the root reaches hi on every axis (found by the fuzzer:
  // lo = -1.9e289 and hi = 14 gave a root ending at 0).
  for (size_t a = 0; a < kAxes; ++a) {
    while (lo[a] + side < hi[a])
      side = std::nextafter(side, std::numeric_limits<double>::infinity());
  }
  root_ = NewNode();
  Node& r = nodes_[root_];
  for (size_t a = 0; a < kAxes; ++a) {
    r.lo[a] = lo[a];
    r.hi[a] = lo[a] + side;
    if (!(r.hi[a] <= kMax)) {  // past the largest double: hold it from above instead
      r.hi[a] = kMax;
      r.lo[a] = std::min(lo[a], std::max(-kMax, kMax - side));
    }
    r.mid[a] = Midpoint(r.lo[a], r.hi[a]);
  }
}

// Doubles the root towards b on every axis b leaves (upwards on the others); false if that
// would leave the finite doubles on some axis in both directions.
template <int K, Coordinate T>
bool DynamicOctreeCore<K, T>::GrowOnce(const Box<K, T>& b) {
  Bounds lo, mid, hi;
  size_t o = 0;
  {
    const Node& r = nodes_[root_];
    for (size_t a = 0; a < kAxes; ++a) {
      double w = r.hi[a] - r.lo[a];
      double below = r.lo[a] - w, above = r.hi[a] + w;
      bool can_down = std::isfinite(below) && below < r.lo[a];
      bool can_up = std::isfinite(above) && above > r.hi[a];
      double blo = ToBound(b.lo[a]), bhi = ToBound(b.hi[a]);
      bool down = blo < r.lo[a] && !(bhi > r.hi[a] && bhi - r.hi[a] > r.lo[a] - blo);
      if (down ? !can_down : !can_up) down = !down;
      if (down ? !can_down : !can_up) return false;
      if (down) {
        lo[a] = below, mid[a] = r.lo[a], hi[a] = r.hi[a];
        o |= size_t{1} << a;
      } else {
        lo[a] = r.lo[a], mid[a] = r.hi[a], hi[a] = above;
      }
    }
  }
  uint32_t old = root_;
  uint32_t n = NewNode();
  Node& r = nodes_[n];
  r.lo = lo;
  r.mid = mid;
  r.hi = hi;
  r.level = nodes_[old].level + 1;
  r.split = true;
  r.count = nodes_[old].count;
  r.child[o] = old;
  nodes_[old].parent = n;
  nodes_[old].which = static_cast<uint32_t>(o);
  root_ = n;
  // The old root's own objects straddle its split planes (or it was a leaf): they still fit
  // in no child of the old root, and the old root is inside the new one: invariant 2 holds.
  return true;
}

// A new or larger root may hold objects of the overflow list: move those into the tree
// (invariant 2). Inserting a box inside the root grows nothing, so this does not recurse.
template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::AdoptOverflow() {
  regrow_.clear();
  for (size_t i = 0; i < overflow_.size();) {
    if (Contains(nodes_[root_], overflow_[i].box)) {
      uint32_t o = overflow_[i].handle;
      RemoveEntry(o);
      regrow_.push_back(o);
    } else {
      ++i;
    }
  }
  std::vector<uint32_t> adopt;
  adopt.swap(regrow_);
  for (uint32_t o : adopt) Insert(o);
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::Insert(uint32_t h) {
  const Box<K, T>& b = boxes_[h];
  if (root_ == kNone) {
    Bounds lo, hi;
    for (size_t a = 0; a < kAxes; ++a) lo[a] = ToBound(b.lo[a]), hi[a] = ToBound(b.hi[a]);
    CreateRoot(lo, hi);
    AdoptOverflow();
  }
  if (!Contains(nodes_[root_], b) && nodes_[root_].count == 0 && !nodes_[root_].split) {
    // An empty root (fitted to boxes that all went elsewhere): refit it instead of nesting an
    // empty subtree under a grown root.
    FreeNode(root_);
    root_ = kNone;
    Bounds lo, hi;
    for (size_t a = 0; a < kAxes; ++a) lo[a] = ToBound(b.lo[a]), hi[a] = ToBound(b.hi[a]);
    CreateRoot(lo, hi);
    AdoptOverflow();
  }
  if (!Contains(nodes_[root_], b)) {
    bool grew = false;
    while (!Contains(nodes_[root_], b) && GrowOnce(b)) grew = true;
    if (grew) AdoptOverflow();
    if (!Contains(nodes_[root_], b)) {
      AddEntry(kOverflow, h);
      return;
    }
  }
  uint32_t n = root_;
  for (;;) {
    const Node& node = nodes_[n];
    if (!node.split) break;
    size_t o = Octant(node, b);
    if (o == kChildren) break;
    uint32_t c = node.child[o];
    n = c != kNone ? c : MakeChild(n, o);
  }
  AddEntry(n, h);
  for (uint32_t p = n; p != kNone; p = nodes_[p].parent) ++nodes_[p].count;
  const Node& node = nodes_[n];
  if (!node.split && node.objects.size() > options_.max_objects_per_node && CanSplit(node)) {
    Split(n);
  }
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::Split(uint32_t n) {
  ReserveNodes(kChildren);  // no reallocation below: the references stay valid
  Node& node = nodes_[n];
  node.split = true;
  size_t keep = 0;
  for (size_t i = 0; i < node.objects.size(); ++i) {
    const Entry e = node.objects[i];
    size_t o = Octant(node, e.box);
    if (o == kChildren) {
      slot_[e.handle] = static_cast<uint32_t>(keep);
      node.objects[keep++] = e;
      continue;
    }
    uint32_t c = node.child[o] != kNone ? node.child[o] : MakeChild(n, o);
    Node& child = nodes_[c];
    node_of_[e.handle] = c;
    slot_[e.handle] = static_cast<uint32_t>(child.objects.size());
    child.objects.push_back(e);
    ++child.count;
  }
  node.objects.resize(keep);
  for (size_t o = 0; o < kChildren; ++o) {
    uint32_t c = nodes_[n].child[o];
    if (c == kNone) continue;
    const Node& child = nodes_[c];
    if (child.objects.size() > options_.max_objects_per_node && CanSplit(child)) Split(c);
  }
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::Remove(uint32_t h) {
  uint32_t n = node_of_[h];
  if (n == kOverflow) {
    RemoveEntry(h);
    return;
  }
  RemoveEntry(h);
  for (uint32_t p = n; p != kNone; p = nodes_[p].parent) --nodes_[p].count;
  // Free the nodes this emptied (a node whose count reaches 0 has no children left).
  while (n != root_ && nodes_[n].count == 0) {
    uint32_t parent = nodes_[n].parent;
    nodes_[parent].child[nodes_[n].which] = kNone;
    FreeNode(n);
    n = parent;
  }
  if (nodes_[root_].count == 0) {
    FreeNode(root_);
    root_ = kNone;
    return;
  }
  // Collapse the highest split node that holds few enough objects.
  uint32_t top = kNone;
  for (uint32_t p = n; p != kNone; p = nodes_[p].parent) {
    if (nodes_[p].split && nodes_[p].count <= options_.max_objects_per_node / 2) top = p;
  }
  if (top != kNone) Merge(top);
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::Merge(uint32_t top) {
  stack_.clear();
  for (uint32_t c : nodes_[top].child) {
    if (c != kNone) stack_.push_back(c);
  }
  std::vector<Entry>& list = nodes_[top].objects;
  while (!stack_.empty()) {
    uint32_t n = stack_.back();
    stack_.pop_back();
    for (uint32_t c : nodes_[n].child) {
      if (c != kNone) stack_.push_back(c);
    }
    for (const Entry& e : nodes_[n].objects) {
      node_of_[e.handle] = top;
      slot_[e.handle] = static_cast<uint32_t>(list.size());
      list.push_back(e);
    }
    FreeNode(n);
  }
  nodes_[top].split = false;
  nodes_[top].child.fill(kNone);
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::Relocate(uint32_t h) {
  const Box<K, T>& b = boxes_[h];
  uint32_t n = node_of_[h];
  if (n != kOverflow) {
    Node& node = nodes_[n];
    if (Contains(node, b) && (!node.split || Octant(node, b) == kChildren)) {
      node.objects[slot_[h]].box = b;
      ++stays_;
      return;
    }
  }
  ++relocations_;
  Remove(h);
  Insert(h);
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::ShrinkRoot() {
  while (root_ != kNone) {
    const Node& r = nodes_[root_];
    if (!r.split || !r.objects.empty()) return;
    uint32_t only = kNone;
    for (uint32_t c : r.child) {
      if (c == kNone) continue;
      if (only != kNone) return;
      only = c;
    }
    if (only == kNone) return;
    FreeNode(root_);
    root_ = only;
    nodes_[only].parent = kNone;
    nodes_[only].which = 0;
  }
}

template <int K, Coordinate T>
void DynamicOctreeCore<K, T>::Collect(uint32_t h, std::vector<uint32_t>* out) {
  const Box<K, T>& b = boxes_[h];
  for (const Entry& e : overflow_) {
    ++tests_;
    if (e.handle != h && Overlaps(e.box, b) && tracker_.Accepts(h, e.handle))
      out->push_back(e.handle);
  }
  if (root_ == kNone) return;
  Bounds qlo, qhi;
  for (size_t a = 0; a < kAxes; ++a) qlo[a] = ToBound(b.lo[a]), qhi[a] = ToBound(b.hi[a]);
  {
    const Node& r = nodes_[root_];
    for (size_t a = 0; a < kAxes; ++a) {
      if (qhi[a] < r.lo[a] || r.hi[a] < qlo[a]) return;
    }
  }
  stack_.clear();
  stack_.push_back(root_);
  while (!stack_.empty()) {
    const Node& node = nodes_[stack_.back()];
    stack_.pop_back();
    for (const Entry& e : node.objects) {
      ++tests_;
      if (e.handle != h && Overlaps(e.box, b) && tracker_.Accepts(h, e.handle))
        out->push_back(e.handle);
    }
    if (!node.split) continue;
    // The node overlaps the box; a child does iff it does on the child's side of every plane.
    size_t lower = 0, upper = 0;
    for (size_t a = 0; a < kAxes; ++a) {
      if (qlo[a] <= node.mid[a]) lower |= size_t{1} << a;
      if (qhi[a] >= node.mid[a]) upper |= size_t{1} << a;
    }
    for (size_t o = 0; o < kChildren; ++o) {
      uint32_t c = node.child[o];
      if (c != kNone && (o & ~upper) == 0 && (~o & ~lower & (kChildren - 1)) == 0) {
        stack_.push_back(c);
      }
    }
  }
}

template <int K, Coordinate T>
int DynamicOctreeCore<K, T>::depth() const {
  if (root_ == kNone) return -1;
  int deepest = 0;
  for (size_t n = 0; n < nodes_.size(); ++n) {
    if (!nodes_[n].free) deepest = std::max(deepest, nodes_[root_].level - nodes_[n].level);
  }
  return deepest;
}

template <int K, Coordinate T>
int DynamicOctreeCore<K, T>::DepthOf(uint32_t h) const {
  uint32_t n = node_of_[h];
  return n == kOverflow ? -1 : nodes_[root_].level - nodes_[n].level;
}

}  // namespace detail

/// The dynamic octree baseline (paper, section 4) behind the common interface.
template <int K, Coordinate T, class Key = uint64_t>
using DynamicOctree = detail::FrontEnd<detail::DynamicOctreeCore<K, T>, Key>;

}  // namespace bp

#include "bp/detail/dynamic_octree_validate.h"  // NOLINT(build/include_order): defines Validate
