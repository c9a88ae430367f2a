// Helpers that fill UpdateBatch box arrays (struct-of-arrays) and read EventBatch pairs.
//
// Thread safety: free functions on caller-owned messages.
#pragma once

#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "broadphase.pb.h"

#include "bp/box.h"

namespace bp::client {

/// Appends box (float corners) with id to a float-precision array.
template <int K>
void AddBox(wire::BoxArray* array, uint64_t id, const Box<K, float>& box) {
  array->add_ids(id);
  for (int a = 0; a < K; ++a) array->add_lo32(box.lo[static_cast<size_t>(a)]);
  for (int a = 0; a < K; ++a) array->add_hi32(box.hi[static_cast<size_t>(a)]);
}

/// Appends box (double corners) with id to a double-precision array.
template <int K>
void AddBox(wire::BoxArray* array, uint64_t id, const Box<K, double>& box) {
  array->add_ids(id);
  for (int a = 0; a < K; ++a) array->add_lo64(box.lo[static_cast<size_t>(a)]);
  for (int a = 0; a < K; ++a) array->add_hi64(box.hi[static_cast<size_t>(a)]);
}

/// The pairs of a flattened pair array (a0, b0, a1, b1, ...).
inline std::vector<std::pair<uint64_t, uint64_t>> Pairs(
    const google::protobuf::RepeatedField<uint64_t>& flat) {
  std::vector<std::pair<uint64_t, uint64_t>> out;
  out.reserve(static_cast<size_t>(flat.size()) / 2);
  for (int i = 0; i + 1 < flat.size(); i += 2) out.emplace_back(flat[i], flat[i + 1]);
  return out;
}

}  // namespace bp::client
