// EngineHost without DDS: the service-boundary validation, the id space, coordinate conversion
// and filtering, checked against the brute-force oracle and a model of the live set. Why one
// file of about 700 lines: one test per rule of the engine host's validation (engine_host.h).
#include "engine_host.h"

#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <set>

#include <gtest/gtest.h>

#include "bp/brute_force.h"
#include "bp/client/batch_builder.h"

namespace bp::service {
namespace {

using PairList = std::vector<std::pair<uint64_t, uint64_t>>;

std::unique_ptr<EngineHost> MakeHost(const char* algorithm, int dim, CoordinateType coordinate,
                                     uint64_t max_objects = 1 << 20) {
  EngineConfig config;
  config.algorithm = algorithm;
  config.dimension = dim;
  config.coordinate = coordinate;
  std::unique_ptr<EngineHost> host;
  Status s = MakeEngineHost(config, max_objects, &host);
  EXPECT_TRUE(s.ok()) << s.ToString();
  return host;
}

PairList ToPairs(const std::vector<uint64_t>& flat) {
  PairList out;
  for (size_t i = 0; i + 1 < flat.size(); i += 2) out.emplace_back(flat[i], flat[i + 1]);
  return out;
}

struct Outcome {
  std::vector<Reject> rejects;
  ApplyCounts counts;
};

Outcome Apply(EngineHost& host, const wire::UpdateBatch& batch) {
  Outcome out;
  host.Apply(
      batch, [&](Reject&& r) { out.rejects.push_back(std::move(r)); }, &out.counts);
  return out;
}

// The (index, reason) of each of out's rejects, every one expected to be of operation op.
std::vector<std::pair<uint32_t, wire::RejectReason>> RejectsOf(const Outcome& out, wire::Op op) {
  std::vector<std::pair<uint32_t, wire::RejectReason>> got;
  for (const Reject& r : out.rejects) {
    EXPECT_EQ(r.op, op);
    got.emplace_back(r.index, r.reason);
  }
  return got;
}

wire::UpdateBatch Batch(uint32_t producer, int dim) {
  wire::UpdateBatch b;
  b.set_version(wire::SCHEMA_VERSION_1);
  b.set_producer(producer);
  b.set_dim(static_cast<uint32_t>(dim));
  return b;
}

void AddBox(wire::BoxArray* a, uint64_t id, const std::vector<double>& lo,
            const std::vector<double>& hi) {
  a->add_ids(id);
  for (double v : lo) a->add_lo64(v);
  for (double v : hi) a->add_hi64(v);
}

// Random batches from three producers with valid and invalid items; the host's events must
// equal the oracle's on the valid items, and each invalid item must be refused for its reason.
template <int K>
void RandomBatches(const char* algorithm, CoordinateType coordinate, uint64_t seed) {
  SCOPED_TRACE(::testing::Message() << algorithm << " K=" << K << " seed=" << seed);
  auto host = MakeHost(algorithm, K, coordinate);
  BruteForce<K, double, uint64_t> oracle;
  std::mt19937_64 rng(seed);
  std::map<uint64_t, bool> live;  // global key -> live (model)
  auto coord = [&] { return static_cast<double>(rng() % 40); };
  for (int frame = 0; frame < 40; ++frame) {
    std::set<uint64_t> touched;  // keys named by a valid item in this frame's batches
    for (uint32_t producer = 1; producer <= 3; ++producer) {
      wire::UpdateBatch batch = Batch(producer, K);
      std::vector<wire::RejectReason> expect_insert, expect_update, expect_erase;
      std::set<uint64_t> erased_now;
      for (int i = 0; i < 6; ++i) {
        const uint64_t id = rng() % 30;
        const uint64_t key = GlobalKey(producer, id);
        const bool ok = live.count(key) > 0 && live[key];
        if (ok && rng() % 2 == 0 && !erased_now.count(id)) {
          batch.add_erases(id);
          erased_now.insert(id);
          expect_erase.push_back(wire::REJECT_REASON_UNSPECIFIED);
          live[key] = false;
          ASSERT_TRUE(oracle.Erase(key).ok());
        } else if (!ok && rng() % 4 == 0) {
          batch.add_erases(id);  // unknown
          expect_erase.push_back(wire::UNKNOWN_ID);
        }
      }
      for (int i = 0; i < 6; ++i) {
        const uint64_t id = rng() % 30;
        const uint64_t key = GlobalKey(producer, id);
        std::vector<double> lo(K), hi(K);
        for (int a = 0; a < K; ++a) {
          lo[static_cast<size_t>(a)] = coord();
          hi[static_cast<size_t>(a)] = lo[static_cast<size_t>(a)] + static_cast<double>(rng() % 6);
        }
        wire::RejectReason expect = wire::REJECT_REASON_UNSPECIFIED;
        const int fault = static_cast<int>(rng() % 10);
        if (fault == 0) {
          lo[0] = std::numeric_limits<double>::quiet_NaN();
          expect = wire::NOT_FINITE;
        } else if (fault == 1) {
          std::swap(lo[K - 1], hi[K - 1]);
          hi[K - 1] -= 1;
          expect = wire::INVERTED;
        } else if (live.count(key) && live[key]) {
          expect = wire::DUPLICATE_INSERT;
        }
        AddBox(batch.mutable_inserts(), id, lo, hi);
        expect_insert.push_back(expect);
        if (expect == wire::REJECT_REASON_UNSPECIFIED) {
          live[key] = true;
          Box<K, double> box;
          for (size_t a = 0; a < K; ++a) box.lo[a] = lo[a], box.hi[a] = hi[a];
          ASSERT_TRUE(oracle.Insert(key, box).ok());
        }
      }
      for (int i = 0; i < 6; ++i) {
        const uint64_t id = rng() % 30;
        const uint64_t key = GlobalKey(producer, id);
        std::vector<double> lo(K), hi(K);
        for (int a = 0; a < K; ++a) {
          lo[static_cast<size_t>(a)] = coord();
          hi[static_cast<size_t>(a)] = lo[static_cast<size_t>(a)] + static_cast<double>(rng() % 6);
        }
        const bool known = live.count(key) && live[key];
        AddBox(batch.mutable_updates(), id, lo, hi);
        expect_update.push_back(known ? wire::REJECT_REASON_UNSPECIFIED : wire::UNKNOWN_ID);
        if (known) {
          Box<K, double> box;
          for (size_t a = 0; a < K; ++a) box.lo[a] = lo[a], box.hi[a] = hi[a];
          ASSERT_TRUE(oracle.Update(key, box).ok());
        }
      }
      Outcome out = Apply(*host, batch);
      auto check = [&](wire::Op op, const std::vector<wire::RejectReason>& expect) {
        for (size_t i = 0; i < expect.size(); ++i) {
          const Reject* found = nullptr;
          for (auto& r : out.rejects) {
            if (r.op == op && r.index == i) found = &r;
          }
          if (expect[i] == wire::REJECT_REASON_UNSPECIFIED) {
            EXPECT_EQ(found, nullptr) << "op " << op << " item " << i << ": " << found->message;
          } else {
            ASSERT_NE(found, nullptr) << "op " << op << " item " << i << " not rejected";
            EXPECT_EQ(found->reason, expect[i]) << found->message;
          }
        }
      };
      check(wire::OP_ERASE, expect_erase);
      check(wire::OP_INSERT, expect_insert);
      check(wire::OP_UPDATE, expect_update);
    }
    std::vector<uint64_t> unc, col;
    host->Query(&unc, &col);
    PairList want_unc, want_col;
    struct Sink final : EventSink<uint64_t> {
      PairList* u;
      PairList* c;
      void Collide(const uint64_t& a, const uint64_t& b) override { c->emplace_back(a, b); }
      void Uncollide(const uint64_t& a, const uint64_t& b) override { u->emplace_back(a, b); }
    } sink;
    sink.u = &want_unc;
    sink.c = &want_col;
    oracle.Query(sink);
    ASSERT_EQ(ToPairs(unc), want_unc) << "frame " << frame;
    ASSERT_EQ(ToPairs(col), want_col) << "frame " << frame;
    EXPECT_EQ(host->Objects(), oracle.Size());
  }
}

TEST(EngineHost, RandomBatchesMatchTheOracle) {
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    for (const char* algorithm : {"segmented_sap", "batch_sap", "dynamic_octree", "brute_force",
                                  "grid_segmented_sap", "grid_batch_sap", "grid_dense"}) {
      for (CoordinateType c :
           {CoordinateType::kFloat, CoordinateType::kDouble, CoordinateType::kInt32}) {
        RandomBatches<3>(algorithm, c, seed);
        RandomBatches<2>(algorithm, c, seed);
      }
    }
  }
}

// engine.threads reaches the grid engines: their pool has that many threads (it once did not),
// and auto resolves to EngineThreads.
TEST(EngineHost, ThreadsReachTheGridEngines) {
  for (const char* algorithm : {"grid_segmented_sap", "grid_batch_sap", "grid_dense"}) {
    EngineConfig config;
    config.algorithm = algorithm;
    config.threads = 3;
    std::unique_ptr<EngineHost> host;
    ASSERT_TRUE(MakeEngineHost(config, 1 << 20, &host).ok()) << algorithm;
    EXPECT_EQ(host->GetStats().threads, 3u) << algorithm;
    // The default, auto: the CPUs the process may run on.
    config.threads = 0;
    ASSERT_TRUE(MakeEngineHost(config, 1 << 20, &host).ok()) << algorithm;
    EXPECT_EQ(host->GetStats().threads, static_cast<size_t>(EngineThreads(config))) << algorithm;
    EXPECT_GE(host->GetStats().threads, 1u) << algorithm;
  }
  // A single-threaded engine says so whatever the setting.
  EngineConfig config;
  config.algorithm = "segmented_sap";
  std::unique_ptr<EngineHost> host;
  ASSERT_TRUE(MakeEngineHost(config, 1 << 20, &host).ok());
  EXPECT_EQ(host->GetStats().threads, 1u);
}

// Updates reach the engine in runs through UpdateMany; a run ends before an item the host refuses
// itself, so every refusal must come out in index order, with the counts adding up.
TEST(EngineHost, UpdateRefusalsComeInIndexOrder) {
  auto host = MakeHost("grid_dense", 3, CoordinateType::kFloat);
  wire::UpdateBatch load = Batch(1, 3);
  for (uint64_t id = 1; id <= 40; ++id) {
    const double x = static_cast<double>(id) * 3;
    AddBox(load.mutable_inserts(), id, {x, 0, 0}, {x + 1, 1, 1});
  }
  ASSERT_TRUE(Apply(*host, load).rejects.empty());
  std::vector<uint64_t> unc, col;
  host->Query(&unc, &col);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  wire::UpdateBatch batch = Batch(1, 3);
  std::vector<std::pair<uint32_t, wire::RejectReason>> want;
  auto add = [&](uint64_t id, double x, wire::RejectReason reason) {
    if (reason != wire::REJECT_REASON_UNSPECIFIED) {
      want.emplace_back(static_cast<uint32_t>(batch.updates().ids_size()), reason);
    }
    AddBox(batch.mutable_updates(), id, {x, 0, 0}, {x + 1, 1, 1});
  };
  add(100, 0, wire::UNKNOWN_ID);
  add(1, nan, wire::NOT_FINITE);
  add(101, 0, wire::UNKNOWN_ID);
  add(2, 9, wire::REJECT_REASON_UNSPECIFIED);  // onto 3 (9.5..10.5 after its update)
  add(uint64_t{1} << 48, 0, wire::ID_OUT_OF_RANGE);
  add(102, 0, wire::UNKNOWN_ID);
  for (uint64_t id = 3; id <= 32; ++id) {  // a run longer than the engine's look-ahead
    add(id, static_cast<double>(id) * 3 + 0.5, wire::REJECT_REASON_UNSPECIFIED);
  }
  add(103, 0, wire::UNKNOWN_ID);
  add(33, 99.5, wire::REJECT_REASON_UNSPECIFIED);
  add(1, 102.5, wire::REJECT_REASON_UNSPECIFIED);  // its NaN was refused; onto 34 (102..103)
  Outcome out = Apply(*host, batch);
  EXPECT_EQ(RejectsOf(out, wire::OP_UPDATE), want);
  EXPECT_EQ(out.counts.updates, 33u);
  EXPECT_EQ(out.counts.rejected, want.size());
  host->Query(&unc, &col);  // the kept updates applied, the refused ones not
  EXPECT_TRUE(unc.empty());
  EXPECT_EQ(col, (std::vector<uint64_t>{GlobalKey(1, 1), GlobalKey(1, 34), GlobalKey(1, 2),
                                        GlobalKey(1, 3)}));
}

// Erases reach the engine in runs through EraseMany; a run ends before an id the host refuses
// itself, so refusals come out in index order; the kept erases take their objects' pairs along.
TEST(EngineHost, EraseRefusalsComeInIndexOrder) {
  auto host = MakeHost("grid_dense", 3, CoordinateType::kFloat);
  wire::UpdateBatch load = Batch(1, 3);
  for (uint64_t id = 1; id <= 40; ++id) {  // 2k-1 and 2k overlap
    const double x = static_cast<double>((id + 1) / 2) * 3;
    AddBox(load.mutable_inserts(), id, {x, 0, 0}, {x + 1, 1, 1});
  }
  ASSERT_TRUE(Apply(*host, load).rejects.empty());
  std::vector<uint64_t> unc, col;
  host->Query(&unc, &col);
  ASSERT_EQ(col.size(), 40u);
  wire::UpdateBatch batch = Batch(1, 3);
  std::vector<std::pair<uint32_t, wire::RejectReason>> want;
  auto erase = [&](uint64_t id, wire::RejectReason reason) {
    if (reason != wire::REJECT_REASON_UNSPECIFIED) {
      want.emplace_back(static_cast<uint32_t>(batch.erases_size()), reason);
    }
    batch.add_erases(id);
  };
  erase(100, wire::UNKNOWN_ID);
  erase(1, wire::REJECT_REASON_UNSPECIFIED);
  erase(1, wire::UNKNOWN_ID);  // erased by this batch already
  erase(uint64_t{1} << 48, wire::ID_OUT_OF_RANGE);
  for (uint64_t id = 3; id <= 31; id += 2) erase(id, wire::REJECT_REASON_UNSPECIFIED);  // > 16
  erase(101, wire::UNKNOWN_ID);
  erase(33, wire::REJECT_REASON_UNSPECIFIED);
  Outcome out = Apply(*host, batch);
  EXPECT_EQ(RejectsOf(out, wire::OP_ERASE), want);
  EXPECT_EQ(out.counts.erases, 17u);
  EXPECT_EQ(out.counts.rejected, want.size());
  EXPECT_EQ(host->Objects(), 23u);
  host->Query(&unc, &col);  // the pairs of the 17 erased objects end
  EXPECT_TRUE(col.empty());
  EXPECT_EQ(unc.size(), 2 * 17u);
}

TEST(EngineHost, UnknownAlgorithmOrDimensionIsRefused) {
  EngineConfig config;
  std::unique_ptr<EngineHost> host;
  config.algorithm = "octree";
  EXPECT_EQ(MakeEngineHost(config, 10, &host).code(), StatusCode::kInvalidArgument);
  config.algorithm = "segmented_sap";
  config.dimension = 4;
  Status s = MakeEngineHost(config, 10, &host);
  EXPECT_NE(s.message().find("engine.dimension must be 2 or 3"), std::string::npos);
}

TEST(EngineHost, IntegerEngineTakesIntegersInRangeOnly) {
  auto host = MakeHost("segmented_sap", 2, CoordinateType::kInt32);
  wire::UpdateBatch b = Batch(1, 2);
  AddBox(b.mutable_inserts(), 1, {0, 0}, {2, 2});
  AddBox(b.mutable_inserts(), 2, {0.5, 0}, {2, 2});
  AddBox(b.mutable_inserts(), 3, {0, 0}, {3e9, 2});
  AddBox(b.mutable_inserts(), 4, {-2147483648.0, 0}, {2147483647.0, 2});
  // As floats, 2^31 (INT32_MAX rounded up) is out of range; -2^31 is in.
  wire::UpdateBatch f = Batch(1, 2);
  client::AddBox<2>(f.mutable_inserts(), 5, Box<2, float>{{-2147483648.0f, 0}, {0, 2}});
  client::AddBox<2>(f.mutable_inserts(), 6, Box<2, float>{{0, 0}, {2147483648.0f, 2}});
  Outcome out = Apply(*host, f);
  ASSERT_EQ(out.rejects.size(), 1u);
  EXPECT_EQ(out.rejects[0].index, 1u);
  EXPECT_EQ(out.rejects[0].reason, wire::NOT_FINITE);
  EXPECT_NE(out.rejects[0].message.find("hi on axis 0"), std::string::npos);
  out = Apply(*host, b);
  ASSERT_EQ(out.rejects.size(), 2u);
  EXPECT_EQ(out.rejects[0].reason, wire::NOT_INTEGRAL);
  EXPECT_NE(out.rejects[0].message.find("insert[1] id 2: lo on axis 0"), std::string::npos);
  EXPECT_EQ(out.rejects[1].reason, wire::NOT_FINITE);
  EXPECT_NE(out.rejects[1].message.find("hi on axis 0 is 3e+09, out of the engine's integer range"),
            std::string::npos)
      << out.rejects[1].message;
  // Values print in their type's shortest form: a float 0.1 as 0.1, not as the double it widens to.
  wire::UpdateBatch g = Batch(1, 2);
  client::AddBox<2>(g.mutable_inserts(), 7, Box<2, float>{{0.1f, 0}, {2, 2}});
  out = Apply(*host, g);
  ASSERT_EQ(out.rejects.size(), 1u);
  EXPECT_NE(out.rejects[0].message.find("lo on axis 0 is 0.1, not an integer"), std::string::npos)
      << out.rejects[0].message;
  std::vector<uint64_t> unc, col;
  host->Query(&unc, &col);
  EXPECT_EQ(ToPairs(col), (PairList{{GlobalKey(1, 1), GlobalKey(1, 4)},
                                    {GlobalKey(1, 1), GlobalKey(1, 5)},
                                    {GlobalKey(1, 4), GlobalKey(1, 5)}}));
}

TEST(EngineHost, FloatEngineRoundsDoublesOutward) {
  auto host = MakeHost("segmented_sap", 2, CoordinateType::kFloat);
  // In double, [0, 0.1] and [0.1, 1] touch. 0.1 is not a float: rounding each to nearest
  // gives the same float for both, but outward rounding must keep them touching, and boxes
  // that are apart by less than a float ulp may be reported (never the reverse).
  wire::UpdateBatch b = Batch(1, 2);
  AddBox(b.mutable_inserts(), 1, {0, 0}, {0.1, 1});
  AddBox(b.mutable_inserts(), 2, {0.1, 0}, {1, 1});
  AddBox(b.mutable_inserts(), 3, {0.1 + 1e-12, 2}, {1, 3});
  AddBox(b.mutable_inserts(), 4, {0, 2}, {0.1, 3});
  EXPECT_TRUE(Apply(*host, b).rejects.empty());
  std::vector<uint64_t> unc, col;
  host->Query(&unc, &col);
  EXPECT_EQ(ToPairs(col),
            (PairList{{GlobalKey(1, 1), GlobalKey(1, 2)}, {GlobalKey(1, 3), GlobalKey(1, 4)}}));
}

TEST(EngineHost, CapacityRefusesInsertsBeyondTheLimit) {
  auto host = MakeHost("segmented_sap", 3, CoordinateType::kFloat, 3);
  wire::UpdateBatch b = Batch(1, 3);
  for (uint64_t id = 0; id < 5; ++id) AddBox(b.mutable_inserts(), id, {0, 0, 0}, {1, 1, 1});
  Outcome out = Apply(*host, b);
  ASSERT_EQ(out.rejects.size(), 2u);
  EXPECT_EQ(out.rejects[0].reason, wire::CAPACITY);
  EXPECT_EQ(host->Objects(), 3u);
  // An erase makes room again, within the same batch order (erases first).
  wire::UpdateBatch c = Batch(1, 3);
  c.add_erases(0);
  AddBox(c.mutable_inserts(), 9, {0, 0, 0}, {1, 1, 1});
  EXPECT_TRUE(Apply(*host, c).rejects.empty());
}

TEST(EngineHost, EraseAndReinsertInOneBatchIsAnUpdate) {
  auto host = MakeHost("segmented_sap", 3, CoordinateType::kFloat);
  wire::UpdateBatch a = Batch(1, 3);
  AddBox(a.mutable_inserts(), 1, {0, 0, 0}, {1, 1, 1});
  AddBox(a.mutable_inserts(), 2, {0, 0, 0}, {1, 1, 1});
  Apply(*host, a);
  std::vector<uint64_t> unc, col;
  host->Query(&unc, &col);
  ASSERT_EQ(col.size(), 2u);
  wire::UpdateBatch b = Batch(1, 3);
  b.add_erases(2);
  AddBox(b.mutable_inserts(), 2, {0.5, 0, 0}, {1, 1, 1});
  EXPECT_TRUE(Apply(*host, b).rejects.empty());
  host->Query(&unc, &col);
  EXPECT_TRUE(unc.empty());
  EXPECT_TRUE(col.empty());
  // Reinserting with a mask that rejects 1 in the frame of the erase uncollides the pair.
  wire::UpdateBatch c = Batch(1, 3);
  c.add_erases(2);
  AddBox(c.mutable_inserts(), 2, {0.5, 0, 0}, {1, 1, 1});
  c.mutable_inserts()->add_category(1);
  c.mutable_inserts()->add_mask(2);
  EXPECT_TRUE(Apply(*host, c).rejects.empty());
  host->Query(&unc, &col);
  EXPECT_EQ(ToPairs(unc), (PairList{{GlobalKey(1, 1), GlobalKey(1, 2)}}));
  EXPECT_TRUE(col.empty());
  EXPECT_EQ(host->Overlaps(), 0u);
  // Static objects never pair with each other: 3 and 4 overlap 1 but only 1 pairs with them.
  wire::UpdateBatch d = Batch(1, 3);
  AddBox(d.mutable_inserts(), 3, {0, 0, 0}, {1, 1, 1});
  AddBox(d.mutable_inserts(), 4, {0, 0, 0}, {1, 1, 1});
  d.mutable_inserts()->add_static_flags(true);
  d.mutable_inserts()->add_static_flags(true);
  EXPECT_TRUE(Apply(*host, d).rejects.empty());
  host->Query(&unc, &col);
  EXPECT_EQ(ToPairs(col),
            (PairList{{GlobalKey(1, 1), GlobalKey(1, 3)}, {GlobalKey(1, 1), GlobalKey(1, 4)}}));
}

TEST(EngineHost, RestateReplacesLiveObjectsAndInsertsTheOthers) {
  for (const char* algorithm : {"segmented_sap", "grid_dense", "brute_force"}) {
    SCOPED_TRACE(algorithm);
    auto host = MakeHost(algorithm, 3, CoordinateType::kFloat, 3);
    wire::UpdateBatch a = Batch(1, 3);
    AddBox(a.mutable_inserts(), 1, {0, 0, 0}, {1, 1, 1});
    AddBox(a.mutable_inserts(), 2, {0.5, 0, 0}, {1.5, 1, 1});
    ASSERT_TRUE(Apply(*host, a).rejects.empty());
    std::vector<uint64_t> unc, col;
    host->Query(&unc, &col);
    EXPECT_EQ(ToPairs(col), (PairList{{GlobalKey(1, 1), GlobalKey(1, 2)}}));
    // At capacity (3 of 3, with 9 far away), a restate: 1 moved away and 2 unchanged replace
    // the live ones (no DUPLICATE_INSERT, no CAPACITY); 3 is new, and refused for capacity.
    wire::UpdateBatch full = Batch(1, 3);
    AddBox(full.mutable_inserts(), 9, {100, 0, 0}, {101, 1, 1});
    ASSERT_TRUE(Apply(*host, full).rejects.empty());
    wire::UpdateBatch r = Batch(1, 3);
    r.set_restate(true);
    AddBox(r.mutable_inserts(), 1, {5, 0, 0}, {6, 1, 1});
    AddBox(r.mutable_inserts(), 2, {0.5, 0, 0}, {1.5, 1, 1});
    AddBox(r.mutable_inserts(), 3, {5.5, 0, 0}, {6.5, 1, 1});
    Outcome out = Apply(*host, r);
    ASSERT_EQ(out.rejects.size(), 1u);
    EXPECT_EQ(out.rejects[0].reason, wire::CAPACITY);
    EXPECT_EQ(out.rejects[0].id, 3u);
    EXPECT_EQ(out.counts.updates, 2u);
    EXPECT_EQ(host->Objects(), 3u);
    // With room again (9 erased), 3 is inserted by the same restate.
    wire::UpdateBatch room = Batch(1, 3);
    room.add_erases(9);
    ASSERT_TRUE(Apply(*host, room).rejects.empty());
    out = Apply(*host, r);
    EXPECT_TRUE(out.rejects.empty()) << out.rejects[0].message;
    EXPECT_EQ(out.counts.updates, 2u);
    EXPECT_EQ(out.counts.inserts, 1u);
    EXPECT_EQ(host->Objects(), 3u);
    host->Query(&unc, &col);
    EXPECT_EQ(ToPairs(unc), (PairList{{GlobalKey(1, 1), GlobalKey(1, 2)}}));
    EXPECT_EQ(ToPairs(col), (PairList{{GlobalKey(1, 1), GlobalKey(1, 3)}}));
    // Restating with other attributes rekeys: the pair with 1 ends when 3's mask rejects it.
    wire::UpdateBatch m = Batch(1, 3);
    m.set_restate(true);
    AddBox(m.mutable_inserts(), 3, {5.5, 0, 0}, {6.5, 1, 1});
    m.mutable_inserts()->add_category(2);
    m.mutable_inserts()->add_mask(2);
    EXPECT_TRUE(Apply(*host, m).rejects.empty());
    host->Query(&unc, &col);
    EXPECT_EQ(ToPairs(unc), (PairList{{GlobalKey(1, 1), GlobalKey(1, 3)}}));
    EXPECT_TRUE(col.empty());
    // Without the flag the same insert is a duplicate (below capacity: 1 is erased first).
    wire::UpdateBatch d = Batch(1, 3);
    d.add_erases(1);
    AddBox(d.mutable_inserts(), 2, {0, 0, 0}, {1, 1, 1});
    out = Apply(*host, d);
    ASSERT_EQ(out.rejects.size(), 1u);
    EXPECT_EQ(out.rejects[0].reason, wire::DUPLICATE_INSERT);
  }
}

TEST(EngineHost, EraseProducerErasesThatProducersObjectsOnly) {
  auto host = MakeHost("grid_dense", 2, CoordinateType::kDouble);
  for (uint32_t producer : {1u, 2u, 3u}) {
    wire::UpdateBatch b = Batch(producer, 2);
    for (uint64_t id = 0; id < 4; ++id) {
      AddBox(b.mutable_inserts(), id, {0.1 * static_cast<double>(id), 0}, {1, 1});
    }
    ASSERT_TRUE(Apply(*host, b).rejects.empty());
  }
  std::vector<uint64_t> unc, col;
  host->Query(&unc, &col);
  EXPECT_EQ(host->Overlaps(), 66u);  // 12 boxes, all overlapping
  // Producer 2: 4 live objects, plus one inserted since the query (buffered) and one erased.
  wire::UpdateBatch more = Batch(2, 2);
  more.add_erases(3);
  AddBox(more.mutable_inserts(), 9, {0, 0}, {1, 1});
  ASSERT_TRUE(Apply(*host, more).rejects.empty());
  EXPECT_EQ(host->EraseProducer(2, nullptr), 4u);
  EXPECT_EQ(host->Objects(), 8u);
  host->Query(&unc, &col);
  EXPECT_EQ(unc.size() / 2, 66u - 28u);  // every pair with one of producer 2's 4 live objects
  EXPECT_TRUE(col.empty());
  for (size_t i = 0; i < unc.size(); i += 2) {
    EXPECT_TRUE((unc[i] >> kProducerShift) == 2 || (unc[i + 1] >> kProducerShift) == 2);
  }
  EXPECT_EQ(host->EraseProducer(2, nullptr), 0u);
  EXPECT_EQ(host->Overlaps(), 28u);
}

TEST(EngineHost, EraseProducerKeepsTheListedIds) {
  auto host = MakeHost("segmented_sap", 2, CoordinateType::kDouble);
  for (uint32_t producer : {1u, 2u}) {
    wire::UpdateBatch b = Batch(producer, 2);
    for (uint64_t id = 0; id < 6; ++id) {
      AddBox(b.mutable_inserts(), id, {0.1 * static_cast<double>(id), 0}, {1, 1});
    }
    ASSERT_TRUE(Apply(*host, b).rejects.empty());
  }
  std::vector<uint64_t> unc, col;
  host->Query(&unc, &col);
  // The end of a restate of producer 2 that named 1, 4 and 7 (7 it does not hold).
  const std::vector<uint64_t> keep = {1, 4, 7};
  EXPECT_EQ(host->EraseProducer(2, &keep), 4u);
  EXPECT_EQ(host->Objects(), 8u);
  host->Query(&unc, &col);
  EXPECT_TRUE(col.empty());
  // All 12 boxes overlapped (66 pairs); the 8 left still do (28).
  EXPECT_EQ(unc.size() / 2, 66u - 28u);
  EXPECT_EQ(host->Overlaps(), 28u);
  const std::set<uint64_t> gone = {GlobalKey(2, 0), GlobalKey(2, 2), GlobalKey(2, 3),
                                   GlobalKey(2, 5)};
  for (size_t i = 0; i < unc.size(); i += 2) {
    EXPECT_TRUE(gone.contains(unc[i]) || gone.contains(unc[i + 1])) << unc[i] << " " << unc[i + 1];
  }
  const std::vector<uint64_t> none;
  EXPECT_EQ(host->EraseProducer(1, &none), 6u);
  EXPECT_EQ(host->Objects(), 2u);
}

TEST(EngineHost, FiltersMatchABruteForceFilteredOracle) {
  std::mt19937_64 rng(5);
  auto host = MakeHost("segmented_sap", 2, CoordinateType::kDouble);
  std::map<uint64_t, std::pair<uint64_t, uint64_t>> filter;  // key -> (category, mask)
  std::map<uint64_t, Box<2, double>> boxes;
  std::set<std::pair<uint64_t, uint64_t>> reported;
  for (int frame = 0; frame < 60; ++frame) {
    wire::UpdateBatch b = Batch(1, 2);
    std::set<uint64_t> named;
    for (int i = 0; i < 8; ++i) {
      const uint64_t id = rng() % 25;
      if (named.count(id)) continue;
      named.insert(id);
      const uint64_t key = GlobalKey(1, id);
      const double x = static_cast<double>(rng() % 20), y = static_cast<double>(rng() % 20);
      if (boxes.count(key) && rng() % 3 == 0) {
        b.add_erases(id);
        boxes.erase(key);
        filter.erase(key);
      } else if (boxes.count(key)) {
        AddBox(b.mutable_updates(), id, {x, y}, {x + 4, y + 4});
        boxes[key] = Box<2, double>{{x, y}, {x + 4, y + 4}};
      } else {
        AddBox(b.mutable_inserts(), id, {x, y}, {x + 4, y + 4});
        boxes[key] = Box<2, double>{{x, y}, {x + 4, y + 4}};
        filter[key] = {uint64_t{1} << (rng() % 3), rng() % 8};
      }
    }
    // Category and mask arrays: one value per insert.
    for (int i = 0; i < b.inserts().ids_size(); ++i) {
      const auto& f = filter[GlobalKey(1, b.inserts().ids(i))];
      b.mutable_inserts()->add_category(f.first);
      b.mutable_inserts()->add_mask(f.second);
    }
    ASSERT_TRUE(Apply(*host, b).rejects.empty());
    std::vector<uint64_t> unc, col;
    host->Query(&unc, &col);
    for (auto& p : ToPairs(unc)) EXPECT_EQ(reported.erase(p), 1u);
    for (auto& p : ToPairs(col)) EXPECT_TRUE(reported.insert(p).second);
    std::set<std::pair<uint64_t, uint64_t>> want;
    for (auto& [a, ba] : boxes) {
      for (auto& [b2, bb] : boxes) {
        if (a >= b2 || !Overlaps(ba, bb)) continue;
        const auto& fa = filter[a];
        const auto& fb = filter[b2];
        if ((fa.first & fb.second) && (fb.first & fa.second)) want.insert({a, b2});
      }
    }
    ASSERT_EQ(reported, want) << "frame " << frame;
    EXPECT_EQ(host->Overlaps(), want.size());
  }
}

// Several batches per frame with the same-frame transitions: insert then erase, erase then
// reinsert with the same options or other ones (the engine takes a fresh handle and reports only
// real changes), erase-reinsert-erase, and static objects, over two engines.
TEST(EngineHost, OptionsStayExactAcrossSameFrameTransitions) {
  for (const char* algorithm : {"segmented_sap", "grid_segmented_sap", "grid_dense"}) {
    SCOPED_TRACE(algorithm);
    std::mt19937_64 rng(17);
    auto host = MakeHost(algorithm, 2, CoordinateType::kDouble);
    std::map<uint64_t, ObjectOptions> options;   // live objects' options
    std::map<uint64_t, Box<2, double>> boxes;    // live objects' boxes
    std::map<uint64_t, ObjectOptions> at_query;  // options of the objects live at the last query
    std::set<std::pair<uint64_t, uint64_t>> reported;
    size_t changed = 0, reinserted = 0;
    for (int frame = 0; frame < 300; ++frame) {
      const int batches = 1 + static_cast<int>(rng() % 4);
      for (int k = 0; k < batches; ++k) {
        wire::UpdateBatch b = Batch(1, 2);
        std::set<uint64_t> named;  // one operation per id and batch keeps the model simple
        for (int i = 0; i < 5; ++i) {
          const uint64_t id = rng() % 12;
          if (!named.insert(id).second) continue;
          const uint64_t key = GlobalKey(1, id);
          const double x = static_cast<double>(rng() % 10), y = static_cast<double>(rng() % 10);
          const Box<2, double> box{{x, y}, {x + 3, y + 3}};
          if (boxes.count(key)) {
            if (rng() % 2) {
              b.add_erases(id);
              boxes.erase(key);
              options.erase(key);
            } else {
              AddBox(b.mutable_updates(), id, {x, y}, {x + 3, y + 3});
              boxes[key] = box;
            }
            continue;
          }
          ObjectOptions o;
          o.category = uint64_t{1} << (rng() % 2);
          o.mask = 1 + rng() % 3;
          o.is_static = rng() % 4 == 0;
          AddBox(b.mutable_inserts(), id, {x, y}, {x + 3, y + 3});
          b.mutable_inserts()->add_category(o.category);
          b.mutable_inserts()->add_mask(o.mask);
          b.mutable_inserts()->add_static_flags(o.is_static);
          auto was = at_query.find(key);
          reinserted += was != at_query.end();
          changed += was != at_query.end() && !(was->second == o);
          boxes[key] = box;
          options[key] = o;
        }
        ASSERT_TRUE(Apply(*host, b).rejects.empty()) << "frame " << frame;
      }
      std::vector<uint64_t> unc, col;
      host->Query(&unc, &col);
      for (auto& p : ToPairs(unc)) ASSERT_EQ(reported.erase(p), 1u) << "frame " << frame;
      for (auto& p : ToPairs(col)) ASSERT_TRUE(reported.insert(p).second) << "frame " << frame;
      std::set<std::pair<uint64_t, uint64_t>> want;
      for (auto& [a, ba] : boxes) {
        for (auto& [c, bc] : boxes) {
          if (a < c && Overlaps(ba, bc) && Accepts(options[a], options[c])) want.insert({a, c});
        }
      }
      ASSERT_EQ(reported, want) << "frame " << frame;
      ASSERT_EQ(host->Overlaps(), want.size());
      at_query = options;
    }
    EXPECT_GT(changed, 10u) << "the reinsertion with new options was not exercised";
    EXPECT_GT(reinserted, 20u) << "the reinsertion path was not exercised";
  }
}

// Hostile input: valid batches with random bytes flipped, truncated or extended. Whatever
// parses goes through Apply and Query; nothing may crash (ASan+UBSan in CI), and every query
// validates the engine (BP_VALIDATE in the test builds).
TEST(EngineHost, MutatedBatchesNeverCrash) {
  std::mt19937_64 rng(99);
  for (CoordinateType c :
       {CoordinateType::kFloat, CoordinateType::kDouble, CoordinateType::kInt32}) {
    auto host = MakeHost("segmented_sap", 3, c);
    size_t parsed = 0;
    for (int round = 0; round < 4000; ++round) {
      wire::UpdateBatch b = Batch(1 + static_cast<uint32_t>(rng() % 3), 3);
      for (int i = 0; i < 4; ++i) {
        const double x = static_cast<double>(rng() % 50);
        AddBox(b.mutable_inserts(), rng() % 40, {x, x, x}, {x + 3, x + 3, x + 3});
        AddBox(b.mutable_updates(), rng() % 40, {x, 0, x}, {x + 2, 5, x + 1});
        b.add_erases(rng() % 40);
      }
      // A byte vector, not a std::string: g++ 12 -O3 reports a false -Wrestrict positive in
      // std::string's insert and assign here.
      const std::string serialized = b.SerializeAsString();
      std::vector<uint8_t> bytes(serialized.begin(), serialized.end());
      const int edits = 1 + static_cast<int>(rng() % 4);
      for (int e = 0; e < edits; ++e) {
        const size_t at = rng() % bytes.size();
        switch (rng() % 3) {
          case 0:
            bytes[at] = static_cast<uint8_t>(rng());
            break;
          case 1:
            bytes.resize(at);
            break;
          default:
            bytes.insert(bytes.begin() + static_cast<std::ptrdiff_t>(at), 1 + rng() % 8,
                         static_cast<uint8_t>(rng()));
        }
        if (bytes.empty()) bytes.push_back(0x08);
      }
      wire::UpdateBatch mutated;
      if (!mutated.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) continue;
      ++parsed;
      Apply(*host, mutated);
      if (round % 10 == 0) {
        std::vector<uint64_t> unc, col;
        host->Query(&unc, &col);
      }
    }
    EXPECT_GT(parsed, 300u) << "too few mutants parse to exercise Apply";
    std::vector<uint64_t> unc, col;
    host->Query(&unc, &col);
    EXPECT_TRUE(host->GetStats().objects == host->Objects());
  }
}

}  // namespace
}  // namespace bp::service
