// The grid's composer (detail/grid_core.h): 1, 2 and 4 threads give identical events for every
// cell type (parallel routing and fold included), the phase times in Stats, dense cells that
// give back freed slots, and the validator (detail/grid_validate.h) noticing corrupted witness
// counts and large-object bins.
#include <cstdint>
#include <string>
#include <vector>

#include "grid_test_support.h"

namespace bp::test {
namespace {

// Every event of a scene, in order, with a frame marker between queries.
template <class Engine>
std::vector<std::pair<uint64_t, uint64_t>> SceneEvents(unsigned threads, uint32_t n,
                                                       uint32_t moving, uint32_t churn,
                                                       int frames) {
  typename Engine::Options options;
  options.threads = threads;
  options.parallel_routing_from = 64;  // routed in parallel too
  options.cell_size = 6;               // about 300 cells for 3000 objects
  Engine engine(options);
  workload::SceneParams params;
  params.n = n;
  params.moving = moving;
  params.churn = churn;
  workload::Scene scene(params);
  RecordingSink<uint64_t> sink;
  std::vector<std::pair<uint64_t, uint64_t>> out;
  size_t on_workers = 0, pool_routed = 0;
  auto query = [&] {
    sink.Clear();
    engine.Query(sink);
    on_workers += engine.GetStats().grid.value().worker_cells;
    pool_routed += engine.GetStats().grid.value().pool_routed;
    out.insert(out.end(), sink.uncollides.begin(), sink.uncollides.end());
    out.emplace_back(~uint64_t{0}, ~uint64_t{0});  // collides follow
    out.insert(out.end(), sink.collides.begin(), sink.collides.end());
    out.emplace_back(~uint64_t{0}, 0);  // end of frame
  };
  for (const auto& b : scene.Initial()) {
    EXPECT_TRUE(engine.Insert(b.id, workload::ToBox<3, float>(b, scene.grid())).ok());
  }
  query();
  workload::FrameOps ops;
  auto next_frame = [&] {
    scene.NextFrame(&ops);
    for (uint64_t id : ops.erases) EXPECT_TRUE(engine.Erase(id).ok());
    for (const auto& b : ops.updates) {
      EXPECT_TRUE(engine.Update(b.id, workload::ToBox<3, float>(b, scene.grid())).ok());
    }
    for (const auto& b : ops.inserts) {
      EXPECT_TRUE(engine.Insert(b.id, workload::ToBox<3, float>(b, scene.grid())).ok());
    }
  };
  for (int f = 0; f < frames; ++f) {
    next_frame();
    query();
  }
  // A loop does not wait for a worker that has not joined it, so on a loaded machine the caller
  // may have run every loop alone: a few more frames (not recorded) until a worker took part.
  for (int extra = 0; threads > 1 && on_workers == 0 && extra < 1000; ++extra) {
    next_frame();
    sink.Clear();
    engine.Query(sink);
    on_workers += engine.GetStats().grid.value().worker_cells;
  }
  // The pool exists and its other threads took part (cells: dozens per query).
  EXPECT_EQ(engine.GetStats().threads, threads);
  if (threads > 1) {
    EXPECT_GT(on_workers, 0u) << "no cell was applied off the caller's thread";
    EXPECT_GT(pool_routed, 0u) << "no update was routed on the pool";
  } else {
    EXPECT_EQ(pool_routed, 0u);
  }
  return out;
}

TEST(Grid, ThreadCountDoesNotChangeEvents) {
  using Seg = GridSegmentedSap<3, float>;
  using Batch = GridBatchSap<3, float>;
  const auto one = SceneEvents<Seg>(1, 3000, 600, 40, 30);
  EXPECT_GT(one.size(), 1000u);
  for (unsigned threads : {2u, 4u})
    EXPECT_TRUE(SceneEvents<Seg>(threads, 3000, 600, 40, 30) == one);
  const auto batch = SceneEvents<Batch>(1, 3000, 3000, 100, 20);
  EXPECT_TRUE(batch == SceneEvents<Seg>(1, 3000, 3000, 100, 20));  // and the cells agree
  for (unsigned threads : {2u, 4u}) {
    EXPECT_TRUE(SceneEvents<Batch>(threads, 3000, 3000, 100, 20) == batch);
  }
  // Dense cells: per-thread scratch when many objects of a cell change, and the same events.
  using Dense = GridDense<3, float>;
  const auto dense = SceneEvents<Dense>(1, 3000, 3000, 100, 20);
  EXPECT_TRUE(dense == batch);
  for (unsigned threads : {2u, 4u}) {
    EXPECT_TRUE(SceneEvents<Dense>(threads, 3000, 3000, 100, 20) == dense);
    EXPECT_TRUE(SceneEvents<Dense>(threads, 3000, 600, 40, 30) == one);
  }
}

// Stats time a query by phase: the front end's prepare, core and events for every keyed engine,
// and the grid's route, cells and fold within core (with one thread and with a pool); the
// scene runner times the client's calls before the query.
TEST(Grid, StatsTimeTheQueryPhases) {
  workload::SceneParams params;
  params.n = 3000;
  params.moving = 600;
  params.churn = 40;
  auto check = [&](Broadphase<3, float>& engine, bool grid) {
    workload::SceneRunner<3, float> runner(engine, params);
    runner.Build();
    for (int frame = 0; frame < 3; ++frame) {
      runner.Step();
      const Stats s = engine.GetStats();
      EXPECT_GT(runner.calls_ms(), 0.0);
      EXPECT_GT(s.prepare_ms, 0.0);
      EXPECT_GT(s.core_ms, 0.0);
      EXPECT_GT(s.events_ms, 0.0);
      if (!grid) {
        EXPECT_FALSE(s.grid.has_value()) << "grid counters from an engine that is no grid";
        continue;
      }
      ASSERT_TRUE(s.grid.has_value());
      const GridStats& g = *s.grid;
      EXPECT_GT(g.route_ms, 0.0);
      EXPECT_GT(g.cells_ms, 0.0);
      EXPECT_GT(g.fold_ms, 0.0);
      EXPECT_LE(g.route_ms + g.cells_ms + g.fold_ms, s.core_ms);  // laps within core's span
    }
  };
  for (unsigned threads : {1u, 2u}) {
    GridDenseOptions options;
    options.threads = threads;
    GridDense<3, float> grid(options);
    check(grid, true);
  }
  SegmentedSap<3, float> sap;
  check(sap, false);
}

// A dense cell whose population falls gives its trailing blocks back: the live slots above are
// moved into the lowest free ones (their objects' references and the cell's table follow), and
// the events stay exact, with category/mask filters and static objects (whose options move with
// the slot). One cell holds every object; the low keys take the low slots, so erasing them
// leaves the survivors in the blocks that are given back.
TEST(Grid, DenseCellsGiveBackFreedSlots) {
  GridDenseOptions options;
  options.cell_size = 1000;
  GridDense<3, float> engine(options);
  BruteForce<3, float> oracle;
  std::mt19937_64 rng(7);
  auto box = [&] {
    Box<3, float> b;
    for (size_t a = 0; a < 3; ++a) {
      b.lo[a] = static_cast<float>(rng() % 20);
      b.hi[a] = b.lo[a] + static_cast<float>(1 + rng() % 4);
    }
    return b;
  };
  auto opts = [](uint64_t key) {
    ObjectOptions o;
    o.category = uint64_t{1} << (key % 3);
    o.mask = ~(uint64_t{1} << ((key + 1) % 3));
    o.is_static = key % 5 == 0;
    return o;
  };
  size_t events = 0;
  auto query = [&](const char* what) {
    RecordingSink<uint64_t> got, want;
    engine.Query(got);
    oracle.Query(want);
    ASSERT_EQ(got.uncollides, want.uncollides) << what;
    ASSERT_EQ(got.collides, want.collides) << what;
    events += got.collides.size() + got.uncollides.size();
    Status v = engine.Validate();
    ASSERT_TRUE(v.ok()) << what << ": " << v.ToString();
  };
  std::vector<uint64_t> live;
  for (uint64_t k = 0; k < 96; ++k) {
    const Box<3, float> b = box();
    ASSERT_TRUE(engine.Insert(k, b, opts(k)).ok());
    ASSERT_TRUE(oracle.Insert(k, b, opts(k)).ok());
  }
  query("fill");
  EXPECT_EQ(engine.GetStats().grid.value().cells, 1u);
  EXPECT_EQ(engine.GetStats().grid.value().cell_slots, 96u);
  for (uint64_t k = 0; k < 70; ++k) {
    ASSERT_TRUE(engine.Erase(k).ok());
    ASSERT_TRUE(oracle.Erase(k).ok());
  }
  query("erase the low slots");
  EXPECT_EQ(engine.GetStats().grid.value().cell_slots, 32u);  // 26 live: two blocks, six free slots
  for (uint64_t k = 70; k < 96; ++k) live.push_back(k);
  // Grow and shrink again and again, moving the survivors: each moved object must still be
  // found under its new slot by its updates and erases.
  uint64_t next = 96;
  for (int round = 0; round < 40 && !::testing::Test::HasFailure(); ++round) {
    const bool grow = round % 4 < 2;
    for (int i = 0; i < 12; ++i) {
      if (grow || live.size() < 4) {
        const Box<3, float> b = box();
        ASSERT_TRUE(engine.Insert(next, b, opts(next)).ok());
        ASSERT_TRUE(oracle.Insert(next, b, opts(next)).ok());
        live.push_back(next++);
      } else {
        const size_t j = rng() % live.size();
        ASSERT_TRUE(engine.Erase(live[j]).ok());
        ASSERT_TRUE(oracle.Erase(live[j]).ok());
        live[j] = live.back();
        live.pop_back();
      }
    }
    for (uint64_t k : live) {
      if (rng() % 2 == 0) continue;
      const Box<3, float> b = box();
      ASSERT_TRUE(engine.Update(k, b).ok());
      ASSERT_TRUE(oracle.Update(k, b).ok());
    }
    query(grow ? "grow" : "shrink");
    const size_t slots = engine.GetStats().grid.value().cell_slots;
    EXPECT_LT(slots, live.size() + 16 + 4) << "round " << round << ": blocks not given back";
  }
  EXPECT_GT(events, 200u);  // the scene is not idle
}

TEST(Grid, ValidatorNoticesCorruption) {
  GridSegmentedSapOptions options;
  options.cell_size = 4;
  options.max_cells_per_object = 4;
  {
    GridSegmentedSap<3, float> engine(options);
    ASSERT_TRUE(engine.Insert(1, CubeAt<3, float>(0, 30)).ok());  // large
    ASSERT_TRUE(engine.Insert(2, CubeAt<3, float>(1, 1)).ok());
    RecordingSink<uint64_t> sink;
    engine.Query(sink);
    ASSERT_TRUE(engine.Validate().ok());
    detail::GridTestPeer::DropLargeBinEntry(const_cast<SegmentedGridCore&>(engine.core()));
    EXPECT_FALSE(engine.Validate().ok());
  }
  {
    GridSegmentedSap<3, float> engine(options);
    ASSERT_TRUE(engine.Insert(1, CubeAt<3, float>(0, 1)).ok());
    ASSERT_TRUE(engine.Insert(2, CubeAt<3, float>(1, 1)).ok());
    RecordingSink<uint64_t> sink;
    engine.Query(sink);
    ASSERT_TRUE(engine.Validate().ok());
    detail::GridTestPeer::AddWitness(const_cast<SegmentedGridCore&>(engine.core()));
    Status s = engine.Validate();
    EXPECT_FALSE(s.ok());
    EXPECT_NE(s.message().find("witness"), std::string::npos) << s.message();
  }
}

}  // namespace
}  // namespace bp::test
