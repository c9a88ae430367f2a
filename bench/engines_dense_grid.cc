// bpbench's grid of dense cells (see engines.h).
#include "engines.h"

namespace bp::bench {

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDenseGrid(const EngineChoice& choice, T margin) {
  return std::make_unique<GridDense<K, T>>(choice.grid_dense, margin);
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewDenseGrid<K, T>(const EngineChoice&, T);
BP_BENCH_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::bench
