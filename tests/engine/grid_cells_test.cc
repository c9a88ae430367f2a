// The grid's cell table (detail/grid_cells.h): coordinates far from the origin and cell indices
// that would overflow (clamped to the edge cells), one axis, integer extremes, cells created
// ahead of a moving population and recycled behind it, objects that pair with nothing kept out of
// the cells. Every scene runs against brute force.
#include <cstdint>
#include <string>
#include <vector>

#include "grid_test_support.h"

namespace bp::test {
namespace {

TEST(Grid, FarFromTheOriginFloat) {
  for (double origin : {1e6, -1e6, 1e30, -1e30, 3e38}) {
    for (double unit : {1.0, origin * 1e-5}) {
      GridSegmentedSapOptions options;
      options.cell_size = 1.0;  // cell indices far beyond 2^20: clamped into the edge cells
      GridSegmentedSap<3, float> engine(options);
      RandomScene<3, float>(&engine, origin, unit < 0 ? -unit : unit, 7);
      GridBatchSap<2, float> automatic;
      RandomScene<2, float>(&automatic, origin, unit < 0 ? -unit : unit, 8);
    }
  }
}

TEST(Grid, FarFromTheOriginDouble) {
  for (double origin : {1e12, -1e12, 1e300, -1e300}) {
    GridBatchSapOptions options;
    options.cell_size = 0.5;
    GridBatchSap<3, double> engine(options);
    RandomScene<3, double>(&engine, origin, origin > 0 ? origin * 1e-6 : -origin * 1e-6, 9);
    GridSegmentedSapOptions fine_options;
    fine_options.cell_size = 0.5;
    GridSegmentedSap<3, double> fine(fine_options);
    RandomScene<3, double>(&fine, origin, 1.0, 10);
  }
}

// One axis: 63 bits of cell coordinate (kLimit 2^62), where CellOf cannot take the rounded
// offset it uses for two axes and more (2^62 + q loses the quotient's low bits and overflows
// int64 at the top clamp). Exact against brute force near the origin and far beyond the clamped
// cell range, and the automatic size still makes cells of a few objects each.
TEST(Grid, OneAxis) {
  for (double origin : {0.0, 1e12, -1e12, 1e300, -1e300}) {
    GridDenseOptions options;
    options.cell_size = 1.0;  // far from the origin: indices beyond 2^62, clamped
    GridDense<1, double> engine(options);
    RandomScene<1, double>(&engine, origin, origin == 0 ? 1.0 : std::abs(origin) * 1e-6, 12);
    GridDenseOptions few;
    few.objects_per_cell = 8;  // 120 objects over 18 units: cells of about 1.2
    GridDense<1, float> automatic(few);
    RandomScene<1, float>(&automatic, 0.0, 1.0, 13);
    EXPECT_GE(automatic.GetStats().grid.value().cells, 8u) << origin;
  }
}

TEST(Grid, IntegerExtremes) {
  GridSegmentedSapOptions options;
  options.cell_size = 3;
  GridSegmentedSap<2, int32_t> engine(options);
  Twin<2, int32_t, GridSegmentedSap<2, int32_t>> twin(&engine);
  const int32_t lo = std::numeric_limits<int32_t>::lowest();
  const int32_t hi = std::numeric_limits<int32_t>::max();
  twin.Insert(1, Box<2, int32_t>{{lo, lo}, {lo + 2, lo + 2}});
  twin.Insert(2, Box<2, int32_t>{{hi - 2, hi - 2}, {hi, hi}});
  twin.Insert(3, Box<2, int32_t>{{lo, lo}, {hi, hi}});  // everything: a large object
  twin.Insert(4, Box<2, int32_t>{{lo + 1, lo + 1}, {lo + 1, lo + 1}});
  twin.Query();
  EXPECT_EQ(engine.GetStats().grid.value().large_objects, 1u);
  twin.Update(4, Box<2, int32_t>{{hi - 1, hi - 1}, {hi, hi}});  // across the whole range
  twin.Query();
  twin.Update(3, Box<2, int32_t>{{0, 0}, {1, 1}});  // large becomes small
  twin.Query();
  EXPECT_EQ(engine.GetStats().grid.value().large_objects, 0u);
  twin.Erase(1);
  twin.Erase(2);
  twin.Query();
}

TEST(Grid, CellsAreCreatedAndRecycled) {
  GridSegmentedSapOptions options;
  options.cell_size = 10;
  GridSegmentedSap<3, float> engine(options);
  Twin<3, float, GridSegmentedSap<3, float>> twin(&engine);
  for (uint64_t i = 0; i < 50; ++i) twin.Insert(i, CubeAt<3, float>(static_cast<float>(i), 1));
  twin.Query();
  const size_t cells = engine.GetStats().grid.value().cells;
  EXPECT_GE(cells, 6u);
  // March the whole population far away, a little each frame: cells are created ahead and
  // recycled behind, so their number stays bounded.
  for (int f = 1; f <= 40; ++f) {
    for (uint64_t i = 0; i < 50; ++i) {
      twin.Update(i, CubeAt<3, float>(static_cast<float>(i) + 25.0f * static_cast<float>(f), 1));
    }
    twin.Query();
    EXPECT_LE(engine.GetStats().grid.value().cells, cells + 8) << "frame " << f;
  }
  for (uint64_t i = 0; i < 50; ++i) twin.Erase(i);
  twin.Query();
  EXPECT_EQ(engine.GetStats().grid.value().cells, 0u);
  EXPECT_EQ(engine.Size(), 0u);
}

// An object whose options accept no object (mask 0 or category 0) lives in its record only: a
// grid of nothing else has no cell, and a mixed one reports what brute force does while such
// objects move, leave, come back paired (a rekey) and paired ones turn unpaired.
TEST(Grid, ObjectsThatPairWithNothingStayOutOfTheCells) {
  const ObjectOptions unpaired{.mask = 0}, no_category{.category = 0};
  GridDense<3, float> alone;
  ASSERT_TRUE(alone.Insert(1, CubeAt<3, float>(0, 1), unpaired).ok());
  ASSERT_TRUE(alone.Insert(2, CubeAt<3, float>(0.5f, 1), no_category).ok());
  RecordingSink<uint64_t> sink;
  alone.Query(sink);
  EXPECT_TRUE(sink.collides.empty());
  EXPECT_EQ(alone.GetStats().grid.value().cells, 0u);
  EXPECT_EQ(alone.Size(), 2u);

  GridDense<3, float> engine;
  BruteForce<3, float> oracle;
  std::mt19937_64 rng(21);
  const auto box = [&] {
    return CubeAt<3, float>(std::uniform_real_distribution<float>(0, 30)(rng), 2);
  };
  const auto options = [&](uint64_t k) { return k % 3 == 0 ? unpaired : ObjectOptions{}; };
  for (uint64_t k = 0; k < 300; ++k) {
    const Box<3, float> b = box();
    ASSERT_TRUE(engine.Insert(k, b, options(k)).ok());
    ASSERT_TRUE(oracle.Insert(k, b, options(k)).ok());
  }
  size_t events = 0;
  for (int f = 0; f < 25; ++f) {
    RecordingSink<uint64_t> got, want;
    engine.Query(got);
    oracle.Query(want);
    ASSERT_EQ(got.collides, want.collides) << "frame " << f;
    ASSERT_EQ(got.uncollides, want.uncollides) << "frame " << f;
    events += got.collides.size() + got.uncollides.size();
    for (uint64_t k = 0; k < 300; ++k) {
      const Box<3, float> b = box();
      switch (rng() % 8) {
        case 0: {  // back with the other options: paired turns unpaired, or the other way
          const ObjectOptions o =
              (k + static_cast<uint64_t>(f)) % 2 == 0 ? unpaired : ObjectOptions{};
          ASSERT_TRUE(engine.Erase(k).ok());
          ASSERT_TRUE(oracle.Erase(k).ok());
          ASSERT_TRUE(engine.Insert(k, b, o).ok());
          ASSERT_TRUE(oracle.Insert(k, b, o).ok());
          break;
        }
        case 1:
        case 2:
          ASSERT_TRUE(engine.Update(k, b).ok());
          ASSERT_TRUE(oracle.Update(k, b).ok());
          break;
        default:
          break;
      }
    }
  }
  EXPECT_GT(events, 200u);
}

}  // namespace
}  // namespace bp::test
