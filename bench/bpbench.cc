// bpbench: engine benchmarks on the scenes of docs/WORKLOADS.md. One JSON line per
// (scenario, engine, configuration) on stdout: median/mean/p90 frame milliseconds over all
// repeats, build time, pairs, events, set hash, chain, whether they match the golden table, peak
// RSS. A progress line goes to stderr when it is a terminal. Why one file of about 900 lines:
// it is the one command line of every benchmark, whose options, scene loop, figure sweeps and
// JSON output share one Config; the peer libraries' adapters are apart (peers/).
//
//   bpbench                                   S2a, S2c, S1-10k through segmented_sap
//   bpbench --scenario S1-100k --repeats 3
//   bpbench --sort local|global|auto --chunk 64 --coord double
//   bpbench --engine batch_sap --sort local|global|auto
//   bpbench --engine dynamic_octree --octree-capacity 16 --octree-depth 20
//   bpbench --threshold-sweep [--engine E]    local vs global sort over the moving fraction
//   bpbench --figure 8|9                      the paper's single-cell figures, every cell variant
//   bpbench --engine grid_segmented_sap|grid_batch_sap [--cell-size X | --objects-per-cell N]
//   bpbench --figure 10|11                    the paper's multi-cell figures: grids and octree
#include <algorithm>
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <iterator>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "peer.h"
#include <CLI/CLI.hpp>
#include <sys/resource.h>
#include <unistd.h>

#include "bp/batch_sap.h"
#include "bp/brute_force.h"
#include "bp/dynamic_octree.h"
#include "bp/engines.h"
#include "bp/grid.h"
#include "bp/scene_runner.h"
#include "bp/segmented_sap.h"
#include "bp/workload_scenarios.h"

namespace {

using bp::workload::GoldenScenario;
using bp::workload::SceneParams;

struct Config {
  std::string engine = "segmented_sap";
  std::string coord = "float";
  std::string sort = "auto";
  std::string variant;  // a label for the figure sweeps
  std::string label;    // --label: a name for the run, copied into its JSON line
  uint32_t chunk = 32;
  uint32_t presorted_min = bp::SegmentedSapOptions().presorted_min;
  double global_fraction = -1;  // < 0: the engine's default
  double cell_size = 0;         // grid engines: 0 = automatic
  double objects_per_cell = 0;  // 0: the cell type's default (bp::kDefaultObjectsPerCell)
  uint32_t max_cells = bp::GridSegmentedSapOptions().max_cells_per_object;
  unsigned threads = 1;                // grid engines
  int64_t parallel_routing_from = -1;  // grid engines: < 0 the engine's default
  bool no_parallel_lookups = false;    // grid engines: the front end looks keys up serially
  std::string kernel = "auto";  // grid_dense: "auto" (the widest the CPU has), "avx512", "avx2" or
                                // "portable" (a kernel the CPU lacks falls back to a narrower one)
  uint32_t big_boxes = 0;       // static boxes of big_width cube widths added to the scene
  double big_width = 50;
  bool world_box = false;         // one static box covering the whole scene
  double margin = 0;              // fattened boxes' margin in cube widths (0: exact)
  bool static_rest = false;       // resting slots' objects inserted static
  uint32_t unpaired_every = 0;    // every n-th object pairs with nothing (mask 0)
  bool error_vs_double = false;   // float engine; errors counted against a double engine
  bool compare_exact = false;     // count errors against an exact engine even at margin 0
  std::string shape = "uniform";  // the scene's layout (bp::workload::Shape)
  double offset = 0;              // added to every coordinate (a world far from the origin)
  uint32_t octree_capacity = bp::DynamicOctreeOptions().max_objects_per_node;
  uint32_t octree_depth = bp::DynamicOctreeOptions().max_depth;
  int repeats = 5;
  int frames = 0;  // 0: the scenario's own
  bool progress = false;
  std::string peer;  // set on a peer library's result line
};

struct Result {
  std::vector<double> frame_ms;  // all frames of all repeats
  std::vector<double> run_medians;
  double build_ms = 0;
  uint64_t pairs0 = 0, pairs = 0, collides = 0, uncollides = 0, set_hash = 0, chain = 0;
  uint64_t errors = 0, swaps = 0, tests = 0, global_frames = 0, local_frames = 0;
  // With a margin: pairs reported beyond / missing from the exact set, and updates absorbed by
  // fat boxes, over all frames of the first run.
  uint64_t false_pos = 0, false_neg = 0, fat_skips = 0, error_frames = 0;
  bp::Stats last;  // the engine's counters after the last frame of the last run
  // Per frame (all repeats), the frame's phases in milliseconds: kPhaseNames order.
  std::array<std::vector<double>, 7> phase_ms;
};

// The phases of a frame that bpbench reports (median of each over the frames): the client's
// calls (timed by the scene runner), then the engine's query by Stats (route, cells and fold are
// the grid's parts of core).
constexpr std::array<const char*, 7> kPhaseNames = {"calls", "prepare", "core",  "route",
                                                    "cells", "fold",    "events"};
void AddPhases(double calls_ms, const bp::Stats& s, Result* r) {
  const bp::GridStats g = s.grid.value_or(bp::GridStats{});  // zeros: an engine that is no grid
  const std::array<double, 7> v = {calls_ms,   s.prepare_ms, s.core_ms,  g.route_ms,
                                   g.cells_ms, g.fold_ms,    s.events_ms};
  for (size_t i = 0; i < v.size(); ++i) r->phase_ms[i].push_back(v[i]);
}

bool IsGrid(const Config& cfg) { return cfg.engine.rfind("grid_", 0) == 0; }

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  double pos = q * static_cast<double>(v.size() - 1);
  size_t i = static_cast<size_t>(pos);
  double frac = pos - static_cast<double>(i);
  return i + 1 < v.size() ? v[i] * (1 - frac) + v[i + 1] * frac : v[i];
}

