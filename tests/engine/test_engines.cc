// The engines of test_support.h: built by bp::NewEngine (compiled once, in bp_engines), except
// the single-structure engines on 3-D uint32 (the edge cases' unsigned coordinates), a shape the
// library does not build, compiled here.
#include <cstdio>
#include <cstdlib>

#include "test_support.h"

#include "bp/engines.h"

namespace bp::test {
namespace {

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> FromLibrary(const EngineSpec& spec) {
  std::unique_ptr<Broadphase<K, T>> engine = NewEngine<K, T>(spec);
  if (engine == nullptr) {
    std::fprintf(stderr, "bp::NewEngine does not know '%s'\n", spec.algorithm.c_str());
    std::abort();
  }
  return engine;
}

EngineSpec Named(const char* algorithm) {
  EngineSpec spec;
  spec.algorithm = algorithm;
  return spec;
}

}  // namespace

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewBruteForce() {
  if constexpr (EngineShape<K, T>) {
    return FromLibrary<K, T>(Named("brute_force"));
  } else {
    return std::make_unique<BruteForce<K, T>>();
  }
}
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSegmentedSap(const SegmentedSapOptions& options) {
  if constexpr (EngineShape<K, T>) {
    EngineSpec spec = Named("segmented_sap");
    spec.segmented_sap = options;
    return FromLibrary<K, T>(spec);
  } else {
    return std::make_unique<SegmentedSap<K, T>>(options);
  }
}
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewBatchSap(const BatchSapOptions& options) {
  if constexpr (EngineShape<K, T>) {
    EngineSpec spec = Named("batch_sap");
    spec.batch_sap = options;
    return FromLibrary<K, T>(spec);
  } else {
    return std::make_unique<BatchSap<K, T>>(options);
  }
}
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDynamicOctree(const DynamicOctreeOptions& options) {
  if constexpr (EngineShape<K, T>) {
    EngineSpec spec = Named("dynamic_octree");
    spec.dynamic_octree = options;
    return FromLibrary<K, T>(spec);
  } else {
    return std::make_unique<DynamicOctree<K, T>>(options);
  }
}

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSapCellGrid(const GridSpec& spec) {
  if (spec.cell == CellKind::kBatch) {
    EngineSpec engine = Named("grid_batch_sap");
    engine.grid_batch_sap = GridOptionsOf<GridBatchSapOptions>(spec);
    return FromLibrary<K, T>(engine);
  }
  EngineSpec engine = Named("grid_segmented_sap");
  engine.grid_segmented_sap = GridOptionsOf<GridSegmentedSapOptions>(spec);
  return FromLibrary<K, T>(engine);
}

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDenseGrid(const GridSpec& spec) {
  EngineSpec engine = Named("grid_dense");
  GridDenseOptions& options = engine.grid_dense;
  options = GridOptionsOf<GridDenseOptions>(spec);
  if (spec.cell == CellKind::kDensePortable) options.cell.kernel = DenseKernel::kPortable;
  if (spec.cell == CellKind::kDenseRows) options.cell.matrix_slots = 0;
  if (spec.cell == CellKind::kDenseSmallMatrix) {
    options.cell.matrix_slots = 32;
    options.cell.kernel = DenseKernel::kAvx2;  // so a CPU with AVX-512 checks AVX2 too
  }
  return FromLibrary<K, T>(engine);
}

#define BP_INSTANTIATE_SINGLE(K, T)                                                             \
  template std::unique_ptr<Broadphase<K, T>> NewBruteForce<K, T>();                             \
  template std::unique_ptr<Broadphase<K, T>> NewSegmentedSap<K, T>(const SegmentedSapOptions&); \
  template std::unique_ptr<Broadphase<K, T>> NewBatchSap<K, T>(const BatchSapOptions&);         \
  template std::unique_ptr<Broadphase<K, T>> NewDynamicOctree<K, T>(const DynamicOctreeOptions&);
#define BP_INSTANTIATE(K, T)                                                        \
  BP_INSTANTIATE_SINGLE(K, T)                                                       \
  template std::unique_ptr<Broadphase<K, T>> NewSapCellGrid<K, T>(const GridSpec&); \
  template std::unique_ptr<Broadphase<K, T>> NewDenseGrid<K, T>(const GridSpec&);
BP_TEST_FOR_EACH_SHAPE(BP_INSTANTIATE)
BP_INSTANTIATE_SINGLE(3, uint32_t)
#undef BP_INSTANTIATE
#undef BP_INSTANTIATE_SINGLE

}  // namespace bp::test
