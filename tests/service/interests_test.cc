// InterestTable without DDS: every kind of interest (regions with and without a leave margin,
// pairs inside, keys, producers, categories, and their mixtures) on a real engine host, frame by
// frame against the brute-force oracle filtered the same way; declarations changed and dropped at
// run time; refusals.
#include "interests.h"

#include <algorithm>
#include <map>
#include <random>
#include <set>

#include "interest_oracle.h"
#include <gtest/gtest.h>

#include "bp/box.h"
#include "bp/client/batch_builder.h"
#include "bp/object_options.h"

namespace bp::service {
namespace {

using Pair = std::pair<uint64_t, uint64_t>;
using PairSet = std::set<Pair>;

std::unique_ptr<EngineHost> MakeHost(const char* algorithm, int dim) {
  EngineConfig config;
  config.algorithm = algorithm;
  config.dimension = dim;
  config.coordinate = CoordinateType::kDouble;
  std::unique_ptr<EngineHost> host;
  Status s = MakeEngineHost(config, 1 << 20, &host);
  EXPECT_TRUE(s.ok()) << s.ToString();
  return host;
}

PairSet ToSet(const std::vector<uint64_t>& flat) {
  PairSet out;
  for (size_t i = 0; i + 1 < flat.size(); i += 2) out.emplace(flat[i], flat[i + 1]);
  return out;
}

bool IsSortedFlat(const std::vector<uint64_t>& flat) {
  for (size_t i = 2; i + 1 < flat.size(); i += 2) {
    if (Pair{flat[i - 2], flat[i - 1]} >= Pair{flat[i], flat[i + 1]}) return false;
  }
  return true;
}

template <int K>
class InterestScene {
 public:
  using B = Box<K, double>;
  InterestScene(const char* algorithm, uint32_t seed)
      : host_(MakeHost(algorithm, K)),
        table_(host_.get(), InterestLimits{}, [](uint32_t p) { return p == 1 || p == 2; }),
        rng_(seed) {}

  B RandomBox(double size) {
    std::uniform_real_distribution<double> at(0, 40), extent(0.5, size);
    B b;
    for (size_t a = 0; a < K; ++a) {
      b.lo[a] = at(rng_);
      b.hi[a] = b.lo[a] + extent(rng_);
    }
    return b;
  }

  ObjectOptions RandomOptions() {
    ObjectOptions o;
    const uint64_t categories[] = {1, 2, 4, 3, 1, 1};
    o.category = categories[rng_() % 6];
    const unsigned m = static_cast<unsigned>(rng_() % 20);
    if (m == 0) o.mask = 0;                    // pairs with nothing
    if (m == 1) o.mask = ~kRegionCategory;     // invisible to regions
    if (m == 2) o.mask = 1 | kRegionCategory;  // pairs with category 1 and regions only
    o.is_static = rng_() % 10 == 0;
    return o;
  }

  void Insert(wire::UpdateBatch* batch, uint64_t local) {
    const uint32_t producer = batch->producer();
    const B box = RandomBox(6);
    const ObjectOptions o = RandomOptions();
    client::AddBox<K>(batch->mutable_inserts(), local, box);
    batch->mutable_inserts()->add_category(o.category);
    batch->mutable_inserts()->add_mask(o.mask);
    batch->mutable_inserts()->add_static_flags(o.is_static);
    oracle_.objects[GlobalKey(producer, local)] = {box, o};
  }

