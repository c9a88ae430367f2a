// NewEngine's grid of segmented SAP cells (see engines_families.h).
#include "engines_families.h"

namespace bp::detail {

template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewGridSegmentedSap(const EngineSpec& spec, T margin) {
  return std::make_unique<GridSegmentedSap<K, T>>(spec.grid_segmented_sap, margin);
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewGridSegmentedSap<K, T>(const EngineSpec&, T);
BP_ENGINES_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::detail
