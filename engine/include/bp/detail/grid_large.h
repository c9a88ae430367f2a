// bp::detail::GridLargeSet: objects too big for the cells. An object whose box would cover more
// than max_cells_per_object cells is not copied into cells: it joins the large set, and is
// registered in the lists of the existing cells its range covers (a cell created later lists
// the large objects over it: ListLargeOver). A changed small object is tested against the large
// objects listed in its old and new cells (the candidates); a changed large object is rescanned
// against the objects of the cells it covers and against the other large objects (Rescan, at
// the end of the routing). Each large object keeps its witnessed partners; for large pairs both
// sides hold each other and count once.
//
// Thread safety: none (the large set is touched by the serial routing only: a query with a
// large object routes serially).
// Invariants (checked by GridCore::Validate):
//  1. A cell in use lists exactly the large objects whose range covers it, each once.
//  2. A large object's partners are exactly the live objects overlapping it (and accepted by
//     the filters); large partners hold each other.
//  3. A large slot that is free (handle kNone) has no partners and is on free_large_.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "bp/detail/flat_set.h"
#include "bp/detail/grid_witness.h"

namespace bp::detail {

template <class Cell>
class GridLargeSet : public GridWitness<Cell> {
  using Base = GridWitness<Cell>;

 protected:
  using Base::cells_;
  using Base::ForEachExistingCell;
  using Base::grid;
  using Base::kNone;
  using Base::objects_;
  using Base::refs_;
  using Base::tests_;
  using Base::tracker_;
  using Base::Witness;
  using typename Base::BoxType;
  using typename Base::CellCoord;
  using typename Base::GridCell;
  using typename Base::Object;
  using typename Base::Options;
  using typename Base::Space;
  using typename Base::State;

  explicit GridLargeSet(const Options& options) : Base(options) {}

  struct Large {
    uint32_t handle = kNone;
    bool changed = false;
    FlatSet<uint32_t> partners;  // live objects overlapping this one (global handles)
  };

  void InsertLarge(uint32_t h, const CellCoord& lo, const CellCoord& hi) {
    grid().EndLocalDeferral();
    uint32_t l;
    if (!free_large_.empty()) {
      l = free_large_.back();
      free_large_.pop_back();
    } else {
      l = static_cast<uint32_t>(large_.size());
      large_.emplace_back();
      large_stamp_.push_back(0);
    }
    large_[l].handle = h;
    Object& o = objects_[h];
    o.large = l;
    o.lo = lo;
    o.hi = hi;
    o.nrefs = 0;
    ++large_count_;
    ForEachExistingCell(lo, hi, [&](uint32_t idx) { cells_[idx]->large.push_back(l); });
    MarkChanged(l);
  }

  void MoveLarge(uint32_t l, const CellCoord& lo, const CellCoord& hi) {
    Object& o = objects_[large_[l].handle];
    if (lo != o.lo || hi != o.hi) {
      Unregister(l);
      o.lo = lo;
      o.hi = hi;
      ForEachExistingCell(lo, hi, [&](uint32_t idx) { cells_[idx]->large.push_back(l); });
    }
    MarkChanged(l);
  }

  void Unregister(uint32_t l) {
    const Object& o = objects_[large_[l].handle];
    ForEachExistingCell(o.lo, o.hi, [&](uint32_t idx) {
      std::vector<uint32_t>& list = cells_[idx]->large;
      auto it = std::find(list.begin(), list.end(), l);
      BP_ASSERT(it != list.end());
      *it = list.back();
      list.pop_back();
    });
  }

  void EraseLarge(uint32_t h) {
    uint32_t l = objects_[h].large;
    Unregister(l);
    Large& lg = large_[l];
    scratch_.clear();
    lg.partners.ForEach([&](uint32_t x) { scratch_.push_back(x); });
    for (uint32_t x : scratch_) {
      Witness(h, x, false);
      if (objects_[x].large != kNone) large_[objects_[x].large].partners.Erase(h);
    }
    lg.partners.Clear();
    lg.handle = kNone;
    free_large_.push_back(l);
    objects_[h].large = kNone;
    --large_count_;
  }

  void MarkChanged(uint32_t l) {
    if (!large_[l].changed) {
      large_[l].changed = true;
      changed_large_.push_back(l);
    }
  }

