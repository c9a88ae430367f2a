// bp::client::KeptObjects: the objects an UpdatePublisher keeps for restating (its private
// store). Records are dense (one 128-byte record per object, the id inside it) and an index maps
// an id to its record: the engine's KeyIndex (bp/detail/key_index.h, an 8-byte entry per object),
// so a look-up reads one line of the index and then the record.
//
// Why not std::unordered_map: a scene that moves 20k of its 200k objects per frame looked each
// one up in a node-based map, two dependent cache misses per update, and took a large share of
// a core beside the daemon. A frame's
// updates go through ForEachFound, which prefetches the index lines and then the records a few
// updates ahead, so the misses of successive updates overlap.
//
// Thread safety: none; owned by one publisher.
// Invariants:
//  1. records_[h].id is held by the index under handle h, for every h < size(); nothing else is.
//  2. No id is held twice.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "bp/detail/key_index.h"

namespace bp::client {

class KeptObjects {
 public:
  struct alignas(64) Record {
    uint64_t id = 0;
    std::array<double, 6> lo{};  // the publisher's dimension's values used
    std::array<double, 6> hi{};
    uint64_t category = 1;
    uint64_t mask = ~uint64_t{0};
    bool has_attributes = false;
    bool is_static = false;
  };
  static_assert(sizeof(Record) == 128, "a record spans two cache lines");

  size_t size() const { return records_.size(); }
  /// Records in storage order (restates walk them).
  const Record& at(size_t h) const { return records_[h]; }

  bool Contains(uint64_t id) const { return Find(id) != kNone; }

  /// Keeps record (whose id must not be kept yet).
  void Insert(const Record& record) {
    index_.Insert(record.id, static_cast<uint32_t>(records_.size()));
    records_.push_back(record);
  }

  /// Forgets id; false if it was not kept. The last record moves into its place.
  bool Erase(uint64_t id) {
    const uint32_t h = Find(id);
    if (h == kNone) return false;
    index_.Erase(id, h);
    const auto last = static_cast<uint32_t>(records_.size() - 1);
    if (h != last) {
      index_.Erase(records_[last].id, last);
      index_.Insert(records_[last].id, h);
      records_[h] = records_[last];
    }
    records_.pop_back();
    return true;
  }

  /// Calls f(i, record) for each ids[i] in order, record nullptr for an id not kept. Look-ups
  /// run ahead of f: the index line of ids[i + kIndexAhead] and the record of
  /// ids[i + kRecordAhead] are prefetched while f works on ids[i].
  template <class F>
  void ForEachFound(std::span<const uint64_t> ids, F&& f) {
    const size_t n = ids.size();
    tags_.resize(n);
    for (size_t i = 0; i < n; ++i) tags_[i] = Index::Tag(ids[i]);
    auto key_of = [this](uint32_t h) { return records_[h].id; };
    for (size_t i = 0; i < n; ++i) {
      if (i + kIndexAhead < n) {
        if (const void* line = index_.HomeLine(tags_[i + kIndexAhead])) __builtin_prefetch(line);
      }
      if (i + kRecordAhead < n) {
        const uint32_t g = index_.Guess(tags_[i + kRecordAhead]);
        if (g != kNone) {
          const char* record = reinterpret_cast<const char*>(&records_[g]);
          __builtin_prefetch(record);
          __builtin_prefetch(record + 64);
        }
      }
      const uint32_t h = index_.Find(ids[i], tags_[i], key_of);
      f(i, h == kNone ? nullptr : &records_[h]);
    }
  }

  /// Checks the invariants (tests).
  bool Valid() const {
    if (index_.size() != records_.size()) return false;
    for (size_t h = 0; h < records_.size(); ++h) {
      if (Find(records_[h].id) != h) return false;
    }
    return true;
  }

 private:
  using Index = detail::KeyIndex<uint64_t>;
  static constexpr uint32_t kNone = Index::kNone;
  static constexpr size_t kIndexAhead = 16;
  static constexpr size_t kRecordAhead = 8;

  uint32_t Find(uint64_t id) const {
    return index_.Find(id, [this](uint32_t h) { return records_[h].id; });
  }

  std::vector<Record> records_;
  Index index_;
  std::vector<uint32_t> tags_;  // ForEachFound's scratch
};

}  // namespace bp::client
