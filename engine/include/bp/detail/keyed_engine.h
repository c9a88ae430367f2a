// bp::detail::KeyedEngine: the front end every broadphase shares. It maps client keys to dense
// 32-bit handles once, validates and buffers Insert/Update/Erase, coalesces several calls on one
// key between two queries into at most one operation, hands the core one batch per Query, and
// turns the core's changed handle pairs into canonical key events.
//
// A core works on handles only (it never sees keys) and must provide:
//   static constexpr int kDim; using Coord = T; static constexpr const char* kName;
//   static constexpr size_t kMaxHandles;   // handles are 0..kMaxHandles-1
//   void Apply(span<const uint32_t> erases, span<const HandleBox> updates,
//              span<const HandleBox> inserts);   // in this order
//   PairTracker& tracker(); const PairTracker& tracker() const; size_t live() const;
//   void FillStats(Stats* out) const; Status Validate() const;
//
// Thread safety: none (see bp/broadphase.h).
// Invariants:
//  1. handle_of_[key] exists iff the key is live at the last query or has a pending insert.
//  2. A handle is queued at most once between queries; handles are freed only inside Query,
//     after the core has applied the batch, so a handle never means two keys within one batch.
//  3. erase + insert of one live key between queries becomes an update of the same handle.
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "bp/box.h"
#include "bp/broadphase.h"
#include "bp/detail/assert.h"
#include "bp/detail/pair_tracker.h"

namespace bp::detail {

/// A box addressed by a dense handle: the unit of the core interface.
template <int K, Coordinate T>
struct HandleBox {
  uint32_t handle = 0;
  Box<K, T> box;
};

template <class Core, class Key>
class KeyedEngine final : public Broadphase<Core::kDim, typename Core::Coord, Key> {
  static constexpr int K = Core::kDim;
  using T = typename Core::Coord;
  using Base = Broadphase<K, T, Key>;

 public:
  using BoxType = typename Base::BoxType;
  using Options = typename Core::Options;

  explicit KeyedEngine(const Options& options = Options()) : core_(options) {}

  Status Insert(const Key& key, const BoxType& box) override {
    if (Status s = ValidateBox(box); !s.ok()) return Annotate(s, "insert");
    auto it = handle_of_.find(key);
    if (it != handle_of_.end()) {
      Slot& slot = slots_[it->second];
      if (Present(slot)) return Status(StatusCode::kAlreadyExists, "insert: key already present");
      // Live at the last query and erased since: erase + insert is an update (invariant 3).
      slot.pending = Pending::kUpdate;
      slot.box = box;
      return Status::Ok();
    }
    if (free_.empty() && slots_.size() >= Core::kMaxHandles) {
      return Status(StatusCode::kResourceExhausted,
                    "insert: " + std::to_string(Core::kMaxHandles) + " objects are the limit");
    }
    uint32_t h = AllocHandle();
    Slot& slot = slots_[h];
    slot.key = key;
    slot.box = box;
    slot.live = false;
    slot.pending = Pending::kInsert;
    handle_of_.emplace(key, h);
    Enqueue(h);
    return Status::Ok();
  }

  Status Update(const Key& key, const BoxType& box) override {
    if (Status s = ValidateBox(box); !s.ok()) return Annotate(s, "update");
    auto it = handle_of_.find(key);
    if (it == handle_of_.end() || !Present(slots_[it->second])) {
      return Status(StatusCode::kNotFound, "update: unknown key");
    }
    Slot& slot = slots_[it->second];
    slot.box = box;
    if (slot.pending == Pending::kNone) slot.pending = Pending::kUpdate;
    Enqueue(it->second);
    return Status::Ok();
  }

  Status Erase(const Key& key) override {
    auto it = handle_of_.find(key);
    if (it == handle_of_.end() || !Present(slots_[it->second])) {
      return Status(StatusCode::kNotFound, "erase: unknown key");
    }
    uint32_t h = it->second;
    Slot& slot = slots_[h];
    if (slot.live) {
      slot.pending = Pending::kErase;
      Enqueue(h);
    } else {
      // Inserted and erased between two queries: nothing reaches the core.
      slot.pending = Pending::kNone;
      handle_of_.erase(it);
    }
    return Status::Ok();
  }

