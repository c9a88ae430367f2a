// The grid's large-object set (detail/grid_large.h): world-sized boxes, transitions between
// small and large, an object turning large in the middle of a query, small objects leaving the
// range the bins were laid over and large ones moving with them, bins crowded with large
// objects, the room kept for a scan's changes. Against brute force.
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "grid_test_support.h"

namespace bp::test {
namespace {

TEST(Grid, LargeObjectsAgainstTheGrid) {
  GridSegmentedSapOptions options;
  options.cell_size = 4;
  options.max_cells_per_object = 8;
  GridSegmentedSap<3, float> engine(options);
  Twin<3, float, GridSegmentedSap<3, float>> twin(&engine);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> pos(0, 40);
  for (uint64_t i = 0; i < 400; ++i) twin.Insert(i, CubeAt<3, float>(pos(rng), 1));
  twin.Insert(1000, CubeAt<3, float>(-1e30f, 2e30f));  // the world
  for (uint64_t i = 0; i < 10; ++i) twin.Insert(1001 + i, CubeAt<3, float>(pos(rng), 12));
  twin.Query();
  EXPECT_EQ(engine.GetStats().grid.value().large_objects, 11u);
  for (int f = 0; f < 30 && !HasFailure(); ++f) {
    for (uint64_t i = 0; i < 400; i += 3) twin.Update(i, CubeAt<3, float>(pos(rng), 1));
    twin.Update(1001 + static_cast<uint64_t>(f % 10), CubeAt<3, float>(pos(rng), 12));
    if (f % 5 == 0) {
      // A small object grows into a large one and a large one shrinks into a small one.
      twin.Update(7, CubeAt<3, float>(pos(rng), 15));
      twin.Update(1003, CubeAt<3, float>(pos(rng), 1));
    }
    if (f % 7 == 0) {
      twin.Erase(1001);
      twin.Insert(1001, CubeAt<3, float>(pos(rng), 20));
    }
    if (f == 20) twin.Erase(1000);
    twin.Query();
  }
}

// With no large object when a query starts, the cells allocate the local handles of the objects
// that enter them only when they are applied. An object that turns large in that query ends the
// deferral, so that its scan of the cells' tables finds the objects that entered them before it
// in the same query (here: one migrated, one inserted by an erase and re-insert, both under it).
TEST(Grid, ObjectTurningLargeMidQuerySeesObjectsThatEnteredCellsBefore) {
  for (unsigned threads : {1u, 2u}) {
    GridDenseOptions options;
    options.cell_size = 4;
    options.max_cells_per_object = 8;  // a unit cube spans 8 cells at most
    options.threads = threads;
    GridDense<3, float> engine(options);
    Twin<3, float, GridDense<3, float>> twin(&engine);
    for (uint64_t i = 0; i < 8; ++i) {
      const float x = 40.0f + 6.0f * static_cast<float>(i);
      twin.Insert(i, CubeAt<3, float>(x, 1));
    }
    twin.Query();
    EXPECT_EQ(engine.GetStats().grid.value().large_objects, 0u);
    twin.Update(1, CubeAt<3, float>(9.5f, 1));  // migrates into cells nobody held
    twin.Erase(2);
    twin.Insert(2, CubeAt<3, float>(13, 1));
    twin.Update(3, CubeAt<3, float>(0, 30));  // turns large over both
    twin.Update(4, CubeAt<3, float>(17, 1));  // migrates after it
    twin.Insert(9, CubeAt<3, float>(21, 1));  // inserted after it
    twin.Query();
    EXPECT_EQ(engine.GetStats().grid.value().large_objects, 1u);
    EXPECT_TRUE(engine.Validate().ok()) << engine.Validate().message();
    twin.Update(3, CubeAt<3, float>(0, 1));  // small again: the deferral resumes next query
    twin.Update(1, CubeAt<3, float>(0.5f, 1.5f));
    twin.Query();
    twin.Update(5, CubeAt<3, float>(1, 2));
    twin.Query();
    EXPECT_TRUE(engine.Validate().ok()) << engine.Validate().message();
  }
}

// The bins are laid over the cells in use when a large object changes; small objects that
// march far beyond that range land in the edge bins, and large objects that move along are
// binned again. Every query against brute force.
TEST(Grid, LargeObjectsFollowObjectsBeyondTheBins) {
  GridDenseOptions options;
  options.cell_size = 2;
  options.max_cells_per_object = 8;
  GridDense<3, float> engine(options);
  Twin<3, float, GridDense<3, float>> twin(&engine);
  for (uint64_t i = 0; i < 60; ++i) {
    twin.Insert(i, CubeAt<3, float>(static_cast<float>(i % 20), 1));
  }
  twin.Insert(100, CubeAt<3, float>(0, 12));   // large, stays
  twin.Insert(101, CubeAt<3, float>(-4, 10));  // large, moves with the population
  twin.Query();
  EXPECT_EQ(engine.GetStats().grid.value().large_objects, 2u);
  for (int f = 1; f <= 30 && !::testing::Test::HasFailure(); ++f) {
    const float shift = 3.0f * static_cast<float>(f);
    for (uint64_t i = 0; i < 60; ++i) {
      if (i % 3 != 0 || f % 5 != 0) {  // every fifth frame, a third stays (bins untouched)
        twin.Update(i, CubeAt<3, float>(static_cast<float>(i % 20) + shift, 1));
      }
    }
    if (f % 5 != 0) twin.Update(101, CubeAt<3, float>(shift - 4, 10));
    twin.Query();
  }
  EXPECT_GT(twin.events(), 100u);
}

// Many large objects over a few bins: each bin lists several blocks of them, and most small
// objects' old and new cell ranges straddle bins, where a large object listed in several of
// those bins must count once. Small objects walk, churn and grow into large ones; some large
// ones move, shrink or leave. Every query against brute force, in 3-D float and 2-D double.
template <int K, class T, class Engine>
void CrowdedBins(Engine* engine) {
  Twin<K, T, Engine> twin(engine);
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<T> pos(0, 40), step(-1.5, 1.5);
  std::vector<T> at(300);
  for (uint64_t i = 0; i < at.size(); ++i) {
    at[i] = pos(rng);
    twin.Insert(i, CubeAt<K, T>(at[i], 1));
  }
  for (uint64_t i = 0; i < 70; ++i) twin.Insert(1000 + i, CubeAt<K, T>(pos(rng), 14));
  twin.Query();
  EXPECT_EQ(engine->GetStats().grid.value().large_objects, 70u);
  for (int f = 0; f < 25 && !::testing::Test::HasFailure(); ++f) {
    for (uint64_t i = 0; i < at.size(); i += 2) {
      at[i] += step(rng);
      twin.Update(i, CubeAt<K, T>(at[i], 1));
    }
    const uint64_t churn = 1 + static_cast<uint64_t>(f) * 7 % at.size();
    twin.Erase(churn);
    twin.Insert(churn, CubeAt<K, T>(at[churn], 1));
    if (f % 6 == 1) twin.Update(1000 + static_cast<uint64_t>(f), CubeAt<K, T>(pos(rng), 14));
    if (f % 6 == 3) twin.Update(3, CubeAt<K, T>(at[3], 16));  // grows large, then shrinks
    if (f % 6 == 4) twin.Update(3, CubeAt<K, T>(at[3], 1));
    if (f == 12) twin.Erase(1050);
    twin.Query();
  }
  EXPECT_TRUE(engine->Validate().ok()) << engine->Validate().message();
  EXPECT_GT(twin.events(), 500u);
}

TEST(Grid, CrowdedLargeObjectBinsCountEachPairOnce) {
  GridDenseOptions dense;
  dense.cell_size = 2;
  dense.max_cells_per_object = 8;
  // Every block-test kernel this CPU runs gives the same events.
  for (detail::BlockKernel k :
       {detail::BlockKernel::kWide, detail::BlockKernel::kAvx2, detail::BlockKernel::kPortable}) {
    if ((k == detail::BlockKernel::kWide && !detail::CpuHasAvx512()) ||
        (k == detail::BlockKernel::kAvx2 && !detail::CpuHasAvx2())) {
      continue;
    }
    SCOPED_TRACE(static_cast<int>(k));
    GridDense<3, float> dense_engine(dense);
    detail::GridTestPeer::SetBlockKernel(
        const_cast<detail::GridCore<detail::DenseCellCore<3, float>>&>(dense_engine.core()), k);
    CrowdedBins<3, float>(&dense_engine);
  }
  GridSegmentedSapOptions sap;
  sap.cell_size = 2;
  sap.max_cells_per_object = 8;
  GridSegmentedSap<2, double> sap_engine(sap);
  CrowdedBins<2, double>(&sap_engine);
}

// A small object that crosses the whole world in each query, with thin large objects listed in
// every bin: the room the large set makes for a scan's changes stays bounded by the large
// objects' count, not by the bins the object's range spans times their blocks.
TEST(Grid, ObjectCrossingCrowdedBinsKeepsTheLargeChangeRoomSmall) {
  GridDenseOptions options;
  options.cell_size = 1;
  options.max_cells_per_object = 8;
  GridDense<3, float> engine(options);
  Twin<3, float, GridDense<3, float>> twin(&engine);
  std::mt19937_64 rng(12);
  std::uniform_real_distribution<float> pos(0, 63);
  constexpr uint64_t kStrips = 600;
  for (uint64_t i = 0; i < kStrips; ++i) {  // along the first axis, thin on the others
    const float y = pos(rng), z = pos(rng);
    twin.Insert(100 + i, Box<3, float>{{0, y, z}, {64, y + 0.5f, z + 0.5f}});
  }
  // Small objects over the whole world, which the bins are laid over (the cells in use).
  for (uint64_t i = 0; i < 20; ++i) twin.Insert(10 + i, CubeAt<3, float>(pos(rng), 1));
  twin.Insert(30, CubeAt<3, float>(0, 1));
  twin.Insert(31, CubeAt<3, float>(63, 1));
  twin.Insert(1, CubeAt<3, float>(0.5f, 1));
  twin.Query();
  for (int f = 0; f < 6 && !::testing::Test::HasFailure(); ++f) {
    twin.Update(1, CubeAt<3, float>(f % 2 == 0 ? 62.0f : 0.5f, 1));
    twin.Query();
  }
  EXPECT_EQ(engine.GetStats().grid.value().large_objects, kStrips);
  EXPECT_LE(detail::GridTestPeer::LargeChangeRoom(engine.core()), 2 * kStrips);
  EXPECT_TRUE(engine.Validate().ok()) << engine.Validate().message();
}

}  // namespace
}  // namespace bp::test
