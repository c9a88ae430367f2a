// White-box tests of the grid: coordinates far from the origin and cell indices that would
// overflow, cells created and recycled, the automatic cell size and the rebuild when the
// population grows, large objects (world-sized boxes, transitions between small and large), and
// the validator noticing corrupted witness counts and large-object lists. Every scene is run
// against the brute-force engine, event by event.
#include "bp/grid.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "test_support.h"
#include <gtest/gtest.h>

#include "bp/scene_runner.h"
#include "bp/segmented_sap.h"
#include "bp/workload.h"

namespace bp {
namespace detail {

struct GridTestPeer {
  template <class Core>
  static void DropLargeListEntry(Core& core) {
    for (auto& cell : core.cells_) {
      if (cell->in_use && !cell->large.empty()) {
        cell->large.pop_back();
        return;
      }
    }
  }
  template <class Core>
  static void AddWitness(Core& core) {
    bool added = false;
    core.tracker_.ForEachOverlap([&](uint32_t a, uint32_t b) {
      if (added) return;
      const uint64_t p = HandlePair(a, b);
      ++core.extra_[core.tracker_.ShardOf(p)].FindOrInsert(p, 0);
      added = true;
    });
  }
};

}  // namespace detail

namespace test {
namespace {

using SegmentedGridCore = detail::GridCore<detail::SegmentedSapCore<3, float>>;

// Runs the same calls on an engine and on brute force; every query must report the same events.
template <int K, class T, class Engine>
class Twin {
 public:
  using BoxType = Box<K, T>;
  explicit Twin(Engine* engine) : engine_(engine) {}

  void Insert(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_->Insert(key, b).ok());
    ASSERT_TRUE(oracle_.Insert(key, b).ok());
  }
  void Update(uint64_t key, const BoxType& b) {
    ASSERT_TRUE(engine_->Update(key, b).ok());
    ASSERT_TRUE(oracle_.Update(key, b).ok());
  }
  void Erase(uint64_t key) {
    ASSERT_TRUE(engine_->Erase(key).ok());
    ASSERT_TRUE(oracle_.Erase(key).ok());
  }
  void Query() {
    RecordingSink<uint64_t> got, want;
    engine_->Query(got);
    oracle_.Query(want);
    ASSERT_EQ(got.uncollides, want.uncollides) << "query " << queries_;
    ASSERT_EQ(got.collides, want.collides) << "query " << queries_;
    ASSERT_EQ(engine_->GetStats().overlaps, oracle_.GetStats().overlaps);
    events_ += got.collides.size() + got.uncollides.size();
    ++queries_;
  }
  size_t events() const { return events_; }

 private:
  Engine* engine_;
  BruteForce<K, T> oracle_;
  size_t queries_ = 0;
  size_t events_ = 0;
};

template <int K, class T>
Box<K, T> Cube(T lo, T extent) {
  Box<K, T> b;
  for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
    b.lo[a] = lo;
    b.hi[a] = static_cast<T>(lo + extent);
  }
  return b;
}

// A random scene around `origin` with boxes of about `unit`, moved, churned and teleported.
template <int K, class T, class Engine>
void RandomScene(Engine* engine, double origin, double unit, uint64_t seed, int objects = 120,
                 int frames = 30) {
  SCOPED_TRACE("origin " + std::to_string(origin) + " unit " + std::to_string(unit));
  Twin<K, T, Engine> twin(engine);
  std::mt19937_64 rng(seed);
  auto coord = [&](double span) {
    double x = origin + std::uniform_real_distribution<double>(-span, span)(rng) * unit;
    return static_cast<T>(x);
  };
  auto box = [&]() {
    Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      T lo = coord(8);
      T hi = static_cast<T>(static_cast<double>(lo) +
                            std::uniform_real_distribution<double>(0, 2)(rng) * unit);
      b.lo[a] = lo;
      b.hi[a] = hi < lo ? lo : hi;
    }
    return b;
  };
  std::vector<uint64_t> live;
  uint64_t next = 1;
  for (int i = 0; i < objects; ++i) {
    twin.Insert(next, box());
    live.push_back(next++);
  }
  twin.Query();
  for (int f = 0; f < frames && !::testing::Test::HasFailure(); ++f) {
    for (int i = 0; i < objects / 4; ++i) {
      size_t j = rng() % live.size();
      switch (rng() % 5) {
        case 0:
          twin.Erase(live[j]);
          live[j] = next;
          twin.Insert(next++, box());
          break;
        default:
          twin.Update(live[j], box());
      }
    }
    twin.Query();
  }
  EXPECT_GT(twin.events(), 0u);
}

