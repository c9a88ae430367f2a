// The single-structure engines of test_support.h, built once per shape.
#include "test_support.h"

namespace bp::test {

template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewBruteForce() {
  return std::make_unique<BruteForce<K, T>>();
}
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSegmentedSap(const SegmentedSapOptions& options) {
  return std::make_unique<SegmentedSap<K, T>>(options);
}
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewBatchSap(const BatchSapOptions& options) {
  return std::make_unique<BatchSap<K, T>>(options);
}
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDynamicOctree(const DynamicOctreeOptions& options) {
  return std::make_unique<DynamicOctree<K, T>>(options);
}

#define BP_INSTANTIATE(K, T)                                                                    \
  template std::unique_ptr<Broadphase<K, T>> NewBruteForce<K, T>();                             \
  template std::unique_ptr<Broadphase<K, T>> NewSegmentedSap<K, T>(const SegmentedSapOptions&); \
  template std::unique_ptr<Broadphase<K, T>> NewBatchSap<K, T>(const BatchSapOptions&);         \
  template std::unique_ptr<Broadphase<K, T>> NewDynamicOctree<K, T>(const DynamicOctreeOptions&);
BP_TEST_FOR_EACH_SHAPE(BP_INSTANTIATE)
BP_INSTANTIATE(3, uint32_t)
#undef BP_INSTANTIATE

}  // namespace bp::test
