// bp::BruteForce: the reference oracle. No spatial structure: every inserted or moved box is
// tested against every live box, O(n) per operation. Deliberately simple, so that it can be
// trusted; every other engine is checked against it event by event.
//
// Thread safety: none (see bp/broadphase.h).
// Invariants:
//  1. live_[pos_[h]] == h for every live handle h; live_ holds each live handle once.
//  2. The tracker's overlap set equals the overlapping pairs among live boxes.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/front_end.h"
#include "bp/detail/pair_tracker.h"
#include "bp/detail/sweep.h"

namespace bp {

/// The oracle has nothing to tune.
struct BruteForceOptions {};

namespace detail {

template <int K, Coordinate T>
class BruteForceCore {
 public:
  static constexpr int kDim = K;
  using Coord = T;
  static constexpr const char* kName = "brute_force";
  // Pair keys pack two handles; 0xFFFFFFFF stays free so no pair key is all ones.
  static constexpr size_t kMaxHandles = 0xFFFFFFFFu;
  using Options = BruteForceOptions;

  explicit BruteForceCore(const Options& /*options*/ = Options()) {}

  void Apply(std::span<const uint32_t> erases, std::span<const HandleBox<K, T>> updates,
             std::span<const HandleBox<K, T>> inserts) {
    tests_ = 0;
    for (uint32_t h : erases) {
      for (uint32_t other : live_) {
        if (other != h) tracker_.Remove(h, other);
      }
      uint32_t pos = pos_[h];
      live_[pos] = live_.back();
      pos_[live_[pos]] = pos;
      live_.pop_back();
    }
    for (const auto& [h, box] : updates) {
      boxes_[h] = box;
      Retest(h);
    }
    for (const auto& [h, box] : inserts) {
      if (h >= boxes_.size()) {
        boxes_.resize(h + 1);
        pos_.resize(h + 1);
      }
      boxes_[h] = box;
      pos_[h] = static_cast<uint32_t>(live_.size());
      live_.push_back(h);
      Retest(h);
    }
  }

  PairTracker& tracker() { return tracker_; }
  const PairTracker& tracker() const { return tracker_; }
  void FillStats(Stats* out) const { out->overlap_tests = tests_; }
  size_t live() const { return live_.size(); }
  /// The box of live handle h as of the last Apply (the spot query's, see Broadphase).
  const Box<K, T>& box(uint32_t h) const { return boxes_[h]; }

  Status Validate() const {
    for (size_t i = 0; i < live_.size(); ++i) {
      if (pos_[live_[i]] != i) return Status(StatusCode::kInternal, "brute_force: bad position");
    }
    return CheckOverlapSet(boxes_, live_, tracker_, kName);
  }

 private:
  void Retest(uint32_t h) {
    for (uint32_t other : live_) {
      if (other == h) continue;
      ++tests_;
      if (Overlaps(boxes_[h], boxes_[other])) {  // Add applies the filter
        tracker_.Add(h, other);
      } else {
        tracker_.Remove(h, other);
      }
    }
  }

  std::vector<Box<K, T>> boxes_;
  std::vector<uint32_t> pos_;
  std::vector<uint32_t> live_;
  PairTracker tracker_;
  size_t tests_ = 0;
};

}  // namespace detail

/// The brute-force oracle behind the common interface.
template <int K, Coordinate T, class Key = uint64_t>
using BruteForce = detail::FrontEnd<detail::BruteForceCore<K, T>, Key>;

}  // namespace bp
