// bp::Grid: the superstructure of Tracy, Buss and Woods (IEEE VR 2009, sections 3.1 and 3.3): a
// uniform grid whose cells are broadphase instances of their own (segmented interval lists,
// batch insertion and removal, or dense cells), with a witness-count table that turns per-cell
// overlap changes into exactly one collide and one uncollide per pair.
//
// Contract (for GridSegmentedSap, GridBatchSap and GridDense, on top of bp/broadphase.h's):
//  - Exact: the events and the overlap set are those of the live boxes, whatever the cell size
//    (any monotone map from coordinates to cells keeps the grid exact: two boxes that overlap
//    share a cell on every axis). The world is unbounded: cells are hashed by their integer
//    coordinates, and coordinates far from the origin land in the edge cells.
//  - Small and large objects: an object covering at most `max_cells_per_object` cells lives in
//    each of them; a bigger one is kept apart, in the large set, and tested against the objects
//    of the cells it covers.
//  - Work per query is O(u + e) plus the cells' own work (u changes, e events): only the cells
//    with buffered operations are applied.
//  - With `threads` > 1 a worker pool routes the changes and applies the touched cells; the
//    events do not depend on the thread count.
//  - The cell size is either given or chosen from the objects (about `objects_per_cell` per
//    cell), and chosen again, every cell rebuilt, when the live count has changed fourfold and
//    the best size differs by more than a factor of two.
//
// Thread safety: none for callers (see bp/broadphase.h).
//
// Where each concept lives (each part has its contract and invariants at its top):
//   bp/grid_options.h               GridOptions, the tuning
//   detail/grid_core.h              GridCore: composes the parts, runs a query's phases
//   detail/grid_objects.h           object records, cell references, tracker, counters
//   detail/grid_cells.h             the cell table: coordinates -> cell, recycling, local handles
//   detail/grid_routing.h           serial routing of a query's changes to the cells
//   detail/grid_parallel_routing.h  routing on the worker pool
//   detail/grid_witness.h           witness counts and their fold
//   detail/grid_large.h             the large-object set
//   detail/grid_sizing.h            the automatic cell size, regridding
//   detail/grid_validate.h          Validate: every invariant recomputed from scratch
#pragma once

#include <cstdint>

#include "bp/batch_sap.h"
#include "bp/dense_cell.h"
#include "bp/detail/front_end.h"
#include "bp/detail/grid_core.h"
#include "bp/grid_options.h"
#include "bp/segmented_sap.h"

namespace bp {

/// The grid over segmented-interval-list cells (few movers, few events per cell).
template <int K, Coordinate T, class Key = uint64_t>
using GridSegmentedSap = detail::FrontEnd<detail::GridCore<detail::SegmentedSapCore<K, T>>, Key>;
/// The grid over batch insertion and removal cells (many movers or many events per cell).
template <int K, Coordinate T, class Key = uint64_t>
using GridBatchSap = detail::FrontEnd<detail::GridCore<detail::BatchSapCore<K, T>>, Key>;
/// The grid over dense cells (boxes in flat arrays, brute force within a cell; beyond the paper:
/// fastest with small cells on scenes that spread their objects, see bp/dense_cell.h).
template <int K, Coordinate T, class Key = uint64_t>
using GridDense = detail::FrontEnd<detail::GridCore<detail::DenseCellCore<K, T>>, Key>;
/// Options of GridSegmentedSap, GridBatchSap and GridDense.
using GridSegmentedSapOptions = GridOptions<SegmentedSapOptions>;
using GridBatchSapOptions = GridOptions<BatchSapOptions>;
using GridDenseOptions = GridOptions<DenseCellOptions>;

}  // namespace bp
