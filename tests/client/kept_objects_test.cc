// The publisher's store of kept objects (client/src/kept_objects.h) against a std::unordered_map
// model: random inserts, erases (kept and unknown ids) and batched look-ups with prefetching,
// with ids dense, in steps of 16 and near 2^48.

#include "kept_objects.h"

#include <cstdint>
#include <random>
#include <unordered_map>
#include <vector>

#include <gtest/gtest.h>

namespace bp::client {
namespace {

uint64_t MakeId(std::mt19937_64& rng, int style) {
  switch (style) {
    case 0:
      return rng() % 3000;  // dense
    case 1:
      return (rng() % 3000) * 16;  // low bits never vary
    default:
      return (uint64_t{1} << 48) - 1 - rng() % 3000;  // near the top of the id space
  }
}

TEST(KeptObjects, MatchesAMapUnderRandomInsertsErasesAndBatchedLookups) {
  for (int style = 0; style < 3; ++style) {
    std::mt19937_64 rng(static_cast<uint64_t>(1234 + style));
    KeptObjects kept;
    std::unordered_map<uint64_t, double> model;  // id -> lo[0]
    for (int round = 0; round < 300; ++round) {
      const int inserts = static_cast<int>(rng() % 40);
      for (int i = 0; i < inserts; ++i) {
        const uint64_t id = MakeId(rng, style);
        ASSERT_EQ(kept.Contains(id), model.contains(id));
        if (model.contains(id)) continue;
        KeptObjects::Record r;
        r.id = id;
        r.lo[0] = static_cast<double>(rng() % 1000);
        kept.Insert(r);
        model[id] = r.lo[0];
      }
      const int erases = static_cast<int>(rng() % 30);
      for (int i = 0; i < erases; ++i) {
        const uint64_t id = MakeId(rng, style);
        ASSERT_EQ(kept.Erase(id), model.erase(id) == 1) << "id " << id;
      }
      // A batch of look-ups longer than the prefetch distances, with unknown and repeated ids.
      std::vector<uint64_t> ids(rng() % 60);
      for (uint64_t& id : ids) id = MakeId(rng, style);
      std::vector<int> seen(ids.size(), 0);
      kept.ForEachFound(ids, [&](size_t i, KeptObjects::Record* r) {
        ++seen[i];
        const auto it = model.find(ids[i]);
        ASSERT_EQ(r != nullptr, it != model.end()) << "id " << ids[i];
        if (r == nullptr) return;
        ASSERT_EQ(r->id, ids[i]);
        ASSERT_EQ(r->lo[0], it->second);
        r->lo[0] += 1;
        it->second += 1;
      });
      for (int s : seen) ASSERT_EQ(s, 1);
      ASSERT_EQ(kept.size(), model.size());
      ASSERT_TRUE(kept.Valid()) << "style " << style << " round " << round;
    }
    // Storage order holds each kept id once, with its last value.
    std::unordered_map<uint64_t, double> stored;
    for (size_t h = 0; h < kept.size(); ++h) {
      ASSERT_TRUE(stored.emplace(kept.at(h).id, kept.at(h).lo[0]).second);
    }
    EXPECT_EQ(stored, model);
  }
}

}  // namespace
}  // namespace bp::client