double Mean(const std::vector<double>& v) {
  double sum = 0;
  for (double x : v) sum += x;
  return v.empty() ? 0 : sum / static_cast<double>(v.size());
}

long PeakRssKb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss;
}

// --sort and --global-fraction, on either cell's global_sort_fraction (default: the cell's).
void SetSortFraction(const Config& cfg, double* fraction) {
  if (cfg.sort == "local") *fraction = 1e300;
  if (cfg.sort == "global") *fraction = 0.0;
  if (cfg.sort == "auto" && cfg.global_fraction >= 0) *fraction = cfg.global_fraction;
}

bp::SegmentedSapOptions SapOptions(const Config& cfg) {
  bp::SegmentedSapOptions options;
  options.chunk_capacity = cfg.chunk;
  options.presorted_min = cfg.presorted_min;
  SetSortFraction(cfg, &options.global_sort_fraction);
  return options;
}

bp::BatchSapOptions BatchOptions(const Config& cfg) {
  bp::BatchSapOptions options;
  SetSortFraction(cfg, &options.global_sort_fraction);
  return options;
}

template <class GridOptions>
GridOptions MakeGridOptions(const Config& cfg, const decltype(GridOptions::cell)& cell) {
  GridOptions options;
  options.cell_size = cfg.cell_size;
  if (cfg.objects_per_cell > 0) options.objects_per_cell = cfg.objects_per_cell;
  options.max_cells_per_object = cfg.max_cells;
  options.threads = cfg.threads;
  if (cfg.parallel_routing_from >= 0)
    options.parallel_routing_from = static_cast<size_t>(cfg.parallel_routing_from);
  options.parallel_lookups = !cfg.no_parallel_lookups;
  options.cell = cell;
  return options;
}

// The objects per cell the grid aims at: the option, or the cell type's default.
double ObjectsPerCell(const Config& cfg) {
  if (cfg.objects_per_cell > 0) return cfg.objects_per_cell;
  return cfg.engine == "grid_dense" ? bp::kDefaultObjectsPerCell<bp::DenseCellOptions>
                                    : bp::kDefaultObjectsPerCell<bp::SegmentedSapOptions>;
}

bp::DenseKernel RequestedKernel(const Config& cfg) {
  for (bp::DenseKernel k :
       {bp::DenseKernel::kAvx512, bp::DenseKernel::kAvx2, bp::DenseKernel::kPortable}) {
    if (cfg.kernel == bp::DenseKernelName(k)) return k;
  }
  return bp::DenseKernel::kAuto;
}

// The kernel the dense cells run for cfg's coordinate type on this CPU.
bp::DenseKernel ResolvedKernel(const Config& cfg) {
  const bp::DenseKernel k = RequestedKernel(cfg);
  if (cfg.coord == "double") return bp::detail::ResolveDenseKernel<double>(k);
  if (cfg.coord == "int32") return bp::detail::ResolveDenseKernel<int32_t>(k);
  return bp::detail::ResolveDenseKernel<float>(k);
}

bp::DenseCellOptions DenseOptions(const Config& cfg) {
  bp::DenseCellOptions options;
  options.kernel = RequestedKernel(cfg);
  return options;
}

bp::DynamicOctreeOptions OctreeOptions(const Config& cfg) {
  bp::DynamicOctreeOptions options;
  options.max_objects_per_node = cfg.octree_capacity;
  options.max_depth = cfg.octree_depth;
  return options;
}

// The engine of cfg; margin is in the engine's units (the scene's cube width is 1).
template <int K, class T>
std::unique_ptr<bp::Broadphase<K, T>> MakeEngine(const Config& cfg, T margin) {
  // bp::NewEngine: the engines are compiled once, in bp_engines, for the six shapes bpbench runs.
  bp::EngineSpec spec;
  spec.algorithm = cfg.engine;
  spec.segmented_sap = SapOptions(cfg);
  spec.batch_sap = BatchOptions(cfg);
  spec.dynamic_octree = OctreeOptions(cfg);
  spec.grid_segmented_sap = MakeGridOptions<bp::GridSegmentedSapOptions>(cfg, SapOptions(cfg));
  spec.grid_batch_sap = MakeGridOptions<bp::GridBatchSapOptions>(cfg, BatchOptions(cfg));
  spec.grid_dense = MakeGridOptions<bp::GridDenseOptions>(cfg, DenseOptions(cfg));
  std::unique_ptr<bp::Broadphase<K, T>> engine = bp::NewEngine<K, T>(spec, margin);
  if (engine == nullptr) {
    std::fprintf(stderr, "bpbench: unknown engine '%s' (known: %s)\n", cfg.engine.c_str(),
                 bp::EngineAlgorithmList().c_str());
    std::exit(2);
  }
  return engine;
}

// The engine's overlap set as sorted pair keys.
template <int K, class T>
std::vector<uint64_t> SortedPairs(const bp::Broadphase<K, T>& engine) {
  std::vector<uint64_t> out;
  out.reserve(engine.GetStats().overlaps);
  engine.ForEachOverlap(
      [&](uint64_t a, uint64_t b) { out.push_back(bp::workload::PairKey(a, b)); });
  std::sort(out.begin(), out.end());
  return out;
}

// The options of the never-moving boxes added to a scene: static with --static-rest.
bp::ObjectOptions StaticIf(const Config& cfg) {
  bp::ObjectOptions o;
  o.is_static = cfg.static_rest;
  return o;
}