  void Query(EventSink<Key>& sink) override {
    erases_.clear();
    updates_.clear();
    inserts_.clear();
    for (uint32_t h : queue_) {
      Slot& slot = slots_[h];
      switch (slot.pending) {
        case Pending::kErase:
          erases_.push_back(h);
          break;
        case Pending::kUpdate:
          updates_.push_back({h, slot.box});
          break;
        case Pending::kInsert:
          inserts_.push_back({h, slot.box});
          break;
        case Pending::kNone:
          break;
      }
    }
    core_.Apply(erases_, updates_, inserts_);

    collides_.clear();
    uncollides_.clear();
    core_.tracker().DrainChanges([&](uint32_t a, uint32_t b, bool now) {
      const Key& ka = slots_[a].key;
      const Key& kb = slots_[b].key;
      auto pair = std::less<Key>()(ka, kb) ? std::make_pair(ka, kb) : std::make_pair(kb, ka);
      (now ? collides_ : uncollides_).push_back(std::move(pair));
    });

    // Commit the slot states, then free erased and cancelled handles (invariant 2).
    for (uint32_t h : queue_) {
      Slot& slot = slots_[h];
      slot.queued = false;
      if (slot.pending == Pending::kErase) {
        handle_of_.erase(slot.key);
        slot.live = false;
      } else if (slot.pending != Pending::kNone) {
        slot.live = true;
      }
      slot.pending = Pending::kNone;
      if (!slot.live) free_.push_back(h);
    }
    queue_.clear();

    std::sort(uncollides_.begin(), uncollides_.end());
    std::sort(collides_.begin(), collides_.end());
    if constexpr (kValidateEachQuery) {
      if (Status v = Validate(); !v.ok()) ReportFailure(__FILE__, __LINE__, v.message().c_str());
    }
    for (const auto& [a, b] : uncollides_) sink.Uncollide(a, b);
    for (const auto& [a, b] : collides_) sink.Collide(a, b);
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

  size_t Size() const override { return core_.live(); }

  Stats GetStats() const override {
    Stats s;
    core_.FillStats(&s);
    s.objects = core_.live();
    s.overlaps = core_.tracker().overlaps();
    s.inserts = inserts_.size();
    s.updates = updates_.size();
    s.erases = erases_.size();
    s.collides = collides_.size();
    s.uncollides = uncollides_.size();
    return s;
  }

  Status Validate() const override {
    auto fail = [](const char* what) {
      return Status(StatusCode::kInternal, std::string("front end: ") + what);
    };
    if (core_.tracker().pending_changes() != 0) return fail("changed pairs left after a query");
    size_t live = 0, mapped = 0, queued = 0;
    for (const Slot& slot : slots_) {
      live += slot.live ? 1 : 0;
      mapped += (slot.live || slot.pending == Pending::kInsert) ? 1 : 0;
      queued += slot.queued ? 1 : 0;
    }
    if (live != core_.live()) return fail("live counts disagree");
    if (mapped != handle_of_.size()) return fail("key map size differs from mapped slots");
    if (queued != queue_.size()) return fail("queue differs from queued flags");
    for (const auto& [key, h] : handle_of_) {
      if (h >= slots_.size() || !(slots_[h].key == key)) return fail("key map points astray");
    }
    std::vector<uint8_t> free_seen(slots_.size(), 0);
    for (uint32_t h : free_) {
      if (h >= slots_.size() || free_seen[h]++) return fail("free list broken");
      const Slot& slot = slots_[h];
      if (slot.live || slot.queued || slot.pending != Pending::kNone) {
        return fail("free handle in use");
      }
    }
    return core_.Validate();
  }

  std::string Name() const override { return Core::kName; }

  /// The core, for white-box tests.
  const Core& core() const { return core_; }

 private:
  enum class Pending : uint8_t { kNone, kInsert, kUpdate, kErase };
  struct Slot {
    Key key{};
    BoxType box;
    bool live = false;    // present as of the last query
    bool queued = false;  // in queue_
    Pending pending = Pending::kNone;
  };

  static bool Present(const Slot& slot) {
    return slot.pending == Pending::kInsert || (slot.live && slot.pending != Pending::kErase);
  }
  static Status Annotate(const Status& s, const char* what) {
    return Status(s.code(), std::string(what) + ": " + s.message());
  }

  uint32_t AllocHandle() {
    if (!free_.empty()) {
      uint32_t h = free_.back();
      free_.pop_back();
      return h;
    }
    slots_.emplace_back();
    return static_cast<uint32_t>(slots_.size() - 1);
  }
  void Enqueue(uint32_t h) {
    if (!slots_[h].queued) {
      slots_[h].queued = true;
      queue_.push_back(h);
    }
  }

  Core core_;
  std::vector<Slot> slots_;
  std::unordered_map<Key, uint32_t> handle_of_;
  std::vector<uint32_t> free_;
  std::vector<uint32_t> queue_;
  // Per-query buffers, kept to reuse their allocations.
  std::vector<uint32_t> erases_;
  std::vector<HandleBox<K, T>> updates_;
  std::vector<HandleBox<K, T>> inserts_;
  std::vector<std::pair<Key, Key>> collides_;
  std::vector<std::pair<Key, Key>> uncollides_;
};

}  // namespace bp::detail
