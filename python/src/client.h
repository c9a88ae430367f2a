// broadphase's client classes (client.cc).
#pragma once

#include <pybind11/pybind11.h>

namespace bp::python {
void BindClient(pybind11::module_& m);
}  // namespace bp::python
