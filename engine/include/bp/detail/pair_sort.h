// bp::detail::SortKeyPairs: sorts a query's event pairs by (first, second), as std::sort with
// operator< on the pairs would.
//
// Why not std::sort alone: a frame's events are thousands of unrelated pairs, and comparing
// pairs of keys is two data-dependent branches that mispredict about half the time; from a few
// thousand pairs on, that is most of the events phase. For integral keys of up to 64 bits, a
// list of at least kRadixFrom pairs is sorted instead by a least-significant-digit radix sort:
// 11-bit digits of the second key, then of the first (each pass stable), skipping every digit
// on which all the pairs agree (keys of one scene mostly share their high bits). Other keys,
// and shorter lists, go to std::sort.
//
// Thread safety: none; two lists may be sorted at once with two scratch vectors.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

namespace bp::detail {

/// Lists at least this long are radix sorted (integral keys); shorter ones go to std::sort,
/// which is faster on them.
inline constexpr size_t kRadixFrom = 2048;

/// A 64-bit image of an integral key whose unsigned order is the key's order.
template <class Key>
uint64_t OrderBits(Key k) {
  if constexpr (std::is_signed_v<Key>) {
    return static_cast<uint64_t>(static_cast<int64_t>(k)) ^ (uint64_t{1} << 63);
  } else {
    return static_cast<uint64_t>(k);
  }
}

/// Sorts *pairs by (first, second); *scratch is working space (its contents are lost).
template <class Key>
void SortKeyPairs(std::vector<std::pair<Key, Key>>* pairs,
                  std::vector<std::pair<Key, Key>>* scratch) {
  using Pair = std::pair<Key, Key>;
  if constexpr (!std::is_integral_v<Key> || sizeof(Key) > 8 || std::is_same_v<Key, bool>) {
    std::sort(pairs->begin(), pairs->end());
    (void)scratch;
  } else {
    const size_t n = pairs->size();
    if (n < kRadixFrom || n > UINT32_MAX) {
      std::sort(pairs->begin(), pairs->end());
      return;
    }
    // The bits on which some pairs differ, per key (0: first, 1: second).
    std::array<uint64_t, 2> any{0, 0}, all{~uint64_t{0}, ~uint64_t{0}};
    for (const Pair& p : *pairs) {
      const uint64_t a = OrderBits(p.first), b = OrderBits(p.second);
      any[0] |= a;
      all[0] &= a;
      any[1] |= b;
      all[1] &= b;
    }
    constexpr unsigned kDigit = 11;
    constexpr size_t kBuckets = size_t{1} << kDigit;
    scratch->resize(n);
    Pair* src = pairs->data();
    Pair* dst = scratch->data();
    std::array<uint32_t, kBuckets> start;
    for (int key = 1; key >= 0; --key) {  // least significant first: the second key
      const uint64_t varies = any[static_cast<size_t>(key)] ^ all[static_cast<size_t>(key)];
      for (unsigned shift = 0; shift < 64; shift += kDigit) {
        if (((varies >> shift) & (kBuckets - 1)) == 0) continue;
        const auto digit = [&](const Pair& p) {
          return static_cast<size_t>((OrderBits(key == 0 ? p.first : p.second) >> shift) &
                                     (kBuckets - 1));
        };
        start.fill(0);
        for (size_t i = 0; i < n; ++i) ++start[digit(src[i])];
        uint32_t sum = 0;
        for (uint32_t& s : start) sum += std::exchange(s, sum);
        for (size_t i = 0; i < n; ++i) dst[start[digit(src[i])]++] = src[i];
        std::swap(src, dst);
      }
    }
    if (src != pairs->data()) std::copy(src, src + n, pairs->data());
  }
}

}  // namespace bp::detail
