// Grids of dense cells (the widest kernel the CPU has, the portable one, or, with the matrix
// capped low, AVX2 where the CPU has it; the pair matrix as by default, never, or capped low) for
// test_support.h, built once per shape.
#include "test_support.h"

namespace bp::test {

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDenseGrid(const GridSpec& spec) {
  auto options = GridOptionsOf<GridDenseOptions>(spec);
  if (spec.cell == CellKind::kDensePortable) options.cell.kernel = DenseKernel::kPortable;
  if (spec.cell == CellKind::kDenseRows) options.cell.matrix_slots = 0;
  if (spec.cell == CellKind::kDenseSmallMatrix) {
    options.cell.matrix_slots = 32;
    options.cell.kernel = DenseKernel::kAvx2;  // so a CPU with AVX-512 checks AVX2 too
  }
  return std::make_unique<GridDense<K, T>>(options);
}

#define BP_INSTANTIATE(K, T) \
  template std::unique_ptr<Broadphase<K, T>> NewDenseGrid<K, T>(const GridSpec&);
BP_TEST_FOR_EACH_SHAPE(BP_INSTANTIATE)
#undef BP_INSTANTIATE

}  // namespace bp::test
