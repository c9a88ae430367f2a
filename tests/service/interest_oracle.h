// The brute-force oracle of interests (transport/broadphase.proto, Interest), shared by the
// in-process and the DDS tests: each frame, every interest's set recomputed from scratch from the
// objects' boxes and options, with each region's membership carried from the frame before
// (hysteresis: an object enters on overlapping the region, leaves on not overlapping the region
// grown by the leave margin).
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <utility>
#include <vector>

#include "broadphase.pb.h"
#include "engine_host.h"

#include "bp/box.h"
#include "bp/object_options.h"

namespace bp::test {

template <int K>
struct InterestOracle {
  using Pair = std::pair<uint64_t, uint64_t>;
  using B = Box<K, double>;
  struct Object {
    B box;
    ObjectOptions options;
  };
  struct Declared {
    wire::Interest decl;
    std::vector<std::set<uint64_t>> members;  // by region index
    std::set<Pair> set;
  };

  std::map<uint64_t, Object> objects;
  std::map<uint64_t, Declared> interests;
  std::set<Pair> world;

  static B RegionBox(const wire::Interest& in, size_t r, double grow) {
    B b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = in.region_lo(static_cast<int>(r * K + a)) - grow;
      b.hi[a] = in.region_hi(static_cast<int>(r * K + a)) + grow;
    }
    return b;
  }
  static bool SeenByRegions(const ObjectOptions& o) {
    return (o.mask & service::kRegionCategory) != 0 &&
           (o.category & ~service::kRegionCategory) != 0;
  }

  /// Declares or changes an interest: its regions keep their members by index.
  void Declare(const wire::Interest& in) { interests[in.id()].decl = in; }

  /// The objects overlapping box, sorted.
  std::vector<uint64_t> Spot(const B& box) const {
    std::vector<uint64_t> out;
    for (const auto& [key, o] : objects) {
      if (Overlaps(o.box, box)) out.push_back(key);
    }
    return out;
  }

  /// Advances to the current boxes: the world's pairs, each interest's memberships and set.
  void Step() {
    world.clear();
    for (auto a = objects.begin(); a != objects.end(); ++a) {
      for (auto b = std::next(a); b != objects.end(); ++b) {
        if (Overlaps(a->second.box, b->second.box) &&
            Accepts(a->second.options, b->second.options)) {
          world.emplace(a->first, b->first);
        }
      }
    }
    for (auto& [id, d] : interests) {
      const wire::Interest& in = d.decl;
      const size_t regions = static_cast<size_t>(in.region_lo_size()) / K;
      d.members.resize(regions);
      std::set<uint64_t> inside;
      d.set.clear();
      for (size_t r = 0; r < regions; ++r) {
        const B region = RegionBox(in, r, 0), grown = RegionBox(in, r, in.leave_margin());
        std::set<uint64_t> next;
        for (const auto& [key, o] : objects) {
          if (!SeenByRegions(o.options)) continue;
          if (Overlaps(o.box, region) || (d.members[r].count(key) && Overlaps(o.box, grown))) {
            next.insert(key);
          }
        }
        d.members[r] = next;
        for (uint64_t key : next) {
          inside.insert(key);
          d.set.emplace(r, key);
        }
      }
      const std::set<uint64_t> keys(in.keys().begin(), in.keys().end());
      const std::set<uint32_t> producers(in.producers().begin(), in.producers().end());
      for (const Pair& p : world) {
        bool in_set = in.pairs_inside() && inside.count(p.first) && inside.count(p.second);
        for (uint64_t k : {p.first, p.second}) {
          in_set = in_set || keys.count(k) || producers.count(static_cast<uint32_t>(k >> 48)) ||
                   (objects.at(k).options.category & in.category_mask()) != 0;
        }
        if (in_set) d.set.insert(p);
      }
    }
  }
};

}  // namespace bp::test