TEST(Grid, FarFromTheOriginFloat) {
  for (double origin : {1e6, -1e6, 1e30, -1e30, 3e38}) {
    for (double unit : {1.0, origin * 1e-5}) {
      GridSegmentedSapOptions options;
      options.cell_size = 1.0;  // cell indices far beyond 2^20: clamped into the edge cells
      GridSegmentedSap<3, float> engine(options);
      RandomScene<3, float>(&engine, origin, unit < 0 ? -unit : unit, 7);
      GridBatchSap<2, float> automatic;
      RandomScene<2, float>(&automatic, origin, unit < 0 ? -unit : unit, 8);
    }
  }
}

TEST(Grid, FarFromTheOriginDouble) {
  for (double origin : {1e12, -1e12, 1e300, -1e300}) {
    GridBatchSapOptions options;
    options.cell_size = 0.5;
    GridBatchSap<3, double> engine(options);
    RandomScene<3, double>(&engine, origin, origin > 0 ? origin * 1e-6 : -origin * 1e-6, 9);
    GridSegmentedSapOptions fine_options;
    fine_options.cell_size = 0.5;
    GridSegmentedSap<3, double> fine(fine_options);
    RandomScene<3, double>(&fine, origin, 1.0, 10);
  }
}

// One axis: 63 bits of cell coordinate (kLimit 2^62), where CellOf cannot take the rounded
// offset it uses for two axes and more (2^62 + q loses the quotient's low bits and overflows
// int64 at the top clamp). Exact against brute force near the origin and far beyond the clamped
// cell range, and the automatic size still makes cells of a few objects each.
TEST(Grid, OneAxis) {
  for (double origin : {0.0, 1e12, -1e12, 1e300, -1e300}) {
    GridDenseOptions options;
    options.cell_size = 1.0;  // far from the origin: indices beyond 2^62, clamped
    GridDense<1, double> engine(options);
    RandomScene<1, double>(&engine, origin, origin == 0 ? 1.0 : std::abs(origin) * 1e-6, 12);
    GridDenseOptions few;
    few.objects_per_cell = 8;  // 120 objects over 18 units: cells of about 1.2
    GridDense<1, float> automatic(few);
    RandomScene<1, float>(&automatic, 0.0, 1.0, 13);
    EXPECT_GE(automatic.GetStats().cells, 8u) << origin;
  }
}

// Cells are counted from an origin at the middle of the first objects, so a world far from zero
// gets the cells it would get at zero (not one cell per 2^-20 of the coordinates' magnitude,
// which would be a single cell at 1e12), and stays exact.
TEST(Grid, FarWorldKeepsSmallAutomaticCells) {
  for (double origin : {0.0, 1e12, -1e12}) {
    GridDense<3, double> engine;
    RandomScene<3, double>(&engine, origin, 1.0, 11);
    const Stats stats = engine.GetStats();
    EXPECT_GT(stats.cell_size, 0.5) << origin;
    EXPECT_LT(stats.cell_size, 16.0) << origin;
  }
}

TEST(Grid, IntegerExtremes) {
  GridSegmentedSapOptions options;
  options.cell_size = 3;
  GridSegmentedSap<2, int32_t> engine(options);
  Twin<2, int32_t, GridSegmentedSap<2, int32_t>> twin(&engine);
  const int32_t lo = std::numeric_limits<int32_t>::lowest();
  const int32_t hi = std::numeric_limits<int32_t>::max();
  twin.Insert(1, Box<2, int32_t>{{lo, lo}, {lo + 2, lo + 2}});
  twin.Insert(2, Box<2, int32_t>{{hi - 2, hi - 2}, {hi, hi}});
  twin.Insert(3, Box<2, int32_t>{{lo, lo}, {hi, hi}});  // everything: a large object
  twin.Insert(4, Box<2, int32_t>{{lo + 1, lo + 1}, {lo + 1, lo + 1}});
  twin.Query();
  EXPECT_EQ(engine.GetStats().large_objects, 1u);
  twin.Update(4, Box<2, int32_t>{{hi - 1, hi - 1}, {hi, hi}});  // across the whole range
  twin.Query();
  twin.Update(3, Box<2, int32_t>{{0, 0}, {1, 1}});  // large becomes small
  twin.Query();
  EXPECT_EQ(engine.GetStats().large_objects, 0u);
  twin.Erase(1);
  twin.Erase(2);
  twin.Query();
}

