// NewEngine's single-structure engines (see engines_families.h).
#include "engines_families.h"

namespace bp::detail {

template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewSingleEngine(const EngineSpec& spec, T margin) {
  if (spec.algorithm == "brute_force") {
    return std::make_unique<BruteForce<K, T>>(BruteForceOptions(), margin);
  }
  if (spec.algorithm == "segmented_sap") {
    return std::make_unique<SegmentedSap<K, T>>(spec.segmented_sap, margin);
  }
  if (spec.algorithm == "batch_sap") {
    return std::make_unique<BatchSap<K, T>>(spec.batch_sap, margin);
  }
  if (spec.algorithm == "dynamic_octree") {
    return std::make_unique<DynamicOctree<K, T>>(spec.dynamic_octree, margin);
  }
  return nullptr;
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewSingleEngine<K, T>(const EngineSpec&, T);
BP_ENGINES_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::detail
