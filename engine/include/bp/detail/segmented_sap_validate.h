// SegmentedSapCore::Validate: every invariant of bp/segmented_sap.h recomputed from scratch
// (sorted lists, positions, links and chunk populations, checkpoints and R sets, the candidate
// set). O(n log n + chunks); run after every query when BP_VALIDATE is set.
#pragma once

#include <algorithm>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "bp/detail/sweep.h"
#include "bp/segmented_sap.h"

namespace bp::detail {

template <int K, Coordinate T>
Status SegmentedSapCore<K, T>::Validate() const {
  auto fail = [](const std::string& what) {
    return Status(StatusCode::kInternal, "segmented_sap: " + what);
  };
  std::vector<uint32_t> live;
  size_t live_flags = 0;
  for (uint8_t f : live_flag_) live_flags += f;
  if (live_flags != live_) return fail("live flags differ from the live count");
  for (size_t a = 0; a < kAxes; ++a) {
    const Axis& ax = axes_[a];
    size_t total = 0;
    const Ext* prev = nullptr;
    std::vector<uint8_t> open(live_flag_.size(), 0);
    size_t open_count = 0;
    // Walk the links; every chunk id must be linked once or free once.
    std::vector<uint8_t> seen(ax.chunks.size(), 0);
    size_t r = 0;
    uint32_t before = kNone;
    for (uint32_t c = ax.head; c != kNone; before = c, c = ax.chunks[c].next, ++r) {
      if (c >= ax.chunks.size() || seen[c]++) return fail("chunk links broken or cyclic");
      const Chunk& ch = ax.chunks[c];
      if (ch.prev != before) return fail("chunk prev link out of date");
      if (ax.order_valid && (r >= ax.order.size() || ax.order[r] != c)) {
        return fail("chunk index differs from the links");
      }
      if (ch.count == 0 || ch.count > cap_) return fail("chunk population out of range");
      if (before != kNone && ax.chunks[before].count + ch.count <= cap_ / 2) {
        return fail("two adjacent chunks hold half a chunk or less");
      }
      for (uint32_t i = 0; i < ch.count; ++i) {
        uint32_t p = Base(c) + i;
        const Ext& e = ax.items[p];
        uint32_t h = HandleOf(e.ref);
        if (h >= live_flag_.size() || !live_flag_[h]) return fail("extremum of a dead handle");
        if (ax.pos[e.ref] != p) return fail("position table out of date");
        T expect = IsMax(e.ref) ? boxes_[h].hi[a] : boxes_[h].lo[a];
        if (!(e.value == expect)) {
          return fail("extremum value differs from the box");
        }
        if (prev != nullptr && Less(e, *prev)) {
          return fail("axis " + std::to_string(a) + " not sorted");
        }
        prev = &e;
        ++total;
        if (a == 0) {
          if (IsMax(e.ref)) {
            if (!open[h]) return fail("max before min");
            open[h] = 0;
            --open_count;
          } else {
            open[h] = 1;
            ++open_count;
            live.push_back(h);
          }
        }
      }
      if (a == 0) {
        if (!rsets_[c].empty()) return fail("R set not empty between queries");
        const FlatSet<uint32_t>& cp = checkpoints_[c];
        if (cp.size() != open_count) return fail("checkpoint set size differs from recomputation");
        bool ok = true;
        cp.ForEach([&](uint32_t h) { ok = ok && h < open.size() && open[h]; });
        if (!ok) return fail("checkpoint set differs from recomputation");
      }
    }
    if (total != 2 * live_) return fail("extrema count differs from live objects");
    if (r != ax.chunk_count || (ax.order_valid && ax.order.size() != r)) {
      return fail("chunk count differs from the links");
    }
    for (uint32_t c : ax.free_chunks) {
      if (c >= seen.size() || seen[c]++) return fail("free chunk linked or listed twice");
      if (ax.chunks[c].count != 0) return fail("free chunk not empty");
      if (a == 0 && (!checkpoints_[c].empty() || !rsets_[c].empty())) {
        return fail("free chunk keeps checkpoints");
      }
    }
    if (std::find(seen.begin(), seen.end(), 0) != seen.end()) return fail("chunk id lost");
  }
  return CheckOverlapSet(boxes_, std::move(live), tracker_, kName);
}

}  // namespace bp::detail