TEST(Grid, CellsAreCreatedAndRecycled) {
  GridSegmentedSapOptions options;
  options.cell_size = 10;
  GridSegmentedSap<3, float> engine(options);
  Twin<3, float, GridSegmentedSap<3, float>> twin(&engine);
  for (uint64_t i = 0; i < 50; ++i) twin.Insert(i, Cube<3, float>(static_cast<float>(i), 1));
  twin.Query();
  const size_t cells = engine.GetStats().cells;
  EXPECT_GE(cells, 6u);
  // March the whole population far away, a little each frame: cells are created ahead and
  // recycled behind, so their number stays bounded.
  for (int f = 1; f <= 40; ++f) {
    for (uint64_t i = 0; i < 50; ++i) {
      twin.Update(i, Cube<3, float>(static_cast<float>(i) + 25.0f * static_cast<float>(f), 1));
    }
    twin.Query();
    EXPECT_LE(engine.GetStats().cells, cells + 8) << "frame " << f;
  }
  for (uint64_t i = 0; i < 50; ++i) twin.Erase(i);
  twin.Query();
  EXPECT_EQ(engine.GetStats().cells, 0u);
  EXPECT_EQ(engine.Size(), 0u);
}

TEST(Grid, AutomaticSizeFollowsThePopulation) {
  GridBatchSap<3, float> engine;  // automatic size
  Twin<3, float, GridBatchSap<3, float>> twin(&engine);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> pos(0, 60);
  uint64_t key = 0;
  for (int i = 0; i < 20; ++i) twin.Insert(key++, Cube<3, float>(pos(rng), 1));
  twin.Query();
  const double first = engine.GetStats().cell_size;
  bool rebuilt = false;
  for (int f = 0; f < 8; ++f) {               // 20 to 5120 objects
    int n = static_cast<int>(engine.Size());  // double the population each frame
    for (int i = 0; i < n; ++i) twin.Insert(key++, Cube<3, float>(pos(rng), 1));
    twin.Update(0, Cube<3, float>(pos(rng), 1));
    twin.Query();
    rebuilt = rebuilt || engine.GetStats().rebuilt;
  }
  EXPECT_TRUE(rebuilt);
  EXPECT_LT(engine.GetStats().cell_size, first / 2);  // denser world: smaller cells
  EXPECT_GE(engine.GetStats().cells, 8u);             // one cell at first
}

TEST(Grid, AutomaticSizeAfterAFirstFillOfPoints) {
  GridSegmentedSap<3, float> engine;  // automatic size, from 200 points at one spot
  Twin<3, float, GridSegmentedSap<3, float>> twin(&engine);
  for (uint64_t i = 0; i < 200; ++i) twin.Insert(i, Cube<3, float>(5, 0));
  twin.Query();
  EXPECT_GE(engine.GetStats().cell_size, 5 * 0x1p-20);  // not a denormal
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<float> pos(0, 40);
  for (uint64_t i = 0; i < 200; ++i) twin.Update(i, Cube<3, float>(pos(rng), 1));
  twin.Query();  // exact, though the boxes crowd the clamped edge cells or are large
  for (uint64_t i = 200; i < 1000; ++i) twin.Insert(i, Cube<3, float>(pos(rng), 1));
  twin.Query();  // the population grew fourfold: sized again from the spread boxes
  EXPECT_TRUE(engine.GetStats().rebuilt);
  EXPECT_EQ(engine.GetStats().large_objects, 0u);
  EXPECT_GE(engine.GetStats().cell_size, 1.0);
  for (uint64_t i = 0; i < 1000; i += 3) twin.Update(i, Cube<3, float>(pos(rng), 1));
  twin.Query();
}

