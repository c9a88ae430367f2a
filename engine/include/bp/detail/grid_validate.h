// GridCore::Validate: every invariant of the grid's parts recomputed from scratch, one validator
// per part (the records' references against their ranges and the cells; no routing work left;
// the cell table's hash, membership and large lists; the large set's partners; the witness
// counts against the cells' own overlap sets), then the overlap set against a sort and sweep. O(n
// log n + cells x large objects + n x large objects); run after every query when BP_VALIDATE is
// set.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "bp/detail/flat_map.h"
#include "bp/detail/grid_core.h"
#include "bp/detail/sweep.h"

namespace bp::detail {

template <class Cell>
Status GridCore<Cell>::Validate() const {
  std::vector<uint32_t> live;
  FlatMap<uint64_t, uint32_t> count;  // per pair, the witnesses the cells and the large set hold
  if (Status s = ValidateRecords(&live); !s.ok()) return s;
  if (Status s = ValidateNoWorkLeft(); !s.ok()) return s;
  if (Status s = ValidateCellTable(&count); !s.ok()) return s;
  if (Status s = ValidateLargeSet(live, &count); !s.ok()) return s;
  if (Status s = ValidateWitnessCounts(count); !s.ok()) return s;
  std::vector<BoxType> boxes(objects_.size());
  for (uint32_t h = 0; h < objects_.size(); ++h) boxes[h] = objects_[h].box;
  // The composer's invariant: the tracker's set is the live boxes' overlapping pairs.
  return CheckOverlapSet(boxes, std::move(live), tracker_, kName);
}

// The records (grid_objects.h, invariant 1): each live object's cell range, set, references
// against the cells; the live and large counts. Lists the live handles.
template <class Cell>
Status GridCore<Cell>::ValidateRecords(std::vector<uint32_t>* live_out) const {
  std::vector<uint32_t>& live = *live_out;
  live.clear();
  size_t large_live = 0, unpaired = 0;
  for (uint32_t h = 0; h < objects_.size(); ++h) {
    const Object& o = objects_[h];
    if (o.state != State::kLive) {
      if (o.large == kUnpaired) return Invalid("object " + std::to_string(h) + ": dead unpaired");
      continue;
    }
    live.push_back(h);
    if (o.large == kUnpaired || PairsWithNothing(h)) {
      if (o.large != kUnpaired || o.nrefs != 0 || !PairsWithNothing(h))
        return Invalid("object " + std::to_string(h) + ": pairs with nothing, yet placed");
      ++unpaired;
      continue;
    }
    CellCoord lo, hi;
    RangeOf(objects_[h].box, &lo, &hi);
    if (lo != o.lo || hi != o.hi)
      return Invalid("object " + std::to_string(h) + ": stale cell range");
    bool is_large = CellCount(lo, hi) > options_.max_cells_per_object;
    if (is_large != (o.large != kNone))
      return Invalid("object " + std::to_string(h) + ": wrong set");
    if (is_large) {
      ++large_live;
      if (o.large >= large_.size() || large_[o.large].handle != h) return Invalid("large index");
      continue;
    }
    if (o.nrefs != CellCount(lo, hi)) return Invalid("object " + std::to_string(h) + ": ref count");
    uint32_t i = 0;
    bool ok = true;
    Space::ForEachCoord(lo, hi, [&](const CellCoord& c) {
      CellRef ref = refs_[o.refs + i++];
      ok = ok && ref.cell < cells_.size() && cells_[ref.cell]->in_use &&
           cells_[ref.cell]->coord == c && ref.local < cells_[ref.cell]->global.size() &&
           cells_[ref.cell]->global[ref.local] == h;
    });
    if (!ok) return Invalid("object " + std::to_string(h) + ": cell refs astray");
  }
  if (live.size() != live_) return Invalid("live count differs");
  if (large_live != large_count_) return Invalid("large count differs");
  if (unpaired != unpaired_) return Invalid("unpaired count differs");
  return Status::Ok();
}

// Routing (grid_routing.h, grid_parallel_routing.h): no work left between queries.
template <class Cell>
Status GridCore<Cell>::ValidateNoWorkLeft() const {
  if (!touched_.empty() || !changed_large_.empty() || !routed_.empty() || !routed_erases_.empty() ||
      !routed_inserts_.empty()) {
    return Invalid("work left after a query");
  }
  for (const Shard& sh : shards_) {
    const auto has_work = [](const auto& by_part) {
      return std::any_of(by_part.begin(), by_part.end(), [](const auto& v) { return !v.empty(); });
    };
    if (has_work(sh.routed) || has_work(sh.touched) || !sh.deferred.empty() ||
        std::any_of(sh.counts.begin(), sh.counts.end(), [](uint32_t c) { return c != 0; })) {
      return Invalid("routing shard left with work after a query");
    }
  }
  if (cell_work_.size() != cells_.size()) return Invalid("per-cell work table of the wrong size");
  if (std::any_of(shard_work_.begin(), shard_work_.end(),
                  [](const ShardWork& w) { return w.count != 0; })) {
    return Invalid("shard updates left after a query");
  }
  return Status::Ok();
}

// The cell table (grid_cells.h) and each cell's core: hash, members, free locals, slots,
// options. Adds each cell's pairs to count.
template <class Cell>
Status GridCore<Cell>::ValidateCellTable(FlatMap<uint64_t, uint32_t>* count_out) const {
  FlatMap<uint64_t, uint32_t>& count = *count_out;
  size_t in_use = 0;
  for (uint32_t idx = 0; idx < cells_.size(); ++idx) {
    const GridCell& c = *cells_[idx];
    if (!c.in_use) continue;
    ++in_use;
    const uint32_t* found = cell_of_.Find(c.key);
    if (c.key != Space::Pack(c.coord) || found == nullptr || *found != idx)
      return Invalid("cell hash");
    size_t members = 0;
    for (uint32_t g : c.global) members += g != kNone ? 1 : 0;
    if (members != c.members || members != c.core.live() || members == 0) {
      return Invalid("cell members differ");
    }
    // The free locals are exactly the unused ones, each once; a dense cell holds a live slot
    // exactly where the table names an object (its compaction moves both together).
    std::vector<bool> free_seen(c.global.size(), false);
    for (uint32_t l : c.free_local) {
      if (l >= c.global.size() || c.global[l] != kNone || free_seen[l]) {
        return Invalid("cell's free locals");
      }
      free_seen[l] = true;
    }
    if (c.free_local.size() + members != c.global.size()) return Invalid("cell's free locals");
    if constexpr (requires { c.core.slots(); }) {
      for (uint32_t l = 0; l < c.global.size(); ++l) {
        if (c.core.holds(l) != (c.global[l] != kNone)) return Invalid("cell slot and table differ");
      }
    }
    if (cell_work_[idx].touched || cell_work_[idx].updates != 0 || cell_work_[idx].erases != 0 ||
        cell_work_[idx].inserts != 0) {
      return Invalid("cell left with buffered operations");
    }
    if (Status s = c.core.Validate(); !s.ok()) return Invalid("cell: " + s.message());
    for (uint32_t local = 0; local < c.global.size(); ++local) {
      uint32_t g = c.global[local];
      if (g != kNone && !(CellPairs(c.core).options(local) == tracker_.options(g)))
        return Invalid("a cell's object options differ from the grid's");
    }
    CellPairs(c.core).ForEachOverlap([&](uint32_t a, uint32_t b) {
      ++count.FindOrInsert(HandlePair(c.global[a], c.global[b]), 0);
    });
  }
  if (in_use != cell_of_.size()) return Invalid("cells in the hash differ from cells in use");
  return Status::Ok();
}

// The large set (grid_large.h, invariants 1 to 3): the bins, partners exact and mutual. Adds
// each large pair to count once.
template <class Cell>
Status GridCore<Cell>::ValidateLargeSet(const std::vector<uint32_t>& live,
                                        FlatMap<uint64_t, uint32_t>* count_out) const {
  FlatMap<uint64_t, uint32_t>& count = *count_out;
  if (bins_stale_) return Invalid("large bins out of date after a query");
  if (large_change_count_ != 0) return Invalid("large-object changes left after a query");
  if (large_count_ != 0 && bin_begin_.size() < 2) return Invalid("large objects without bins");
  if (!bin_begin_.empty()) {
    // Each live large object once in every bin its range touches, with its box and owned bits,
    // and nothing else listed.
    bool ok = bin_begin_.back() == blocks_.size();
    for (size_t b = 0; b + 1 < bin_begin_.size() && ok; ++b)
      ok = bin_begin_[b] <= bin_begin_[b + 1];
    if (!ok) return Invalid("large bins' blocks out of order");
    std::vector<uint32_t> listed(large_.size(), 0);
    for (size_t k = 0; k < blocks_.size() && ok; ++k) {
      for (uint32_t i = 0; i < kBlockSlots; ++i) {
        const bool used = (uint32_t{blocks_[k].owned[0]} >> i) & 1u;
        ok = ok && (!used || (blocks_[k].large[i] < large_.size() &&
                              large_[blocks_[k].large[i]].handle != kNone));
        if (used && ok) ++listed[blocks_[k].large[i]];
      }
    }
    std::array<uint32_t, kAxes> blo, bhi;
    for (uint32_t l = 0; l < large_.size() && ok; ++l) {
      if (large_[l].handle == kNone) continue;
      const Object& o = objects_[large_[l].handle];
      BinRange(o.lo, o.hi, &blo, &bhi);
      uint32_t bins = 0;
      ForEachBin(blo, bhi, [&](uint32_t bin, const std::array<uint32_t, kAxes>& at) {
        ++bins;
        uint32_t starts = 0;
        for (size_t a = 0; a < kAxes; ++a) starts |= static_cast<uint32_t>(at[a] == blo[a]) << a;
        uint32_t found = 0;
        for (uint32_t k = bin_begin_[bin]; k < bin_begin_[bin + 1]; ++k) {
          const auto& block = blocks_[k];
          for (uint32_t i = 0; i < kBlockSlots; ++i) {
            if (((uint32_t{block.owned[0]} >> i) & 1u) == 0 || block.large[i] != l) continue;
            ++found;
            for (size_t a = 0; a < kAxes; ++a) {
              ok = ok && block.rows[2 * a * kBlockSlots + i] == o.box.lo[a] &&
                   block.rows[(2 * a + 1) * kBlockSlots + i] == o.box.hi[a];
            }
            for (uint32_t m = 0; m < kMasks; ++m) {
              ok = ok && ((uint32_t{block.owned[m]} >> i) & 1u) == ((starts & m) == m ? 1u : 0u);
            }
          }
        }
        ok = ok && found == 1;
      });
      ok = ok && listed[l] == bins;
    }
    if (!ok) return Invalid("large bins differ from the set");
  }
  for (uint32_t l = 0; l < large_.size(); ++l) {
    const Large& lg = large_[l];
    if (lg.handle == kNone) {
      if (!lg.partners.empty()) return Invalid("free large slot with partners");
      continue;
    }
    size_t overlapping = 0;
    for (uint32_t g : live) {
      overlapping += g != lg.handle && Overlaps(objects_[g].box, objects_[lg.handle].box) &&
                     tracker_.Accepts(g, lg.handle);
    }
    if (overlapping != lg.partners.size()) return Invalid("large partners differ");
    bool ok = true;
    lg.partners.ForEach([&](uint32_t x) {
      ok = ok && objects_[x].state == State::kLive &&
           Overlaps(objects_[x].box, objects_[lg.handle].box) && tracker_.Accepts(x, lg.handle);
      if (objects_[x].large != kNone) {
        ok = ok && large_[objects_[x].large].partners.Contains(lg.handle);
        if (x < lg.handle) return;  // a large pair counts once
      }
      ++count.FindOrInsert(HandlePair(x, lg.handle), 0);
    });
    if (!ok) return Invalid("large partner not overlapping or not mutual");
  }
  return Status::Ok();
}

// The witness counts (grid_witness.h): count (the cells' and the large set's) against the
// tracker's set and extra_.
template <class Cell>
Status GridCore<Cell>::ValidateWitnessCounts(const FlatMap<uint64_t, uint32_t>& count) const {
  size_t multi = 0;
  bool ok = true;
  count.ForEach([&](uint64_t p, uint32_t n) {
    ok = ok && tracker_.Contains(PairFirst(p), PairSecond(p));
    const uint32_t* e = extra_[tracker_.ShardOf(p)].Find(p);
    ok = ok && (n == 1 ? e == nullptr : (e != nullptr && *e == n - 1));
    multi += n > 1;
  });
  for (const auto& w : serial_witnessed_) {
    if (!w.empty()) return Invalid("witness changes left after a query");
  }
  size_t extras = 0;
  for (const auto& extra : extra_) extras += extra.size();
  if (!ok || count.size() != tracker_.overlaps() || multi != extras) {
    return Invalid("witness counts differ from the cells");
  }
  return Status::Ok();
}

}  // namespace bp::detail
