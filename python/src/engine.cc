// broadphase.Engine: every engine of the library by name (bp::NewEngine), fed and read with numpy
// arrays. One Python class over the six compiled shapes (2 or 3 axes; float32, float64 or int32
// coordinates): EngineOf<K, T> implements EngineBase for each.
//
// Thread safety: the GIL is released while the engine works (the calls' batches, Query, the
// reads); a mutex per engine serialises the Python threads that share one. Arrays are converted
// while the GIL is held, before the engine is locked, and results are built after it is unlocked,
// so no thread waits for the GIL while it holds the engine.
#include "engine.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "arrays.h"
#include <pybind11/stl.h>

#include "bp/engines.h"

namespace bp::python {
namespace {

// The refusals of one batch call: (index, "Code: message").
struct Refusals {
  std::vector<size_t> index;
  std::vector<std::string> reason;
  void Add(size_t i, const Status& s) {
    index.push_back(i);
    reason.push_back(s.ToString());
  }
};

// Raises broadphase.RefusedError for refusals (if any): the items at `index` were refused for
// `reasons`, every other item of the call was applied.
void RaiseIfRefused(const std::string& op, size_t n, Refusals&& r) {
  if (r.index.empty()) return;
  std::string msg = op + ": " + std::to_string(r.index.size()) + " of " + std::to_string(n) +
                    " items refused (the others were applied): ";
  const size_t shown = std::min<size_t>(r.index.size(), 5);
  for (size_t k = 0; k < shown; ++k) {
    if (k != 0) msg += "; ";
    msg += '[';
    msg += std::to_string(r.index[k]);
    msg += "] ";
    msg += r.reason[k];
  }
  if (shown < r.index.size()) msg += "; ...";
  py::object type = py::module_::import("broadphase._broadphase").attr("RefusedError");
  py::object error = type(msg);
  std::vector<uint64_t> idx(r.index.begin(), r.index.end());
  error.attr("indices") = Vector(idx.data(), idx.size());
  error.attr("reasons") = py::cast(std::move(r.reason));
  error.attr("applied") = py::int_(n - idx.size());
  PyErr_SetObject(type.ptr(), error.ptr());
  throw py::error_already_set();
}

class Sink final : public EventSink<uint64_t> {
 public:
  void Collide(const uint64_t& a, const uint64_t& b) override {
    collides.push_back(a);
    collides.push_back(b);
  }
  void Uncollide(const uint64_t& a, const uint64_t& b) override {
    uncollides.push_back(a);
    uncollides.push_back(b);
  }
  std::vector<uint64_t> collides, uncollides;
};

py::dict StatsDict(const Stats& s) {
  py::dict d;
  d["objects"] = s.objects;
  d["overlaps"] = s.overlaps;
  d["inserts"] = s.inserts;
  d["updates"] = s.updates;
  d["erases"] = s.erases;
  d["collides"] = s.collides;
  d["uncollides"] = s.uncollides;
  d["swaps"] = s.swaps;
  d["overlap_tests"] = s.overlap_tests;
  d["global_sort"] = s.global_sort;
  d["rebuilt"] = s.rebuilt;
  d["threads"] = s.threads;
  d["margin"] = s.margin;
  d["fat_skips"] = s.fat_skips;
  d["prepare_ms"] = s.prepare_ms;
  d["core_ms"] = s.core_ms;
  d["events_ms"] = s.events_ms;
  if (s.grid) {
    py::dict g;
    g["cells"] = s.grid->cells;
    g["cells_queried"] = s.grid->cells_queried;
    g["large_objects"] = s.grid->large_objects;
    g["cell_slots"] = s.grid->cell_slots;
    g["cell_size"] = s.grid->cell_size;
    g["worker_cells"] = s.grid->worker_cells;
    g["pool_routed"] = s.grid->pool_routed;
    g["route_ms"] = s.grid->route_ms;
    g["cells_ms"] = s.grid->cells_ms;
    g["fold_ms"] = s.grid->fold_ms;
    d["grid"] = g;
  }
  if (s.segmented_sap) {
    py::dict g;
    g["chunks"] = s.segmented_sap->chunks;
    d["segmented_sap"] = g;
  }
  return d;
}

template <int K, class T>
class EngineOf final : public EngineBase {
 public:
  using Item = KeyedBox<K, T>;
  EngineOf(std::unique_ptr<Broadphase<K, T>> engine, double margin)
      : engine_(std::move(engine)), margin_(margin) {}

