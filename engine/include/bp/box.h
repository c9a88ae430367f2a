// bp::Box: an axis-aligned bounding box in K dimensions with coordinate type T.
//
// Overlap is closed: a and b overlap iff on every axis a.lo <= b.hi && b.lo <= a.hi. Touching
// faces overlap; a zero-extent box is a point and overlaps every box that contains it.
// A box is valid iff on every axis lo <= hi and (for floating T) both are finite.
//
// Thread safety: plain value type.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <limits>
#include <string>
#include <type_traits>

#include "bp/status.h"

namespace bp {

/// Coordinate types the engine accepts: floating point or signed/unsigned integers.
template <class T>
concept Coordinate = std::is_arithmetic_v<T> && !std::is_same_v<T, bool>;

/// An axis-aligned box: lo[a] <= hi[a] on every axis a of the K axes.
template <int K, Coordinate T>
struct Box {
  static_assert(K >= 1, "a box needs at least one axis");
  std::array<T, static_cast<std::size_t>(K)> lo{};  ///< min corner
  std::array<T, static_cast<std::size_t>(K)> hi{};  ///< max corner

  friend bool operator==(const Box&, const Box&) = default;
};

/// True iff a and b overlap (closed intervals on every axis).
template <int K, Coordinate T>
inline bool Overlaps(const Box<K, T>& a, const Box<K, T>& b) {
  for (std::size_t i = 0; i < static_cast<std::size_t>(K); ++i) {
    if (a.hi[i] < b.lo[i] || b.hi[i] < a.lo[i]) return false;
  }
  return true;
}

/// True iff the box is valid: on every axis lo <= hi and, for floating T, both finite. Without
/// branches: lo >= lowest fails for NaN and -inf, hi <= max for NaN and +inf, and lo <= hi
/// covers lo = +inf and hi = -inf (the other bound would have to be infinite too).
template <int K, Coordinate T>
inline bool IsValidBox(const Box<K, T>& box) {
  unsigned ok = 1;
  for (std::size_t i = 0; i < static_cast<std::size_t>(K); ++i) {
    if constexpr (std::is_floating_point_v<T>) {
      ok &= static_cast<unsigned>(box.lo[i] >= std::numeric_limits<T>::lowest()) &
            static_cast<unsigned>(box.hi[i] <= std::numeric_limits<T>::max());
    }
    ok &= static_cast<unsigned>(box.lo[i] <= box.hi[i]);
  }
  return ok != 0;
}

namespace detail {
/// ValidateBox's error for a box IsValidBox refuses: the first bad axis and why.
template <int K, Coordinate T>
[[gnu::noinline, gnu::cold]] Status InvalidBoxStatus(const Box<K, T>& box) {
  for (std::size_t i = 0; i < static_cast<std::size_t>(K); ++i) {
    if constexpr (std::is_floating_point_v<T>) {
      if (std::isnan(box.lo[i]) || std::isnan(box.hi[i])) {
        return Status(StatusCode::kInvalidArgument, "NaN coordinate on axis " + std::to_string(i));
      }
      if (std::isinf(box.lo[i]) || std::isinf(box.hi[i])) {
        return Status(StatusCode::kInvalidArgument,
                      "infinite coordinate on axis " + std::to_string(i));
      }
    }
    if (box.hi[i] < box.lo[i]) {
      return Status(StatusCode::kInvalidArgument, "lo > hi on axis " + std::to_string(i));
    }
  }
  return Status::Ok();
}
}  // namespace detail

/// Ok if the box is valid; otherwise InvalidArgument naming the axis and the reason. The check
/// is IsValidBox, inline; the message is built out of line, only for a bad box.
template <int K, Coordinate T>
inline Status ValidateBox(const Box<K, T>& box) {
  if (IsValidBox(box)) [[likely]]
    return Status::Ok();
  return detail::InvalidBoxStatus(box);
}

}  // namespace bp