// The large-object scene: the scene plus one box over the whole world and big_boxes boxes of
// big_width cube widths at positions drawn with splitmix64 (ids from 2^40, never moved); they
// join the scene's first query. The golden hashes then no longer apply: compare engines.
template <int K, class T>
void AddStaticBoxes(const Config& cfg, const SceneParams& p, bp::Broadphase<K, T>* engine) {
  const double side = K == 3 ? std::cbrt(p.n / p.density) : std::sqrt(p.n / p.density);
  uint64_t id = uint64_t{1} << 40;
  if (cfg.world_box) {
    bp::Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      b.lo[a] = static_cast<T>(-1) + static_cast<T>(cfg.offset);
      b.hi[a] = static_cast<T>(side + 1) + static_cast<T>(cfg.offset);
    }
    if (!engine->Insert(id++, b, StaticIf(cfg)).ok())
      std::fprintf(stderr, "bpbench: world box refused\n");
  }
  uint64_t state = p.seed ^ 0xB16B0E5;
  for (uint32_t i = 0; i < cfg.big_boxes; ++i) {
    bp::Box<K, T> b;
    for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
      double u = static_cast<double>(bp::workload::SplitMix64(state) >> 11) * 0x1p-53;
      double lo = u * std::max(0.0, side - cfg.big_width);
      b.lo[a] = static_cast<T>(lo) + static_cast<T>(cfg.offset);
      b.hi[a] = static_cast<T>(lo + cfg.big_width) + static_cast<T>(cfg.offset);
    }
    if (!engine->Insert(id++, b, StaticIf(cfg)).ok())
      std::fprintf(stderr, "bpbench: big box refused\n");
  }
}

// TE: the exact engine's coordinates (T, or double for --error-vs-double).
template <int K, class T, class TE = T>
Result RunTyped(const SceneParams& params, int frames, const Config& cfg,
                const std::string& label) {
  Result r;
  const bool fat = cfg.margin > 0 || cfg.error_vs_double || cfg.compare_exact;
  for (int rep = 0; rep < cfg.repeats; ++rep) {
    auto engine = MakeEngine<K, T>(cfg, static_cast<T>(cfg.margin));
    AddStaticBoxes<K, T>(cfg, params, engine.get());
    bp::workload::SceneRunner<K, T> runner(*engine, params, cfg.static_rest, cfg.unpaired_every);
    // With a margin, the first run also drives an exact engine through the same scene, untimed,
    // and compares the overlap sets after every frame.
    std::unique_ptr<bp::Broadphase<K, TE>> exact;
    std::unique_ptr<bp::workload::SceneRunner<K, TE>> exact_runner;
    if (fat && rep == 0) {
      exact = MakeEngine<K, TE>(cfg, TE{});
      AddStaticBoxes<K, TE>(cfg, params, exact.get());
      exact_runner = std::make_unique<bp::workload::SceneRunner<K, TE>>(
          *exact, params, cfg.static_rest, cfg.unpaired_every);
      exact_runner->Build();
    }
    double build = runner.Build();
    if (rep == 0) r.build_ms = build;
    std::vector<double> run;
    for (int f = 1; f <= frames; ++f) {
      run.push_back(runner.Step());
      bp::Stats s = engine->GetStats();
      AddPhases(runner.calls_ms(), s, &r);
      if (exact_runner) {
        exact_runner->Step();
        std::vector<uint64_t> got = SortedPairs(*engine), want = SortedPairs(*exact);
        std::vector<uint64_t> diff;
        std::set_difference(got.begin(), got.end(), want.begin(), want.end(),
                            std::back_inserter(diff));
        r.false_pos += diff.size();
        diff.clear();
        std::set_difference(want.begin(), want.end(), got.begin(), got.end(),
                            std::back_inserter(diff));
        r.false_neg += diff.size();
        r.fat_skips += s.fat_skips;
        ++r.error_frames;
      }
      r.swaps += s.swaps;
      r.tests += s.overlap_tests;
      (s.global_sort ? r.global_frames : r.local_frames) += 1;
      if (cfg.progress && (f % 5 == 0 || f == frames)) {
        std::fprintf(stderr, "\r%-40s repeat %d/%d frame %3d/%d", label.c_str(), rep + 1,
                     cfg.repeats, f, frames);
      }
    }
    r.last = engine->GetStats();
    r.frame_ms.insert(r.frame_ms.end(), run.begin(), run.end());
    r.run_medians.push_back(Quantile(run, 0.5));
    r.pairs0 = runner.pairs_frame0();
    r.pairs = runner.pairs();
    r.collides = runner.collides();
    r.uncollides = runner.uncollides();
    r.set_hash = runner.set_hash();
    r.chain = runner.chain();
    r.errors += runner.errors();
  }
  if (cfg.progress) std::fprintf(stderr, "\r%-80s\r", "");
  return r;
}

// The scenario's parameters with the configuration's shape and offset.
SceneParams Shaped(SceneParams p, const Config& cfg) {
  if (!bp::workload::ParseShape(cfg.shape.c_str(), &p.shape))
    p.shape = bp::workload::Shape::kUniform;
  p.offset = cfg.offset;
  return p;
}

// The golden values hold only for WORKLOADS.md's own scene.
bool GoldenScene(const Config& cfg) {
  return cfg.margin == 0 && !cfg.static_rest && cfg.unpaired_every == 0 && cfg.shape == "uniform" &&
         cfg.offset == 0 && !cfg.error_vs_double && !cfg.world_box && cfg.big_boxes == 0;
}

Result Run(const SceneParams& scenario, int frames, const Config& cfg, const std::string& label) {
  const SceneParams params = Shaped(scenario, cfg);
  bool planar = params.dim == 2;
  if (cfg.coord == "double") {
    return planar ? RunTyped<2, double>(params, frames, cfg, label)
                  : RunTyped<3, double>(params, frames, cfg, label);
  }
  if (cfg.coord == "int32") {
    return planar ? RunTyped<2, int32_t>(params, frames, cfg, label)
                  : RunTyped<3, int32_t>(params, frames, cfg, label);
  }
  if (cfg.error_vs_double) {
    return planar ? RunTyped<2, float, double>(params, frames, cfg, label)
                  : RunTyped<3, float, double>(params, frames, cfg, label);
  }
  return planar ? RunTyped<2, float>(params, frames, cfg, label)
                : RunTyped<3, float>(params, frames, cfg, label);
}

std::string Hex(uint64_t v) {
  char buf[20];
  std::snprintf(buf, sizeof buf, "%016" PRIx64, v);
  return buf;
}