TEST(Grid, LargeObjectsAgainstTheGrid) {
  GridSegmentedSapOptions options;
  options.cell_size = 4;
  options.max_cells_per_object = 8;
  GridSegmentedSap<3, float> engine(options);
  Twin<3, float, GridSegmentedSap<3, float>> twin(&engine);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> pos(0, 40);
  for (uint64_t i = 0; i < 400; ++i) twin.Insert(i, Cube<3, float>(pos(rng), 1));
  twin.Insert(1000, Cube<3, float>(-1e30f, 2e30f));  // the world
  for (uint64_t i = 0; i < 10; ++i) twin.Insert(1001 + i, Cube<3, float>(pos(rng), 12));
  twin.Query();
  EXPECT_EQ(engine.GetStats().large_objects, 11u);
  for (int f = 0; f < 30 && !HasFailure(); ++f) {
    for (uint64_t i = 0; i < 400; i += 3) twin.Update(i, Cube<3, float>(pos(rng), 1));
    twin.Update(1001 + static_cast<uint64_t>(f % 10), Cube<3, float>(pos(rng), 12));
    if (f % 5 == 0) {
      // A small object grows into a large one and a large one shrinks into a small one.
      twin.Update(7, Cube<3, float>(pos(rng), 15));
      twin.Update(1003, Cube<3, float>(pos(rng), 1));
    }
    if (f % 7 == 0) {
      twin.Erase(1001);
      twin.Insert(1001, Cube<3, float>(pos(rng), 20));
    }
    if (f == 20) twin.Erase(1000);
    twin.Query();
  }
}

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
    on_workers += engine.GetStats().worker_cells;
    pool_routed += engine.GetStats().pool_routed;
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
    on_workers += engine.GetStats().worker_cells;
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
        EXPECT_EQ(s.route_ms + s.cells_ms + s.fold_ms, 0.0);
        continue;
      }
      EXPECT_GT(s.route_ms, 0.0);
      EXPECT_GT(s.cells_ms, 0.0);
      EXPECT_GT(s.fold_ms, 0.0);
      EXPECT_LE(s.route_ms + s.cells_ms + s.fold_ms, s.core_ms);  // laps within core's span
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

// The dense cell's modes against each other, directly on cells: the pair matrix with each
// kernel (AVX-512, AVX2 and portable; one the CPU lacks runs the next narrower), the rows (no
// matrix, then and now tested: few and many changes per query, both paths of FindChanges) with
// each kernel, and a matrix capped at 64 slots. Random boxes on a small lattice (many exact
// touches and equal coordinates), random erases, updates and inserts; phases alternate between
// handles below 24 and below 70, and a low phase starts by erasing the high handles and
// compacting, so that the capped cell drops its matrix and builds it again. Every change list is
// compared, and every cell validated (matrix against boxes).
template <class T>
void ExpectCellModesAgree(uint64_t seed) {
  using Core = detail::DenseCellCore<3, T>;
  using HB = detail::HandleBox<3, T>;
  // Core 0: the matrix and the widest kernel; 1: capped matrix; then matrix and rows per kernel.
  std::vector<Core> cores;
  cores.emplace_back(DenseCellOptions{});
  DenseCellOptions capped;
  capped.matrix_slots = 64;
  cores.emplace_back(capped);
  for (DenseKernel k : {DenseKernel::kAvx512, DenseKernel::kAvx2, DenseKernel::kPortable}) {
    DenseCellOptions matrix, rows;
    matrix.kernel = rows.kernel = k;
    rows.matrix_slots = 0;
    cores.emplace_back(matrix);
    cores.emplace_back(rows);
  }
  std::mt19937_64 rng(seed);
  auto coord = [&] { return static_cast<T>(static_cast<int>(rng() % 12)); };
  auto box = [&] {
    Box<3, T> b;
    for (size_t a = 0; a < 3; ++a) {
      b.lo[a] = coord();
      b.hi[a] = static_cast<T>(b.lo[a] + static_cast<T>(rng() % 4));
    }
    return b;
  };
  std::vector<bool> live(70, false);
  size_t changes = 0, switches = 0;
  bool had_matrix = false;
  for (int query = 0; query < 480; ++query) {
    const bool low = (query / 60) % 2 == 0;
    const uint32_t range = low ? 24 : 70;
    std::vector<uint32_t> erases;
    std::vector<HB> updates, inserts;
    const bool phase_start = query % 60 == 0 && query > 0;
    const uint64_t ops = query % 3 == 0 ? 40 : 1 + rng() % 8;
    std::vector<bool> used(live.size(), false);
    if (phase_start && low) {
      for (uint32_t h = range; h < live.size(); ++h) {
        if (live[h]) erases.push_back(h);
      }
    } else {
      for (uint64_t i = 0; i < ops; ++i) {
        const auto h = static_cast<uint32_t>(rng() % range);
        if (used[h]) continue;
        used[h] = true;
        if (!live[h]) {
          inserts.push_back({h, box()});
        } else if (rng() % 4 == 0) {
          erases.push_back(h);
        } else {
          updates.push_back({h, box()});
        }
      }
    }
    for (uint32_t h : erases) live[h] = false;
    for (const HB& hb : inserts) live[hb.handle] = true;
    std::vector<std::vector<std::tuple<uint32_t, uint32_t, bool>>> got(cores.size());
    for (size_t c = 0; c < cores.size(); ++c) {
      cores[c].Apply(erases, updates, inserts);
      cores[c].DrainChanges([&](uint32_t x, uint32_t y, bool now) {
        got[c].emplace_back(std::min(x, y), std::max(x, y), now);
      });
      std::sort(got[c].begin(), got[c].end());
      ASSERT_TRUE(cores[c].Validate().ok())
          << "core " << c << ", query " << query << ": " << cores[c].Validate().message();
      if (c > 0) {
        ASSERT_EQ(got[c], got[0]) << "core " << c << ", query " << query;
      }
    }
    changes += got[0].size();
    if (phase_start && low) {
      // The survivors sit below 24 but the cells keep 80 slots: give the blocks back (every core
      // moves the same slots: they hold the same live slots).
      std::vector<std::vector<std::pair<uint32_t, uint32_t>>> moves(cores.size());
      for (size_t c = 0; c < cores.size(); ++c) {
        cores[c].Compact([&](uint32_t from, uint32_t to) { moves[c].emplace_back(from, to); });
        ASSERT_TRUE(cores[c].Validate().ok()) << cores[c].Validate().message();
        ASSERT_EQ(moves[c], moves[0]);
      }
      for (const auto& [from, to] : moves[0]) {
        live[to] = true;
        live[from] = false;
      }
    }
    for (size_t c = 2; c < cores.size(); ++c) EXPECT_EQ(cores[c].has_matrix(), c % 2 == 0);
    EXPECT_TRUE(cores[0].has_matrix());
    switches += cores[1].has_matrix() != had_matrix;
    had_matrix = cores[1].has_matrix();
  }
  EXPECT_GT(changes, 1000u);  // the scene is not idle
  EXPECT_GE(switches, 4u);    // the capped cell dropped its matrix and built it again
}