  void Insert(const py::handle& keys_obj, const py::handle& lo_obj, const py::handle& hi_obj,
              const py::handle& category, const py::handle& mask,
              const py::handle& is_static) override {
    const std::vector<uint64_t> keys = Keys(keys_obj, "insert: keys");
    const auto n = static_cast<py::ssize_t>(keys.size());
    const std::vector<T> lo = Coords<K, T>(lo_obj, "insert: lo", n);
    const std::vector<T> hi = Coords<K, T>(hi_obj, "insert: hi", n);
    const bool defaults = category.is_none() && mask.is_none() && is_static.is_none();
    std::vector<ObjectOptions> options;
    if (!defaults) {
      const auto cat = PerItemU64(category, "insert: category", keys.size(), 1);
      const auto msk = PerItemU64(mask, "insert: mask", keys.size(), ~uint64_t{0});
      const auto st = PerItemBool(is_static, "insert: static", keys.size());
      options.resize(keys.size());
      for (size_t i = 0; i < keys.size(); ++i) options[i] = {cat[i], msk[i], st[i] != 0};
    }
    std::vector<Item> items(keys.size());
    for (size_t i = 0; i < keys.size(); ++i) items[i] = {keys[i], BoxAt<K, T>(lo, hi, i)};
    Refusals r;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      engine_->InsertMany(items, options, [&](size_t i, const Status& s) { r.Add(i, s); });
    }
    RaiseIfRefused("insert", keys.size(), std::move(r));
  }

  void Update(const py::handle& keys_obj, const py::handle& lo_obj,
              const py::handle& hi_obj) override {
    const std::vector<uint64_t> keys = Keys(keys_obj, "update: keys");
    const auto n = static_cast<py::ssize_t>(keys.size());
    const std::vector<T> lo = Coords<K, T>(lo_obj, "update: lo", n);
    const std::vector<T> hi = Coords<K, T>(hi_obj, "update: hi", n);
    std::vector<Item> items(keys.size());
    for (size_t i = 0; i < keys.size(); ++i) items[i] = {keys[i], BoxAt<K, T>(lo, hi, i)};
    Refusals r;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      engine_->UpdateMany(items, [&](size_t i, const Status& s) { r.Add(i, s); });
    }
    RaiseIfRefused("update", keys.size(), std::move(r));
  }

  void Erase(const py::handle& keys_obj) override {
    const std::vector<uint64_t> keys = Keys(keys_obj, "erase: keys");
    Refusals r;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      engine_->EraseMany(keys, [&](size_t i, const Status& s) { r.Add(i, s); });
    }
    RaiseIfRefused("erase", keys.size(), std::move(r));
  }

  std::pair<py::array, py::array> Query() override {
    Sink sink;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      engine_->Query(sink);
    }
    return {Matrix(sink.collides.data(), sink.collides.size() / 2, 2),
            Matrix(sink.uncollides.data(), sink.uncollides.size() / 2, 2)};
  }

  py::array Overlaps() const override {
    std::vector<std::pair<uint64_t, uint64_t>> pairs;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      engine_->ForEachOverlap([&](uint64_t a, uint64_t b) { pairs.emplace_back(a, b); });
      std::sort(pairs.begin(), pairs.end());
    }
    std::vector<uint64_t> flat;
    flat.reserve(2 * pairs.size());
    for (const auto& [a, b] : pairs) {
      flat.push_back(a);
      flat.push_back(b);
    }
    return Matrix(flat.data(), pairs.size(), 2);
  }

  py::array Overlapping(const py::handle& lo_obj, const py::handle& hi_obj) const override {
    const std::vector<T> lo = Coords<K, T>(lo_obj, "overlapping: lo", 1, true);
    const std::vector<T> hi = Coords<K, T>(hi_obj, "overlapping: hi", 1, true);
    const Box<K, T> box = BoxAt<K, T>(lo, hi, 0);
    if (Status s = ValidateBox(box); !s.ok()) throw py::value_error("overlapping: " + s.ToString());
    std::vector<uint64_t> keys;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      engine_->ForEachOverlapping(box, [&](uint64_t k) { keys.push_back(k); });
      std::sort(keys.begin(), keys.end());
    }
    return Vector(keys.data(), keys.size());
  }

  py::array Keys_() const override {
    std::vector<uint64_t> keys;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      engine_->ForEachObject([&](uint64_t k) { keys.push_back(k); });
      std::sort(keys.begin(), keys.end());
    }
    return Vector(keys.data(), keys.size());
  }

  size_t Size() const override {
    py::gil_scoped_release release;  // another thread may hold the engine in a long query
    std::lock_guard lock(mu_);
    return engine_->Size();
  }
  py::dict GetStats() const override {
    Stats s;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      s = engine_->GetStats();
    }
    return StatsDict(s);
  }
  void Validate() const override {
    Status s;
    {
      py::gil_scoped_release release;
      std::lock_guard lock(mu_);
      s = engine_->Validate();
    }
    if (!s.ok()) throw std::runtime_error("validate: " + s.ToString());
  }
  std::string Name() const override { return engine_->Name(); }
  int Dims() const override { return K; }
  std::string Dtype() const override {
    if constexpr (std::is_same_v<T, float>) return "float32";
    if constexpr (std::is_same_v<T, double>) return "float64";
    return "int32";
  }
  double Margin() const override { return margin_; }

 private:
  std::unique_ptr<Broadphase<K, T>> engine_;
  double margin_;
  mutable std::mutex mu_;
};

