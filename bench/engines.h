// The engines bpbench builds, constructed out of line: each family is compiled in a file of its
// own (engines_*.cc) for the six shapes bpbench runs (2-D and 3-D; float, double, int32), so
// that a build on two cores compiles them side by side. In one file with the rest of bpbench
// they took 12 minutes to compile under ASan, the last and longest step of CI's ASan build.
#pragma once

#include <memory>
#include <string>

#include "bp/batch_sap.h"
#include "bp/broadphase.h"
#include "bp/brute_force.h"
#include "bp/dynamic_octree.h"
#include "bp/grid.h"
#include "bp/segmented_sap.h"

namespace bp::bench {

/// Which engine, and the options of each kind (only the chosen one's are read).
struct EngineChoice {
  std::string engine;  // segmented_sap, batch_sap, dynamic_octree, brute_force or grid_*
  SegmentedSapOptions sap;
  BatchSapOptions batch;
  DynamicOctreeOptions octree;
  GridSegmentedSapOptions grid_sap;
  GridBatchSapOptions grid_batch;
  GridDenseOptions grid_dense;
};

/// The single-structure engines: brute_force, dynamic_octree, batch_sap, else segmented_sap
/// (engines_single.cc).
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSingleEngine(const EngineChoice& choice, T margin);
/// grid_segmented_sap and grid_batch_sap (engines_sap_grid.cc).
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewSapCellGrid(const EngineChoice& choice, T margin);
/// grid_dense (engines_dense_grid.cc).
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewDenseGrid(const EngineChoice& choice, T margin);

/// The engine of choice; margin is in the engine's units.
template <int K, class T>
std::unique_ptr<Broadphase<K, T>> NewEngine(const EngineChoice& choice, T margin) {
  if (choice.engine == "grid_dense") return NewDenseGrid<K, T>(choice, margin);
  if (choice.engine == "grid_segmented_sap" || choice.engine == "grid_batch_sap") {
    return NewSapCellGrid<K, T>(choice, margin);
  }
  return NewSingleEngine<K, T>(choice, margin);
}

#define BP_BENCH_FOR_EACH_SHAPE(X) \
  X(2, float) X(3, float) X(2, double) X(3, double) X(2, int32_t) X(3, int32_t)

}  // namespace bp::bench
