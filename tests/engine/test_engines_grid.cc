// Grids of segmented and batch SAP cells for test_support.h, built once per shape.
#include "test_support.h"

namespace bp::test {

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSapCellGrid(const GridSpec& spec) {
  if (spec.cell == CellKind::kBatch) {
    return std::make_unique<GridBatchSap<K, T>>(GridOptionsOf<GridBatchSapOptions>(spec));
  }
  return std::make_unique<GridSegmentedSap<K, T>>(GridOptionsOf<GridSegmentedSapOptions>(spec));
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewSapCellGrid<K, T>(const GridSpec&);
BP_TEST_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::test