// A keyword option's value as T, in [lo, hi]: TypeError if it is not a number of T's kind,
// ValueError if it is out of range.
template <class T>
T Option(const std::string& algo, const std::string& name, const py::handle& value, double lo,
         double hi) {
  const std::string where = "Engine: " + algo + " option " + name;
  const bool integral = std::is_integral_v<T>;
  if (PyBool_Check(value.ptr()) ||
      !(integral ? PyLong_Check(value.ptr()) : PyNumber_Check(value.ptr()))) {
    throw py::type_error(where + " must be " + (integral ? "an integer" : "a number") + ", got " +
                         py::repr(value).cast<std::string>());
  }
  const double v = PyFloat_AsDouble(value.ptr());  // an int too (OverflowError beyond doubles)
  if (v == -1.0 && PyErr_Occurred() != nullptr) throw py::error_already_set();
  if (!(v >= lo && v <= hi)) {
    throw py::value_error(where + " is " + py::repr(value).cast<std::string>() +
                          ": expected a value in [" + py::repr(py::float_(lo)).cast<std::string>() +
                          ", " + py::repr(py::float_(hi)).cast<std::string>() + "]");
  }
  return static_cast<T>(v);
}

// Sets spec's options of its algorithm from keyword arguments; TypeError for a name the
// algorithm does not take or a value of the wrong kind, ValueError for one out of range (the
// ranges the engines accept without adjusting the value).
void ApplyOptions(EngineSpec* spec, const py::dict& options) {
  const std::string& algo = spec->algorithm;
  const bool grid = algo.rfind("grid_", 0) == 0;
  std::vector<std::string> known;
  if (grid) known = {"cell_size", "objects_per_cell", "max_cells_per_object", "threads"};
  if (algo == "segmented_sap" || algo == "grid_segmented_sap") {
    known.insert(known.end(), {"chunk_capacity", "global_sort_fraction", "bulk_load_min"});
  }
  if (algo == "batch_sap" || algo == "grid_batch_sap") known.push_back("global_sort_fraction");
  if (algo == "dynamic_octree") known = {"max_objects_per_node", "max_depth"};
  constexpr double kMax32 = 4294967295.0;
  for (const auto& [key, value] : options) {
    const std::string name = py::str(key);
    if (std::find(known.begin(), known.end(), name) == known.end()) {
      std::string list;
      for (const auto& k : known) list += (list.empty() ? "" : ", ") + k;
      throw py::type_error(
          "Engine: " + algo + " has no option '" + name + "'" +
          (known.empty() ? std::string(" (it takes none)") : " (it takes " + list + ")"));
    }
    const auto set_grid = [&](auto& g) {
      if (name == "cell_size") g.cell_size = Option<double>(algo, name, value, 0, 1e300);
      if (name == "objects_per_cell")
        g.objects_per_cell = Option<double>(algo, name, value, 1, 1e9);
      if (name == "max_cells_per_object")
        g.max_cells_per_object = Option<uint32_t>(algo, name, value, 1, 1e6);
      if (name == "threads") g.threads = Option<unsigned>(algo, name, value, 1, 256);
    };
    const auto set_sap = [&](SegmentedSapOptions& o) {
      if (name == "chunk_capacity") {
        o.chunk_capacity = Option<uint32_t>(algo, name, value, 4, 4096);
        if (!std::has_single_bit(o.chunk_capacity)) {
          throw py::value_error("Engine: " + algo + " option chunk_capacity is " +
                                std::to_string(o.chunk_capacity) + ": expected a power of two");
        }
      }
      if (name == "global_sort_fraction")
        o.global_sort_fraction = Option<double>(algo, name, value, 0, 1);
      if (name == "bulk_load_min") o.bulk_load_min = Option<uint32_t>(algo, name, value, 0, kMax32);
    };
    if (algo == "grid_dense") set_grid(spec->grid_dense);
    if (algo == "grid_batch_sap") {
      set_grid(spec->grid_batch_sap);
      if (name == "global_sort_fraction")
        spec->grid_batch_sap.cell.global_sort_fraction = Option<double>(algo, name, value, 0, 1);
    }
    if (algo == "grid_segmented_sap") {
      set_grid(spec->grid_segmented_sap);
      set_sap(spec->grid_segmented_sap.cell);
    }
    if (algo == "segmented_sap") set_sap(spec->segmented_sap);
    if (algo == "batch_sap" && name == "global_sort_fraction")
      spec->batch_sap.global_sort_fraction = Option<double>(algo, name, value, 0, 1);
    if (algo == "dynamic_octree") {
      if (name == "max_objects_per_node")
        spec->dynamic_octree.max_objects_per_node = Option<uint32_t>(algo, name, value, 1, 1e6);
      if (name == "max_depth")
        spec->dynamic_octree.max_depth = Option<uint32_t>(algo, name, value, 1, 64);
    }
  }
}