void PrintJson(const std::string& scenario, const SceneParams& p, int frames, const Config& cfg,
               const Result& r, const GoldenScenario* golden, const std::string& extra) {
  std::ostringstream o;
  o.precision(6);
  o << "{\"scenario\":\"" << scenario << "\",\"engine\":\"" << cfg.engine << "\",\"dim\":" << p.dim
    << ",\"coord\":\"" << cfg.coord << "\",\"n\":" << p.n << ",\"moving\":" << p.moving
    << ",\"churn\":" << p.churn << ",\"frames\":" << frames << ",\"repeats\":" << cfg.repeats;
  const bp::GridStats last_grid = r.last.grid.value_or(bp::GridStats{});  // zeros: no grid
  if (IsGrid(cfg)) {
    o << ",\"cell_size\":" << last_grid.cell_size << ",\"auto_size\":" << (cfg.cell_size == 0)
      << ",\"objects_per_cell\":" << ObjectsPerCell(cfg) << ",\"max_cells\":" << cfg.max_cells
      << ",\"threads\":" << cfg.threads << ",\"parallel_routing_from\":"
      << (cfg.parallel_routing_from >= 0 ? static_cast<size_t>(cfg.parallel_routing_from)
                                         : bp::GridDenseOptions().parallel_routing_from)
      << ",\"parallel_lookups\":" << (cfg.no_parallel_lookups ? "false" : "true")
      << ",\"cells\":" << last_grid.cells << ",\"large_objects\":" << last_grid.large_objects;
  }
  if (cfg.engine == "grid_dense") {
    o << ",\"kernel\":\"" << bp::DenseKernelName(ResolvedKernel(cfg)) << "\""
      << ",\"cell_slots\":" << last_grid.cell_slots;
  }
  if (cfg.engine == "segmented_sap" || cfg.engine == "grid_segmented_sap") {
    o << ",\"chunk\":" << cfg.chunk << ",\"presorted_min\":" << cfg.presorted_min;
  }
  if (cfg.engine == "dynamic_octree") {
    o << ",\"octree_capacity\":" << cfg.octree_capacity << ",\"octree_depth\":" << cfg.octree_depth;
  } else if (cfg.engine != "brute_force" && cfg.peer.empty()) {
    bool batch = cfg.engine == "batch_sap" || cfg.engine == "grid_batch_sap";
    double fraction =
        batch ? BatchOptions(cfg).global_sort_fraction : SapOptions(cfg).global_sort_fraction;
    o << ",\"sort\":\"" << cfg.sort << "\",\"global_fraction\":" << fraction;
  }
  if (!cfg.variant.empty()) o << ",\"variant\":\"" << cfg.variant << "\"";
  if (!cfg.label.empty()) o << ",\"label\":\"" << cfg.label << "\"";
  if (cfg.static_rest) o << ",\"static_rest\":true";
  if (cfg.unpaired_every != 0) o << ",\"unpaired_every\":" << cfg.unpaired_every;
  if (cfg.shape != "uniform") o << ",\"shape\":\"" << cfg.shape << "\"";
  if (cfg.offset != 0) o << ",\"offset\":" << cfg.offset;
  if (cfg.margin > 0 || cfg.error_vs_double || cfg.compare_exact) {
    if (cfg.error_vs_double) o << ",\"error_vs\":\"double\"";
    const double ef = static_cast<double>(std::max<uint64_t>(r.error_frames, 1));
    o << ",\"margin\":" << cfg.margin
      << ",\"false_pos_per_frame\":" << static_cast<double>(r.false_pos) / ef
      << ",\"false_neg_per_frame\":" << static_cast<double>(r.false_neg) / ef
      << ",\"fat_skips_per_frame\":" << static_cast<double>(r.fat_skips) / ef;
  }
  if (cfg.world_box || cfg.big_boxes != 0) {
    o << ",\"world_box\":" << cfg.world_box << ",\"big_boxes\":" << cfg.big_boxes
      << ",\"big_width\":" << cfg.big_width;
  }
  o << extra << ",\"median_ms\":" << Quantile(r.run_medians, 0.5)
    << ",\"mean_ms\":" << Mean(r.frame_ms) << ",\"p90_ms\":" << Quantile(r.frame_ms, 0.9)
    << ",\"run_medians_ms\":[";
  for (size_t i = 0; i < r.run_medians.size(); ++i) o << (i ? "," : "") << r.run_medians[i];
  double frames_total = static_cast<double>(r.frame_ms.size());
  o << "],\"build_ms\":" << r.build_ms << ",\"pairs_frame0\":" << r.pairs0
    << ",\"pairs\":" << r.pairs << ",\"collides\":" << r.collides
    << ",\"uncollides\":" << r.uncollides << ",\"set_hash\":\"" << Hex(r.set_hash)
    << "\",\"chain\":\"" << Hex(r.chain)
    << "\",\"swaps_per_frame\":" << static_cast<double>(r.swaps) / frames_total
    << ",\"tests_per_frame\":" << static_cast<double>(r.tests) / frames_total
    << ",\"global_frames\":" << r.global_frames << ",\"local_frames\":" << r.local_frames
    << ",\"errors\":" << r.errors;
  if (!r.phase_ms[0].empty()) {
    // Medians per phase: where a frame goes (they need not add up to median_ms exactly).
    o << ",\"phases_ms\":{";
    bool first = true;
    for (size_t i = 0; i < kPhaseNames.size(); ++i) {
      const bool grid_part = i >= 3 && i <= 5;
      if (grid_part && !IsGrid(cfg)) continue;
      o << (first ? "" : ",") << "\"" << kPhaseNames[i] << "\":" << Quantile(r.phase_ms[i], 0.5);
      first = false;
    }
    o << "}";
  }
  if (golden != nullptr && frames == static_cast<int>(golden->frames)) {
    bool ok = r.pairs0 == golden->pairs_frame0 && r.pairs == golden->pairs_end &&
              r.collides == golden->collides && r.uncollides == golden->uncollides &&
              r.set_hash == golden->set_hash_end && r.chain == golden->chain;
    o << ",\"golden_ok\":" << (ok ? "true" : "false");
  }
  o << ",\"peak_rss_kb\":" << PeakRssKb() << "}";
  std::printf("%s\n", o.str().c_str());
  std::fflush(stdout);
}

