// bp::detail::HugeAllocator: large arrays get their own 2 MiB-aligned mapping (on Linux, outside
// the sanitizers), small ones std::allocator's; either way a vector behaves as a vector: it grows
// across the threshold and back, keeps its contents, and swaps and moves between instances.
#include "bp/detail/huge_alloc.h"

#include <cstdint>
#include <numeric>
#include <vector>

#include <gtest/gtest.h>

#include "bp/detail/flat_map.h"
#include "bp/detail/flat_set.h"

namespace bp::detail {
namespace {

bool HugeAligned(const void* p) { return reinterpret_cast<uintptr_t>(p) % kHugePage == 0; }

TEST(HugeAllocatorTest, LargeArraysAreMappedAlignedSmallOnesAreNot) {
  const size_t large = kHugeFrom / sizeof(uint64_t) + 5;  // just above the threshold
  HugeVector<uint64_t> v(large);
  if (HugeMapped(large * sizeof(uint64_t))) {
    EXPECT_TRUE(HugeAligned(v.data()));
  }
#if defined(__linux__) && !defined(BP_HUGE_ALLOC_OFF)
  EXPECT_TRUE(HugeMapped(large * sizeof(uint64_t)));
#endif
  EXPECT_FALSE(HugeMapped(kHugeFrom - 1));
  HugeVector<uint64_t> small(16);
  EXPECT_FALSE(HugeMapped(small.capacity() * sizeof(uint64_t)));
}

TEST(HugeAllocatorTest, GrowsAcrossTheThresholdKeepingItsContents) {
  HugeVector<uint32_t> v;
  const size_t n = 3 * kHugeFrom / sizeof(uint32_t) + 17;  // several huge pages, not a multiple
  for (size_t i = 0; i < n; ++i) v.push_back(static_cast<uint32_t>(i * 2654435761u));
  for (size_t i = 0; i < n; i += 4093) ASSERT_EQ(v[i], static_cast<uint32_t>(i * 2654435761u));
  EXPECT_EQ(v.back(), static_cast<uint32_t>((n - 1) * 2654435761u));
  // Every byte of the rounded mapping is usable up to the capacity.
  v.resize(v.capacity(), 7u);
  EXPECT_EQ(v.back(), 7u);
  // Back under the threshold (a small allocation), and empty.
  v.resize(100);
  v.shrink_to_fit();
  EXPECT_EQ(v.size(), 100u);
  EXPECT_EQ(v[99], static_cast<uint32_t>(99 * 2654435761u));
  v.clear();
  v.shrink_to_fit();
  EXPECT_TRUE(v.empty());
}

TEST(HugeAllocatorTest, SwapsAndMovesBetweenVectors) {
  const size_t n = kHugeFrom / sizeof(uint16_t) * 2;
  HugeVector<uint16_t> a(n);
  std::iota(a.begin(), a.end(), uint16_t{0});
  HugeVector<uint16_t> b(10, uint16_t{3});
  a.swap(b);
  EXPECT_EQ(a.size(), 10u);
  EXPECT_EQ(b.size(), n);
  EXPECT_EQ(b[n - 1], static_cast<uint16_t>(n - 1));
  HugeVector<uint16_t> c(std::move(b));
  EXPECT_EQ(c.size(), n);
  EXPECT_EQ(c[12345], uint16_t{12345});
  HugeVector<uint16_t> d;
  d = c;  // a copy: its own mapping
  c[0] = 99;
  EXPECT_EQ(d[0], 0);
  EXPECT_EQ(d.size(), n);
}

TEST(HugeAllocatorTest, OverAlignedElements) {
  struct alignas(64) Line {
    uint64_t v[8];
  };
  HugeVector<Line> small(3), large(kHugeFrom / sizeof(Line) + 1);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(small.data()) % 64, 0u);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(large.data()) % 64, 0u);
  large.back().v[7] = 5;
  EXPECT_EQ(large.back().v[7], 5u);
}

// The hash tables on it rehash across the threshold both ways.
TEST(HugeAllocatorTest, TablesRehashAcrossTheThreshold) {
  FlatSet<uint64_t> set;
  FlatMap<uint64_t, uint32_t> map;
  const uint64_t n = 400000;  // tables of several MiB
  for (uint64_t k = 1; k <= n; ++k) {
    ASSERT_TRUE(set.Insert(k * 0x9E3779B97F4A7C15ULL));
    map.FindOrInsert(k, static_cast<uint32_t>(k)) += 1;
  }
  EXPECT_EQ(set.size(), n);
  for (uint64_t k = 1; k <= n; k += 997) {
    ASSERT_TRUE(set.Contains(k * 0x9E3779B97F4A7C15ULL));
    ASSERT_NE(map.Find(k), nullptr);
    EXPECT_EQ(*map.Find(k), static_cast<uint32_t>(k) + 1);
  }
  for (uint64_t k = 1; k <= n; ++k) {
    ASSERT_TRUE(set.Erase(k * 0x9E3779B97F4A7C15ULL));
    map.Erase(k);
  }
  EXPECT_EQ(set.size(), 0u);
  EXPECT_EQ(map.size(), 0u);
}

}  // namespace
}  // namespace bp::detail