TEST(DenseCell, MatrixRowsAndKernelsReportTheSameChanges) {
  for (uint64_t seed : {uint64_t{1}, uint64_t{2}, uint64_t{3}}) {
    ExpectCellModesAgree<float>(seed);
    ExpectCellModesAgree<double>(seed);
    ExpectCellModesAgree<int32_t>(seed);
  }
  // Which kernels ran (a kernel the CPU lacks ran as the next narrower one).
  std::string kernels;
  for (DenseKernel k : {DenseKernel::kAvx512, DenseKernel::kAvx2, DenseKernel::kPortable}) {
    if (detail::ResolveDenseKernel<float>(k) == k) {
      kernels += std::string(kernels.empty() ? "" : " ") + DenseKernelName(k);
    }
  }
  RecordProperty("kernels", kernels);
}

// A requested kernel resolves to itself when the CPU has it, else to the next narrower one, and
// a cell reports the one it runs; coordinate types without wide kernels run the portable one.
TEST(DenseCell, KernelResolvesToWhatTheCpuRuns) {
  using detail::ResolveDenseKernel;
  const bool avx512 = detail::CpuHasAvx512(), avx2 = detail::CpuHasAvx2();
  const DenseKernel widest = avx512 ? DenseKernel::kAvx512
                             : avx2 ? DenseKernel::kAvx2
                                    : DenseKernel::kPortable;
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kAuto), widest);
  EXPECT_EQ(ResolveDenseKernel<double>(DenseKernel::kAuto), widest);
  EXPECT_EQ(ResolveDenseKernel<int32_t>(DenseKernel::kAuto), widest);
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kAvx512), widest);
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kAvx2),
            avx2 ? DenseKernel::kAvx2 : DenseKernel::kPortable);
  EXPECT_EQ(ResolveDenseKernel<float>(DenseKernel::kPortable), DenseKernel::kPortable);
  EXPECT_EQ(ResolveDenseKernel<int64_t>(DenseKernel::kAuto), DenseKernel::kPortable);
  DenseCellOptions o;
  o.kernel = DenseKernel::kAvx2;
  const detail::DenseCellCore<2, double> cell(o);
  EXPECT_EQ(cell.kernel(), ResolveDenseKernel<double>(o.kernel));
  EXPECT_STREQ(DenseKernelName(DenseKernel::kAvx2), "avx2");
  RecordProperty("widest", DenseKernelName(widest));
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
  EXPECT_EQ(engine.GetStats().cells, 1u);
  EXPECT_EQ(engine.GetStats().cell_slots, 96u);
  for (uint64_t k = 0; k < 70; ++k) {
    ASSERT_TRUE(engine.Erase(k).ok());
    ASSERT_TRUE(oracle.Erase(k).ok());
  }
  query("erase the low slots");
  EXPECT_EQ(engine.GetStats().cell_slots, 32u);  // 26 live: two blocks, six free slots
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
    const size_t slots = engine.GetStats().cell_slots;
    EXPECT_LT(slots, live.size() + 16 + 4) << "round " << round << ": blocks not given back";
  }
  EXPECT_GT(events, 200u);  // the scene is not idle
}

