// broadphase.Scene and broadphase.golden: the benchmark scenes of docs/WORKLOADS.md
// (bp::workload::Scene), frame by frame as numpy arrays, and their golden values.
#include "workload.h"

#include <string>
#include <vector>

#include "arrays.h"
#include <pybind11/stl.h>

#include "bp/workload.h"
#include "bp/workload_scenarios.h"

namespace bp::python {
namespace {

std::string GoldenNames() {
  std::string s;
  for (const auto& g : workload::kGoldenScenarios)
    s += (s.empty() ? "" : ", ") + std::string(g.name);
  return s;
}

// keys uint64[n], lo and hi float32[n, dim] of boxes.
py::tuple Boxes(const std::vector<workload::SceneBox>& boxes, int dim) {
  const size_t n = boxes.size(), k = static_cast<size_t>(dim);
  std::vector<uint64_t> keys(n);
  std::vector<float> lo(n * k), hi(n * k);
  for (size_t i = 0; i < n; ++i) {
    keys[i] = boxes[i].id;
    for (size_t a = 0; a < k; ++a) {
      lo[i * k + a] = boxes[i].lo[a];
      hi[i * k + a] = boxes[i].hi[a];
    }
  }
  return py::make_tuple(Vector(keys.data(), n), Matrix(lo.data(), n, k), Matrix(hi.data(), n, k));
}

class PyScene {
 public:
  explicit PyScene(const workload::SceneParams& p) : scene_(p) {}
  py::tuple Initial() const { return Boxes(scene_.Initial(), scene_.dim()); }
  py::dict NextFrame() {
    {
      py::gil_scoped_release release;
      scene_.NextFrame(&ops_);
    }
    py::dict d;
    d["erase"] = Vector(ops_.erases.data(), ops_.erases.size());
    py::tuple u = Boxes(ops_.updates, scene_.dim());
    d["update_keys"] = u[0];
    d["update_lo"] = u[1];
    d["update_hi"] = u[2];
    py::tuple in = Boxes(ops_.inserts, scene_.dim());
    d["insert_keys"] = in[0];
    d["insert_lo"] = in[1];
    d["insert_hi"] = in[2];
    return d;
  }
  const workload::Scene& scene() const { return scene_; }

 private:
  workload::Scene scene_;
  workload::FrameOps ops_;
};

}  // namespace

void BindWorkload(py::module_& m) {
  py::class_<PyScene>(m, "Scene", R"doc(
A benchmark scene of docs/WORKLOADS.md: cubes in a cube, some moving at constant speed and
bouncing off the walls, some replaced every frame (churn). Deterministic for a seed; with the
default seed the golden values (``golden(name)``) hold.

    scene = broadphase.Scene("S1-10k")
    keys, lo, hi = scene.initial()        # frame 0: uint64[n], float32[n, dims] twice
    frame = scene.next_frame()            # dict of arrays: erase, update_keys/lo/hi,
                                          # insert_keys/lo/hi (apply in that order)
)doc")
      .def(py::init([](const std::string& name, py::object seed) {
             const auto* g = workload::FindGolden(name);
             if (g == nullptr) {
               throw py::value_error("Scene: no scenario named '" + name + "' (" + GoldenNames() +
                                     ")");
             }
             workload::SceneParams p = g->Params();
             if (!seed.is_none()) p.seed = IntArg(seed, "Scene: seed", 0, ~uint64_t{0});
             return new PyScene(p);
           }),
           py::arg("name"), py::arg("seed") = py::none(),
           "The golden scenario `name` (S2a, S2b, S2c, S1-10k, S1-100k, S1-200k, S3, S4, 2-D).")
      .def(py::init([](uint32_t n, uint32_t moving, uint32_t churn, int dims, uint64_t seed) {
             if (dims != 2 && dims != 3) throw py::value_error("Scene: dims must be 2 or 3");
             if (moving > n || churn > n) {
               throw py::value_error("Scene: moving and churn must be at most n");
             }
             workload::SceneParams p;
             p.n = n;
             p.moving = moving;
             p.churn = churn;
             p.dim = dims;
             p.seed = seed;
             return new PyScene(p);
           }),
           py::kw_only(), py::arg("n"), py::arg("moving"), py::arg("churn"), py::arg("dims") = 3,
           py::arg("seed") = 12345,
           "A scene of n cubes, `moving` of them moving, `churn` replaced per frame.")
      .def("initial", &PyScene::Initial,
           "Frame 0: (keys uint64[n], lo float32[n, dims], hi float32[n, dims]), in key order.")
      .def("next_frame", &PyScene::NextFrame,
           "The next frame's operations, to apply as erases, then updates, then inserts: a dict "
           "of erase (uint64[e]), update_keys, update_lo, update_hi, insert_keys, insert_lo, "
           "insert_hi.")
      .def_property_readonly("dims", [](const PyScene& s) { return s.scene().dim(); })
      .def_property_readonly(
          "side", [](const PyScene& s) { return s.scene().side(); },
          "The side of the environment cube.")
      .def_property_readonly("n", [](const PyScene& s) { return s.scene().params().n; });

  m.def(
      "golden",
      [](const std::string& name) {
        const auto* g = workload::FindGolden(name);
        if (g == nullptr) {
          throw py::value_error("golden: no scenario named '" + name + "' (" + GoldenNames() + ")");
        }
        py::dict d;
        d["name"] = std::string(g->name);
        d["dims"] = g->dim;
        d["n"] = g->n;
        d["moving"] = g->moving;
        d["churn"] = g->churn;
        d["frames"] = g->frames;
        d["pairs_frame0"] = g->pairs_frame0;
        d["pairs_end"] = g->pairs_end;
        d["collides"] = g->collides;
        d["uncollides"] = g->uncollides;
        d["set_hash_end"] = g->set_hash_end;
        d["chain"] = g->chain;
        return d;
      },
      py::arg("name"),
      "The golden values of scenario `name` (docs/WORKLOADS.md): pairs at frame 0 and at the end, "
      "collide and uncollide events over the frames, the set hash at the end and the chain.");

  m.def(
      "set_hash",
      [](const py::handle& pairs_obj) {
        py::array a = AsArray(pairs_obj, "set_hash: pairs");
        if (a.ndim() != 2 || a.shape(1) != 2) {
          throw py::value_error("set_hash: expected pairs of shape (n, 2), got " + ShapeOf(a));
        }
        std::vector<uint64_t> flat = Keys(a.reshape({a.shape(0) * 2}), "set_hash: pairs");
        workload::SetHash h;
        for (size_t i = 0; i + 1 < flat.size(); i += 2) {
          if (flat[i] >> 32 != 0 || flat[i + 1] >> 32 != 0) {
            throw py::value_error("set_hash: pair " + std::to_string(i / 2) +
                                  " has an id of 2**32 or more (the set hash packs two ids "
                                  "below 2**32)");
          }
          h.Collide(flat[i], flat[i + 1]);
        }
        return h.value();
      },
      py::arg("pairs"),
      "The set hash of docs/WORKLOADS.md of a set of pairs (uint64[n, 2], ids below 2**32).");
}

}  // namespace bp::python