  // One producer's batch of moves, erases, inserts and recategorizations (erase and reinsert).
  void Churn(uint32_t producer) {
    wire::UpdateBatch batch;
    batch.set_version(wire::SCHEMA_VERSION_1);
    batch.set_producer(producer);
    batch.set_dim(K);
    std::vector<uint64_t> mine;
    for (const auto& [key, o] : oracle_.objects) {
      if ((key >> 48) == producer) mine.push_back(key & (kLocalIdLimit - 1));
    }
    std::set<uint64_t> touched;
    for (uint64_t local : mine) {
      const unsigned roll = static_cast<unsigned>(rng_() % 100);
      const uint64_t key = GlobalKey(producer, local);
      if (roll < 3) {
        batch.add_erases(local);
        oracle_.objects.erase(key);
      } else if (roll < 5) {
        batch.add_erases(local);
        Insert(&batch, local);
        touched.insert(local);
      } else if (roll < 30) {
        B box = oracle_.objects[key].box;
        std::uniform_real_distribution<double> step(-2.5, 2.5);
        for (size_t a = 0; a < K; ++a) {
          const double d = step(rng_);
          box.lo[a] += d;
          box.hi[a] += d;
        }
        client::AddBox<K>(batch.mutable_updates(), local, box);
        oracle_.objects[key].box = box;
      }
    }
    for (int i = 0; i < 6; ++i) Insert(&batch, next_local_++);
    ApplyCounts counts;
    host_->Apply(
        batch, [](Reject&& r) { ADD_FAILURE() << r.message; }, &counts);
  }

  wire::Interest RandomInterest(uint64_t id, int kind) {
    wire::Interest in;
    in.set_id(id);
    in.set_dim(K);
    auto add_region = [&](double size) {
      const B b = RandomBox(size);
      for (size_t a = 0; a < K; ++a) in.add_region_lo(b.lo[a]);
      for (size_t a = 0; a < K; ++a) in.add_region_hi(b.hi[a]);
    };
    switch (kind % 6) {
      case 0:  // two regions, pairs inside
        add_region(15);
        add_region(15);
        in.set_pairs_inside(true);
        break;
      case 1:  // a region with hysteresis
        add_region(20);
        in.set_leave_margin(3);
        break;
      case 2:  // keys, some not live
        for (int i = 0; i < 12; ++i) in.add_keys(GlobalKey(1 + rng_() % 2, rng_() % next_local_));
        break;
      case 3:
        in.add_producers(2);
        break;
      case 4:
        in.set_category_mask(4);
        break;
      default:  // a mixture
        add_region(12);
        add_region(12);
        add_region(12);
        in.set_leave_margin(static_cast<double>(rng_() % 3));
        in.set_pairs_inside(rng_() % 2 == 0);
        in.add_keys(GlobalKey(1, rng_() % next_local_));
        in.set_category_mask(2);
        break;
    }
    return in;
  }

  void Declare(const wire::Interest& in) {
    const bool changed = table_.Contains(in.id());
    Status s = table_.Declare(in, /*owner=*/7);
    ASSERT_TRUE(s.ok()) << s.ToString();
    // A changed interest's snapshot waits for the frame that applies the change.
    EXPECT_EQ(table_.SnapshotReady(in.id()), !changed);
    oracle_.Declare(in);
  }

  void Frame(int frame) {
    std::vector<uint64_t> uncollide, collide;
    host_->Query(&uncollide, &collide);
    table_.OnFrame(&uncollide, &collide);
    const PairSet world_before = oracle_.world;
    std::map<uint64_t, PairSet> before;
    for (const auto& [id, d] : oracle_.interests) before[id] = d.set;
    oracle_.Step();
    // The world's stream shows no region.
    PairSet expect_unc, expect_col;
    std::set_difference(world_before.begin(), world_before.end(), oracle_.world.begin(),
                        oracle_.world.end(), std::inserter(expect_unc, expect_unc.end()));
    std::set_difference(oracle_.world.begin(), oracle_.world.end(), world_before.begin(),
                        world_before.end(), std::inserter(expect_col, expect_col.end()));
    ASSERT_EQ(ToSet(uncollide), expect_unc) << "frame " << frame;
    ASSERT_EQ(ToSet(collide), expect_col) << "frame " << frame;
    ASSERT_EQ(host_->Overlaps() - table_.region_pairs(), oracle_.world.size());
    ASSERT_TRUE(table_.CheckWatches().ok()) << table_.CheckWatches().ToString();
    std::map<uint64_t, InterestTable::Delta> deltas;
    table_.ForEachDelta([&](uint64_t id, const InterestTable::Delta& d) { deltas[id] = d; });
    for (const auto& [id, d] : oracle_.interests) {
      const PairSet& old_set = before[id];
      PairSet unc, col;
      std::set_difference(old_set.begin(), old_set.end(), d.set.begin(), d.set.end(),
                          std::inserter(unc, unc.end()));
      std::set_difference(d.set.begin(), d.set.end(), old_set.begin(), old_set.end(),
                          std::inserter(col, col.end()));
      const InterestTable::Delta& got = deltas[id];
      ASSERT_TRUE(IsSortedFlat(got.uncollide) && IsSortedFlat(got.collide));
      ASSERT_EQ(ToSet(got.uncollide), unc) << "interest " << id << " frame " << frame;
      ASSERT_EQ(ToSet(got.collide), col) << "interest " << id << " frame " << frame;
      std::vector<Pair> snapshot;
      ASSERT_TRUE(table_.SnapshotReady(id));
      ASSERT_TRUE(table_.Snapshot(id, &snapshot));
      ASSERT_EQ(PairSet(snapshot.begin(), snapshot.end()), d.set) << "interest " << id;
      ASSERT_EQ(table_.SetSize(id), d.set.size());
    }
  }

