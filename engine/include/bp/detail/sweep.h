// bp::detail::CheckOverlapSet: recomputes the overlapping pairs of a set of boxes from scratch
// by sort and sweep on axis 0 and compares them with a PairTracker. Shared by the validators of
// every engine, so each engine is checked against code that shares nothing with its own.
//
// Thread safety: pure function.
#pragma once

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "bp/box.h"
#include "bp/detail/pair_tracker.h"
#include "bp/status.h"

namespace bp::detail {

/// Ok iff tracker holds exactly the overlapping pairs among boxes[h] for h in live that pass
/// its filter.
template <int K, Coordinate T>
Status CheckOverlapSet(const std::vector<Box<K, T>>& boxes, std::vector<uint32_t> live,
                       const PairTracker& tracker, const char* engine) {
  std::sort(live.begin(), live.end(),
            [&](uint32_t x, uint32_t y) { return boxes[x].lo[0] < boxes[y].lo[0]; });
  size_t pairs = 0;
  for (size_t i = 0; i < live.size(); ++i) {
    const Box<K, T>& a = boxes[live[i]];
    for (size_t j = i + 1; j < live.size() && !(a.hi[0] < boxes[live[j]].lo[0]); ++j) {
      if (!Overlaps(a, boxes[live[j]]) || !tracker.Accepts(live[i], live[j])) continue;
      ++pairs;
      if (!tracker.Contains(live[i], live[j])) {
        return Status(StatusCode::kInternal, std::string(engine) + ": overlapping pair " +
                                                 std::to_string(live[i]) + "," +
                                                 std::to_string(live[j]) + " missing");
      }
    }
  }
  if (pairs != tracker.overlaps()) {
    return Status(StatusCode::kInternal, std::string(engine) + ": " +
                                             std::to_string(tracker.overlaps() - pairs) +
                                             " spurious pairs in the overlap set");
  }
  return Status::Ok();
}

}  // namespace bp::detail
