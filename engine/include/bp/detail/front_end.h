// bp::detail::FrontEnd: the front end every broadphase shares. It maps client keys to dense
// 32-bit handles once, validates and buffers Insert/Update/Erase, coalesces several calls on one
// key between two queries into at most one operation, hands the core one batch per Query, and
// turns the core's changed handle pairs into canonical key events. With a margin, the core sees
// fattened boxes (detail/front_end_fat.h).
//
// The front end is composed of parts, each with its contract and invariants at its top:
//   detail/front_end_contract.h   what a core provides (FrontEndCore), HandleBox
//   detail/front_end_fat.h        fattened boxes (FatBoxes)
//   detail/front_end_slots.h      keys, handles, slots, staged calls, epochs (FrontEndSlots)
//   detail/front_end_events.h     changed pairs to key events in canonical order (FrontEndEvents)
//   detail/front_end_lookahead.h  batch calls with their look-ups in flight (FrontEndLookAhead)
//   detail/front_end_validate.h   Validate: every invariant recomputed from scratch
//
// Thread safety: none (see bp/broadphase.h).
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "bp/broadphase.h"
#include "bp/detail/front_end_contract.h"
#include "bp/detail/front_end_lookahead.h"
#include "bp/detail/stopwatch.h"
#include "bp/object_options.h"

