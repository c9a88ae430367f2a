// libFuzzer target: random engine operation sequences against the model oracle.
//
// The input picks an engine family and its options (cell sizes down to 1e-3, one object per
// octree node, chunks of 4, ...), a dimension (2 or 3) and a coordinate type (float, double,
// int32), then a sequence of calls: inserts with options, updates, erases and queries, over a
// small key space so that keys are reused, erased and reinserted within a frame. Coordinates
// come from a palette of hard values (±0, denormals, the type's ends, ±1e30/±1e300, NaN, ±inf, a
// small lattice for exact touching) or from raw bits. Each call's success must be what the
// model predicts (a bad box, a live key on insert, an unknown key on update or erase: refused);
// each query's events must equal the model's exactly and the engine's validators must pass.
// On a mismatch the target prints what differs and aborts, so libFuzzer saves the input.
//
//   build: cmake --preset ci-fuzz && cmake --build --preset ci-fuzz   (clang)
//   run:   scripts/fuzz run engine_ops [RUNS]   (RUNS inputs; scripts/fuzz smoke: the CI stage)
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <vector>

#include "../engine/test_support.h"
#include <fuzzer/FuzzedDataProvider.h>

#include "bp/engines.h"

namespace {

using bp::test::CellKind;

template <class T>
T ConsumeCoord(FuzzedDataProvider& fdp) {
  using L = std::numeric_limits<T>;
  const uint8_t mode = fdp.ConsumeIntegral<uint8_t>();
  if (mode < 160) return static_cast<T>(static_cast<int>(mode % 17) - 8);  // lattice -8..8
  if (mode < 200) {
    T v{};
    if constexpr (std::is_floating_point_v<T>) {
      const T palette[] = {T(0),          -T(0),          L::denorm_min(), -L::denorm_min(),
                           L::min(),      -L::min(),      L::max(),        L::lowest(),
                           T(1e30),       T(-1e30),       T(0.5),          T(-0.5),
                           T(0.3),        T(1e-6),        T(1e6),          L::quiet_NaN(),
                           L::infinity(), -L::infinity(), L::epsilon(),    T(2.9999999)};
      v = palette[mode % (sizeof(palette) / sizeof(palette[0]))];
      if constexpr (std::is_same_v<T, double>) {
        if (mode % 7 == 0) v = (mode & 8) != 0 ? 1e300 : -1e300;
      }
    } else {
      const T palette[] = {L::max(), L::lowest(), T(L::max() / 2), T(L::lowest() / 2), T(3), T(-3)};
      v = palette[mode % (sizeof(palette) / sizeof(palette[0]))];
    }
    return v;
  }
  // Raw bits: any value of the type, NaN payloads and denormals included.
  uint8_t bytes[sizeof(T)] = {};
  const std::vector<uint8_t> raw = fdp.ConsumeBytes<uint8_t>(sizeof(T));
  if (!raw.empty()) std::memcpy(bytes, raw.data(), raw.size());
  T v;
  std::memcpy(&v, bytes, sizeof(T));
  return v;
}

template <int K, class T>
bp::Box<K, T> ConsumeBox(FuzzedDataProvider& fdp) {
  bp::Box<K, T> box;
  for (size_t a = 0; a < static_cast<size_t>(K); ++a) {
    box.lo[a] = ConsumeCoord<T>(fdp);
    // Usually a non-negative extent on the lattice, sometimes an independent value (which may
    // invert the box).
    const uint8_t e = fdp.ConsumeIntegral<uint8_t>();
    if (e < 200) {
      if constexpr (std::is_integral_v<T>) {
        const int64_t hi = int64_t{box.lo[a]} + e % 5;
        box.hi[a] = hi > int64_t{std::numeric_limits<T>::max()} ? box.lo[a] : static_cast<T>(hi);
      } else {
        box.hi[a] = box.lo[a] + static_cast<T>(e % 5);
        if (!(box.hi[a] >= box.lo[a])) box.hi[a] = box.lo[a];  // rounding or NaN
      }
    } else {
      box.hi[a] = ConsumeCoord<T>(fdp);
    }
  }
  return box;
}

// The engine the input picks, built by bp::NewEngine (compiled once, in bp_engines).
template <int K, class T>
std::unique_ptr<bp::Broadphase<K, T>> MakeEngine(FuzzedDataProvider& fdp) {
  const double cell_sizes[] = {0, 0, 0.3, 1, 3, 1e-3, 1e6};
  const uint32_t max_cells[] = {16, 1, 2, 8, 64};
  auto grid_options = [&](auto& options) {
    options.cell_size = cell_sizes[fdp.ConsumeIntegralInRange<size_t>(0, 6)];
    options.max_cells_per_object = max_cells[fdp.ConsumeIntegralInRange<size_t>(0, 4)];
    if (fdp.ConsumeBool()) options.objects_per_cell = fdp.ConsumeIntegralInRange<int>(1, 64);
  };
  const double fractions[] = {0.07, 0, 1e300, 0.5};
  bp::EngineSpec spec;
  switch (fdp.ConsumeIntegralInRange<int>(0, 7)) {
    case 0:
      spec.algorithm = "brute_force";
      break;
    case 1: {
      spec.algorithm = "segmented_sap";
      bp::SegmentedSapOptions& o = spec.segmented_sap;
      o.chunk_capacity = 4u << fdp.ConsumeIntegralInRange<uint32_t>(0, 4);
      o.global_sort_fraction = fractions[fdp.ConsumeIntegralInRange<size_t>(0, 3)];
      o.bulk_load_min = fdp.ConsumeIntegralInRange<uint32_t>(0, 70);
      o.presorted_min = fdp.ConsumeIntegralInRange<uint32_t>(0, 40);
      break;
    }
    case 2:
      spec.algorithm = "batch_sap";
      spec.batch_sap.global_sort_fraction = fractions[fdp.ConsumeIntegralInRange<size_t>(0, 3)];
      break;
    case 3:
      spec.algorithm = "grid_segmented_sap";
      grid_options(spec.grid_segmented_sap);
      spec.grid_segmented_sap.cell.chunk_capacity = 4;
      break;
    case 4:
      spec.algorithm = "grid_batch_sap";
      grid_options(spec.grid_batch_sap);
      break;
    case 5:
    case 6:
      spec.algorithm = "grid_dense";
      grid_options(spec.grid_dense);
      break;
    default:
      spec.algorithm = "dynamic_octree";
      spec.dynamic_octree.max_objects_per_node = fdp.ConsumeIntegralInRange<uint32_t>(1, 32);
      spec.dynamic_octree.max_depth = fdp.ConsumeIntegralInRange<uint32_t>(1, 20);
      break;
  }
  std::unique_ptr<bp::Broadphase<K, T>> engine = bp::NewEngine<K, T>(spec);
  if (engine == nullptr) std::abort();  // every name above is one of bp::kEngineAlgorithms
  return engine;
}

[[noreturn]] void Fail(const char* what, const std::string& engine, int step) {
  std::fprintf(stderr, "fuzz_engine_ops: %s (engine %s, call %d)\n", what, engine.c_str(), step);
  std::abort();
}

template <int K, class T>
void Run(FuzzedDataProvider& fdp) {
  std::unique_ptr<bp::Broadphase<K, T>> engine = MakeEngine<K, T>(fdp);
  const std::string name = engine->Name();
  bp::test::ModelOracle<K, T> model;
  bp::test::RecordingSink<uint64_t> sink;
  std::vector<std::pair<uint64_t, uint64_t>> collides, uncollides;
  auto query = [&](int step) {
    sink.Clear();
    engine->Query(sink);
    model.Query(&collides, &uncollides);
    if (sink.collides != collides) Fail("collides differ from the model", name, step);
    if (sink.uncollides != uncollides) Fail("uncollides differ from the model", name, step);
    // The engine validates its structures itself after every query (BP_VALIDATE).
    if (engine->Size() != model.boxes().size()) Fail("live count differs", name, step);
  };
  for (int step = 0; step < 1000 && fdp.remaining_bytes() > 0; ++step) {
    const int op = fdp.ConsumeIntegralInRange<int>(0, 9);
    const uint64_t key = fdp.ConsumeIntegralInRange<uint64_t>(0, 47);
    auto& boxes = model.boxes();
    const bool live = boxes.count(key) != 0;
    if (op <= 2) {  // insert
      const bp::Box<K, T> box = ConsumeBox<K, T>(fdp);
      bp::ObjectOptions options;
      if (fdp.ConsumeIntegralInRange<int>(0, 3) == 0) {
        options.category = fdp.ConsumeIntegralInRange<uint64_t>(0, 7);
        options.mask = fdp.ConsumeIntegralInRange<uint64_t>(0, 7);
        options.is_static = fdp.ConsumeBool();
      }
      const bool valid = bp::ValidateBox(box).ok() && !live;
      if (engine->Insert(key, box, options).ok() != valid) Fail("insert status", name, step);
      if (valid) {
        boxes[key] = box;
        if (options == bp::ObjectOptions{})
          model.options().erase(key);
        else
          model.options()[key] = options;
      }
    } else if (op <= 6) {  // update
      const bp::Box<K, T> box = ConsumeBox<K, T>(fdp);
      const bool valid = bp::ValidateBox(box).ok() && live;
      if (engine->Update(key, box).ok() != valid) Fail("update status", name, step);
      if (valid) boxes[key] = box;
    } else if (op <= 7) {  // erase
      if (engine->Erase(key).ok() != live) Fail("erase status", name, step);
      boxes.erase(key);
      model.options().erase(key);
    } else {
      query(step);
    }
  }
  query(-1);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  FuzzedDataProvider fdp(data, size);
  switch (fdp.ConsumeIntegralInRange<int>(0, 5)) {
    case 0:
      Run<3, float>(fdp);
      break;
    case 1:
      Run<3, double>(fdp);
      break;
    case 2:
      Run<3, int32_t>(fdp);
      break;
    case 3:
      Run<2, float>(fdp);
      break;
    case 4:
      Run<2, double>(fdp);
      break;
    default:
      Run<2, int32_t>(fdp);
      break;
  }
  return 0;
}