  void BeginLargeCandidates() {
    NextEpoch(&large_epoch_, &large_stamp_, nullptr);
    candidates_.clear();
  }
  // Stamps are compared with an epoch; when it wraps, the stamps restart from zero.
  static void NextEpoch(uint32_t* epoch, std::vector<uint32_t>* a, std::vector<uint32_t>* b) {
    if (++*epoch != 0) return;
    std::fill(a->begin(), a->end(), 0);
    if (b != nullptr) std::fill(b->begin(), b->end(), 0);
    *epoch = 1;
  }
  // The large objects listed in h's current cells, each once.
  void AddLargeCandidates(uint32_t h) {
    const Object& o = objects_[h];
    for (uint32_t i = 0; i < o.nrefs; ++i) {
      for (uint32_t l : cells_[refs_[o.refs + i].cell]->large) {
        if (large_stamp_[l] != large_epoch_) {
          large_stamp_[l] = large_epoch_;
          candidates_.push_back(l);
        }
      }
    }
  }
  // Brings the pairs of small object h with the candidates up to date (h dead: removes them).
  // `before` is h's box at the last query (nullptr: h was in no partner set), which tells, for a
  // candidate unchanged this query, whether h is its partner without a look-up; a candidate
  // that changed is rescanned afterwards, which settles its pairs anyway.
  void TestLargeCandidates(uint32_t h, const BoxType* before) {
    const bool alive = objects_[h].state == State::kLive;
    for (uint32_t l : candidates_) {
      Large& lg = large_[l];
      if (!tracker_.Accepts(h, lg.handle)) continue;  // never a partner
      const BoxType& lbox = objects_[lg.handle].box;
      ++tests_;
      bool now = alive && Overlaps(objects_[h].box, lbox);
      if (!lg.changed) {
        bool had = before != nullptr && Overlaps(*before, lbox);
        if (had == now) continue;
      }
      if (now ? lg.partners.Insert(h) : lg.partners.Erase(h)) Witness(h, lg.handle, now);
    }
  }

  // Sets a changed large object's partners to exactly the live objects overlapping it: the small
  // ones in the cells its range covers and the other large ones.
  void Rescan(uint32_t l) {
    const uint32_t h = large_[l].handle;
    const BoxType& box = objects_[h].box;
    const Object& o = objects_[h];
    if (stamp_.size() < objects_.size()) {
      stamp_.resize(objects_.size(), 0);
      mark_.resize(objects_.size(), 0);
    }
    NextEpoch(&epoch_, &stamp_, &mark_);
    found_.clear();
    ForEachExistingCell(o.lo, o.hi, [&](uint32_t idx) {
      for (uint32_t g : cells_[idx]->global) {
        if (g == kNone || stamp_[g] == epoch_) continue;
        stamp_[g] = epoch_;
        const Object& x = objects_[g];
        if (x.state != State::kLive || x.large != kNone) continue;  // left, or now large
        if (!tracker_.Accepts(g, h)) continue;
        ++tests_;
        if (Overlaps(objects_[g].box, box)) {
          mark_[g] = epoch_;
          found_.push_back(g);
        }
      }
    });
    for (const Large& other : large_) {
      uint32_t g = other.handle;
      if (g == kNone || g == h || !tracker_.Accepts(g, h)) continue;
      ++tests_;
      if (Overlaps(objects_[g].box, box)) {
        mark_[g] = epoch_;
        found_.push_back(g);
      }
    }
    Large& lg = large_[l];
    scratch_.clear();
    lg.partners.ForEach([&](uint32_t x) {
      if (mark_[x] != epoch_) scratch_.push_back(x);
    });
    for (uint32_t x : scratch_) {
      lg.partners.Erase(x);
      Witness(h, x, false);
      if (objects_[x].large != kNone) large_[objects_[x].large].partners.Erase(h);
    }
    for (uint32_t x : found_) {
      if (!lg.partners.Insert(x)) continue;
      Witness(h, x, true);
      if (objects_[x].large != kNone) large_[objects_[x].large].partners.Insert(h);
    }
  }

  // Lists in a new cell the large objects whose range covers it (see CellAt).
  void ListLargeOver(GridCell& cell) {
    for (uint32_t l = 0; l < large_.size(); ++l) {
      uint32_t lh = large_[l].handle;
      if (lh != kNone && Space::Contains(objects_[lh].lo, objects_[lh].hi, cell.coord))
        cell.large.push_back(l);
    }
  }
  // Rescans the large objects that changed in this query (after its routing).
  void RescanChanged() {
    for (uint32_t l : changed_large_) {
      large_[l].changed = false;
      if (large_[l].handle != kNone) Rescan(l);
    }
    changed_large_.clear();
  }
  // Drops the whole set (a rebuild: see GridSizing::Regrid).
  void ClearLarge() {
    large_.clear();
    large_stamp_.clear();
    free_large_.clear();
    changed_large_.clear();
    large_count_ = 0;
  }

  std::vector<Large> large_;
  std::vector<uint32_t> free_large_;
  std::vector<uint32_t> changed_large_;
  size_t large_count_ = 0;
  // Scratch of the large-object paths.
  std::vector<uint32_t> stamp_, mark_;  // by global handle, against epoch_ (sized by Rescan)
  uint32_t epoch_ = 0;
  std::vector<uint32_t> large_stamp_;  // by large index, against large_epoch_
  uint32_t large_epoch_ = 0;
  std::vector<uint32_t> candidates_, found_, scratch_;
};

}  // namespace bp::detail
