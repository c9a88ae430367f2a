// bp::GridOptions: the tuning of the grid (bp/grid.h), apart from the grid itself so that a
// caller that only configures a grid (the engine registry, a config reader) needs no engine.
#pragma once

#include <cstddef>
#include <cstdint>

namespace bp {

struct DenseCellOptions;

/// The objects per cell the automatic size aims at, by cell type: about 300 for SAP cells (the
/// paper's finding on uniform scenes), 32 for dense cells (measured on S1-200k, S3 and S4:
/// docs/TUNING.md).
template <class CellOptions>
inline constexpr double kDefaultObjectsPerCell = 300;
template <>
inline constexpr double kDefaultObjectsPerCell<DenseCellOptions> = 32;

/// Tuning of the grid; CellOptions are the options of its cell engine.
template <class CellOptions>
struct GridOptions {
  /// Edge of a cell on every axis; 0 chooses it from the objects and adapts it as they grow.
  double cell_size = 0;
  /// The automatic cell size aims at this many objects per cell (kDefaultObjectsPerCell).
  double objects_per_cell = kDefaultObjectsPerCell<CellOptions>;
  /// An object whose box would cover more cells than this is kept in the large set instead.
  uint32_t max_cells_per_object = 16;
  /// Threads that apply the touched cells of a query (the caller's included). Events do not
  /// depend on it: cells are independent, and their changes fold to the same counts and sets
  /// in any order (see GridCore::FoldCells).
  unsigned threads = 1;
  /// With threads > 1, a query with at least this many updates routes them in parallel, and an
  /// UpdateMany or EraseMany of at least this many items looks their keys up in parallel
  /// (below, waking the workers costs more than it saves); 0 never does either.
  size_t parallel_routing_from = 4096;
  /// With threads > 1, a large UpdateMany or EraseMany (as many items as above) looks its keys
  /// up on every thread first (faster calls). The daemon turns it off: its update→event tail
  /// is lower without (docs/TUNING.md).
  bool parallel_lookups = true;
  /// Options of every cell.
  CellOptions cell{};
};

}  // namespace bp
