// SortKeyPairs (detail/pair_sort.h) orders key pairs exactly as std::sort does, for every
// integral key type (signed ones across zero, narrow ones, keys that share their high bits or
// differ only there), on both sides of the length at which it switches to the radix sort, after
// an odd number of radix passes as after an even one, and for a key type that is not integral.
#include "bp/detail/pair_sort.h"

#include <algorithm>
#include <cstdint>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace bp::detail {
namespace {

template <class Key, class DrawFirst, class DrawSecond>
void ExpectSortedLikeStdSort(size_t n, DrawFirst first, DrawSecond second) {
  std::vector<std::pair<Key, Key>> pairs(n), scratch;
  for (auto& p : pairs) p = {first(), second()};
  std::vector<std::pair<Key, Key>> expected = pairs;
  std::sort(expected.begin(), expected.end());
  SortKeyPairs(&pairs, &scratch);
  EXPECT_EQ(pairs, expected) << "n " << n;
}

template <class Key, class Draw>
void ExpectSortedLikeStdSort(size_t n, Draw draw) {
  ExpectSortedLikeStdSort<Key>(n, draw, draw);
}

const size_t kLengths[] = {0, 1, 17, kRadixFrom - 1, kRadixFrom, kRadixFrom + 1, 7000};

TEST(PairSort, UnsignedKeysOverTheFullRangeAndSharingHighBits) {
  std::mt19937_64 rng(5);
  for (size_t n : kLengths) {
    ExpectSortedLikeStdSort<uint64_t>(n, [&] { return rng(); });
    // Ids of one scene: a common high part, a few low bits that vary, many equal keys.
    ExpectSortedLikeStdSort<uint64_t>(n, [&] { return (uint64_t{1} << 40) + rng() % 300; });
    // Differing only in the top digit.
    ExpectSortedLikeStdSort<uint64_t>(n, [&] { return (rng() % 4) << 62; });
  }
}

TEST(PairSort, SignedAndNarrowKeys) {
  std::mt19937_64 rng(6);
  for (size_t n : kLengths) {
    ExpectSortedLikeStdSort<int64_t>(n, [&] { return static_cast<int64_t>(rng()); });
    ExpectSortedLikeStdSort<int64_t>(n, [&] { return static_cast<int64_t>(rng() % 2001) - 1000; });
    ExpectSortedLikeStdSort<int32_t>(n, [&] { return static_cast<int32_t>(rng()); });
    ExpectSortedLikeStdSort<int8_t>(n, [&] { return static_cast<int8_t>(rng()); });
    ExpectSortedLikeStdSort<uint16_t>(n, [&] { return static_cast<uint16_t>(rng()); });
  }
}

TEST(PairSort, AnOddNumberOfPassesEndsInTheList) {
  // Each radix pass moves the pairs between the list and the scratch: an odd number of passes
  // leaves them in the scratch, to be copied back. One digit varies (the first key's), or three.
  std::mt19937_64 rng(8);
  for (size_t n : {kRadixFrom, size_t{5000}}) {
    ExpectSortedLikeStdSort<uint64_t>(
        n, [&] { return rng() % 100; }, [] { return uint64_t{7}; });
    ExpectSortedLikeStdSort<uint64_t>(
        n, [&] { return rng() % 100; }, [&] { return rng() % (uint64_t{1} << 22); });
  }
}

TEST(PairSort, AllPairsEqualAndKeysThatAreNotIntegral) {
  std::mt19937_64 rng(7);
  ExpectSortedLikeStdSort<uint32_t>(5000, [] { return 42u; });
  ExpectSortedLikeStdSort<std::string>(3000, [&] { return std::to_string(rng() % 500); });
}

}  // namespace
}  // namespace bp::detail