// "float32", "float64" or "int32" for any spelling numpy accepts (np.float32, "f4", float, ...).
std::string CanonicalDtype(const py::handle& dtype) {
  if (dtype.is_none()) {
    throw py::type_error("Engine: dtype None is not supported (float32, float64 or int32)");
  }
  py::dtype d;
  try {
    d = py::dtype::from_args(py::reinterpret_borrow<py::object>(dtype));
  } catch (const py::error_already_set&) {
    throw py::type_error("Engine: dtype " + py::repr(dtype).cast<std::string>() +
                         " is not a numpy dtype (float32, float64 or int32)");
  }
  const std::string name = py::str(d);
  if (name != "float32" && name != "float64" && name != "int32") {
    throw py::type_error("Engine: dtype " + name + " is not supported (float32, float64 or int32)");
  }
  return name;
}

template <int K, class T>
std::unique_ptr<EngineBase> Make(const EngineSpec& spec, double margin) {
  if constexpr (std::is_integral_v<T>) {
    if (margin > static_cast<double>(std::numeric_limits<T>::max()) ||
        margin != std::floor(margin)) {
      throw py::value_error("Engine: an int32 engine takes an integer margin, got " +
                            std::to_string(margin));
    }
  }
  auto engine = NewEngine<K, T>(spec, static_cast<T>(margin));
  if (!engine) {
    throw py::value_error("Engine: no engine named '" + spec.algorithm + "' (" +
                          EngineAlgorithmList() + ")");
  }
  return std::make_unique<EngineOf<K, T>>(std::move(engine), margin);
}

}  // namespace

std::unique_ptr<EngineBase> NewPythonEngine(const std::string& algorithm, int dims,
                                            const py::handle& dtype, double margin,
                                            const py::dict& options) {
  if (std::find(kEngineAlgorithms.begin(), kEngineAlgorithms.end(), algorithm) ==
      kEngineAlgorithms.end()) {
    throw py::value_error("Engine: no engine named '" + algorithm + "' (" + EngineAlgorithmList() +
                          ")");
  }
  if (dims != 2 && dims != 3) {
    throw py::value_error("Engine: dims must be 2 or 3, got " + std::to_string(dims));
  }
  if (!(margin >= 0) || !std::isfinite(margin)) {
    throw py::value_error("Engine: margin must be finite and >= 0, got " + std::to_string(margin));
  }
  EngineSpec spec;
  spec.algorithm = algorithm;
  ApplyOptions(&spec, options);
  const std::string t = CanonicalDtype(dtype);
  if (t == "float32")
    return dims == 2 ? Make<2, float>(spec, margin) : Make<3, float>(spec, margin);
  if (t == "float64") {
    return dims == 2 ? Make<2, double>(spec, margin) : Make<3, double>(spec, margin);
  }
  return dims == 2 ? Make<2, int32_t>(spec, margin) : Make<3, int32_t>(spec, margin);
}

}  // namespace bp::python