namespace bp::detail {

template <class Core, class Key>
class FrontEnd final : public Broadphase<Core::kDim, typename Core::Coord, Key>,
                       private FrontEndLookAhead<Core, Key> {
  static_assert(FrontEndCore<Core>);
  static constexpr int K = Core::kDim;
  using T = typename Core::Coord;
  using Base = Broadphase<K, T, Key>;
  using Parts = FrontEndLookAhead<Core, Key>;

 public:
  using BoxType = typename Base::BoxType;
  using Options = typename Core::Options;

  using Base::Insert;

  /// margin > 0 keeps fattened boxes (FatBoxes); 0, negative or NaN keeps exact boxes.
  explicit FrontEnd(const Options& options = Options(), T margin = T{}) : Parts(options, margin) {}

  Status Insert(const Key& key, const BoxType& box, const ObjectOptions& options) override {
    return InsertTagged(key, KeyIndex<Key>::Tag(key), box, options);
  }

  /// As Insert per item, with the look-ups of later items started early, as in UpdateMany, and
  /// the slots of the handles the inserts will take from the free list (churn frees handles all
  /// over the table).
  size_t InsertMany(std::span<const typename Base::Item> items,
                    std::span<const ObjectOptions> options = {},
                    const typename Base::RefusedFn& refused = nullptr) override {
    if (!options.empty() && options.size() != items.size()) {
      return Base::InsertMany(items, options, refused);  // refuses every item, saying why
    }
    static const ObjectOptions kDefault;
    return ForEachAhead(
        items, [](const typename Base::Item& item) -> const Key& { return item.key; }, refused,
        [&](size_t i, uint32_t tag, uint32_t /*hint: new keys are mostly absent*/) {
          constexpr size_t kFreeAhead = 8;
          if (free_.size() > kFreeAhead) {
            PrefetchForWrite(&slots_[free_[free_.size() - 1 - kFreeAhead]]);
          }
          return InsertTagged(items[i].key, tag, items[i].box,
                              options.empty() ? kDefault : options[i]);
        });
  }

  Status Update(const Key& key, const BoxType& box) override {
    return UpdateTagged(key, KeyIndex<Key>::Tag(key), box, kNoHandle);
  }

  /// As Update per item, with the look-ups of later items started early (ForEachAhead): a loop
  /// of Update calls waits on the key index's line and the slot, one item after the other.
  size_t UpdateMany(std::span<const typename Base::Item> items,
                    const typename Base::RefusedFn& refused = nullptr) override {
    if (margin_ == T{}) {
      if (WorkerPool* pool = LookupPool(items.size())) return UpdateManyOn(pool, items, refused);
    }
    return ForEachResolved(
        items, [](const typename Base::Item& item) -> const Key& { return item.key; }, refused,
        [&](size_t i, uint32_t tag, uint32_t hint) {
          return UpdateTagged(items[i].key, tag, items[i].box, hint);
        });
  }

  Status Erase(const Key& key) override {
    return EraseTagged(key, KeyIndex<Key>::Tag(key), kNoHandle);
  }

  /// As Erase per key, with the look-ups of later keys started early, as in UpdateMany (churn
  /// names keys all over the table).
  size_t EraseMany(std::span<const Key> keys,
                   const typename Base::RefusedFn& refused = nullptr) override {
    return ForEachResolved(
        keys, [](const Key& key) -> const Key& { return key; }, refused,
        [&](size_t i, uint32_t tag, uint32_t hint) { return EraseTagged(keys[i], tag, hint); });
  }

  void Query(EventSink<Key>& sink) override {
    Stopwatch phase;
    PairTracker& tracker = core_.tracker();
    // The tracker learns an inserted object's options before the core pairs it (invariant 5).
    // Default options need no call until some object has others (see PairTracker::SetOptions);
    // an object inserted and erased since is skipped (its handle is not reused before commit).
    for (const auto& [h, options] : insert_options_) {
      if (PendingOf(slots_[h]) == Pending::kInsert) tracker.SetOptions(h, options);
    }
    insert_options_.clear();
    // The staged lists are the batch, once the entries that later calls retired are gone.
    if (tombstones_ != 0) {
      std::erase(erases_, kNoHandle);
      std::erase_if(updates_, [](const HandleBox<K, T>& hb) { return hb.handle == kNoHandle; });
      std::erase_if(inserts_, [](const HandleBox<K, T>& hb) { return hb.handle == kNoHandle; });
      tombstones_ = 0;
    }
    prepare_ms_ = phase.Lap();
    // The commit of the erased slots (CommitErases) touches nothing of the core's: a core that
    // can runs it on its pool among its own parallel work (GridCore::Apply).
    bool committed = false;
    if constexpr (requires { Core::kAppliesBeside; }) {
      if (erases_.empty()) {
        core_.Apply(erases_, updates_, inserts_);
      } else {
        committed = core_.Apply(erases_, updates_, inserts_, [this] { CommitErases(); });
      }
    } else {
      core_.Apply(erases_, updates_, inserts_);
    }
    core_ms_ = phase.Lap();

    // The changed pairs' keys, sorted (FrontEndEvents), and the commit of the erased slots if
    // not done yet.
    KeyEvents(committed);
    free_.insert(free_.end(), cancelled_.begin(), cancelled_.end());
    cancelled_.clear();
    last_erases_ = erases_.size();
    last_updates_ = updates_.size();
    last_inserts_ = inserts_.size();
    erases_.clear();
    updates_.clear();
    inserts_.clear();
    NextEpoch();

    if (rekeyed_) CancelRekeyedPairs();
    last_fat_skips_ = fat_skips_;
    fat_skips_ = 0;
    if constexpr (kValidateEachQuery) {
      if (Status v = Validate(); !v.ok()) ReportFailure(__FILE__, __LINE__, v.message().c_str());
    }
    Deliver(sink);
    events_ms_ = phase.Lap();
  }

  void ForEachOverlap(const std::function<void(const Key&, const Key&)>& f) const override {
    core_.tracker().ForEachOverlap([&](uint32_t a, uint32_t b) {
      const Key& ka = slots_[a].key;
      const Key& kb = slots_[b].key;
      if (std::less<Key>()(ka, kb)) {
        f(ka, kb);
      } else {
        f(kb, ka);
      }
    });
  }

  void ForEachOverlapping(const BoxType& box,
                          const std::function<void(const Key&)>& f) const override {
    if constexpr (requires { core_.ForEachOverlapping(box, [](uint32_t) {}); }) {
      core_.ForEachOverlapping(box, [&](uint32_t h) { f(slots_[h].key); });
    } else {
      // Every handle live in the core as of the last query, its box from the core.
      for (uint32_t h = 0; h < slots_.size(); ++h) {
        if (LiveOf(slots_[h]) && Overlaps(core_.box(h), box)) f(slots_[h].key);
      }
    }
  }

  void ForEachObject(const std::function<void(const Key&)>& f) const override {
    for (const Slot& slot : slots_) {
      if (Present(slot)) f(slot.key);
    }
  }

  size_t Size() const override { return core_.live(); }

  Stats GetStats() const override {
    Stats s;
    core_.FillStats(&s);
    s.objects = core_.live();
    s.overlaps = core_.tracker().overlaps();
    s.inserts = last_inserts_;
    s.updates = last_updates_;
    s.erases = last_erases_;
    s.collides = collides_.size();
    s.uncollides = uncollides_.size();
    s.margin = static_cast<double>(margin_);
    s.fat_skips = last_fat_skips_;
    s.prepare_ms = prepare_ms_;
    s.core_ms = core_ms_;
    s.events_ms = events_ms_;
    return s;
  }

  Status Validate() const override;

  std::string Name() const override { return Core::kName; }

  /// The core, for white-box tests.
  const Core& core() const { return core_; }
  /// White-box tests move the epoch to its wrap-around through this peer.
  friend struct FrontEndTestPeer;

 private:
  using Parts::cancelled_;
  using Parts::CancelRekeyedPairs;
  using Parts::collides_;
  using Parts::CommitErases;
  using Parts::core_;
  using Parts::Deliver;
  using Parts::erases_;
  using Parts::EraseTagged;
  using Parts::fat_;
  using Parts::fat_skips_;
  using Parts::Find;
  using Parts::ForEachAhead;
  using Parts::ForEachResolved;
  using Parts::free_;
  using Parts::index_;
  using Parts::insert_options_;
  using Parts::inserts_;
  using Parts::InsertTagged;
  using Parts::KeyEvents;
  using Parts::kNoHandle;
  using Parts::last_fat_skips_;
  using Parts::LiveOf;
  using Parts::LookupPool;
  using Parts::margin_;
  using Parts::NextEpoch;
  using Parts::PendingOf;
  using Parts::Present;
  using Parts::rekeyed_;
  using Parts::slots_;
  using Parts::tombstones_;
  using Parts::uncollides_;
  using Parts::UpdateManyOn;
  using Parts::updates_;
  using Parts::UpdateTagged;
  using typename Parts::Pending;
  using typename Parts::Slot;

  // Validate's parts (detail/front_end_validate.h), one per part, in the order Validate runs
  // them: the slots count the present and the dead ones for the key map and the free lists.
  static Status Invalid(const char* what);
  Status ValidateSlots(size_t* present, size_t* dead) const;
  Status ValidateKeyMap(size_t present) const;
  Status ValidateFreeLists(size_t dead) const;
  Status ValidateFatBoxes() const;
  Status ValidateEventsDrained() const;

  size_t last_erases_ = 0, last_updates_ = 0, last_inserts_ = 0;  // the last query's batch
  double prepare_ms_ = 0, core_ms_ = 0, events_ms_ = 0;           // the last query's phases (Stats)
};

}  // namespace bp::detail

#include "bp/detail/front_end_validate.h"  // NOLINT(build/include_order): defines Validate