// With no large object when a query starts, the cells allocate the local handles of the objects
// that enter them only when they are applied. An object that turns large in that query ends the
// deferral, so that its scan of the cells' tables finds the objects that entered them before it
// in the same query (here: one migrated, one inserted by an erase and re-insert, both under it).
TEST(Grid, ObjectTurningLargeMidQuerySeesObjectsThatEnteredCellsBefore) {
  for (unsigned threads : {1u, 2u}) {
    GridDenseOptions options;
    options.cell_size = 4;
    options.max_cells_per_object = 8;  // a unit cube spans 8 cells at most
    options.threads = threads;
    GridDense<3, float> engine(options);
    Twin<3, float, GridDense<3, float>> twin(&engine);
    for (uint64_t i = 0; i < 8; ++i) {
      const float x = 40.0f + 6.0f * static_cast<float>(i);
      twin.Insert(i, Cube<3, float>(x, 1));
    }
    twin.Query();
    EXPECT_EQ(engine.GetStats().large_objects, 0u);
    twin.Update(1, Cube<3, float>(9.5f, 1));  // migrates into cells nobody held
    twin.Erase(2);
    twin.Insert(2, Cube<3, float>(13, 1));
    twin.Update(3, Cube<3, float>(0, 30));  // turns large over both
    twin.Update(4, Cube<3, float>(17, 1));  // migrates after it
    twin.Insert(9, Cube<3, float>(21, 1));  // inserted after it
    twin.Query();
    EXPECT_EQ(engine.GetStats().large_objects, 1u);
    EXPECT_TRUE(engine.Validate().ok()) << engine.Validate().message();
    twin.Update(3, Cube<3, float>(0, 1));  // small again: the deferral resumes next query
    twin.Update(1, Cube<3, float>(0.5f, 1.5f));
    twin.Query();
    twin.Update(5, Cube<3, float>(1, 2));
    twin.Query();
    EXPECT_TRUE(engine.Validate().ok()) << engine.Validate().message();
  }
}

TEST(Grid, ValidatorNoticesCorruption) {
  GridSegmentedSapOptions options;
  options.cell_size = 4;
  options.max_cells_per_object = 4;
  {
    GridSegmentedSap<3, float> engine(options);
    ASSERT_TRUE(engine.Insert(1, Cube<3, float>(0, 30)).ok());  // large
    ASSERT_TRUE(engine.Insert(2, Cube<3, float>(1, 1)).ok());
    RecordingSink<uint64_t> sink;
    engine.Query(sink);
    ASSERT_TRUE(engine.Validate().ok());
    detail::GridTestPeer::DropLargeListEntry(const_cast<SegmentedGridCore&>(engine.core()));
    EXPECT_FALSE(engine.Validate().ok());
  }
  {
    GridSegmentedSap<3, float> engine(options);
    ASSERT_TRUE(engine.Insert(1, Cube<3, float>(0, 1)).ok());
    ASSERT_TRUE(engine.Insert(2, Cube<3, float>(1, 1)).ok());
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
}  // namespace test
}  // namespace bp
