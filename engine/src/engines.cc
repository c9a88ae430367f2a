#include "bp/engines.h"

#include "engines_families.h"

namespace bp {

std::string EngineAlgorithmList() {
  std::string list;
  for (std::string_view name : kEngineAlgorithms) {
    if (!list.empty()) list += ", ";
    list += name;
  }
  return list;
}

template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewEngine(const EngineSpec& spec,
                                            T margin) requires EngineShape<K, T> {
  if (spec.algorithm == "grid_dense") return detail::NewGridDense<K, T>(spec, margin);
  if (spec.algorithm == "grid_segmented_sap")
    return detail::NewGridSegmentedSap<K, T>(spec, margin);
  if (spec.algorithm == "grid_batch_sap") return detail::NewGridBatchSap<K, T>(spec, margin);
  return detail::NewSingleEngine<K, T>(spec, margin);
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewEngine<K, T>(const EngineSpec&, T);
BP_ENGINES_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp
