// Conversions between numpy arrays and the engine's items, shared by the module's parts.
//
// Every conversion checks before it copies: an array of the wrong rank, length or kind is
// refused with a TypeError or ValueError naming the argument, the expected shape or kind and the
// one it got, and nothing is applied. Arrays need not be contiguous or of the exact dtype: any
// integer array is taken for keys (negative values refused), any real array for the coordinates
// of a floating-point engine (rounded to its type as numpy's astype would), any integer array
// for an int32 engine (values outside int32 refused). Booleans, complex and object arrays are
// refused.
#pragma once

#include <array>
#include <cstdint>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "bp/box.h"

namespace bp::python {

namespace py = pybind11;

// A numpy array of obj (no copy if it is one), or a TypeError naming `what`.
inline py::array AsArray(const py::handle& obj, const std::string& what) {
  py::array a = py::array::ensure(obj);
  if (!a) throw py::type_error(what + ": expected an array (numpy or a sequence of numbers)");
  return a;
}

// The numpy kind letter of an array's dtype: 'i', 'u', 'f', 'b', 'c', 'O', ...; an empty array
// counts as any kind ('-': a Python [] arrives as float64).
inline char KindOf(const py::array& a) { return a.size() == 0 ? '-' : a.dtype().kind(); }

// a as a C-contiguous array of T (a copy if it is not one already); numpy's own error (an
// overflow under np.seterr(over='raise'), say) is raised as it is.
template <class T>
py::array_t<T, py::array::c_style | py::array::forcecast> As(const py::array& a) {
  return py::array_t<T, py::array::c_style | py::array::forcecast>(a);
}

inline std::string ShapeOf(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t d = 0; d < a.ndim(); ++d) {
    if (d != 0) s += ", ";
    s += std::to_string(a.shape(d));
  }
  return s + (a.ndim() == 1 ? ",)" : ")");
}

inline std::string DtypeName(const py::array& a) { return py::str(a.dtype()).cast<std::string>(); }

// A Python integer argument in [lo, hi]: TypeError if it is not an integer, ValueError if it is
// out of range.
inline uint64_t IntArg(const py::handle& obj, const std::string& what, uint64_t lo, uint64_t hi) {
  if (!PyLong_Check(obj.ptr()) || PyBool_Check(obj.ptr())) {
    throw py::type_error(what + " must be an integer, got " + py::repr(obj).cast<std::string>());
  }
  int overflow = 0;
  const long long v = PyLong_AsLongLongAndOverflow(obj.ptr(), &overflow);
  uint64_t u = 0;
  bool ok = overflow == 0 && v >= 0;
  if (ok) {
    u = static_cast<uint64_t>(v);
  } else if (overflow > 0) {
    u = PyLong_AsUnsignedLongLong(obj.ptr());
    ok = !(u == ~uint64_t{0} && PyErr_Occurred() != nullptr);
    PyErr_Clear();
  }
  if (!ok || u < lo || u > hi) {
    throw py::value_error(what + " is " + py::repr(obj).cast<std::string>() +
                          ": expected an integer in [" + std::to_string(lo) + ", " +
                          std::to_string(hi) + "]");
  }
  return u;
}

// keys as uint64 values: a 1-D integer array (n == -1: any length).
inline std::vector<uint64_t> Keys(const py::handle& obj, const std::string& what,
                                  py::ssize_t n = -1) {
  py::array a = AsArray(obj, what);
  if (a.ndim() != 1) {
    throw py::value_error(what + ": expected a 1-D array of keys, got shape " + ShapeOf(a));
  }
  if (n >= 0 && a.shape(0) != n) {
    throw py::value_error(what + ": expected " + std::to_string(n) + " keys, got " +
                          std::to_string(a.shape(0)));
  }
  const char kind = KindOf(a);
  if (kind != 'i' && kind != 'u' && kind != '-') {
    throw py::type_error(what + ": expected unsigned 64-bit integers, got dtype " + DtypeName(a));
  }
  std::vector<uint64_t> out(static_cast<size_t>(a.shape(0)));
  if (out.empty()) return out;
  if (kind == 'i') {
    auto s = As<int64_t>(a);
    const int64_t* p = s.data();
    for (size_t i = 0; i < out.size(); ++i) {
      if (p[i] < 0) {
        throw py::value_error(what + "[" + std::to_string(i) + "] is " + std::to_string(p[i]) +
                              ": expected an unsigned 64-bit integer");
      }
      out[i] = static_cast<uint64_t>(p[i]);
    }
  } else {
    auto s = As<uint64_t>(a);
    std::copy(s.data(), s.data() + out.size(), out.begin());
  }
  return out;
}

// Per-item uint64 values (categories, masks): None (fill), a scalar (all) or n values.
inline std::vector<uint64_t> PerItemU64(const py::handle& obj, const std::string& what, size_t n,
                                        uint64_t fill) {
  if (obj.is_none()) return std::vector<uint64_t>(n, fill);
  py::array a = AsArray(obj, what);
  if (a.ndim() == 0) {
    std::vector<uint64_t> one = Keys(a.reshape({1}), what);
    return std::vector<uint64_t>(n, one[0]);
  }
  return Keys(a, what, static_cast<py::ssize_t>(n));
}

