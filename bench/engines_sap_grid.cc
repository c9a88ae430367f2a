// bpbench's grids of segmented and batch SAP cells (see engines.h).
#include "engines.h"

namespace bp::bench {

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSapCellGrid(const EngineChoice& choice, T margin) {
  if (choice.engine == "grid_batch_sap") {
    return std::make_unique<GridBatchSap<K, T>>(choice.grid_batch, margin);
  }
  return std::make_unique<GridSegmentedSap<K, T>>(choice.grid_sap, margin);
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewSapCellGrid<K, T>(const EngineChoice&, T);
BP_BENCH_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::bench
