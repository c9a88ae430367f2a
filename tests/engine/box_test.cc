// IsValidBox (branch-free, inline) against the rule it implements, and ValidateBox's messages,
// on the values at the edges of float, double, long double, int32, int64 and uint32: NaN, both
// infinities, the largest finite values, signed zeros, subnormals, and the integer limits.
#include "bp/box.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace bp {
namespace {

// The rule, spelled out with branches: on every axis lo <= hi and, for floating T, both finite.
template <int K, class T>
bool ValidByRule(const Box<K, T>& box) {
  for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(box.lo[a]) || !std::isfinite(box.hi[a])) return false;
    }
    if (!(box.lo[a] <= box.hi[a])) return false;
  }
  return true;
}

template <class T>
std::vector<T> EdgeValues() {
  using L = std::numeric_limits<T>;
  std::vector<T> v = {L::lowest(), L::max(), T{0}, T{1}, static_cast<T>(-1)};
  if constexpr (std::is_floating_point_v<T>) {
    v.insert(v.end(), {L::quiet_NaN(), L::infinity(), -L::infinity(), L::denorm_min(),
                       -L::denorm_min(), static_cast<T>(-0.0), std::nextafter(L::max(), T{0})});
  } else {
    v.push_back(static_cast<T>(L::lowest() + 1));
  }
  return v;
}

template <class T>
void CheckEveryPairOnEachAxis() {
  const std::vector<T> values = EdgeValues<T>();
  for (T lo : values) {
    for (T hi : values) {
      for (size_t axis = 0; axis < 2; ++axis) {
        Box<2, T> box{{T{0}, T{0}}, {T{1}, T{1}}};
        box.lo[axis] = lo;
        box.hi[axis] = hi;
        const bool want = ValidByRule(box);
        SCOPED_TRACE("axis " + std::to_string(axis) + ": lo " + std::to_string(lo) + ", hi " +
                     std::to_string(hi));
        EXPECT_EQ(IsValidBox(box), want);
        const Status s = ValidateBox(box);
        EXPECT_EQ(s.ok(), want) << s.ToString();
        if (!want) {
          EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
          EXPECT_NE(s.message().find("axis " + std::to_string(axis)), std::string::npos)
              << s.message();
        }
      }
    }
  }
}

TEST(Box, IsValidBoxFollowsTheRuleAtTheEdgesOfFloat) { CheckEveryPairOnEachAxis<float>(); }
TEST(Box, IsValidBoxFollowsTheRuleAtTheEdgesOfDouble) { CheckEveryPairOnEachAxis<double>(); }
TEST(Box, IsValidBoxFollowsTheRuleAtTheEdgesOfInt32) { CheckEveryPairOnEachAxis<int32_t>(); }
TEST(Box, IsValidBoxFollowsTheRuleAtTheEdgesOfInt64) { CheckEveryPairOnEachAxis<int64_t>(); }
TEST(Box, IsValidBoxFollowsTheRuleAtTheEdgesOfUint32) { CheckEveryPairOnEachAxis<uint32_t>(); }
TEST(Box, IsValidBoxFollowsTheRuleAtTheEdgesOfLongDouble) {
  CheckEveryPairOnEachAxis<long double>();
}

TEST(Box, ValidateBoxNamesTheFirstBadAxisAndTheReason) {
  constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
  constexpr float kInf = std::numeric_limits<float>::infinity();
  EXPECT_EQ(ValidateBox(Box<3, float>{{0, 0, kNaN}, {1, 1, 1}}).message(),
            "NaN coordinate on axis 2");
  EXPECT_EQ(ValidateBox(Box<3, float>{{0, -kInf, 0}, {1, 1, 1}}).message(),
            "infinite coordinate on axis 1");
  EXPECT_EQ(ValidateBox(Box<3, float>{{2, 0, 0}, {1, 1, 1}}).message(), "lo > hi on axis 0");
  // Two bad axes: the first is named; on one axis NaN is named before infinity and inversion.
  EXPECT_EQ(ValidateBox(Box<3, float>{{0, 3, kNaN}, {1, 2, 1}}).message(), "lo > hi on axis 1");
  EXPECT_EQ(ValidateBox(Box<1, float>{{kInf}, {kNaN}}).message(), "NaN coordinate on axis 0");
  EXPECT_TRUE(ValidateBox(Box<3, float>{{-0.0f, 0, 0}, {0.0f, 0, 0}}).ok());  // a point
}

}  // namespace
}  // namespace bp