// Per-item flags: None (all false), a scalar, or n booleans (or 0/1 integers).
inline std::vector<uint8_t> PerItemBool(const py::handle& obj, const std::string& what, size_t n) {
  if (obj.is_none()) return std::vector<uint8_t>(n, 0);
  py::array a = AsArray(obj, what);
  const char kind = KindOf(a);
  if (kind != 'b' && kind != 'i' && kind != 'u' && kind != '-') {
    throw py::type_error(what + ": expected booleans, got dtype " + DtypeName(a));
  }
  if (a.ndim() > 1 || (a.ndim() == 1 && static_cast<size_t>(a.shape(0)) != n)) {
    throw py::value_error(what + ": expected " + std::to_string(n) + " flags, got shape " +
                          ShapeOf(a));
  }
  std::vector<uint8_t> out(n);
  if (a.size() == 0) return out;
  auto s = As<int64_t>(a);
  for (size_t i = 0; i < n; ++i) {
    const int64_t v = s.data()[a.ndim() == 0 ? 0 : i];
    if (v != 0 && v != 1) {
      throw py::value_error(what + "[" + std::to_string(i) + "] is " + std::to_string(v) +
                            ": expected a boolean (or 0 or 1)");
    }
    out[i] = static_cast<uint8_t>(v);
  }
  return out;
}

// Coordinates of n boxes with k axes as T: an array of shape (n, k) (n == -1: any n; a single
// box may be given as shape (k,) when single is true).
template <class T>
std::vector<T> CoordsOf(const py::handle& obj, const std::string& what, py::ssize_t n, int k,
                        bool single = false) {
  py::array a = AsArray(obj, what);
  const std::string given = ShapeOf(a);
  if (!single && n <= 0 && a.ndim() == 1 && a.size() == 0) return {};  // [] for no boxes
  if (single && a.ndim() == 1) a = a.reshape({py::ssize_t{1}, a.shape(0)});
  if (a.ndim() != 2 || a.shape(1) != k || (n >= 0 && a.shape(0) != n)) {
    const std::string rows = n >= 0 ? std::to_string(n) : std::string("n");
    const std::string kk = std::to_string(k);
    throw py::value_error(
        what + ": expected shape " +
        (single ? "(" + kk + ",) or (1, " + kk + ")" : "(" + rows + ", " + kk + ")") + ", got " +
        given);
  }
  const char kind = KindOf(a);
  const size_t count = static_cast<size_t>(a.shape(0)) * static_cast<size_t>(k);
  const auto at = [&](size_t i) {  // "[row, axis]" (appended piece by piece: g++ 12 warns of
                                   // a bogus overlap in "[" + std::string)
    std::string s(1, '[');
    s += std::to_string(i / static_cast<size_t>(k));
    s += ", ";
    s += std::to_string(i % static_cast<size_t>(k));
    s += ']';
    return s;
  };
  std::vector<T> out(count);
  if (count == 0) return out;
  if constexpr (std::is_floating_point_v<T>) {
    if (kind != 'f' && kind != 'i' && kind != 'u') {
      throw py::type_error(what + ": coordinates must be real numbers, got dtype " + DtypeName(a));
    }
    auto s = As<T>(a);
    std::copy(s.data(), s.data() + count, out.begin());
  } else {
    if (kind != 'i' && kind != 'u') {
      throw py::type_error(what +
                           ": an engine of int32 coordinates takes integer arrays, got dtype " +
                           DtypeName(a));
    }
    if (kind == 'u') {
      auto u = As<uint64_t>(a);
      for (size_t i = 0; i < count; ++i) {
        if (u.data()[i] > static_cast<uint64_t>(std::numeric_limits<T>::max())) {
          throw py::value_error(what + at(i) + " is " + std::to_string(u.data()[i]) +
                                ": outside int32");
        }
      }
    }
    auto s = As<int64_t>(a);
    for (size_t i = 0; i < count; ++i) {
      const int64_t v = s.data()[i];
      if (v < std::numeric_limits<T>::lowest() || v > std::numeric_limits<T>::max()) {
        throw py::value_error(what + at(i) + " is " + std::to_string(v) + ": outside int32");
      }
      out[i] = static_cast<T>(v);
    }
  }
  return out;
}
template <int K, class T>
std::vector<T> Coords(const py::handle& obj, const std::string& what, py::ssize_t n,
                      bool single = false) {
  return CoordsOf<T>(obj, what, n, K, single);
}

// The boxes of lo and hi rows (both from Coords).
template <int K, class T>
Box<K, T> BoxAt(const std::vector<T>& lo, const std::vector<T>& hi, size_t i) {
  Box<K, T> b;
  for (size_t a = 0; a < K; ++a) {
    b.lo[a] = lo[i * K + a];
    b.hi[a] = hi[i * K + a];
  }
  return b;
}

// A new C-contiguous array of shape (rows, cols) holding data.
template <class T>
py::array_t<T> Matrix(const T* data, size_t rows, size_t cols) {
  py::array_t<T> out({static_cast<py::ssize_t>(rows), static_cast<py::ssize_t>(cols)});
  if (rows * cols != 0) std::copy(data, data + rows * cols, out.mutable_data());
  return out;
}
template <class T>
py::array_t<T> Vector(const T* data, size_t n) {
  py::array_t<T> out(static_cast<py::ssize_t>(n));
  if (n != 0) std::copy(data, data + n, out.mutable_data());
  return out;
}

}  // namespace bp::python
