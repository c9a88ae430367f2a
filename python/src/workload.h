// broadphase.Scene, broadphase.golden and broadphase.set_hash (workload.cc).
#pragma once

#include <pybind11/pybind11.h>

namespace bp::python {
void BindWorkload(pybind11::module_& m);
}  // namespace bp::python
