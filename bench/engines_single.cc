// bpbench's single-structure engines (see engines.h).
#include "engines.h"

namespace bp::bench {

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSingleEngine(const EngineChoice& choice, T margin) {
  if (choice.engine == "brute_force") {
    return std::make_unique<BruteForce<K, T>>(BruteForceOptions(), margin);
  }
  if (choice.engine == "dynamic_octree") {
    return std::make_unique<DynamicOctree<K, T>>(choice.octree, margin);
  }
  if (choice.engine == "batch_sap") return std::make_unique<BatchSap<K, T>>(choice.batch, margin);
  return std::make_unique<SegmentedSap<K, T>>(choice.sap, margin);
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewSingleEngine<K, T>(const EngineChoice&, T);
BP_BENCH_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::bench
