// NewEngine's grid of batch SAP cells (see engines_families.h).
#include "engines_families.h"

namespace bp::detail {

template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewGridBatchSap(const EngineSpec& spec, T margin) {
  return std::make_unique<GridBatchSap<K, T>>(spec.grid_batch_sap, margin);
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewGridBatchSap<K, T>(const EngineSpec&, T);
BP_ENGINES_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::detail
