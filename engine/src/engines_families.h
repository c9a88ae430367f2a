// The engine families of NewEngine (bp/engines.h), each compiled in a file of its own so that a
// build on two cores compiles them side by side.
#pragma once

#include <memory>

#include "bp/engines.h"

namespace bp::detail {

/// brute_force, segmented_sap, batch_sap, dynamic_octree; nullptr for any other name
/// (engines_single.cc).
template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewSingleEngine(const EngineSpec& spec, T margin);
/// grid_segmented_sap (engines_grid_segmented.cc).
template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewGridSegmentedSap(const EngineSpec& spec, T margin);
/// grid_batch_sap (engines_grid_batch.cc).
template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewGridBatchSap(const EngineSpec& spec, T margin);
/// grid_dense (engines_grid_dense.cc).
template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewGridDense(const EngineSpec& spec, T margin);

}  // namespace bp::detail
