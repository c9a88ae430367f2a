// bp::NewEngine: every engine of the library by name, compiled once, out of line.
//
// The engines are header-only templates; a translation unit that constructs one compiles all of
// it (a grid of dense cells is minutes of compiling under a sanitizer). NewEngine is compiled
// once, in the library broadphase::engines, for the six shapes below, so that a program that
// picks its engine at run time (the daemon, bpbench, the tests, the fuzz targets) sees the
// engines only as Broadphase<K, T> and compiles none of them again.
//
// Shapes: K = 2 or 3 axes; T = float, double or int32_t; keys uint64_t. For any other shape,
// construct the engine's class directly (bp/grid.h, bp/segmented_sap.h, ...).
//
// Every translation unit that instantiates an engine must agree on BP_VALIDATE (see
// engine/CMakeLists.txt): the library is compiled with this build's BP_VALIDATE, and its
// targets hand the define on. The same holds for NDEBUG where a program also constructs engine
// classes itself: build it as the library was built (both Release, say).
#pragma once

#include <array>
#include <concepts>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "bp/batch_sap.h"
#include "bp/broadphase.h"
#include "bp/brute_force.h"
#include "bp/dynamic_octree.h"
#include "bp/grid.h"
#include "bp/segmented_sap.h"

namespace bp {

/// The engines' names, as EngineSpec::algorithm spells them.
inline constexpr std::array<std::string_view, 7> kEngineAlgorithms = {
    "brute_force",        "segmented_sap",  "batch_sap", "dynamic_octree",
    "grid_segmented_sap", "grid_batch_sap", "grid_dense"};

/// The names of kEngineAlgorithms joined by ", " (for error messages).
std::string EngineAlgorithmList();

/// Which engine, and the options of each kind: only the chosen one's are read.
struct EngineSpec {
  std::string algorithm = "grid_dense";  // one of kEngineAlgorithms
  SegmentedSapOptions segmented_sap;
  BatchSapOptions batch_sap;
  DynamicOctreeOptions dynamic_octree;
  GridSegmentedSapOptions grid_segmented_sap;
  GridBatchSapOptions grid_batch_sap;
  GridDenseOptions grid_dense;
};

/// The shapes NewEngine is compiled for: K = 2, 3 and T = float, double, int32_t.
template <int K, class T>
concept EngineShape = (K == 2 || K == 3) && (std::same_as<T, float> || std::same_as<T, double> ||
                                             std::same_as<T, int32_t>);

/// The engine spec.algorithm names, with that kind's options and the given margin (in the
/// engine's units: every box is grown by it on each side, see the engines' constructors);
/// nullptr if no engine has that name.
template <int K, Coordinate T>
std::unique_ptr<Broadphase<K, T>> NewEngine(const EngineSpec& spec,
                                            T margin = T{}) requires EngineShape<K, T>;

#define BP_ENGINES_FOR_EACH_SHAPE(X) \
  X(2, float) X(3, float) X(2, double) X(3, double) X(2, int32_t) X(3, int32_t)

#define BP_ENGINES_DECLARE(K, T) \
  extern template std::unique_ptr<Broadphase<K, T>> NewEngine<K, T>(const EngineSpec&, T);
BP_ENGINES_FOR_EACH_SHAPE(BP_ENGINES_DECLARE)
#undef BP_ENGINES_DECLARE

}  // namespace bp