// Runs each peer through the scenario our engine just ran (result ours) and prints its line:
// the same fields, plus the ratio of its median to ours and whether its exact set matched ours
// after the last frame and over the whole chain.
void RunPeers(const std::vector<const bp::bench::PeerInfo*>& peers, const std::string& scenario,
              const SceneParams& scenario_params, int frames, const Config& cfg, const Result& ours,
              const GoldenScenario* golden) {
  const SceneParams params = Shaped(scenario_params, cfg);
  for (const bp::bench::PeerInfo* info : peers) {
    Config pc = cfg;
    pc.engine = info->name;
    pc.peer = info->description;
    if (info->max_objects != 0 && params.n > info->max_objects) {
      std::printf(
          "{\"scenario\":\"%s\",\"engine\":\"%s\",\"library\":\"%s\",\"n\":%u,"
          "\"skipped\":\"%s\"}\n",
          scenario.c_str(), info->name.c_str(), info->description.c_str(), params.n,
          info->limit_reason.c_str());
      std::fflush(stdout);
      continue;
    }
    const std::string label = scenario + " " + info->name;
    auto progress = [&](int rep, int f) {
      if (cfg.progress && (f % 5 == 0 || f == frames)) {
        std::fprintf(stderr, "\r%-40s repeat %d/%d frame %3d/%d", label.c_str(), rep + 1,
                     cfg.repeats, f, frames);
      }
    };
    bp::bench::PeerRun run =
        bp::bench::RunPeer(*info, params, frames, cfg.repeats, cfg.coord, progress);
    if (cfg.progress) std::fprintf(stderr, "\r%-80s\r", "");
    Result r;
    r.frame_ms = run.frame_ms;
    r.run_medians = run.run_medians;
    r.build_ms = run.build_ms;
    r.pairs0 = run.pairs0;
    r.pairs = run.pairs;
    r.collides = run.collides;
    r.uncollides = run.uncollides;
    r.set_hash = run.set_hash;
    r.chain = run.chain;
    const double ours_ms = Quantile(ours.run_medians, 0.5);
    std::ostringstream extra;
    extra.precision(6);
    extra << ",\"library\":\"" << info->description << "\",\"compared_to\":\"" << cfg.engine
          << "\",\"ratio_to_engine\":" << (ours_ms > 0 ? Quantile(r.run_medians, 0.5) / ours_ms : 0)
          << ",\"same_set_as_engine\":"
          << (r.set_hash == ours.set_hash && r.chain == ours.chain ? "true" : "false")
          << ",\"candidates_per_frame\":"
          << static_cast<double>(run.candidates) / std::max(frames, 1)
          << ",\"duplicate_candidates\":" << run.duplicates;
    PrintJson(scenario, scenario_params, frames, pc, r, golden, extra.str());
  }
}

// Local versus global sort as the moving fraction grows (one SAP instance, churn 1; churn 0 for
// the batch cell): where the global insertion sort starts to win is the default
// global_sort_fraction.
void ThresholdSweep(Config cfg, const std::vector<uint32_t>& sizes) {
  const double fractions[] = {0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.6, 0.8, 1.0};
  int frames = cfg.frames > 0 ? cfg.frames : 50;
  for (uint32_t n : sizes) {
    for (double f : fractions) {
      SceneParams p;
      p.n = n;
      p.moving = std::max<uint32_t>(1, static_cast<uint32_t>(f * n + 0.5));
      // The batch cell passes globally whenever a record is pending: measure it on moves alone.
      p.churn = cfg.engine == "batch_sap" ? 0 : 1;
      for (const char* sort : {"local", "global"}) {
        cfg.sort = sort;
        std::string label =
            "threshold n=" + std::to_string(n) + " moving=" + std::to_string(p.moving) + " " + sort;
        Result r = Run(p, frames, cfg, label);
        PrintJson("threshold", p, frames, cfg, r, nullptr,
                  ",\"moving_fraction\":" + std::to_string(f));
      }
    }
  }
}

// The cells compared in the figure sweeps: the batch cell; the segmented cell as the paper
// describes it (one insert or erase at a time); the segmented cell with the paper's proposed
// presorted, chunk-by-chunk integration for every event; and the per-event segmented cell forced
// to sort globally or locally (the adaptive choice should follow the lower of the two).
std::vector<Config> FigureVariants(const Config& base) {
  std::vector<Config> out;
  auto add = [&](const char* variant, const char* engine, const char* sort, uint32_t presorted) {
    Config c = base;
    c.variant = variant;
    c.engine = engine;
    c.sort = sort;
    c.presorted_min = presorted;
    out.push_back(c);
  };
  add("batch", "batch_sap", "auto", 0);
  add("segmented", "segmented_sap", "auto", 0);
  add("segmented, presorted", "segmented_sap", "auto", 1);
  add("segmented, global sort only", "segmented_sap", "global", 0);
  add("segmented, local sort only", "segmented_sap", "local", 0);
  return out;
}

