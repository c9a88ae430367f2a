// The grid's automatic cell size (detail/grid_sizing.h): following the population, after a
// first fill of points, and small cells for a world far from zero. Against brute force.
#include <cstdint>
#include <string>
#include <vector>

#include "grid_test_support.h"

namespace bp::test {
namespace {

// Cells are counted from an origin at the middle of the first objects, so a world far from zero
// gets the cells it would get at zero (not one cell per 2^-20 of the coordinates' magnitude,
// which would be a single cell at 1e12), and stays exact.
TEST(Grid, FarWorldKeepsSmallAutomaticCells) {
  for (double origin : {0.0, 1e12, -1e12}) {
    GridDense<3, double> engine;
    RandomScene<3, double>(&engine, origin, 1.0, 11);
    const Stats stats = engine.GetStats();
    EXPECT_GT(stats.grid.value().cell_size, 0.5) << origin;
    EXPECT_LT(stats.grid.value().cell_size, 16.0) << origin;
  }
}

TEST(Grid, AutomaticSizeFollowsThePopulation) {
  GridBatchSap<3, float> engine;  // automatic size
  Twin<3, float, GridBatchSap<3, float>> twin(&engine);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> pos(0, 60);
  uint64_t key = 0;
  for (int i = 0; i < 20; ++i) twin.Insert(key++, CubeAt<3, float>(pos(rng), 1));
  twin.Query();
  const double first = engine.GetStats().grid.value().cell_size;
  bool rebuilt = false;
  for (int f = 0; f < 8; ++f) {               // 20 to 5120 objects
    int n = static_cast<int>(engine.Size());  // double the population each frame
    for (int i = 0; i < n; ++i) twin.Insert(key++, CubeAt<3, float>(pos(rng), 1));
    twin.Update(0, CubeAt<3, float>(pos(rng), 1));
    twin.Query();
    rebuilt = rebuilt || engine.GetStats().rebuilt;
  }
  EXPECT_TRUE(rebuilt);
  EXPECT_LT(engine.GetStats().grid.value().cell_size, first / 2);  // denser world: smaller cells
  EXPECT_GE(engine.GetStats().grid.value().cells, 8u);             // one cell at first
}

TEST(Grid, AutomaticSizeAfterAFirstFillOfPoints) {
  GridSegmentedSap<3, float> engine;  // automatic size, from 200 points at one spot
  Twin<3, float, GridSegmentedSap<3, float>> twin(&engine);
  for (uint64_t i = 0; i < 200; ++i) twin.Insert(i, CubeAt<3, float>(5, 0));
  twin.Query();
  EXPECT_GE(engine.GetStats().grid.value().cell_size, 5 * 0x1p-20);  // not a denormal
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<float> pos(0, 40);
  for (uint64_t i = 0; i < 200; ++i) twin.Update(i, CubeAt<3, float>(pos(rng), 1));
  twin.Query();  // exact, though the boxes crowd the clamped edge cells or are large
  for (uint64_t i = 200; i < 1000; ++i) twin.Insert(i, CubeAt<3, float>(pos(rng), 1));
  twin.Query();  // the population grew fourfold: sized again from the spread boxes
  EXPECT_TRUE(engine.GetStats().rebuilt);
  EXPECT_EQ(engine.GetStats().grid.value().large_objects, 0u);
  EXPECT_GE(engine.GetStats().grid.value().cell_size, 1.0);
  for (uint64_t i = 0; i < 1000; i += 3) twin.Update(i, CubeAt<3, float>(pos(rng), 1));
  twin.Query();
}

}  // namespace
}  // namespace bp::test
