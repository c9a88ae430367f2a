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

// The numpy kind letter of an array's dtype: 'i', 'u', 'f', 'b', 'c', 'O', ...
inline char KindOf(const py::array& a) { return a.dtype().kind(); }

inline std::string ShapeOf(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t d = 0; d < a.ndim(); ++d) {
    if (d != 0) s += ", ";
    s += std::to_string(a.shape(d));
  }
  return s + (a.ndim() == 1 ? ",)" : ")");
}

inline std::string DtypeName(const py::array& a) { return py::str(a.dtype()).cast<std::string>(); }

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
  if (kind != 'i' && kind != 'u') {
    throw py::type_error(what + ": keys must be integers (uint64), got dtype " + DtypeName(a));
  }
  std::vector<uint64_t> out(static_cast<size_t>(a.shape(0)));
  if (kind == 'i') {
    auto s = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(a);
    const int64_t* p = s.data();
    for (size_t i = 0; i < out.size(); ++i) {
      if (p[i] < 0) {
        throw py::value_error(what + "[" + std::to_string(i) + "] is " + std::to_string(p[i]) +
                              ": keys are unsigned 64-bit integers");
      }
      out[i] = static_cast<uint64_t>(p[i]);
    }
  } else {
    auto s = py::array_t<uint64_t, py::array::c_style | py::array::forcecast>::ensure(a);
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
  if (kind != 'b' && kind != 'i' && kind != 'u') {
    throw py::type_error(what + ": expected booleans, got dtype " + DtypeName(a));
  }
  auto s = py::array_t<bool, py::array::c_style | py::array::forcecast>::ensure(a);
  if (s.ndim() == 0) return std::vector<uint8_t>(n, s.data()[0] ? 1 : 0);
  if (s.ndim() != 1 || static_cast<size_t>(s.shape(0)) != n) {
    throw py::value_error(what + ": expected " + std::to_string(n) + " flags, got shape " +
                          ShapeOf(a));
  }
  std::vector<uint8_t> out(n);
  for (size_t i = 0; i < n; ++i) out[i] = s.data()[i] ? 1 : 0;
  return out;
}

// Coordinates of n boxes with k axes as T: an array of shape (n, k) (n == -1: any n; a single
// box may be given as shape (k,) when single is true).
template <class T>
std::vector<T> CoordsOf(const py::handle& obj, const std::string& what, py::ssize_t n, int k,
                        bool single = false) {
  py::array a = AsArray(obj, what);
  if (single && a.ndim() == 1) a = a.reshape({py::ssize_t{1}, a.shape(0)});
  if (a.ndim() != 2 || a.shape(1) != k || (n >= 0 && a.shape(0) != n)) {
    const std::string rows = n >= 0 ? std::to_string(n) : std::string("n");
    throw py::value_error(what + ": expected shape (" + (single ? std::string("") : rows + ", ") +
                          std::to_string(k) + ")" + ", got " + ShapeOf(a));
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
  if constexpr (std::is_floating_point_v<T>) {
    if (kind != 'f' && kind != 'i' && kind != 'u') {
      throw py::type_error(what + ": coordinates must be real numbers, got dtype " + DtypeName(a));
    }
    auto s = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(a);
    std::copy(s.data(), s.data() + count, out.begin());
  } else {
    if (kind != 'i' && kind != 'u') {
      throw py::type_error(what +
                           ": an engine of int32 coordinates takes integer arrays, got dtype " +
                           DtypeName(a));
    }
    if (kind == 'u') {
      auto u = py::array_t<uint64_t, py::array::c_style | py::array::forcecast>::ensure(a);
      for (size_t i = 0; i < count; ++i) {
        if (u.data()[i] > static_cast<uint64_t>(std::numeric_limits<T>::max())) {
          throw py::value_error(what + at(i) + " is " + std::to_string(u.data()[i]) +
                                ": outside int32");
        }
      }
    }
    auto s = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(a);
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