// The paper's multi-cell figures (section 4.2), through the grid over either cell and the octree:
// 10: 100k objects, 10k moving, inserts = erases per frame swept from 0 to 4000;
// 11: 10% moving, 0.5% inserts and 0.5% erases per frame, n swept from 10k to 200k.
void GridFigure(int figure, const Config& base) {
  int frames = base.frames > 0 ? base.frames : 50;
  std::vector<SceneParams> points;
  if (figure == 10) {
    for (uint32_t c : {0u, 50u, 100u, 250u, 500u, 1000u, 2000u, 4000u}) {
      SceneParams p;
      p.n = 100000;
      p.moving = 10000;
      p.churn = c;
      points.push_back(p);
    }
  } else {
    for (uint32_t n : {10000u, 25000u, 50000u, 100000u, 150000u, 200000u}) {
      SceneParams p;
      p.n = n;
      p.moving = n / 10;
      p.churn = n / 200;
      points.push_back(p);
    }
  }
  const std::string scenario = "fig" + std::to_string(figure);
  for (const SceneParams& p : points) {
    for (const char* engine :
         {"grid_segmented_sap", "grid_batch_sap", "grid_dense", "dynamic_octree"}) {
      Config cfg = base;
      cfg.engine = engine;
      cfg.variant = engine;
      std::string label = scenario + " n=" + std::to_string(p.n) +
                          " churn=" + std::to_string(p.churn) + " " + engine;
      Result r = Run(p, frames, cfg, label);
      PrintJson(scenario, p, frames, cfg, r, nullptr, "");
    }
  }
}

// Least-squares slope of log(y) against log(x): the growth exponent of y(x).
double FitExponent(const std::vector<double>& x, const std::vector<double>& y) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  const auto n = static_cast<double>(x.size());
  for (size_t i = 0; i < x.size(); ++i) {
    const double lx = std::log(x[i]), ly = std::log(std::max(y[i], 1e-12));
    sx += lx;
    sy += ly;
    sxx += lx * lx;
    sxy += lx * ly;
  }
  const double den = n * sxx - sx * sx;
  return den > 0 ? (n * sxy - sx * sy) / den : 0;
}

// The paper's Figure 2: one SAP instance with every object moving and no churn, n swept; the
// frame time grows as n^1.76 there (theory: the swaps grow as n^(5/3)). The same sweep through
// the grids shows what subdivision does to it. After the points, one "fig2-fit" line per engine
// with the fitted exponents of the frame time and of the swaps (or overlap tests).
void Figure2(const Config& base, const std::vector<uint32_t>& sizes) {
  const int frames = base.frames > 0 ? base.frames : 20;
  for (const char* engine : {"segmented_sap", "batch_sap", "grid_segmented_sap", "grid_dense"}) {
    std::vector<double> ns, ms, work;
    for (uint32_t n : sizes) {
      SceneParams p;
      p.n = n;
      p.moving = n;
      p.churn = 0;
      Config cfg = base;
      cfg.engine = engine;
      cfg.variant = engine;
      Result r = Run(p, frames, cfg, "fig2 n=" + std::to_string(n) + " " + engine);
      PrintJson("fig2", p, frames, cfg, r, nullptr, "");
      ns.push_back(n);
      ms.push_back(Quantile(r.run_medians, 0.5));
      const double per_frame = static_cast<double>(r.swaps != 0 ? r.swaps : r.tests) /
                               static_cast<double>(std::max<size_t>(r.frame_ms.size(), 1));
      work.push_back(per_frame);
    }
    std::printf(
        "{\"scenario\":\"fig2-fit\",\"engine\":\"%s\",\"n_min\":%u,\"n_max\":%u,\"points\":%zu,"
        "\"time_exponent\":%.4f,\"work_exponent\":%.4f,\"work\":\"%s\",\"paper_exponent\":1.76,"
        "\"theory_exponent\":%.4f}\n",
        engine, sizes.front(), sizes.back(), ns.size(), FitExponent(ns, ms), FitExponent(ns, work),
        std::string(engine).find("dense") != std::string::npos ? "overlap tests" : "swaps",
        5.0 / 3.0);
    std::fflush(stdout);
  }
}

