// bp::service::InterestTable (interests.h).
#include "interests.h"

#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <set>
#include <span>

namespace bp::service {
namespace {

// An interest's name in messages: its id in hex, as clients print it.
std::string Name(uint64_t id) {
  char text[32];
  std::snprintf(text, sizeof(text), "interest %016" PRIx64, id);
  return text;
}

// Sorts a flattened pair list by (a, b).
void SortFlat(std::vector<uint64_t>* flat) {
  std::vector<std::pair<uint64_t, uint64_t>> pairs(flat->size() / 2);
  for (size_t i = 0; i < pairs.size(); ++i) pairs[i] = {(*flat)[2 * i], (*flat)[2 * i + 1]};
  std::sort(pairs.begin(), pairs.end());
  for (size_t i = 0; i < pairs.size(); ++i) {
    (*flat)[2 * i] = pairs[i].first;
    (*flat)[2 * i + 1] = pairs[i].second;
  }
}

// Removes one occurrence of value from the list of key in lists (order not kept), and the
// entry once its list is empty.
template <class Map, class V>
void EraseFromList(Map& lists, const typename Map::key_type& key, const V& value) {
  const auto it = lists.find(key);
  if (it == lists.end()) return;
  auto& list = it->second;
  const auto at = std::find(list.begin(), list.end(), value);
  if (at != list.end()) {
    *at = list.back();
    list.pop_back();
  }
  if (list.empty()) lists.erase(it);
}

// Pairs at the front of a canonical list whose first key is a region's (below 2^48).
size_t RegionPrefix(const std::vector<uint64_t>& flat) {
  size_t n = 0;
  while (2 * n < flat.size() && flat[2 * n] < kLocalIdLimit) ++n;
  return n;
}

}  // namespace

struct InterestTable::State {
  struct Region {
    uint64_t enter_key = 0;  // the region's engine object
    uint64_t leave_key = 0;  // the grown region's (== enter_key without a leave margin)
    bool gone = false;       // retired; dropped at the end of the next frame
    detail::FlatSet<uint64_t> members;
    // Members when the region's objects were replaced (a new shape): they stay inside if they
    // overlap the new grown region at the next frame, as they would have by moving in place.
    detail::FlatSet<uint64_t> carry;
    // Membership changes since the last frame: (object, a member before the change); an
    // object's first record says whether it was a member at the last frame.
    std::vector<std::pair<uint64_t, bool>> changed;
  };
  uint64_t id = 0;
  uint64_t owner = 0;
  std::vector<Region> regions;
  bool pairs_inside = false;
  std::unordered_set<uint64_t> keys;
  std::vector<uint32_t> producers;  // sorted, unique
  uint64_t category_mask = 0;
  // With pairs_inside only: object -> regions of the interest it is inside (> 0), and the
  // objects whose count crossed 0 in the frame.
  std::unordered_map<uint64_t, uint32_t> inside;
  std::vector<uint64_t> inside_changed;
  PairSet pairs;  // the object pairs of the set
  Delta delta;
  bool dirty = true;     // declared or changed: the next frame recomputes its pairs whole
  bool changed = false;  // changed since the last frame (its regions may be half replaced)
  uint64_t stamp = 0;
};

InterestTable::InterestTable(EngineHost* host, InterestLimits limits,
                             std::function<bool(uint32_t)> known_producer)
    : host_(host), limits_(limits), known_producer_(std::move(known_producer)) {}

InterestTable::~InterestTable() = default;

Status InterestTable::Validate(const wire::Interest& in, uint64_t owner, bool take_over) const {
  auto refuse = [&](std::string why) {
    return Status(StatusCode::kInvalidArgument, Name(in.id()) + ": " + std::move(why));
  };
  if (in.id() == 0) return refuse("id 0 is not an interest id (choose a random nonzero id)");
  const auto existing = by_id_.find(in.id());
  if (existing != by_id_.end() && existing->second->owner != owner && !take_over) {
    return Status(StatusCode::kAlreadyExists,
                  Name(in.id()) + " is held by another client's writer");
  }
  if (existing == by_id_.end() && by_id_.size() >= limits_.max_interests) {
    return refuse("the daemon holds limits.max_interests = " +
                  std::to_string(limits_.max_interests) + " interests");
  }
  const size_t k = static_cast<size_t>(host_->Dimension());
  const size_t values = static_cast<size_t>(in.region_lo_size());
  if (!in.region_lo().empty() || !in.region_hi().empty()) {
    if (in.dim() != k) {
      return refuse("its regions have dim " + std::to_string(in.dim()) +
                    "; the daemon's dimension is " + std::to_string(k));
    }
    if (values != static_cast<size_t>(in.region_hi_size()) || values % k != 0) {
      return refuse("region_lo and region_hi must hold " + std::to_string(k) +
                    " values per region; got " + std::to_string(values) + " and " +
                    std::to_string(in.region_hi_size()));
    }
  }
  const size_t regions = values / k;
  if (regions > limits_.max_regions) {
    return refuse(std::to_string(regions) + " regions exceed limits.max_interest_regions = " +
                  std::to_string(limits_.max_regions));
  }
  const double m = in.leave_margin();
  if (!std::isfinite(m) || m < 0) {
    return refuse("leave_margin must be finite and >= 0; got " + std::to_string(m));
  }
  std::vector<double> lo(k), hi(k);
  for (size_t r = 0; r < regions; ++r) {
    std::span<const double> rlo(in.region_lo().data() + r * k, k);
    std::span<const double> rhi(in.region_hi().data() + r * k, k);
    if (Status s = host_->CheckBox(rlo, rhi, false); !s.ok()) {
      return refuse("region " + std::to_string(r) + ": " + s.message());
    }
    for (size_t a = 0; a < k; ++a) {
      lo[a] = rlo[a] - m;
      hi[a] = rhi[a] + m;
    }
    if (Status s = host_->CheckBox(lo, hi, true); !s.ok()) {
      return refuse("region " + std::to_string(r) + " grown by leave_margin: " + s.message());
    }
  }
  const size_t listed =
      static_cast<size_t>(in.keys_size()) + static_cast<size_t>(in.producers_size());
  if (listed > limits_.max_keys) {
    return refuse(std::to_string(listed) +
                  " keys and producers exceed limits.max_interest_keys = " +
                  std::to_string(limits_.max_keys));
  }
  for (int i = 0; i < in.keys_size(); ++i) {
    if (in.keys(i) < kLocalIdLimit) {
      return refuse("keys[" + std::to_string(i) + "] = " + std::to_string(in.keys(i)) +
                    " names no producer's object (a key is (producer << 48) | local id)");
    }
  }
  for (int i = 0; i < in.producers_size(); ++i) {
    const uint32_t p = in.producers(i);
    if (p == 0 || p > 65535) {
      return refuse("producers[" + std::to_string(i) + "] = " + std::to_string(p) +
                    " is not a producer id (1..65535)");
    }
    if (!known_producer_(p)) {
      return refuse("producers[" + std::to_string(i) + "] = " + std::to_string(p) +
                    " is unknown (no writer holds it now)");
    }
  }
  if (regions == 0 && in.keys_size() == 0 && in.producers_size() == 0 && in.category_mask() == 0) {
    return refuse("it declares nothing (no region, key, producer or category); drop it instead");
  }
  if (in.pairs_inside() && regions == 0) return refuse("pairs_inside needs a region");
  return Status::Ok();
}

Status InterestTable::Declare(const wire::Interest& in, uint64_t owner, bool take_over) {
  if (Status s = Validate(in, owner, take_over); !s.ok()) return s;
  auto& slot = by_id_[in.id()];
  const bool fresh = !slot;
  if (fresh) {
    slot = std::make_unique<State>();
    slot->id = in.id();
    slot->owner = owner;
  }
  State& s = *slot;
  s.owner = owner;
  if (!fresh) s.changed = true;
  Unwatch(s);
  if (Status st = PlaceRegions(s, in); !st.ok()) {
    // The boxes were checked: only the engine itself can refuse here (it says why).
    Watch(s);
    if (fresh) (void)Drop(in.id(), owner);
    return Status(st.code(), Name(in.id()) + ": " + st.message());
  }
  if (in.pairs_inside() != s.pairs_inside) {
    // The inside counts are kept only for pairs_inside: built from the members, or dropped.
    s.inside.clear();
    if (in.pairs_inside()) {
      for (const auto& region : s.regions) {
        region.members.ForEach([&](uint64_t o) { ++s.inside[o]; });
      }
    }
  }
  s.pairs_inside = in.pairs_inside();
  s.keys = std::unordered_set<uint64_t>(in.keys().begin(), in.keys().end());
  s.producers.assign(in.producers().begin(), in.producers().end());
  std::sort(s.producers.begin(), s.producers.end());
  s.producers.erase(std::unique(s.producers.begin(), s.producers.end()), s.producers.end());
  s.category_mask = in.category_mask();
  s.dirty = true;
  Watch(s);
  if (!adjacency_built_ && NeedsAdjacency(s)) BuildAdjacency();
  return Status::Ok();
}

Status InterestTable::PlaceRegions(State& s, const wire::Interest& in) {
  const size_t k = static_cast<size_t>(host_->Dimension());
  const size_t n = static_cast<size_t>(in.region_lo_size()) / k;
  const double m = in.leave_margin();
  const bool grown = m > 0;
  std::vector<double> lo(k), hi(k);
  for (size_t r = 0; r < n; ++r) {
    std::span<const double> rlo(in.region_lo().data() + r * k, k);
    std::span<const double> rhi(in.region_hi().data() + r * k, k);
    for (size_t a = 0; a < k; ++a) {
      lo[a] = rlo[a] - m;
      hi[a] = rhi[a] + m;
    }
    if (r < s.regions.size() && !s.regions[r].gone && !limits_.fat_boxes &&
        (s.regions[r].leave_key != s.regions[r].enter_key) == grown) {
      // Moved in place: the engine reports exactly who entered and who left.
      State::Region& region = s.regions[r];
      if (Status st = host_->PlaceRegion(region.enter_key, rlo, rhi, false, false); !st.ok()) {
        return st;
      }
      if (grown) {
        if (Status st = host_->PlaceRegion(region.leave_key, lo, hi, true, false); !st.ok()) {
          return st;
        }
      }
      continue;
    }
    if (r < s.regions.size()) {
      EraseRegions(s, r);  // placed anew: another shape, or fat boxes
    } else {
      s.regions.emplace_back();
    }
    State::Region& region = s.regions[r];
    region.gone = false;
    region.enter_key = next_region_key_++;
    region.leave_key = grown ? next_region_key_++ : region.enter_key;
    if (Status st = host_->PlaceRegion(region.enter_key, rlo, rhi, false, true); !st.ok())
      return st;
    region_refs_[region.enter_key] = RegionRef{&s, static_cast<uint32_t>(r), true, !grown};
    if (grown) {
      if (Status st = host_->PlaceRegion(region.leave_key, lo, hi, true, true); !st.ok()) return st;
      region_refs_[region.leave_key] = RegionRef{&s, static_cast<uint32_t>(r), false, true};
    }
  }
  for (size_t r = n; r < s.regions.size(); ++r) EraseRegions(s, r);
  return Status::Ok();
}

// Retires region r of s: its engine objects go, its members leave (their uncollides are
// emitted at the next frame unless they are inside again by then).
void InterestTable::EraseRegions(State& s, size_t r) {
  State::Region& region = s.regions[r];
  if (region.gone) return;
  for (uint64_t key : {region.enter_key, region.leave_key}) {
    if (region_refs_.erase(key) != 0) host_->EraseRegion(key);
  }
  region.members.ForEach([&](uint64_t o) {
    region.changed.emplace_back(o, true);
    region.carry.Insert(o);
    if (!s.pairs_inside) return;
    auto in = s.inside.find(o);
    if (in != s.inside.end() && --in->second == 0) s.inside.erase(in);
  });
  region.members.Clear();
  region.gone = true;
}

Status InterestTable::Drop(uint64_t id, uint64_t owner) {
  const auto it = by_id_.find(id);
  if (it == by_id_.end()) {
    return Status(StatusCode::kNotFound, Name(id) + " does not exist");
  }
  if (it->second->owner != owner) {
    return Status(StatusCode::kAlreadyExists, Name(id) + " is held by another client's writer");
  }
  State& s = *it->second;
  Unwatch(s);
  for (size_t r = 0; r < s.regions.size(); ++r) EraseRegions(s, r);
  by_id_.erase(it);
  return Status::Ok();
}

std::vector<uint64_t> InterestTable::DropOwner(uint64_t owner) {
  std::vector<uint64_t> ids;
  for (const auto& [id, s] : by_id_) {
    if (s->owner == owner) ids.push_back(id);
  }
  std::sort(ids.begin(), ids.end());
  for (uint64_t id : ids) (void)Drop(id, owner);
  return ids;
}

void InterestTable::AddWatch(uint64_t key, State* s) { watch_keys_[key].push_back(s); }

void InterestTable::RemoveWatch(uint64_t key, State* s) { EraseFromList(watch_keys_, key, s); }

void InterestTable::Watch(State& s) {
  for (uint64_t key : s.keys) AddWatch(key, &s);
  if (s.pairs_inside) {
    for (const auto& [o, count] : s.inside) AddWatch(o, &s);
  }
  for (uint32_t p : s.producers) watch_producers_[p].push_back(&s);
  if (s.category_mask != 0) category_interests_.push_back(&s);
}

void InterestTable::Unwatch(State& s) {
  for (uint64_t key : s.keys) RemoveWatch(key, &s);
  if (s.pairs_inside) {
    for (const auto& [o, count] : s.inside) RemoveWatch(o, &s);
  }
  for (uint32_t p : s.producers) {
    auto& list = watch_producers_[p];
    list.erase(std::remove(list.begin(), list.end(), &s), list.end());
    if (list.empty()) watch_producers_.erase(p);
  }
  category_interests_.erase(std::remove(category_interests_.begin(), category_interests_.end(), &s),
                            category_interests_.end());
}

bool InterestTable::Predicate(const State& s, uint64_t a, uint64_t b) const {
  if (s.pairs_inside && s.inside.count(a) != 0 && s.inside.count(b) != 0) return true;
  if (!s.keys.empty() && (s.keys.count(a) != 0 || s.keys.count(b) != 0)) return true;
  if (!s.producers.empty()) {
    for (uint64_t key : {a, b}) {
      const auto p = static_cast<uint32_t>(key >> kProducerShift);
      if (std::binary_search(s.producers.begin(), s.producers.end(), p)) return true;
    }
  }
  if (s.category_mask != 0 && ((host_->Category(a) & s.category_mask) != 0 ||
                               (host_->Category(b) & s.category_mask) != 0)) {
    return true;
  }
  return false;
}

void InterestTable::Reevaluate(State& s, uint64_t a, uint64_t b) {
  const Pair p = a < b ? Pair{a, b} : Pair{b, a};
  if (Predicate(s, p.first, p.second)) {
    if (s.pairs.insert(p).second) {
      s.delta.collide.push_back(p.first);
      s.delta.collide.push_back(p.second);
    }
  } else if (s.pairs.erase(p) != 0) {
    s.delta.uncollide.push_back(p.first);
    s.delta.uncollide.push_back(p.second);
  }
}

void InterestTable::Candidates(uint64_t a, uint64_t b) {
  candidates_.clear();
  ++stamp_;
  auto add = [&](const std::vector<State*>& list) {
    for (State* s : list) {
      if (s->stamp == stamp_ || s->dirty) continue;
      s->stamp = stamp_;
      candidates_.push_back(s);
    }
  };
  if (!watch_keys_.empty()) {
    for (uint64_t key : {a, b}) {
      if (const auto it = watch_keys_.find(key); it != watch_keys_.end()) add(it->second);
    }
  }
  if (!watch_producers_.empty()) {
    for (uint64_t key : {a, b}) {
      const auto p = static_cast<uint32_t>(key >> kProducerShift);
      if (const auto it = watch_producers_.find(p); it != watch_producers_.end()) add(it->second);
    }
  }
  add(category_interests_);
}

bool InterestTable::NeedsAdjacency(const State& s) {
  return s.pairs_inside || !s.keys.empty() || !s.producers.empty() || s.category_mask != 0;
}

void InterestTable::BuildAdjacency() {
  adjacency_.clear();
  std::vector<std::pair<uint64_t, uint64_t>> pairs;
  host_->Snapshot(&pairs);
  for (const auto& [a, b] : pairs) {
    if (a >= kLocalIdLimit) Link(a, b);  // not a region's pair
  }
  adjacency_built_ = true;
}

void InterestTable::Link(uint64_t a, uint64_t b) {
  adjacency_[a].push_back(b);
  adjacency_[b].push_back(a);
}

void InterestTable::Unlink(uint64_t a, uint64_t b) {
  EraseFromList(adjacency_, a, b);
  EraseFromList(adjacency_, b, a);
}

void InterestTable::Recompute(State& s) {
  PairSet fresh;
  auto consider = [&](uint64_t a, uint64_t b) {
    if (Predicate(s, a, b)) fresh.insert(a < b ? Pair{a, b} : Pair{b, a});
  };
  if (!s.producers.empty() || s.category_mask != 0) {
    for (const auto& [a, partners] : adjacency_) {
      for (uint64_t b : partners) {
        if (a < b) consider(a, b);
      }
    }
  } else {
    auto partners_of = [&](uint64_t o) {
      if (const auto it = adjacency_.find(o); it != adjacency_.end()) {
        for (uint64_t x : it->second) consider(o, x);
      }
    };
    for (uint64_t key : s.keys) partners_of(key);
    if (s.pairs_inside) {
      for (const auto& [o, count] : s.inside) partners_of(o);
    }
  }
  for (const Pair& p : s.pairs) {
    if (fresh.count(p) == 0) {
      s.delta.uncollide.push_back(p.first);
      s.delta.uncollide.push_back(p.second);
    }
  }
  for (const Pair& p : fresh) {
    if (s.pairs.count(p) == 0) {
      s.delta.collide.push_back(p.first);
      s.delta.collide.push_back(p.second);
    }
  }
  s.pairs = std::move(fresh);
  s.dirty = false;
}

void InterestTable::OnFrame(Flat* uncollide, Flat* collide) {
  host_->TakeRecategorized(&recategorized_);  // every frame, so that the host's list stays short
  for (auto& [id, s] : by_id_) {
    s->delta.uncollide.clear();
    s->delta.collide.clear();
  }
  // The world's pairs by object, while an interest needs them (see NeedsAdjacency). Built
  // here, they already reflect this frame's events.
  const bool need_adjacency = std::any_of(by_id_.begin(), by_id_.end(),
                                          [](const auto& e) { return NeedsAdjacency(*e.second); });
  bool link = adjacency_built_;
  if (adjacency_built_ && !need_adjacency) {
    adjacency_.clear();
    adjacency_built_ = false;
    link = false;
  }
  if (region_refs_.empty() && region_pairs_ == 0 && by_id_.empty()) return;

  // 1. The regions' pairs, out of the world's events: memberships.
  const size_t region_unc = RegionPrefix(*uncollide);
  const size_t region_col = RegionPrefix(*collide);
  region_pairs_ += region_col;
  region_pairs_ -= region_unc;
  std::vector<std::pair<State*, uint64_t>> left_inside;  // watches to remove at the end
  for (size_t i = 0; i < region_unc; ++i) {
    const auto ref = region_refs_.find((*uncollide)[2 * i]);
    if (ref == region_refs_.end() || !ref->second.leave) continue;
    State& s = *ref->second.state;
    const uint64_t o = (*uncollide)[2 * i + 1];
    State::Region& region = s.regions[ref->second.region];
    if (!region.members.Erase(o)) continue;
    region.changed.emplace_back(o, true);
    if (!s.pairs_inside) continue;
    auto in = s.inside.find(o);
    if (--in->second == 0) {
      s.inside.erase(in);
      s.inside_changed.push_back(o);
      left_inside.emplace_back(&s, o);
    }
  }
  for (size_t i = 0; i < region_col; ++i) {
    const auto ref = region_refs_.find((*collide)[2 * i]);
    if (ref == region_refs_.end()) continue;
    State& s = *ref->second.state;
    const uint64_t o = (*collide)[2 * i + 1];
    State::Region& region = s.regions[ref->second.region];
    if (!ref->second.enter && !region.carry.Contains(o)) continue;
    if (!region.members.Insert(o)) continue;
    region.changed.emplace_back(o, false);
    if (s.pairs_inside && ++s.inside[o] == 1) {
      s.inside_changed.push_back(o);
      AddWatch(o, &s);
    }
  }
  uncollide->erase(uncollide->begin(),
                   uncollide->begin() + static_cast<std::ptrdiff_t>(2 * region_unc));
  collide->erase(collide->begin(), collide->begin() + static_cast<std::ptrdiff_t>(2 * region_col));

  // 2. The object pairs.
  if (need_adjacency && !adjacency_built_) BuildAdjacency();
  if (link) {
    for (size_t i = 0; i < uncollide->size(); i += 2) Unlink((*uncollide)[i], (*uncollide)[i + 1]);
    for (size_t i = 0; i < collide->size(); i += 2) Link((*collide)[i], (*collide)[i + 1]);
  }
  for (size_t i = 0; i < uncollide->size(); i += 2) {
    const uint64_t a = (*uncollide)[i], b = (*uncollide)[i + 1];
    Candidates(a, b);
    for (State* s : candidates_) {
      if (s->pairs.erase(Pair{a, b}) != 0) {
        s->delta.uncollide.push_back(a);
        s->delta.uncollide.push_back(b);
      }
    }
  }
  for (size_t i = 0; i < collide->size(); i += 2) {
    const uint64_t a = (*collide)[i], b = (*collide)[i + 1];
    Candidates(a, b);
    for (State* s : candidates_) {
      if (Predicate(*s, a, b) && s->pairs.insert(Pair{a, b}).second) {
        s->delta.collide.push_back(a);
        s->delta.collide.push_back(b);
      }
    }
  }
  // 3. Objects that entered or left an interest's regions, or changed category: their pairs.
  for (auto& [id, s] : by_id_) {
    if (s->pairs_inside && !s->dirty) {
      for (uint64_t o : s->inside_changed) {
        const auto it = adjacency_.find(o);
        if (it == adjacency_.end()) continue;
        for (uint64_t x : it->second) Reevaluate(*s, o, x);
      }
    }
    s->inside_changed.clear();
  }
  for (State* s : category_interests_) {
    if (s->dirty) continue;
    for (uint64_t o : recategorized_) {
      const auto it = adjacency_.find(o);
      if (it == adjacency_.end()) continue;
      for (uint64_t x : it->second) Reevaluate(*s, o, x);
    }
  }
  // 4. New and changed declarations, whole; then the region pairs, as net changes.
  for (auto& [id, s] : by_id_) {
    if (s->dirty) Recompute(*s);
    for (size_t r = 0; r < s->regions.size(); ++r) {
      State::Region& region = s->regions[r];
      // Each object once, with its first record (its membership at the last frame).
      std::stable_sort(region.changed.begin(), region.changed.end(),
                       [](const auto& x, const auto& y) { return x.first < y.first; });
      for (size_t i = 0; i < region.changed.size(); ++i) {
        const auto [o, was] = region.changed[i];
        if (i > 0 && region.changed[i - 1].first == o) continue;
        const bool now = region.members.Contains(o);
        if (was == now) continue;
        Flat& out = now ? s->delta.collide : s->delta.uncollide;
        out.push_back(r);
        out.push_back(o);
      }
      region.changed.clear();
      region.carry.Clear();
    }
    while (!s->regions.empty() && s->regions.back().gone) s->regions.pop_back();
    s->changed = false;
    SortFlat(&s->delta.uncollide);
    SortFlat(&s->delta.collide);
  }
  // One watch each: an object that left and entered again (another region) was watched twice.
  for (const auto& [s, o] : left_inside) RemoveWatch(o, s);
}

void InterestTable::ForEachDelta(const std::function<void(uint64_t, const Delta&)>& f) const {
  for (const auto& [id, s] : by_id_) {
    if (!s->delta.uncollide.empty() || !s->delta.collide.empty()) f(id, s->delta);
  }
}

bool InterestTable::Snapshot(uint64_t id, std::vector<std::pair<uint64_t, uint64_t>>* out) const {
  out->clear();
  const auto it = by_id_.find(id);
  if (it == by_id_.end()) return false;
  const State& s = *it->second;
  for (size_t r = 0; r < s.regions.size(); ++r) {
    s.regions[r].members.ForEach([&](uint64_t o) { out->emplace_back(r, o); });
  }
  out->insert(out->end(), s.pairs.begin(), s.pairs.end());
  std::sort(out->begin(), out->end());
  return true;
}

bool InterestTable::SnapshotReady(uint64_t id) const {
  const auto it = by_id_.find(id);
  return it != by_id_.end() && !it->second->changed;
}

uint64_t InterestTable::SetSize(uint64_t id) const {
  const auto it = by_id_.find(id);
  if (it == by_id_.end()) return 0;
  uint64_t n = it->second->pairs.size();
  for (const auto& region : it->second->regions) n += region.members.size();
  return n;
}

Status InterestTable::CheckWatches() const {
  std::multiset<std::pair<uint64_t, const State*>> want, have;
  size_t categories = 0, producers = 0, listed = 0;
  for (const auto& [id, s] : by_id_) {
    for (uint64_t key : s->keys) want.emplace(key, s.get());
    if (s->pairs_inside) {
      for (const auto& [o, count] : s->inside) want.emplace(o, s.get());
    }
    if (s->category_mask != 0) ++categories;
    producers += s->producers.size();
  }
  for (const auto& [key, list] : watch_keys_) {
    for (const State* s : list) have.emplace(key, s);
  }
  for (const auto& [p, list] : watch_producers_) listed += list.size();
  if (want != have || categories != category_interests_.size() || producers != listed) {
    return Status(StatusCode::kInternal,
                  "watch lists: " + std::to_string(have.size()) + " key entries for " +
                      std::to_string(want.size()) + ", " + std::to_string(listed) +
                      " producer entries for " + std::to_string(producers) + ", " +
                      std::to_string(category_interests_.size()) + " category interests for " +
                      std::to_string(categories));
  }
  return Status::Ok();
}

uint64_t InterestTable::Owner(uint64_t id) const {
  const auto it = by_id_.find(id);
  return it == by_id_.end() ? 0 : it->second->owner;
}

bool InterestTable::Contains(uint64_t id) const { return by_id_.count(id) != 0; }

}  // namespace bp::service
