// The benchmark scene's frames (bp/workload.h) as update batches (broadphase.proto): what
// `bpctl scene` publishes and the service tests feed the daemon. Apart from the client library,
// which needs no scene generator.
//
// Thread safety: free functions on caller-owned messages.
#pragma once

#include <cstdint>

#include "broadphase.pb.h"

#include "bp/workload.h"

namespace bp::tools {

/// Appends a scene box's first dim axes (float precision).
inline void AddSceneBox(wire::BoxArray* array, const workload::SceneBox& box, int dim) {
  array->add_ids(box.id);
  for (int a = 0; a < dim; ++a) array->add_lo32(box.lo[static_cast<size_t>(a)]);
  for (int a = 0; a < dim; ++a) array->add_hi32(box.hi[static_cast<size_t>(a)]);
}

/// Fills batch (cleared of boxes first) with a scene frame: erases, updates and inserts.
inline void FillSceneFrame(const workload::FrameOps& ops, int dim, wire::UpdateBatch* batch) {
  batch->mutable_inserts()->Clear();
  batch->mutable_updates()->Clear();
  batch->clear_erases();
  batch->set_dim(static_cast<uint32_t>(dim));
  for (uint64_t id : ops.erases) batch->add_erases(id);
  for (const workload::SceneBox& b : ops.updates) AddSceneBox(batch->mutable_updates(), b, dim);
  for (const workload::SceneBox& b : ops.inserts) AddSceneBox(batch->mutable_inserts(), b, dim);
}

}  // namespace bp::tools
