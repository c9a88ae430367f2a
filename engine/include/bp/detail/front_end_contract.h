// The contract between the front end (detail/front_end.h) and a core: the front end maps keys to
// dense handles, stages calls, and hands the core one batch per query; the core keeps the boxes
// by handle and reports its changed pairs through its PairTracker.
//
// A core works on handles only (it never sees keys) and must provide (FrontEndCore):
//   static constexpr int kDim; using Coord = T; static constexpr const char* kName;
//   static constexpr size_t kMaxHandles;   // handles are 0..kMaxHandles-1
//   void Apply(span<const uint32_t> erases, span<const HandleBox> updates,
//              span<const HandleBox> inserts);   // in this order
//   PairTracker& tracker(); const PairTracker& tracker() const; size_t live() const;
//   void FillStats(Stats* out) const; Status Validate() const;
//
//
// Handles are dense (the front end reuses a freed one only after the query that applied its
// erase), a batch names each handle at most once, and an erase or update names a live handle.
#pragma once

#include <concepts>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/pair_tracker.h"
#include "bp/status.h"

namespace bp::detail {

/// A box addressed by a dense handle: the unit of the core interface.
template <int K, Coordinate T>
struct HandleBox {
  uint32_t handle = 0;
  Box<K, T> box;
};

/// Appends {h, box} to v, written in place: a braced temporary is stored piecewise and read back
/// whole, a failed store-to-load forward that took most of the grid's routing time (perf, S3).
template <int K, Coordinate T, class Alloc>
inline void PushBox(std::vector<HandleBox<K, T>, Alloc>& v, uint32_t h, const Box<K, T>& box) {
  HandleBox<K, T>& out = v.emplace_back();
  out.handle = h;
  out.box = box;
}

/// What the front end needs of a core (see above).
template <class C>
concept FrontEndCore = requires(C& core, const C& view, std::span<const uint32_t> erases,
                                std::span<const HandleBox<C::kDim, typename C::Coord>> boxes,
                                Stats* stats) {
  typename C::Options;
  { C::kDim } -> std::convertible_to<int>;
  { C::kName } -> std::convertible_to<const char*>;
  { C::kMaxHandles } -> std::convertible_to<size_t>;
  core.Apply(erases, boxes, boxes);
  { core.tracker() } -> std::same_as<PairTracker&>;
  { view.tracker() } -> std::same_as<const PairTracker&>;
  { view.live() } -> std::convertible_to<size_t>;
  view.FillStats(stats);
  { view.Validate() } -> std::same_as<Status>;
};

}  // namespace bp::detail