  void Run(int frames) {
    for (uint32_t kind = 0; kind < 6; ++kind) Churn(1 + kind % 2);  // a world first
    Frame(0);
    for (int kind = 0; kind < 6; ++kind)
      Declare(RandomInterest(100 + static_cast<uint64_t>(kind), kind));
    size_t region_events = 0, object_events = 0;
    for (int f = 1; f <= frames; ++f) {
      Churn(1);
      Churn(2);
      const uint64_t id = 100 + rng_() % 6;
      const unsigned roll = static_cast<unsigned>(rng_() % 10);
      if (roll < 3) {
        // Changed at run time: any new kind keeps the id (regions move, margins change...).
        Declare(RandomInterest(id, static_cast<int>(rng_() % 6)));
      } else if (roll == 3 && oracle_.interests.count(id)) {
        ASSERT_TRUE(table_.Drop(id, 7).ok());
        oracle_.interests.erase(id);
      } else if (roll == 4 && oracle_.interests.count(id)) {
        // A moving region: the same declaration shifted.
        wire::Interest in = oracle_.interests[id].decl;
        for (int i = 0; i < in.region_lo_size(); ++i) {
          in.set_region_lo(i, in.region_lo(i) + 1.5);
          in.set_region_hi(i, in.region_hi(i) + 1.5);
        }
        if (in.region_lo_size() > 0) Declare(in);
      }
      Frame(f);
      if (::testing::Test::HasFatalFailure()) return;
      table_.ForEachDelta([&](uint64_t, const InterestTable::Delta& d) {
        for (const auto* flat : {&d.uncollide, &d.collide}) {
          for (size_t i = 0; i < flat->size(); i += 2) {
            ++((*flat)[i] < kLocalIdLimit ? region_events : object_events);
          }
        }
      });
    }
    EXPECT_GT(region_events, 40u) << "the scene exercises the regions";
    EXPECT_GT(object_events, 100u) << "the scene exercises the object pairs";
  }