// The paper's single-cell figures (section 4.1), 3000 objects (or `objects`), no subdivision:
//  8: one insert and one erase per frame, moving fraction swept from 5% to 100%;
//  9: 5% moving (150 of 3000), inserts = erases per frame swept from 1 to 100.
void Figure(int figure, uint32_t objects, const Config& base) {
  int frames = base.frames > 0 ? base.frames : 200;
  std::vector<SceneParams> points;
  if (figure == 8) {
    for (double f : {0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0}) {
      SceneParams p;
      p.n = objects;
      p.moving = std::max<uint32_t>(1, static_cast<uint32_t>(f * p.n + 0.5));
      p.churn = 1;
      points.push_back(p);
    }
  } else {
    for (uint32_t c : {1u, 2u, 5u, 10u, 15u, 20u, 30u, 40u, 50u, 60u, 80u, 100u}) {
      SceneParams p;
      p.n = objects;
      p.moving = std::max<uint32_t>(1, objects / 20);
      p.churn = std::min(c, objects / 2);
      points.push_back(p);
    }
  }
  const std::string scenario = "fig" + std::to_string(figure);
  for (const SceneParams& p : points) {
    for (const Config& cfg : FigureVariants(base)) {
      std::string label = scenario + " moving=" + std::to_string(p.moving) +
                          " churn=" + std::to_string(p.churn) + " " + cfg.variant;
      Result r = Run(p, frames, cfg, label);
      PrintJson(scenario, p, frames, cfg, r, nullptr, "");
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"bpbench: broadphase engine benchmarks on the WORKLOADS.md scenes (JSON lines)"};
  Config cfg;
  std::string scenarios = "S2a,S2c,S1-10k";
  std::string custom;
  bool sweep = false;
  std::vector<uint32_t> sweep_sizes = {3000, 10000};
  app.add_option("--scenario,-s", scenarios,
                 "comma-separated golden scenarios: S2a,S2b,S2c,S1-10k,S1-100k,S1-200k,S3,S4,2-D")
      ->capture_default_str();
  app.add_option("--custom", custom, "a custom 3-D scene instead: N,MOVING,CHURN");
  app.add_option("--engine,-e", cfg.engine, "one of " + bp::EngineAlgorithmList())
      ->check(CLI::IsMember(
          std::vector<std::string>(bp::kEngineAlgorithms.begin(), bp::kEngineAlgorithms.end())))
      ->capture_default_str();
  app.add_option("--cell-size", cfg.cell_size, "grid engines: cell edge (0: automatic)")
      ->check(CLI::Range(0.0, 1e300))
      ->capture_default_str();
  app.add_option("--objects-per-cell", cfg.objects_per_cell,
                 "grid engines: the automatic cell size aims at this many objects per cell (0: "
                 "the cell type's default, 300 for SAP cells, 32 for dense cells)")
      ->check(CLI::Range(0.0, 1e9))
      ->capture_default_str();
  app.add_option("--big-boxes", cfg.big_boxes, "add this many static boxes of --big-width widths")
      ->capture_default_str();
  app.add_option("--big-width", cfg.big_width, "edge of the --big-boxes, in cube widths")
      ->check(CLI::Range(0.0, 1e6))
      ->capture_default_str();
  app.add_flag("--world-box", cfg.world_box, "add one static box covering the whole scene");
  app.add_option("--label", cfg.label, "a name for the run, copied into its JSON line as \"label\"")
      ->check([](const std::string& v) -> std::string {
        return v.find_first_of("\"\\") == std::string::npos &&
                       std::all_of(v.begin(), v.end(),
                                   [](char c) { return static_cast<unsigned char>(c) >= 0x20; })
                   ? std::string()
                   : "a label holds no quote, backslash or control character";
      });
  app.add_option("--margin", cfg.margin,
                 "fattened boxes: margin in cube widths (0: exact); reports false positives and "
                 "negatives per frame against an exact engine run alongside (untimed)")
      ->check(CLI::Range(0.0, 1e6))
      ->capture_default_str();
  app.add_flag("--static-rest", cfg.static_rest,
               "insert the objects of resting slots as static (no static-static pairs; the golden "
               "hashes no longer apply)");
  app.add_option("--unpaired-every", cfg.unpaired_every,
                 "give every N-th object (by id) mask 0, a category that pairs with nothing (2: "
                 "half of them; the golden hashes no longer apply)");
  app.add_option(
         "--shape", cfg.shape,
         "the scene's layout: uniform (WORKLOADS.md's), clustered (90% of the objects in 1% "
         "of the volume), mixed (widths 1e-3 to 1e3), fast (a tenth of the movers at 25 "
         "widths per frame)")
      ->check(CLI::IsMember({"uniform", "clustered", "mixed", "fast"}))
      ->capture_default_str();
  app.add_option("--offset", cfg.offset,
                 "add this to every coordinate, in the engine's coordinate type (a world far "
                 "from the origin: 1e6 for float, 1e12 for double)")
      ->capture_default_str();
  app.add_flag("--error-vs-double", cfg.error_vs_double,
               "float coordinates fed double input: a float engine, with false positives and "
               "negatives per frame counted against a double engine on the same scene (with "
               "--offset the scene is exact in double and rounded in float)");
  std::vector<double> margin_sweep;
  app.add_option("--margin-sweep", margin_sweep,
                 "run each scenario once per margin (cube widths): error against run time");
  app.add_option("--threads", cfg.threads, "grid engines: threads applying the cells")
      ->check(CLI::Range(1u, 256u))
      ->capture_default_str();
  app.add_option("--parallel-routing-from", cfg.parallel_routing_from,
                 "grid engines with --threads above 1: route a query's updates in parallel from "
                 "this many (0: never; default: the engine's)")
      ->check(CLI::Range(int64_t{0}, int64_t{1} << 40));
  app.add_flag("--no-parallel-lookups", cfg.no_parallel_lookups,
               "grid engines with --threads above 1: look up the keys of a large UpdateMany or "
               "EraseMany on the caller's thread only (as the daemon does)");
  app.add_option("--max-cells", cfg.max_cells,
                 "grid engines: cells an object may cover before it is kept as a large object")
      ->check(CLI::Range(1u, 1000000u))
      ->capture_default_str();
  app.add_option("--kernel", cfg.kernel,
                 "grid_dense: the cells' box-test kernel: auto (the widest the CPU has), avx512, "
                 "avx2 (float, double and int32 on x86-64) or portable; one the CPU lacks falls "
                 "back to the next narrower, and the output's \"kernel\" names the one that ran")
      ->check(CLI::IsMember({"auto", "avx512", "avx2", "portable"}))
      ->capture_default_str();
  app.add_option("--coord", cfg.coord, "coordinate type")
      ->check(CLI::IsMember({"float", "double", "int32"}))
      ->capture_default_str();
  app.add_option("--sort", cfg.sort, "re-sort of moved objects: auto, local or global")
      ->check(CLI::IsMember({"auto", "local", "global"}))
      ->capture_default_str();
  app.add_option("--global-fraction", cfg.global_fraction,
                 "auto sort: global when moved > fraction * objects (default: the engine's)")
      ->capture_default_str();
  app.add_option("--presorted-min", cfg.presorted_min,
                 "segmented_sap: inserts + erases from which a query integrates them presorted, "
                 "chunk by chunk (0: never)")
      ->capture_default_str();
  app.add_option("--chunk", cfg.chunk, "segmented_sap chunk capacity (power of two)")
      ->check(CLI::Range(4u, 4096u))
      ->capture_default_str();
  app.add_option("--octree-capacity", cfg.octree_capacity,
                 "dynamic_octree: objects a leaf holds before it splits")
      ->check(CLI::Range(1u, 1000000u))
      ->capture_default_str();
  app.add_option(
         "--octree-depth", cfg.octree_depth,
         "dynamic_octree: halvings below the first root's size past which nodes do not split")
      ->check(CLI::Range(0u, 2000u))
      ->capture_default_str();
  app.add_option("--repeats,-r", cfg.repeats, "runs per scenario (median of run medians)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  app.add_option("--frames,-f", cfg.frames, "frames per run (0: the scenario's 100)")
      ->check(CLI::Range(0, 100000));
  app.add_flag("--threshold-sweep", sweep, "measure local vs global sort over moving fractions");
  int figure = 0;
  uint32_t figure_objects = 3000;
  app.add_option("--figure", figure,
                 "the paper's figure 2 (one SAP instance, all moving, n swept: growth exponent), "
                 "8 or 9 (single cell, every cell variant), 10 or 11 (grid over either cell and "
                 "the octree)")
      ->check(CLI::IsMember({2, 8, 9, 10, 11}));
  app.add_option("--figure-objects", figure_objects, "objects of the figure's scene (paper: 3000)")
      ->check(CLI::Range(20u, 10000000u))
      ->capture_default_str();
  app.add_option("--sweep-sizes", sweep_sizes,
                 "object counts of the threshold sweep, or of --figure 2 (default 1000 to 128000, "
                 "doubling)")
      ->capture_default_str();
  std::string peer_list;
  app.add_option("--peers", peer_list,
                 "after each scenario, run these peer libraries through the same scene in this "
                 "process: all, or names separated by commas; 'list' shows what this build has");
  CLI11_PARSE(app, argc, argv);
  if (peer_list == "list") {
    for (const auto& p : bp::bench::Peers()) {
      std::printf("%-18s %s%s%s\n", p.name.c_str(), p.description.c_str(),
                  p.max_objects != 0 ? ", skipped above " : "",
                  p.max_objects != 0 ? std::to_string(p.max_objects).c_str() : "");
    }
    if (bp::bench::Peers().empty()) std::printf("(no peer library was found at build time)\n");
    return 0;
  }
  std::vector<const bp::bench::PeerInfo*> peers;
  if (std::string unknown; !bp::bench::SelectPeers(peer_list, &peers, &unknown)) {
    std::fprintf(stderr, "bpbench: peer '%s' is not in this build (bpbench --peers list)\n",
                 unknown.c_str());
    return 2;
  }
  // Peers get the scene's own boxes, exact: refuse what would make our line a different scene.
  if (!peers.empty() && (cfg.world_box || cfg.big_boxes != 0 || cfg.static_rest ||
                         cfg.unpaired_every != 0 || cfg.margin > 0 || cfg.error_vs_double)) {
    std::fprintf(stderr,
                 "bpbench: --peers compares exact sets of the plain scene: not with --world-box, "
                 "--big-boxes, --static-rest, --unpaired-every, --margin or --error-vs-double (a "
                 "--margin-sweep "
                 "compares at its 0 point)\n");
    return 2;
  }
  cfg.progress = isatty(STDERR_FILENO) != 0;
  if ((cfg.margin > 0 || !margin_sweep.empty()) && cfg.coord == "int32") {
    std::fprintf(stderr, "bpbench: --margin needs float or double coordinates\n");
    return 2;
  }
  if (cfg.error_vs_double && cfg.coord != "float") {
    std::fprintf(stderr, "bpbench: --error-vs-double measures a float engine: --coord float\n");
    return 2;
  }
  if (cfg.offset != 0 && cfg.coord == "int32") {
    std::fprintf(stderr, "bpbench: --offset needs float or double coordinates\n");
    return 2;
  }
  if (!std::isfinite(cfg.offset)) {
    std::fprintf(stderr, "bpbench: --offset must be finite\n");
    return 2;
  }
  if (margin_sweep.empty()) margin_sweep.push_back(cfg.margin);
  if (!peers.empty() &&
      std::find(margin_sweep.begin(), margin_sweep.end(), 0.0) == margin_sweep.end()) {
    std::fprintf(stderr, "bpbench: --peers with --margin-sweep needs 0 in the sweep\n");
    return 2;
  }

  if (sweep) {
    ThresholdSweep(cfg, sweep_sizes);
    return 0;
  }
  if (figure == 2) {
    if (!app.count("--sweep-sizes")) {
      sweep_sizes = {1000, 2000, 4000, 8000, 16000, 32000, 64000, 128000};
    }
    Figure2(cfg, sweep_sizes);
    return 0;
  }
  if (figure >= 10) {
    GridFigure(figure, cfg);
    return 0;
  }
  if (figure != 0) {
    Figure(figure, figure_objects, cfg);
    return 0;
  }
  if (!custom.empty()) {
    SceneParams p;
    if (std::sscanf(custom.c_str(), "%u,%u,%u", &p.n, &p.moving, &p.churn) != 3 || p.moving > p.n ||
        p.churn > p.n || p.n == 0) {
      std::fprintf(stderr, "bpbench: --custom wants N,MOVING,CHURN with MOVING, CHURN <= N\n");
      return 2;
    }
    int frames = cfg.frames > 0 ? cfg.frames : 100;
    Result r = Run(p, frames, cfg, "custom");
    PrintJson("custom", p, frames, cfg, r, nullptr, "");
    RunPeers(peers, "custom", p, frames, cfg, r, nullptr);
    return r.errors == 0 ? 0 : 1;
  }
  int status = 0;
  std::stringstream list(scenarios);
  std::string name;
  while (std::getline(list, name, ',')) {
    const GoldenScenario* g = bp::workload::FindGolden(name);
    if (g == nullptr) {
      std::fprintf(stderr, "bpbench: unknown scenario '%s'\n", name.c_str());
      return 2;
    }
    int frames = cfg.frames > 0 ? cfg.frames : static_cast<int>(g->frames);
    for (double margin : margin_sweep) {
      Config run_cfg = cfg;
      run_cfg.margin = margin;
      run_cfg.compare_exact = margin_sweep.size() > 1;  // the sweep's exact point is measured too
      Result r = Run(g->Params(), frames, run_cfg, name + " " + cfg.engine);
      PrintJson(name, g->Params(), frames, run_cfg, r, GoldenScene(run_cfg) ? g : nullptr, "");
      if (margin == 0)
        RunPeers(peers, name, g->Params(), frames, cfg, r, GoldenScene(cfg) ? g : nullptr);
      if (r.errors != 0) status = 1;
    }
  }
  return status;
}
