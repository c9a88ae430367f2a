// bp::detail::CellSpace: integer cell coordinates of the grid (bp/grid.h) in K dimensions:
// packing into one 63-bit hash key, ranges (boxes of cells) and their row-major enumeration.
//
// Thread safety: pure functions.
// Invariants:
//  1. A coordinate lies in [-kLimit, kLimit) on every axis, with kBits = 63 / K bits per axis,
//     so Pack never sets the top bit (never FlatMap's all-ones empty key) and is injective.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <type_traits>

namespace bp::detail {

template <int K>
struct CellSpace {
  static constexpr size_t kAxes = static_cast<size_t>(K);
  static constexpr int kBits = 63 / K;
  static constexpr int64_t kLimit = int64_t{1} << (kBits - 1);
  /// 32 bits whenever they hold kBits (K >= 2): a grid object keeps two coordinates, and a
  /// smaller record is fewer cache lines per frame.
  using Scalar = std::conditional_t<(kBits <= 32), int32_t, int64_t>;
  using Coord = std::array<Scalar, kAxes>;

  /// The hash key of a coordinate (injective; the top bit is never set).
  static uint64_t Pack(const Coord& c) {
    uint64_t key = 0;
    for (size_t a = 0; a < kAxes; ++a) {
      key |= static_cast<uint64_t>(int64_t{c[a]} + kLimit) << (static_cast<uint64_t>(kBits) * a);
    }
    return key;
  }
  /// True iff c lies in the range [lo, hi] on every axis.
  static bool Contains(const Coord& lo, const Coord& hi, const Coord& c) {
    for (size_t a = 0; a < kAxes; ++a) {
      if (c[a] < lo[a] || c[a] > hi[a]) return false;
    }
    return true;
  }
  /// Index of c in the row-major order of the range [lo, hi] (axis 0 fastest).
  static uint32_t RowMajor(const Coord& lo, const Coord& hi, const Coord& c) {
    uint64_t i = 0;
    for (size_t a = kAxes; a-- > 0;) {
      i = i * static_cast<uint64_t>(int64_t{hi[a]} - lo[a] + 1) +
          static_cast<uint64_t>(int64_t{c[a]} - lo[a]);
    }
    return static_cast<uint32_t>(i);
  }
  /// Calls f(coord) for every cell of a (small) range in row-major order.
  template <class F>
  static void ForEachCoord(const Coord& lo, const Coord& hi, F&& f) {
    Coord c = lo;
    for (;;) {
      f(c);
      size_t a = 0;
      for (; a < kAxes && c[a] == hi[a]; ++a) c[a] = lo[a];
      if (a == kAxes) return;
      ++c[a];
    }
  }
};

}  // namespace bp::detail