  std::unique_ptr<EngineHost> host_;
  InterestTable table_;
  std::mt19937_64 rng_;
  test::InterestOracle<K> oracle_;
  uint64_t next_local_ = 1;
};

TEST(Interests, EveryKindMatchesTheOracleFrameByFrame3D) {
  for (uint32_t seed = 1; seed <= 8; ++seed) {
    InterestScene<3> scene("grid_dense", seed);
    scene.Run(60);
  }
}

TEST(Interests, EveryKindMatchesTheOracleFrameByFrame2D) {
  for (uint32_t seed = 1; seed <= 8; ++seed) {
    InterestScene<2> scene("grid_segmented_sap", seed);
    scene.Run(60);
  }
}

TEST(Interests, HysteresisKeepsABorderObjectInside) {
  InterestScene<2> scene("grid_dense", 3);
  wire::UpdateBatch batch;
  batch.set_version(wire::SCHEMA_VERSION_1);
  batch.set_producer(1);
  batch.set_dim(2);
  client::AddBox<2>(batch.mutable_inserts(), 1, Box<2, double>{{{9, 0}}, {{10, 1}}});
  ApplyCounts counts;
  scene.host_->Apply(
      batch, [](Reject&& r) { ADD_FAILURE() << r.message; }, &counts);
  wire::Interest in;
  in.set_id(5);
  in.set_dim(2);
  for (double v : {0.0, 0.0}) in.add_region_lo(v);
  for (double v : {10.0, 10.0}) in.add_region_hi(v);
  in.set_leave_margin(2);
  ASSERT_TRUE(scene.table_.Declare(in, 1).ok());
  std::vector<uint64_t> unc, col;
  auto frame = [&](double x) {
    wire::UpdateBatch move = batch;
    move.clear_inserts();
    client::AddBox<2>(move.mutable_updates(), 1, Box<2, double>{{{x, 0}}, {{x + 1, 1}}});
    scene.host_->Apply(
        move, [](Reject&& r) { ADD_FAILURE() << r.message; }, &counts);
    scene.host_->Query(&unc, &col);
    scene.table_.OnFrame(&unc, &col);
    return scene.table_.SetSize(5);
  };
  EXPECT_EQ(frame(9.5), 1u);   // overlaps the region: inside
  EXPECT_EQ(frame(10.5), 1u);  // beyond the region, within the margin: still inside
  EXPECT_EQ(frame(11.5), 1u);
  EXPECT_EQ(frame(12.5), 0u);  // beyond the margin: left
  EXPECT_EQ(frame(11.5), 0u);  // within the margin only: stays out
  EXPECT_EQ(frame(10.0), 1u);  // touches the region: inside again
}

TEST(Interests, BadDeclarationsAreRefusedWithTheirReason) {
  auto host = MakeHost("grid_dense", 3);
  InterestTable table(host.get(), InterestLimits{2, 2, 3}, [](uint32_t p) { return p == 1; });
  auto region = [](wire::Interest* in, std::vector<double> lo, std::vector<double> hi) {
    for (double v : lo) in->add_region_lo(v);
    for (double v : hi) in->add_region_hi(v);
  };
  auto refused = [&](const wire::Interest& in, const std::string& why) {
    Status s = table.Declare(in, 1);
    EXPECT_FALSE(s.ok());
    EXPECT_NE(s.message().find(why), std::string::npos) << s.message();
  };
  wire::Interest in;
  in.set_dim(3);
  region(&in, {0, 0, 0}, {1, 1, 1});
  refused(in, "id 0");
  in.set_id(9);
  in.set_dim(2);
  refused(in, "dimension is 3");
  in.set_dim(3);
  in.set_region_lo(1, std::nan(""));
  refused(in, "NaN");
  in.set_region_lo(1, 2);
  refused(in, "lo > hi on axis 1");
  in.set_region_lo(1, 0);
  in.set_leave_margin(-1);
  refused(in, "leave_margin");
  in.set_leave_margin(0);
  in.add_keys(5);
  refused(in, "keys[0] = 5 names no producer");
  in.clear_keys();
  in.add_producers(2);
  refused(in, "producers[0] = 2 is unknown");
  in.clear_producers();
  region(&in, {0, 0, 0}, {1, 1, 1});
  region(&in, {0, 0, 0}, {1, 1, 1});
  refused(in, "limits.max_interest_regions");
  wire::Interest empty;
  empty.set_id(3);
  refused(empty, "declares nothing");
  wire::Interest keys;
  keys.set_id(4);
  for (uint64_t k = 1; k <= 4; ++k) keys.add_keys(GlobalKey(1, k));
  refused(keys, "limits.max_interest_keys");
  keys.clear_keys();
  keys.add_producers(1);
  EXPECT_TRUE(table.Declare(keys, 1).ok());
  EXPECT_EQ(table.Declare(keys, 2).code(), StatusCode::kAlreadyExists);
  EXPECT_EQ(table.Drop(4, 2).code(), StatusCode::kAlreadyExists);
  keys.set_id(6);
  EXPECT_TRUE(table.Declare(keys, 1).ok());
  keys.set_id(8);
  refused(keys, "limits.max_interests");
  EXPECT_EQ(table.size(), 2u);
  EXPECT_EQ(table.DropOwner(1), (std::vector<uint64_t>{4, 6}));
  EXPECT_EQ(table.size(), 0u);
  EXPECT_EQ(table.Drop(4, 1).code(), StatusCode::kNotFound);
}

}  // namespace
}  // namespace bp::service
