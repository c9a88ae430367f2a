// The golden values of docs/WORKLOADS.md reproduced through the engines: pairs at frame 0 and
// at the end, collide/uncollide totals, final set hash and chain, for float, double and integer
// coordinates. Rows above 10k objects run only with BP_LONG_TESTS=1 (bpbench covers them). The
// engines come from bp::NewEngine (compiled once, in bp_engines), as the daemon's and bpbench's do.
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "bp/engines.h"
#include "bp/scene_runner.h"
#include "bp/workload_scenarios.h"

namespace bp::workload {
namespace {

bool LongTests() {
  const char* env = std::getenv("BP_LONG_TESTS");
  return env != nullptr && std::string(env) == "1";
}

template <int K, Coordinate T>
void ExpectGolden(Broadphase<K, T>& engine, const GoldenScenario& g) {
  SCOPED_TRACE(std::string(g.name) + " through " + engine.Name());
  ASSERT_EQ(K, g.dim);
  SceneRunner<K, T> runner(engine, g.Params());
  runner.Build();
  EXPECT_EQ(runner.pairs_frame0(), g.pairs_frame0);
  // Each Step's query validates the engine (BP_VALIDATE is on in the tests).
  for (uint32_t f = 1; f <= g.frames; ++f) runner.Step();
  EXPECT_EQ(runner.errors(), 0u) << runner.first_error();
  EXPECT_EQ(runner.pairs(), g.pairs_end);
  EXPECT_EQ(engine.GetStats().overlaps, g.pairs_end);
  EXPECT_EQ(runner.collides(), g.collides);
  EXPECT_EQ(runner.uncollides(), g.uncollides);
  EXPECT_EQ(runner.set_hash(), g.set_hash_end) << std::hex << runner.set_hash();
  EXPECT_EQ(runner.chain(), g.chain) << std::hex << runner.chain();
}

EngineSpec Spec(const char* algorithm) {
  EngineSpec spec;
  spec.algorithm = algorithm;
  return spec;
}

// The golden row `name` through the engine spec names.
template <int K, Coordinate T>
void ExpectGoldenThrough(const EngineSpec& spec, const char* name) {
  const GoldenScenario* g = FindGolden(name);
  ASSERT_NE(g, nullptr);
  std::unique_ptr<Broadphase<K, T>> engine = NewEngine<K, T>(spec);
  ASSERT_TRUE(engine != nullptr) << spec.algorithm;
  ExpectGolden<K, T>(*engine, *g);
}

template <int K, Coordinate T>
void ExpectGoldenSap(const char* name, const SegmentedSapOptions& options = {}) {
  EngineSpec spec = Spec("segmented_sap");
  spec.segmented_sap = options;
  ExpectGoldenThrough<K, T>(spec, name);
}

TEST(GoldenSegmentedSap, S2aFloat) { ExpectGoldenSap<3, float>("S2a"); }
TEST(GoldenSegmentedSap, S2aDouble) { ExpectGoldenSap<3, double>("S2a"); }
TEST(GoldenSegmentedSap, S2aInt32) { ExpectGoldenSap<3, int32_t>("S2a"); }
TEST(GoldenSegmentedSap, S2bFloat) { ExpectGoldenSap<3, float>("S2b"); }
TEST(GoldenSegmentedSap, S2cDouble) { ExpectGoldenSap<3, double>("S2c"); }
TEST(GoldenSegmentedSap, S1_10kFloat) { ExpectGoldenSap<3, float>("S1-10k"); }
TEST(GoldenSegmentedSap, S1_10kInt32) { ExpectGoldenSap<3, int32_t>("S1-10k"); }
TEST(GoldenSegmentedSap, Planar2DFloat) { ExpectGoldenSap<2, float>("2-D"); }
TEST(GoldenSegmentedSap, Planar2DDouble) { ExpectGoldenSap<2, double>("2-D"); }

TEST(GoldenSegmentedSap, TinyChunksAlwaysGlobalS2b) {
  SegmentedSapOptions options;
  options.chunk_capacity = 4;
  options.global_sort_fraction = 0;
  ExpectGoldenSap<3, float>("S2b", options);
}

// The default presorts S2c, S1-10k and 2-D (80..100 inserts + erases a frame) but not S2a and
// S2b: run each row through the other path too.
TEST(GoldenSegmentedSap, PresortedAlwaysS2aS2b) {
  SegmentedSapOptions options;
  options.presorted_min = 1;
  for (const char* name : {"S2a", "S2b"}) ExpectGoldenSap<3, float>(name, options);
}

TEST(GoldenSegmentedSap, PerEventS2cS1_10k) {
  SegmentedSapOptions options;
  options.presorted_min = 0;
  for (const char* name : {"S2c", "S1-10k"}) ExpectGoldenSap<3, float>(name, options);
}

TEST(GoldenSegmentedSap, TinyChunksPresortedS2c) {
  SegmentedSapOptions options;
  options.chunk_capacity = 4;
  options.presorted_min = 1;
  ExpectGoldenSap<3, float>("S2c", options);
}

TEST(GoldenSegmentedSap, LargeRows) {
  if (!LongTests()) GTEST_SKIP() << "set BP_LONG_TESTS=1 for S1-100k, S1-200k, S3, S4";
  for (const char* name : {"S4", "S1-100k", "S3", "S1-200k"}) ExpectGoldenSap<3, float>(name);
}

template <int K, Coordinate T>
void ExpectGoldenBatch(const char* name, const BatchSapOptions& options = {}) {
  EngineSpec spec = Spec("batch_sap");
  spec.batch_sap = options;
  ExpectGoldenThrough<K, T>(spec, name);
}

TEST(GoldenBatchSap, S2aFloat) { ExpectGoldenBatch<3, float>("S2a"); }
TEST(GoldenBatchSap, S2aDouble) { ExpectGoldenBatch<3, double>("S2a"); }
TEST(GoldenBatchSap, S2aInt32) { ExpectGoldenBatch<3, int32_t>("S2a"); }
TEST(GoldenBatchSap, S2bFloat) { ExpectGoldenBatch<3, float>("S2b"); }
TEST(GoldenBatchSap, S2cDouble) { ExpectGoldenBatch<3, double>("S2c"); }
TEST(GoldenBatchSap, S1_10kFloat) { ExpectGoldenBatch<3, float>("S1-10k"); }
TEST(GoldenBatchSap, S1_10kInt32) { ExpectGoldenBatch<3, int32_t>("S1-10k"); }
TEST(GoldenBatchSap, Planar2DFloat) { ExpectGoldenBatch<2, float>("2-D"); }
TEST(GoldenBatchSap, Planar2DDouble) { ExpectGoldenBatch<2, double>("2-D"); }

TEST(GoldenBatchSap, AlwaysLocalS2b) {
  BatchSapOptions options;
  options.global_sort_fraction = 1e300;  // local sort whenever no record is pending
  ExpectGoldenBatch<3, float>("S2b", options);
}

TEST(GoldenBatchSap, LargeRows) {
  if (!LongTests()) GTEST_SKIP() << "set BP_LONG_TESTS=1 for S1-100k, S1-200k, S3, S4";
  for (const char* name : {"S4", "S1-100k", "S3", "S1-200k"}) ExpectGoldenBatch<3, float>(name);
}

// The grid over each cell type: every S row of WORKLOADS.md (the rows above 10k objects with
// BP_LONG_TESTS=1), the automatic cell size, and small cells (size 4: objects span up to 8 cells
// and migrate often; size 1.5 with at most 4 cells per object: many objects are large).
EngineSpec SegmentedGrid(const GridSegmentedSapOptions& options = {}) {
  EngineSpec spec = Spec("grid_segmented_sap");
  spec.grid_segmented_sap = options;
  return spec;
}
EngineSpec BatchGrid(const GridBatchSapOptions& options = {}) {
  EngineSpec spec = Spec("grid_batch_sap");
  spec.grid_batch_sap = options;
  return spec;
}
EngineSpec DenseGrid(const GridDenseOptions& options = {}) {
  EngineSpec spec = Spec("grid_dense");
  spec.grid_dense = options;
  return spec;
}

TEST(GoldenGrid, SegmentedCellsAuto) {
  for (const char* name : {"S2a", "S2b", "S2c", "S1-10k"}) {
    ExpectGoldenThrough<3, float>(SegmentedGrid(), name);
  }
  ExpectGoldenThrough<2, double>(SegmentedGrid(), "2-D");
}

TEST(GoldenGrid, BatchCellsAuto) {
  for (const char* name : {"S2a", "S2b", "S2c", "S1-10k"}) {
    ExpectGoldenThrough<3, float>(BatchGrid(), name);
  }
  ExpectGoldenThrough<2, float>(BatchGrid(), "2-D");
}

TEST(GoldenGrid, DenseCellsAuto) {
  for (const char* name : {"S2a", "S2b", "S2c", "S1-10k"}) {
    ExpectGoldenThrough<3, float>(DenseGrid(), name);
  }
  GridDenseOptions few;
  few.objects_per_cell = 8;  // many small cells: migrations on most frames
  ExpectGoldenThrough<3, float>(DenseGrid(few), "S2c");
  ExpectGoldenThrough<2, double>(DenseGrid(), "2-D");
  ExpectGoldenThrough<3, int32_t>(DenseGrid(), "S2b");
}

TEST(GoldenGrid, Int32AndDouble) {
  ExpectGoldenThrough<3, int32_t>(SegmentedGrid(), "S2c");
  ExpectGoldenThrough<3, double>(BatchGrid(), "S1-10k");
}

TEST(GoldenGrid, SmallCellsAndLargeObjects) {
  GridSegmentedSapOptions small;
  small.cell_size = 4;
  ExpectGoldenThrough<3, float>(SegmentedGrid(small), "S2c");
  GridBatchSapOptions tiny;
  tiny.cell_size = 1.5;
  tiny.max_cells_per_object = 4;
  ExpectGoldenThrough<3, float>(BatchGrid(tiny), "S2b");
  GridDenseOptions dense_tiny;
  dense_tiny.cell_size = 1.5;
  dense_tiny.max_cells_per_object = 4;
  ExpectGoldenThrough<3, float>(DenseGrid(dense_tiny), "S2a");
}

TEST(GoldenGrid, LargeRows) {
  if (!LongTests()) GTEST_SKIP() << "set BP_LONG_TESTS=1 for S1-100k, S1-200k, S3, S4";
  for (const char* name : {"S4", "S1-100k", "S3", "S1-200k"}) {
    ExpectGoldenThrough<3, float>(SegmentedGrid(), name);
    ExpectGoldenThrough<3, float>(BatchGrid(), name);
    ExpectGoldenThrough<3, float>(DenseGrid(), name);
  }
}

template <int K, Coordinate T>
void ExpectGoldenOctree(const char* name, const DynamicOctreeOptions& options = {}) {
  EngineSpec spec = Spec("dynamic_octree");
  spec.dynamic_octree = options;
  ExpectGoldenThrough<K, T>(spec, name);
}

TEST(GoldenDynamicOctree, S2aFloat) { ExpectGoldenOctree<3, float>("S2a"); }
TEST(GoldenDynamicOctree, S2aDouble) { ExpectGoldenOctree<3, double>("S2a"); }
TEST(GoldenDynamicOctree, S2aInt32) { ExpectGoldenOctree<3, int32_t>("S2a"); }
TEST(GoldenDynamicOctree, S2bFloat) { ExpectGoldenOctree<3, float>("S2b"); }
TEST(GoldenDynamicOctree, S2cDouble) { ExpectGoldenOctree<3, double>("S2c"); }
TEST(GoldenDynamicOctree, S1_10kFloat) { ExpectGoldenOctree<3, float>("S1-10k"); }
TEST(GoldenDynamicOctree, S1_10kInt32) { ExpectGoldenOctree<3, int32_t>("S1-10k"); }
TEST(GoldenDynamicOctree, Planar2DFloat) { ExpectGoldenOctree<2, float>("2-D"); }
TEST(GoldenDynamicOctree, Planar2DDouble) { ExpectGoldenOctree<2, double>("2-D"); }

// One object per node, at most 6 levels: deep trees, overfull leaves at the depth limit.
TEST(GoldenDynamicOctree, TinyNodesS2c) {
  DynamicOctreeOptions options;
  options.max_objects_per_node = 1;
  options.max_depth = 6;
  ExpectGoldenOctree<3, float>("S2c", options);
}

TEST(GoldenDynamicOctree, LargeRows) {
  if (!LongTests()) GTEST_SKIP() << "set BP_LONG_TESTS=1 for S1-100k, S1-200k, S3, S4";
  for (const char* name : {"S4", "S1-100k", "S3", "S1-200k"}) ExpectGoldenOctree<3, float>(name);
}

TEST(GoldenBruteForce, S2aFloat) { ExpectGoldenThrough<3, float>(Spec("brute_force"), "S2a"); }

}  // namespace
}  // namespace bp::workload
