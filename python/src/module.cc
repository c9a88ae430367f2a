// The extension module broadphase._broadphase; the package broadphase (python/broadphase)
// re-exports it. Engine and its documentation here; the scenes in workload.cc; the client in
// client.cc.
#include <string>

#include "client.h"
#include "engine.h"
#include "workload.h"
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;
using bp::python::EngineBase;

namespace {

// The events of one query: two uint64[m, 2] arrays; unpacks as (collides, uncollides).
struct Events {
  py::array collides, uncollides;
};

constexpr const char* kEngineDoc = R"doc(
An exact broadphase: axis-aligned boxes in, collide and uncollide events out.

    import numpy as np, broadphase
    e = broadphase.Engine("grid_dense", dims=3, dtype="float32")
    e.insert(np.array([1, 2], np.uint64),
             lo=np.array([[0, 0, 0], [1, 0, 0]], np.float32),
             hi=np.array([[1, 1, 1], [2, 1, 1]], np.float32))
    ev = e.query()          # ev.collides == [[1, 2]] (touching faces overlap)
    collides, uncollides = ev

Calls are buffered and checked against the state the object will have at the next query;
query() applies them and returns exactly the pairs whose overlap changed since the last query.
A batch call (insert, update, erase) applies every valid item; if some were refused it then
raises RefusedError, whose ``indices``, ``reasons`` and ``applied`` tell which, why and how many
were kept. Arrays of the wrong shape or kind raise ValueError or TypeError and apply nothing.
Pairs are (smaller key, larger key), sorted. The GIL is released while the engine works; one
engine may be shared by threads (calls are serialised).

Algorithms: brute_force, segmented_sap, batch_sap, dynamic_octree, grid_segmented_sap,
grid_batch_sap, grid_dense (the default and fastest). Options by keyword:
  grid_*: cell_size (0: automatic), objects_per_cell, max_cells_per_object, threads
  segmented_sap, grid_segmented_sap: chunk_capacity, global_sort_fraction, bulk_load_min
  batch_sap, grid_batch_sap: global_sort_fraction
  dynamic_octree: max_objects_per_node, max_depth
)doc";

}  // namespace

PYBIND11_MODULE(_broadphase, m) {
  m.doc() = "The broadphase engines, benchmark scenes and client, fed and read with numpy arrays.";

  // RefusedError(ValueError): items of a batch call refused; the rest applied.
  py::object refused = py::reinterpret_steal<py::object>(PyErr_NewExceptionWithDoc(
      "broadphase.RefusedError",
      "Some items of a batch call were refused; every other item was applied. Attributes: "
      "indices (uint64 array: the refused items' positions in the call), reasons (list of "
      "str, one per index), applied (int: items kept).",
      PyExc_ValueError, nullptr));
  m.attr("RefusedError") = refused;

  py::class_<Events>(m, "Events", "The events of one query: collides and uncollides, uint64[m, 2].")
      .def_readonly("collides", &Events::collides, "Pairs that overlap now and did not before.")
      .def_readonly("uncollides", &Events::uncollides,
                    "Pairs that overlapped before and do not now (or lost an object).")
      .def("__iter__",
           [](const Events& e) { return py::iter(py::make_tuple(e.collides, e.uncollides)); })
      .def("__len__", [](const Events& e) { return e.collides.shape(0) + e.uncollides.shape(0); })
      .def("__repr__", [](const Events& e) {
        return "Events(collides=" + std::to_string(e.collides.shape(0)) +
               ", uncollides=" + std::to_string(e.uncollides.shape(0)) + ")";
      });

  py::class_<EngineBase>(m, "Engine", kEngineDoc)
      .def(py::init([](const std::string& algorithm, int dims, const py::object& dtype,
                       double margin, const py::kwargs& options) {
             return bp::python::NewPythonEngine(algorithm, dims, dtype, margin, options);
           }),
           py::arg("algorithm") = "grid_dense", py::arg("dims") = 3, py::arg("dtype") = "float32",
           py::arg("margin") = 0.0,
           "Engine(algorithm='grid_dense', dims=3, dtype='float32', margin=0.0, **options): "
           "dims 2 or 3; dtype float32, float64 or int32; margin > 0 fattens every box by it "
           "on each side (fewer updates reach the structure; pairs of the fattened boxes).")
      .def(
          "insert",
          [](EngineBase& e, const py::object& keys, const py::object& lo, const py::object& hi,
             const py::object& category, const py::object& mask,
             const py::object& is_static) { e.Insert(keys, lo, hi, category, mask, is_static); },
          py::arg("keys"), py::arg("lo"), py::arg("hi"), py::arg("category") = py::none(),
          py::arg("mask") = py::none(), py::arg("static") = py::none(),
          "Buffers new objects: keys uint64[n], lo and hi [n, dims]. category and mask "
          "(uint64, per item or one for all): a pair is tracked iff each one's category meets "
          "the other's mask; static (bool): static objects never pair with each other. "
          "Refused: a key already present, an invalid box (NaN, infinite, lo > hi).")
      .def(
          "update",
          [](EngineBase& e, const py::object& keys, const py::object& lo, const py::object& hi) {
            e.Update(keys, lo, hi);
          },
          py::arg("keys"), py::arg("lo"), py::arg("hi"),
          "Buffers new boxes for present keys (a later item on a key wins). Refused: an unknown "
          "key, an invalid box.")
      .def(
          "erase", [](EngineBase& e, const py::object& keys) { e.Erase(keys); }, py::arg("keys"),
          "Buffers the removal of present keys; their pairs uncollide at the next query. "
          "Refused: an unknown key, a key named twice.")
      .def(
          "query",
          [](EngineBase& e) {
            auto [c, u] = e.Query();
            return Events{std::move(c), std::move(u)};
          },
          "Applies the buffered calls; returns Events (collides, uncollides), uint64[m, 2] each.")
      .def("overlaps", &EngineBase::Overlaps,
           "Every overlapping pair as of the last query: uint64[p, 2], sorted.")
      .def(
          "overlapping",
          [](const EngineBase& e, const py::object& lo, const py::object& hi) {
            return e.Overlapping(lo, hi);
          },
          py::arg("lo"), py::arg("hi"),
          "The keys whose boxes overlap the box [lo, hi] as of the last query (any options), "
          "sorted: the spot query.")
      .def("keys", &EngineBase::Keys_, "Every present key (live, or inserted since), sorted.")
      .def("stats", &EngineBase::GetStats,
           "Counters of the engine and of its last query (a dict; grid engines add 'grid').")
      .def("validate", &EngineBase::Validate,
           "Checks every invariant of the internal structures; raises RuntimeError on failure.")
      .def("__len__", &EngineBase::Size, "Live objects as of the last query.")
      .def_property_readonly("algorithm", &EngineBase::Name)
      .def_property_readonly("dims", &EngineBase::Dims)
      .def_property_readonly("dtype", [](const EngineBase& e) { return py::dtype(e.Dtype()); })
      .def_property_readonly("margin", &EngineBase::Margin)
      .def("__repr__", [](const EngineBase& e) {
        return "Engine('" + e.Name() + "', dims=" + std::to_string(e.Dims()) + ", dtype='" +
               e.Dtype() + "', objects=" + std::to_string(e.Size()) + ")";
      });

  bp::python::BindWorkload(m);
  bp::python::BindClient(m);
}
