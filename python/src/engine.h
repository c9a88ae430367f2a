// The engine behind broadphase.Engine: one interface over the compiled shapes (engine.cc).
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <utility>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

namespace bp::python {

namespace py = pybind11;

class EngineBase {
 public:
  virtual ~EngineBase() = default;
  virtual void Insert(const py::handle& keys, const py::handle& lo, const py::handle& hi,
                      const py::handle& category, const py::handle& mask,
                      const py::handle& is_static) = 0;
  virtual void Update(const py::handle& keys, const py::handle& lo, const py::handle& hi) = 0;
  virtual void Erase(const py::handle& keys) = 0;
  // (collides, uncollides), each uint64[m, 2] in canonical order.
  virtual std::pair<py::array, py::array> Query() = 0;
  virtual py::array Overlaps() const = 0;
  virtual py::array Overlapping(const py::handle& lo, const py::handle& hi) const = 0;
  virtual py::array Keys_() const = 0;
  virtual size_t Size() const = 0;
  virtual py::dict GetStats() const = 0;
  virtual void Validate() const = 0;
  virtual std::string Name() const = 0;
  virtual int Dims() const = 0;
  virtual std::string Dtype() const = 0;
  virtual double Margin() const = 0;
};

// The engine `algorithm` with dims axes, coordinates of dtype (float32, float64 or int32), the
// margin and the algorithm's options (keyword arguments); ValueError or TypeError if any is
// unknown or out of range.
std::unique_ptr<EngineBase> NewPythonEngine(const std::string& algorithm, int dims,
                                            const py::handle& dtype, double margin,
                                            const py::dict& options);

}  // namespace bp::python
